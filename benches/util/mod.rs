//! Helpers shared by the benchmarks (and examples/solver_instructions.rs, which includes `timing` by path).

pub mod timing;
