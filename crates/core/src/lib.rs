//! voxhap's pure core: volumes and their trilinear sampling ([`volume`]), the haptic modes and the servo tick
//! ([`haptics`], with the exact solver of `voxhap-solver`), and the status words every layer shares
//! ([`status`]). It does no I/O: no files, devices, threads or sockets; everything above it does.

pub mod haptics;
pub mod status;
pub mod volume;

pub use voxhap_solver::clock;
