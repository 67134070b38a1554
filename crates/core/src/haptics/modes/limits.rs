//! The ranges a mode's settings must lie in. Outside them a run is meaningless (strengths and positions so
//! large that the solver's energies and forces overflow, breakpoints whose spans overflow to a NaN strength,
//! friction no material has), so a value outside is refused with its key, the value and the range, wherever
//! the setting comes from (a scenario file, `--set`, a control command). Solve scenes (voxhap-io) use the same
//! strength and coordinate limits.

/// Largest strength a transfer function breakpoint, a support plane or a solve scene's primitive may have
/// (N): a hundred thousand times a haptic device's force.
pub const MAX_STRENGTH_N: f64 = 1e6;

/// Largest size of a coordinate of a support plane's point or a solve scene's position (m).
pub const MAX_COORDINATE_M: f64 = 1e3;

/// Largest friction coefficient `mu` (dimensionless): real materials lie below about 2; at 10 the proxy
/// already sticks wherever the surface pushes.
pub const MAX_FRICTION_MU: f64 = 10.0;

/// Largest power budget of an active (directed-force) mode (W): ten watts is a 10 N push on a hand moving at
/// 1 m/s, beyond any haptic device's continuous output.
pub const MAX_POWER_BUDGET_W: f64 = 10.0;

/// The power budget of an active mode when its `power_budget_w` key is left out (W): 50 mW, a 1 N push on
/// a hand moving with it at 5 cm/s.
pub const DEFAULT_POWER_BUDGET_W: f64 = 0.05;

/// Largest size of a transfer function's data value `x` (in the data's unit): within it the span of two
/// breakpoints, and the distance of any value between them from either, stay finite.
pub const MAX_TRANSFER_VALUE: f64 = 1e300;

/// A number as a reader writes it in an error message: `0.02`, `1000000`, but `1e300` and `1e-9` (Rust's
/// `Display` writes every digit of a large float).
pub fn readable(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e16 {
        format!("{x:.0}")
    } else if x != 0.0 && x.is_finite() && !(1e-3..=1e7).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

#[cfg(test)]
mod tests {
    use super::readable;

    #[test]
    fn numbers_read_as_written() {
        assert_eq!(readable(1e6), "1000000");
        assert_eq!(readable(-1e300), "-1e300");
        assert_eq!(readable(0.5), "0.5");
        assert_eq!(readable(2.5e-9), "2.5e-9");
        assert_eq!(readable(0.0), "0");
        assert_eq!(readable(f64::NAN), "NaN");
        assert_eq!(readable(f64::INFINITY), "inf");
    }
}
