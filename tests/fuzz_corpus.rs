//! Replays the checked-in corpus of past crashes (fuzz/regressions/TARGET/*) through the cargo-fuzz target
//! bodies (fuzz/bodies.rs), so every input that once crashed, hung or allocated without bound stays fixed in an
//! ordinary `cargo test`, with or without a nightly toolchain. Add a file there for every new fuzz finding.

#[allow(dead_code)] // the fuzz targets use one body each; here all are used through TARGETS
#[path = "../fuzz/bodies.rs"]
mod bodies;

use std::path::Path;
use std::time::{Duration, Instant};

#[test]
fn the_corpus_of_past_crashes_replays_cleanly() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/regressions");
    let mut replayed = 0;
    for (target, body) in bodies::TARGETS {
        let dir = root.join(target);
        let mut entries: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        assert!(!entries.is_empty(), "no corpus for {target}");
        for path in entries {
            let bytes = std::fs::read(&path).unwrap();
            let started = Instant::now();
            body(&bytes);
            // Not a benchmark: a generous bound that only a hang or an unbounded read would exceed.
            assert!(
                started.elapsed() < Duration::from_secs(10),
                "{} took {:?}",
                path.display(),
                started.elapsed()
            );
            replayed += 1;
        }
    }
    assert!(replayed >= bodies::TARGETS.len(), "{replayed} inputs");
}

#[test]
fn every_fuzz_target_has_a_body_and_a_cargo_entry() {
    let manifest =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/Cargo.toml"))
            .unwrap();
    for (target, _) in bodies::TARGETS {
        assert!(
            manifest.contains(&format!("name = \"{target}\"")),
            "fuzz/Cargo.toml has no [[bin]] {target}"
        );
    }
}
