//! Haptic rendering: primitives, the exact proxy solver and the paper's baselines.
//!
//! Data flow within a tick ([`tick`]): [`modes`] sample volumes at the proxy and emit [`primitive::Primitive`]s;
//! [`solver::Solver`] finds the proxy position that balances them against the coupling `k (proxy - probe)` and
//! certifies it; the coupling force goes to the device. [`baselines`] holds the methods the exact solver is
//! compared with, [`bench_scenes`] the deterministic scenes of tests and benchmarks, and [`reference`] a slow independent minimiser used to validate it. [`scene`] reads the JSON
//! scene files of `voxhap solve`.

pub mod baselines;
pub mod loops;
pub mod modes;
pub mod tick;

pub use voxhap_solver as solver;
pub use voxhap_solver::{bench_scenes, primitive, reference};

pub use primitive::{Primitive, PrimitiveError, PrimitiveKind};
pub use solver::{Problem, Solution, SolveError, SolveStatus, Solver, SolverConfig};
