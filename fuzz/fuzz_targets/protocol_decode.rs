//! Fuzz target `protocol_decode`: the device protocol's decoders and sessions, with the body of
//! protocol/fuzz (protocol/tests/protocol/fuzz_body.rs), so .ci/fuzz.sh runs it with the others.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../protocol/tests/protocol/fuzz_body.rs"]
mod fuzz_body;

fuzz_target!(|data: &[u8]| fuzz_body::run(data));
