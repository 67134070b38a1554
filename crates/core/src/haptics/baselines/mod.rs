//! Baselines kept for comparison, benchmarks and demonstrations (docs/design.md, "Baselines"):
//!
//! - [`euler`]: the paper's solver (section 4.3), Euler steps on `f_res` with an adaptive step length;
//! - [`constraint`]: the constraint approach (paper section 2, eq. 1-2), whose non-orthogonal artifact the
//!   primitives were invented to remove;
//! - [`force_field`]: plain force functions, `force = f(data)` at the probe with no proxy.
//!
//! None of them is certified; the exact solver ([`voxhap_solver`]) is the reference.

pub mod constraint;
pub mod euler;
pub mod force_field;

use glam::DVec3;
use serde::Serialize;

/// What a baseline returns: the proxy (or, for force functions, the probe), the device force and its effort.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BaselineSolution {
    pub proxy_m: DVec3,
    /// Force sent to the device (N).
    pub force_n: DVec3,
    pub iterations: u32,
    /// `|f_res|` at the answer (N), as the paper's solver measures its own convergence.
    pub residual_n: f64,
}
