//! Numerics `core` lacks on stable without `std`: a square root.
//!
//! Where it sits: at the bottom of the crate, used by the force clamp ([`crate::device`]) and the octahedral
//! direction decoder ([`crate::local`]).

/// Square root for positive finite `x` without `std` (core has no `sqrt` on stable): a bit-level first guess
/// (halved exponent, error below 6 %), then Newton steps `y <- (y + x/y)/2`, each of which squares the relative error;
/// five reach f64 precision.
pub(crate) fn sqrt(x: f64) -> f64 {
    if x <= 0.0 || !x.is_finite() {
        return x.max(0.0);
    }
    let mut y = f64::from_bits((x.to_bits() >> 1) + 0x1FF8_0000_0000_0000);
    for _ in 0..5 {
        y = 0.5 * (y + x / y);
    }
    y
}
