//! Integration tests of voxhap-protocol, one binary: test vectors both ways, round trips of every message, the
//! decoder under arbitrary and corrupted input (the cargo-fuzz body, shared), and the device and host sessions
//! talking to each other over real encoded bytes.

mod fuzz_body;
mod local;
mod loopback;
mod robustness;
mod roundtrip;
mod sessions;
mod spec_text;
mod strategies;
mod vectors;
