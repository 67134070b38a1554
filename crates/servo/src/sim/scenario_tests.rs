//! Tests of `scenario`.

use super::*;
use proptest::prelude::*;

const MINIMAL: &str = r#"
duration_s = 0.5
k_n_per_m = 500.0

[[volumes]]
name = "density"
builtin = "sphere"

[[modes]]
kind = "surface"
volume = "density"
transfer = [[0.45, 0.0], [0.5, 2.0]]

[arm]
mass_kg = 0.1
damping_n_s_per_m = 1.0
workspace = { shape = "unbounded" }

[hand]
stiffness_n_per_m = 300.0
damping_n_s_per_m = 3.0

[path]
kind = "line"
from_m = [0.0, 0.0, 0.045]
to_m = [0.0, 0.0, 0.02]
duration_s = 0.5
"#;

/// The error with its sources, as `voxhap` prints it.
fn chain(err: &dyn std::error::Error) -> String {
    let mut text = err.to_string();
    let mut source = err.source();
    while let Some(inner) = source {
        text = format!("{text}: {inner}");
        source = inner.source();
    }
    text
}

fn error_of(text: &str) -> String {
    Scenario::parse(text, "test.toml").unwrap_err().to_string()
}

#[test]
fn minimal_scenario_parses_and_loads() {
    let scenario = Scenario::parse(MINIMAL, "test.toml").unwrap();
    assert_eq!(scenario.tick_count(), 500);
    assert_eq!(scenario.rate_hz, 1000.0);
    let loaded = scenario.load(Path::new("."), "test.toml").unwrap();
    assert_eq!(loaded.scene.mode_names(), ["surface"]);
    assert_eq!(loaded.start_m, DVec3::new(0.0, 0.0, 0.045));
    assert_eq!(loaded.volume_description, "builtin:sphere");
}

#[test]
fn errors_name_the_key() {
    let typo = MINIMAL.replace("k_n_per_m", "k_n_per_mm");
    assert!(
        error_of(&typo).contains("k_n_per_mm"),
        "{}",
        error_of(&typo)
    );
    let bad_tf = MINIMAL.replace("[[0.45, 0.0], [0.5, 2.0]]", "[[0.5, 0.0], [0.45, 2.0]]");
    let message = error_of(&bad_tf);
    assert!(
        message.contains("modes[0].transfer") && message.contains("x must increase"),
        "{message}"
    );
    let unknown_mode_key =
        MINIMAL.replace("kind = \"surface\"", "kind = \"surface\"\nstiffness = 3");
    assert!(
        error_of(&unknown_mode_key).contains("stiffness"),
        "{}",
        error_of(&unknown_mode_key)
    );
    let negative = MINIMAL.replace("duration_s = 0.5\nk_n", "duration_s = -1.0\nk_n");
    assert!(
        error_of(&negative).starts_with("test.toml: duration_s: must be"),
        "{}",
        error_of(&negative)
    );
    let both = MINIMAL.replace(
        "builtin = \"sphere\"",
        "builtin = \"sphere\"\nfile = \"x.nii\"",
    );
    assert!(error_of(&both).contains("volumes[0]: give one of builtin and file"));
    let missing_arm = MINIMAL.replace("mass_kg = 0.1\n", "");
    assert!(
        error_of(&missing_arm).contains("mass_kg"),
        "{}",
        error_of(&missing_arm)
    );
}

