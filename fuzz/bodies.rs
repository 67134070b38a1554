//! The bodies of voxhap's cargo-fuzz targets (fuzz/fuzz_targets/*.rs include this file), also run by the
//! normal test suite (tests/fuzz_corpus.rs replays the checked-in corpus of past crashes through them), so
//! they keep compiling where no nightly toolchain exists.
//!
//! Each body feeds arbitrary bytes to one reader and checks more than "no panic" where it can: what loads
//! has finite values and a finite grid, what parses as a trace obeys the trace rules. Paths given to the
//! loaders are in a folder that does not exist, so a header naming a data file cannot reach a real file.

use std::path::Path;

/// A fuzz target's body.
pub type Body = fn(&[u8]);

/// Every body, by target name (the corpus replay uses this table).
pub const TARGETS: &[(&str, Body)] = &[
    ("nifti", nifti),
    ("nrrd", nrrd),
    ("metaimage", metaimage),
    ("raw_header", raw_header),
    ("csv_trace", csv_trace),
    ("mcap_trace", mcap_trace),
    ("scene_toml", scene_toml),
    ("solve_json", solve_json),
    ("control_json", control_json),
];

const NOWHERE: &str = "/nonexistent-voxhap-fuzz";

fn check_loaded(result: Result<voxhap::volume::io::LoadedVolume, voxhap::volume::io::LoadProblem>) {
    if let Ok(loaded) = result {
        let (min, max) = loaded.volume.value_range();
        assert!(
            min.is_finite() && max.is_finite(),
            "non-finite values loaded"
        );
        let grid = loaded.volume.grid();
        assert!(grid.spacing_m().is_finite(), "non-finite spacing");
        assert!(grid.origin_m().is_finite(), "non-finite origin");
    }
}

/// NIfTI-1, plain and gzipped.
pub fn nifti(data: &[u8]) {
    use voxhap::volume::io::nifti::parse;
    check_loaded(parse(data, false, &Path::new(NOWHERE).join("x.nii")));
    check_loaded(parse(data, true, &Path::new(NOWHERE).join("x.nii.gz")));
}

/// NRRD, attached or detached (the detached file cannot be found).
pub fn nrrd(data: &[u8]) {
    check_loaded(voxhap::volume::io::nrrd::parse(
        data,
        &Path::new(NOWHERE).join("x.nrrd"),
    ));
}

/// MetaImage, inline or detached.
pub fn metaimage(data: &[u8]) {
    check_loaded(voxhap::volume::io::metaimage::parse(
        data,
        &Path::new(NOWHERE).join("x.mha"),
    ));
}

/// A raw volume's TOML header, then its data after the first NUL byte.
pub fn raw_header(data: &[u8]) {
    use voxhap::volume::io::raw::{decode_with_header, parse_header};
    let split = data.iter().position(|&b| b == 0).unwrap_or(data.len());
    if let Ok(header) = parse_header(&data[..split]) {
        let rest = data.get(split + 1..).unwrap_or_default();
        check_loaded(decode_with_header(
            &header,
            rest,
            &Path::new(NOWHERE).join("x.toml"),
        ));
    }
}

fn check_samples(mode_names: &[String], samples: &[voxhap::record::TraceSample]) {
    assert!(mode_names.len() <= voxhap::record::MAX_MODES);
    for pair in samples.windows(2) {
        assert!(pair[0].tick < pair[1].tick, "ticks out of order");
    }
    for sample in samples {
        assert!(sample.sent_force_n.is_finite() && sample.t_s.is_finite());
    }
}

/// A CSV force trace.
pub fn csv_trace(data: &[u8]) {
    if let Ok((mode_names, samples)) = voxhap::record::parse_csv_trace(data) {
        check_samples(&mode_names, &samples);
    }
}

/// An MCAP force trace.
pub fn mcap_trace(data: &[u8]) {
    if let Ok((mode_names, samples)) = voxhap::record::parse_mcap_trace(data) {
        check_samples(&mode_names, &samples);
    }
}

/// A scenario / scene TOML file (`voxhap sim`, `voxhap serve --scene`): parsed and validated, not loaded.
pub fn scene_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(scenario) = voxhap::sim::Scenario::parse(text, "fuzz.toml") {
            assert!(scenario.tick_count() <= voxhap::sim::scenario::MAX_TICKS);
        }
    }
}

/// A `voxhap solve` JSON scene: parsed and validated.
pub fn solve_json(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = voxhap::haptics::scene::Scene::parse(text, "fuzz.json");
    }
}

/// A control request body (REST) and a WebSocket client message.
pub fn control_json(data: &[u8]) {
    use voxhap::server::messages::{decode_client_message, decode_command, parse_json};
    if let Ok(value) = parse_json(data) {
        let _ = decode_command(value);
    }
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = decode_client_message(text);
    }
}
