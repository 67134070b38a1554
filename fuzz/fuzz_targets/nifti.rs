//! Fuzz target `nifti`: arbitrary bytes into `bodies::nifti` (fuzz/bodies.rs, shared with the corpus replay in
//! tests/fuzz_corpus.rs).
#![no_main]

use libfuzzer_sys::fuzz_target;

#[allow(dead_code)] // each target uses one body
#[path = "../bodies.rs"]
mod bodies;

fuzz_target!(|data: &[u8]| bodies::nifti(data));