/// A wrong-typed value, an unknown key, a key of another kind or a missing key in any table is
/// refused naming the key's full path (tables chosen by `kind`/`shape` included: device::sim::tagged).
#[test]
fn every_table_names_the_key_in_a_serde_error() {
    let path_line = "[path]\nkind = \"line\"\nfrom_m = [0.0, 0.0, 0.045]\nto_m = [0.0, 0.0, 0.02]\nduration_s = 0.5\n";
    let with_path = |path: &str| MINIMAL.replace(path_line, path);
    let with_workspace =
        |workspace: &str| MINIMAL.replace("workspace = { shape = \"unbounded\" }", workspace);
    let cases: Vec<(String, &str)> = vec![
            (
                MINIMAL.replace("k_n_per_m = 500.0", "k_n_per_m = \"stiff\""),
                "test.toml: k_n_per_m: invalid type: string \"stiff\", expected f64 (line 3, column 13)",
            ),
            (
                format!("{MINIMAL}\n[solver]\nmax_sweeps = \"many\"\n"),
                "test.toml: solver.max_sweeps: invalid type: string \"many\", expected u32 (line ",
            ),
            (
                MINIMAL.replace("builtin = \"sphere\"", "builtin = \"sphere\"\npart = 3"),
                "test.toml: volumes[0].part: wanted string or table (line 8, column 8)",
            ),
            (
                MINIMAL.replace("kind = \"surface\"", "kind = \"surface\"\nenabled = \"yes\""),
                "test.toml: modes[0].enabled: invalid type: string \"yes\", expected a boolean",
            ),
            (
                MINIMAL.replace("mass_kg = 0.1", "mass_kg = \"heavy\""),
                "test.toml: arm.mass_kg: invalid type: string \"heavy\", expected f64",
            ),
            (
                with_workspace("workspace = { shape = \"sphere\", center_m = [0.0, 0.0, 0.0], radius_m = \"big\" }"),
                "test.toml: arm.workspace.radius_m: invalid type: string \"big\", expected f64",
            ),
            (
                with_workspace("workspace = { shape = \"box\", min_m = [0.0, 0.0], max_m = [0.1, 0.1, 0.1] }"),
                "test.toml: arm.workspace.min_m: invalid length 2",
            ),
            (
                with_workspace("workspace = { shape = \"unbounded\", radius = 0.1 }"),
                "test.toml: arm.workspace.radius: unknown field `radius`, expected one of `shape`, `min_m`, `max_m`, `center_m`, `radius_m`",
            ),
            (
                with_workspace("workspace = { shape = \"unbounded\", radius_m = 0.1 }"),
                "test.toml: arm.workspace: shape = \"unbounded\" takes no key `radius_m` (it takes none)",
            ),
            (
                with_workspace("workspace = { shape = \"ball\" }"),
                "test.toml: arm.workspace.shape: unknown variant `ball`, expected one of `box`, `sphere`, `unbounded`",
            ),
            (
                MINIMAL.replace("stiffness_n_per_m = 300.0", "stiffness_n_per_m = [300.0]"),
                "test.toml: hand.stiffness_n_per_m: invalid type: sequence, expected f64",
            ),
            (
                with_path("[path]\nkind = \"waypoints\"\npoints_m = [[0.0, 0.0, 0.04]]\nspeed_m_per_s = \"fast\"\n"),
                "test.toml: path.speed_m_per_s: invalid type: string \"fast\", expected f64",
            ),
            (
                with_path("[path]\nkind = \"waypoints\"\npoints_m = [[0.0, 0.0, 0.04], [0.0, \"y\", 0.0]]\nspeed_m_per_s = 0.1\n"),
                "test.toml: path.points_m[1]",
            ),
            (
                with_path("[path]\nkind = \"raster\"\norigin_m = [0.0, 0.0, 0.0]\nsweep_m = [0.01, 0.0, 0.0]\nstep_m = [0.0, 0.01, 0.0]\nlines = -2\nspeed_m_per_s = 0.1\n"),
                "test.toml: path.lines: invalid value: integer `-2`, expected u32",
            ),
            (
                with_path("[path]\nkind = \"hold\"\nat_m = [0.0, 0.0, 0.04]\nspeed = 2\n"),
                "test.toml: path.speed: unknown field `speed`, expected one of `kind`, `at_m`,",
            ),
            (
                with_path("[path]\nkind = \"hold\"\nat_m = [0.0, 0.0, 0.04]\nradius_m = 0.1\n"),
                "test.toml: path: kind = \"hold\" takes no key `radius_m` (its keys: `at_m`)",
            ),
            (
                with_path("[path]\nkind = \"line\"\nfrom_m = [0.0, 0.0, 0.04]\nto_m = [0.0, 0.0, 0.0]\n"),
                "test.toml: path: missing field `duration_s` (kind = \"line\" needs it)",
            ),
            (
                with_path("[path]\nkind = \"walk\"\n"),
                "test.toml: path.kind: unknown variant `walk`, expected one of `hold`, `line`, `waypoints`, `circle`, `raster`, `force`",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"ramp\"\nfrom_n = [0.0, 0.0, 0.0]\nto_n = [0.0, 0.0, -1.0]\nduration_s = \"slow\"\n"),
                "test.toml: path.profile.duration_s: invalid type: string \"slow\", expected f64",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"constant\"\nforce_n = [0.0, 0.0, -1.0]\nfrequency_hz = 2.0\n"),
                "test.toml: path.profile: shape = \"constant\" takes no key `frequency_hz` (its keys: `force_n`)",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"sine\"\noffset_n = [0.0, 0.0, 0.0]\namplitude_n = [0.0, 0.0, 1.0]\n"),
                "test.toml: path.profile: missing field `frequency_hz` (shape = \"sine\" needs it)",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"constant\"\nforce = [0.0, 0.0, -1.0]\n"),
                "test.toml: path.profile.force: unknown field `force`, expected one of `shape`, `force_n`,",
            ),
        ];
    for (text, expected) in &cases {
        let message = error_of(text);
        assert!(
            message.contains(expected),
            "expected {expected:?}\n     got {message:?}"
        );
        assert!(!message.contains('\n'), "one line: {message:?}");
    }
    // Text rewritten by --set: no line and column (they would point into the rewritten text).
    let edited = Scenario::parse_edited(&cases[0].0, "test.toml (with --set)")
        .unwrap_err()
        .to_string();
    assert_eq!(
        edited,
        "test.toml (with --set): k_n_per_m: invalid type: string \"stiff\", expected f64"
    );
}

