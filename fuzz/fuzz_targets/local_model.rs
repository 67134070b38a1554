//! Fuzz target `local_model`: arbitrary bytes as a LocalModel payload, as the host builder's inputs, and as handle
//! positions for the device-side loop (voxhap-local) running what decoded. The body is
//! crates/local/tests/fuzz_body.rs, which the crate's tests also run under proptest.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../crates/local/tests/fuzz_body.rs"]
mod fuzz_body;

fuzz_target!(|data: &[u8]| fuzz_body::run(data));
