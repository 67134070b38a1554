//! Bisection on a log scale: the boundary between a range where a test holds and one where it fails, when the
//! range spans decades (a stability boundary in stiffness). [`super::zoh_boundary`], `zoh_exact` and the tests
//! of `zoh_boundary` search with it, each with its own stability test.

/// The boundary between `lo` (> 0), where `holds` is true, and `hi` (> `lo`), where it is false, by bisection at
/// the geometric mean until `hi / lo` is at most `1 + rel_tol`, or until `lo` and `hi` are as close as floats get
/// (their mean is one of them; `rel_tol = 0` asks for that). Returns the last `lo`: `holds` is true there, false
/// just above it.
pub fn geometric_bisection(
    mut lo: f64,
    mut hi: f64,
    rel_tol: f64,
    mut holds: impl FnMut(f64) -> bool,
) -> f64 {
    while hi / lo > 1.0 + rel_tol {
        let mid = (lo * hi).sqrt();
        if mid <= lo || mid >= hi {
            break;
        }
        if holds(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

#[cfg(test)]
mod tests {
    use super::geometric_bisection;

    /// `x^3 < 2` from [1, 10]: the cube root of 2, to the float's resolution and to a tolerance, from below.
    #[test]
    fn finds_the_cube_root_of_two() {
        let root = 2f64.cbrt();
        let below_cube_root = |x: f64| x * x * x < 2.0;
        let fine = geometric_bisection(1.0, 10.0, 0.0, below_cube_root);
        assert!(
            below_cube_root(fine) && (fine / root - 1.0).abs() < 1e-15,
            "{fine}"
        );
        let coarse = geometric_bisection(1.0, 10.0, 1e-6, below_cube_root);
        assert!(coarse <= root && root / coarse - 1.0 < 1e-6, "{coarse}");
    }

    /// A threshold twelve decades inside the bracket, as a stiffness boundary is searched for.
    #[test]
    fn finds_a_threshold_across_decades() {
        let found = geometric_bisection(1e-3, 1e9, 0.0, |k| k < 2003.3);
        assert!(
            found < 2003.3 && (found / 2003.3 - 1.0).abs() < 1e-15,
            "{found}"
        );
    }
}
