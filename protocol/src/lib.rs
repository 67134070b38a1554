//! voxhap's device wire protocol: no_std, no allocation, sans-IO.
//!
//! The codec lives here so that firmware and host share one implementation. See SPEC.md.
#![no_std]
