//! The one `f64` function the solve needs beyond `core`: the square root, from the standard library when it is
//! there (the instruction the std build always used) and from `libm` in a `no_std` build.

#[cfg(feature = "std")]
#[inline(always)]
pub(crate) fn sqrt(x: f64) -> f64 {
    x.sqrt()
}

#[cfg(not(feature = "std"))]
#[inline(always)]
pub(crate) fn sqrt(x: f64) -> f64 {
    libm::sqrt(x)
}
