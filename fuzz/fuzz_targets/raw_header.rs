//! Fuzz target `raw_header`: arbitrary bytes into `bodies::raw_header` (fuzz/bodies.rs, shared with the corpus replay in
//! tests/fuzz_corpus.rs).
#![no_main]

use libfuzzer_sys::fuzz_target;

#[allow(dead_code)] // each target uses one body
#[path = "../bodies.rs"]
mod bodies;

fuzz_target!(|data: &[u8]| bodies::raw_header(data));