/// The error (with its sources) of loading the scenario `text` from the folder `dir`.
fn load_error(text: &str, dir: &str) -> String {
    let err = Scenario::parse(text, "t.toml")
        .unwrap()
        .load(Path::new(dir), "t.toml")
        .unwrap_err();
    chain(&err)
}

#[test]
fn load_errors_name_the_volume_and_mode() {
    let wrong_kind = MINIMAL.replace("builtin = \"sphere\"", "builtin = \"rankine\"");
    let err = load_error(&wrong_kind, ".");
    assert!(
        err.contains("modes[0].volume") && err.contains("vector volume"),
        "{err}"
    );
    let missing_file = MINIMAL.replace("builtin = \"sphere\"", "file = \"no-such.nii.gz\"");
    let err = load_error(&missing_file, "/nonexistent-dir");
    assert!(
        err.contains("volumes[0] (density)") && err.contains("/nonexistent-dir/no-such.nii.gz"),
        "{err}"
    );
    let two_fields = MINIMAL.replace("builtin = \"sphere\"", "builtin = \"density-flow\"");
    let err = load_error(&two_fields, ".");
    assert!(err.contains("set part"), "{err}");
    let bad_arm = MINIMAL.replace("mass_kg = 0.1", "mass_kg = -0.1");
    assert_eq!(
        load_error(&bad_arm, "."),
        "t.toml: simulated arm parameter arm.mass_kg = -0.1 must be finite and > 0"
    );
}

proptest! {
    /// Arbitrary text never panics the parser.
    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,400}") {
        let _ = Scenario::parse(&text, "fuzz.toml");
    }

    /// Mutations of a valid scenario (bytes replaced, cut, or spliced) are parsed or refused, never panic,
    /// and whatever parses also loads or is refused cleanly.
    #[test]
    fn mutated_scenarios_never_panic(
        edits in proptest::collection::vec((0usize..2000, any::<u8>()), 0..6),
        cut in 0usize..2000,
    ) {
        let mut bytes = MINIMAL.as_bytes().to_vec();
        for (at, byte) in edits {
            let at = at % bytes.len();
            bytes[at] = byte;
        }
        bytes.truncate(cut.max(1).min(bytes.len()));
        let text = String::from_utf8_lossy(&bytes);
        if let Ok(scenario) = Scenario::parse(&text, "fuzz.toml") {
            let _ = scenario.load(Path::new("/nonexistent-dir"), "fuzz.toml");
        }
    }
}
