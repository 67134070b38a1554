//! Fuzz target: arbitrary bytes into every decoder (serial streaming and slice, HID, both directions) and the
//! sessions behind them. The body lives in protocol/tests/protocol/fuzz_body.rs so that the normal test suite runs
//! it too (as a proptest) and it cannot rot where no nightly toolchain is installed.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../tests/protocol/fuzz_body.rs"]
mod fuzz_body;

fuzz_target!(|data: &[u8]| fuzz_body::run(data));
