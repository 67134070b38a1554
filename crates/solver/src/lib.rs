//! The exact proxy solver: the proxy position that minimises the k-strongly convex energy of the primitives and
//! the coupling, with a certificate of its accuracy on every answer. docs/solver.md has the maths ("The maths"),
//! the proof that the bound is honest ("Why the bound never lies") and the measurements behind the choices
//! below ("Design notes and measurements"); docs/design.md puts the solver in context.
//!
//! # The problem
//!
//! With probe `p`, coupling stiffness `k` and the sum of directed forces `d`, put `y = p + d/k`. The proxy
//! minimises `P(x) = k/2 |x - y|^2 + sum_i s_i dist(x, C_i)`, `C_i` the point, line or half-space of primitive
//! `i`. The dual, maximised over `u_i` in `U_i` (a ball, a disc or a segment of size `s_i`), is
//! `D(u) = -|U|^2/(2k) + sum_i u_i.(y - x_i)` with `U = sum_i u_i` and `x(u) = y - U/k`; `-u_i` is the force of
//! primitive `i` on the proxy. For any `x` and feasible `v`, `|x - x*| <= sqrt(2 (P(x) - D(v)) / k)`.
//!
//! # The methods
//!
//! - **Primal Newton** (`newton.rs`) runs first on cold and large solves: O(N) passes, a 3x3 Newton step on the
//!   kinks the proxy is held on, an exact line search over the planes crossed, multipliers recovered at the end.
//! - **Dual method**: block sweeps (each update a closed-form projection onto `U_i`) with an active-set finish
//!   ([`active_set`]) for near-parallel planes. First for small scenes with last tick's structure (at most 16
//!   non-directed primitives: the servo loop's usual tick), and the fallback when Newton does not certify.
//! - The certificate (`certificate.rs`) checks every answer from scratch, whichever method produced it.
//!
//! # Invariants a maintainer must keep
//!
//! - **The bound never lies.** Every reported bound comes from `certificate.rs`, over all primitives, from duals
//!   projected onto *this* tick's sets (a warm start's were projected onto last tick's), with every rounding
//!   error bounded and added, never subtracted. A method may change without touching the certificate; a change
//!   to the certificate keeps each step of docs/solver.md's argument true and passes tests/solver_props.rs.
//! - **Every exit has a point and its bound**: certified, budget exhausted or stalled. An uncertified exit
//!   returns the point of least energy among the start, the best certified point and Newton's last accepted
//!   point (`energy`, exact sum with a rounding bound), and replaces the start only where the energy is lower
//!   by more than both roundings: never worse than where the solve began. A certified solve never takes it.
//! - **Real time.** [`Solver`] owns its workspace: after the first solve with N primitives, solving any scene
//!   of at most N allocates nothing (tests/alloc_free.rs). The budget bounds sweeps and, given a clock,
//!   nanoseconds.

#![cfg_attr(not(feature = "std"), no_std)]

#[cfg(feature = "alloc")]
extern crate alloc;

pub mod active_set;
#[cfg(feature = "std")]
pub mod bench_scenes;
mod certificate;
mod certificate_terms;
pub mod clock;
mod item;
pub mod linalg;
mod math;
mod newton;
pub mod primitive;
mod problem;
#[cfg(feature = "std")]
pub mod reference;
mod solver;
pub mod storage;
mod sum;

pub use primitive::{Primitive, PrimitiveError};
pub use problem::{Problem, Solution, SolveError, SolveStatus, SolverConfig};
pub use solver::{DefaultStorage, Solver};
