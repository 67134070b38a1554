//! voxhap's pure core: volumes and their trilinear sampling ([`volume`]), the haptic modes and the servo tick
//! ([`haptics`], with the exact solver of `voxhap-solver`), and the status words every layer shares
//! ([`status`]), with [`named_enum!`] for enums written as one table of variants and names. It does no
//! I/O: no files, devices, threads or sockets; everything above it does.

pub mod haptics;
mod named_enum;
pub mod status;
pub mod volume;

pub use voxhap_solver::clock;
