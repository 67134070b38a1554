//! `voxhap sim` with `[local_model]`: the simulated arm as a device whose own loop renders each tick's local model
//! at `rate_hz` (docs/local-model.md). The arm is the default one (0.1 kg, 1 N s/m); its hand (a 50 N/m grip
//! without damping) comes down onto a plane at z = 0 from 10 mm above, reaching it after the device's 0.5 s
//! engage ramp, and holds 3 mm inside. The expected figures come from the analysis, not from the sim: a sampled
//! wall on this arm is passive up to the exact zero-order-hold boundary `exact_boundary(m, b, T, 0)` (2 003 N/m
//! at 1 kHz, 20 003 N/m at 10 kHz; checked against independent values in tests/sim/sweep.rs), and a model
//! carries `serve`'s default force limit of 3 N (docs/safety.md).

use crate::util::sim::voxhap;
use std::ffi::OsStr;
use std::path::Path;
use voxhap::device::sim::zoh_exact::exact_boundary;
use voxhap::haptics::tick::SolverKind;
use voxhap::record::{create_trace_writer, read_trace, Trace, TraceFormat, TraceMeta};
use voxhap::sim::{self, Scenario, SimSummary};

/// The wall scene, without `[local_model]`: `{k}` is the coupling stiffness; the hand's target goes from `{from}`
/// above the plane to `{depth}` inside it (m) in `{path_s}` seconds.
const WALL: &str = r#"
name = "local-model-wall"
duration_s = 3.0
k_n_per_m = {k}
volumes = []

[[modes]]
kind = "support_plane"
point_m = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
strength_n = 50.0

[arm]
mass_kg = 0.1
damping_n_s_per_m = 1.0
workspace = { shape = "unbounded" }

[hand]
stiffness_n_per_m = 50.0
damping_n_s_per_m = 0.0

[path]
kind = "line"
from_m = [0.0, 0.0, {from}]
to_m = [0.0, 0.0, -{depth}]
duration_s = {path_s}
"#;

const LOCAL: &str = "\n[local_model]\nrate_hz = 10000.0\n";

/// 5 000 N/m: 2.5 times the 1 kHz boundary, a quarter of the 10 kHz one.
const K: f64 = 5000.0;

/// The wall at `k` with the hand coming from 10 mm above over 1 s and holding 3 mm inside, with
/// `[local_model]` when `local`.
fn wall(k: f64, local: bool) -> String {
    wall_path(k, 0.01, 0.003, 1.0, local)
}

fn wall_path(k: f64, from_m: f64, depth_m: f64, path_s: f64, local: bool) -> String {
    let mut text = WALL
        .replace("{k}", &format!("{k:?}"))
        .replace("{from}", &format!("{from_m:?}"))
        .replace("{depth}", &format!("{depth_m:?}"))
        .replace("{path_s}", &format!("{path_s:?}"));
    if local {
        text.push_str(LOCAL);
    }
    text
}

/// Runs `text` through the library into `out` (fixed creation time), returning the summary and the trace.
fn run_library(text: &str, out: &Path, format: TraceFormat) -> (SimSummary, Trace) {
    let loaded = Scenario::parse(text, "local-model-wall")
        .unwrap()
        .load(Path::new(""), "local-model-wall")
        .unwrap();
    let mut meta = TraceMeta::new(
        loaded.scene.mode_names().to_vec(),
        loaded.scenario.rate_hz,
        serde_json::to_value(&loaded.scenario).unwrap(),
        loaded.volume_description.clone(),
        SolverKind::Exact.name(),
    );
    meta.created_utc = "2000-01-01T00:00:00Z".to_owned();
    meta.start_utc_ns = 946_684_800_000_000_000;
    let mut writer = create_trace_writer(out, format, &meta).unwrap();
    let summary = sim::run(&loaded, SolverKind::Exact, writer.as_mut(), |_| {}).unwrap();
    writer.finish().unwrap();
    (summary, read_trace(out).unwrap())
}

/// Runs `text` through the `voxhap` binary with `--fail-on active,oscillation`.
fn run_cli(dir: &Path, name: &str, text: &str, extra: &[&str]) -> std::process::Output {
    let scene = dir.join(format!("{name}.toml"));
    std::fs::write(&scene, text).unwrap();
    let out = dir.join(format!("{name}.csv"));
    let mut args = vec![
        OsStr::new("sim"),
        scene.as_os_str(),
        OsStr::new("--out"),
        out.as_os_str(),
    ];
    args.extend(extra.iter().map(OsStr::new));
    voxhap(&args)
}

#[test]
fn a_wall_beyond_the_1_khz_bound_bounces_with_the_host_alone_and_holds_with_a_10_khz_device_loop() {
    let host = exact_boundary(0.1, 1.0, 1e-3, 0);
    let device = exact_boundary(0.1, 1.0, 1e-4, 0);
    assert!(K > 2.0 * host && K < device / 4.0, "{host} {device}");
    let dir = tempfile::tempdir().unwrap();
    let fail_on = ["--fail-on", "active,oscillation"];

    let alone = run_cli(dir.path(), "alone", &wall(K, false), &fail_on);
    let stderr = String::from_utf8_lossy(&alone.stderr);
    assert_eq!(alone.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("oscillation: "), "{stderr}");

    let local = run_cli(dir.path(), "local", &wall(K, true), &fail_on);
    let stderr = String::from_utf8_lossy(&local.stderr);
    let stdout = String::from_utf8_lossy(&local.stdout);
    assert!(local.status.success(), "{stderr}\n{stdout}");
    // Within the device loop's bound: no warning; the summary names the loop.
    assert!(!stderr.contains("warning"), "{stderr}");
    assert!(
        stdout.contains("(3 s at 1000 Hz, device loop at 10000 Hz)"),
        "{stdout}"
    );
}

#[test]
fn two_runs_with_a_device_loop_write_identical_traces() {
    let dir = tempfile::tempdir().unwrap();
    let text = wall(K, true);
    for format in [TraceFormat::Csv, TraceFormat::Mcap] {
        let a = dir.path().join(format!("a.{format}"));
        let b = dir.path().join(format!("b.{format}"));
        run_library(&text, &a, format);
        run_library(&text, &b, format);
        assert!(
            std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
            "{format} traces differ"
        );
    }
}

/// The hand's target comes from 30 mm above (reaching the plane after the engage ramp, at 0.63 s) to 65 mm inside
/// it: its 50 N/m grip pushes with 3.25 N at the plane, more than the model's 3 N limit, so the device's clamp
/// holds the force at 3 N and the arm sinks until the grip pushes 3 N, 5 mm in (where the plane, 50 N strong,
/// still holds the proxy: 5 000 N/m x 5 mm = 25 N).
/// The trace carries what the device reported: its proxy on the plane while the probe is inside, the model of
/// the tick before (the lockstep LocalState follows the state the tick's model asked for, and reports the
/// loop's last cycle before it: 9 cycles of 100 us after the model arrived).
#[test]
fn the_device_loop_never_exceeds_the_models_force_limit_and_its_report_fills_the_trace() {
    const LIMIT_N: f64 = 3.0;
    let dir = tempfile::tempdir().unwrap();
    let (summary, trace) = run_library(
        &wall_path(K, 0.03, 0.065, 2.0, true),
        &dir.path().join("t.csv"),
        TraceFormat::Csv,
    );
    // The applied force, every cycle: the clamp binds (f32 rounding aside) and is never exceeded.
    assert!(
        summary.max_force_n <= LIMIT_N + 1e-6 && summary.max_force_n > LIMIT_N - 1e-3,
        "{summary:?}"
    );
    let last = trace.samples.last().unwrap();
    assert!(
        (last.probe_m.z + 0.005).abs() < 2e-4,
        "the arm rests where the grip pushes 3 N: {:?}",
        last.probe_m
    );
    let mut inside = 0;
    for sample in &trace.samples {
        assert!(
            sample.sent_force_n.length() <= LIMIT_N + 1e-6,
            "tick {}: {}",
            sample.tick,
            sample.sent_force_n
        );
        if sample.tick == 0 {
            // No report names a model before the first one was rendered.
            assert!(sample.truth.device_local.is_none());
            continue;
        }
        let local = sample
            .truth
            .device_local
            .unwrap_or_else(|| panic!("tick {}: no device report", sample.tick));
        assert!(local.proxy_m.is_finite() && local.proxy_bound_m.is_finite());
        assert_eq!(u64::from(local.model_sequence), sample.tick);
        assert!((local.model_age_s - 9e-4).abs() < 1e-9, "{local:?}");
        if sample.probe_m.z < -1e-4 {
            // Inside the plane the device's proxy is on it (the model's offsets are whole micrometres).
            assert!(
                local.proxy_m.z.abs() <= 1e-6,
                "tick {}: {local:?}",
                sample.tick
            );
            inside += 1;
        }
    }
    assert!(inside > 1000, "{inside} ticks inside");
}

/// The stiffness warning and `--fail-on beyond-bound` weigh the stiffness against the bound of the loop that
/// closes the contact: with `[local_model]` the device's, b / (T/2) = 1 / (50 us) = 20 000 N/m at 10 kHz.
#[test]
fn the_stiffness_warning_uses_the_device_loops_rate() {
    let dir = tempfile::tempdir().unwrap();
    let refused = run_cli(
        dir.path(),
        "stiff",
        &wall(25_000.0, true),
        &["--fail-on", "beyond-bound"],
    );
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("k_n_per_m = 25000 N/m is above the arm's passivity bound in the device's 10000 Hz loop")
            && stderr.contains("stiffness cap 20000 N/m")
            && stderr.contains("period 0.1 ms"),
        "{stderr}"
    );
    assert!(!dir.path().join("stiff.csv").exists());
}

/// A local model carries the stiffness in whole N/m in 16 bits: a scene above 65 535 N/m is refused, naming the
/// key, rather than sent saturated.
#[test]
fn a_stiffness_no_local_model_can_carry_is_refused() {
    let error = Scenario::parse(&wall(70_000.0, true), "w").unwrap_err();
    let message = error.to_string();
    assert!(
        message.contains("k_n_per_m: 70000 N/m is above the 65535 N/m a local model carries"),
        "{message}"
    );
    // Without the table the scene file's own range applies.
    assert!(Scenario::parse(&wall(70_000.0, false), "w").is_ok());
}

/// 15 000 N/m with the 10 kHz device loop: below the loop's exact boundary (20 003 N/m), so the contact's bounce
/// decays, slowly (the net damping `b − K T/2` is 0.25 N s/m), and repeats many times in quick succession
/// before it settles. It is not a limit cycle: `--fail-on oscillation` is not met. The undecaying bounce of the
/// 1 kHz host alone at 5 000 N/m is one (the first test of this file).
#[test]
fn a_slowly_decaying_bounce_below_the_device_loops_boundary_is_not_an_oscillation() {
    const STIFF: f64 = 15_000.0;
    assert!(STIFF < exact_boundary(0.1, 1.0, 1e-4, 0));
    let dir = tempfile::tempdir().unwrap();
    let (summary, trace) = run_library(
        &wall(STIFF, true),
        &dir.path().join("t.csv"),
        TraceFormat::Csv,
    );
    // It bounced: enough contacts in quick succession for the rule to judge, and the penetration decays.
    let energy = summary.energy;
    assert!(
        energy.contacts > 20 && energy.longest_cycle_run >= 9,
        "{energy:?}"
    );
    let deepest = |from_s: f64, to_s: f64| {
        trace
            .samples
            .iter()
            .filter(|s| s.t_s >= from_s && s.t_s < to_s)
            .map(|s| -s.probe_m.z)
            .fold(f64::MIN, f64::max)
    };
    assert!(
        deepest(2.5, 3.0) < 0.5 * deepest(1.0, 1.5),
        "{} {}",
        deepest(1.0, 1.5),
        deepest(2.5, 3.0)
    );
    assert!(!energy.oscillating(), "{energy:?}");
    let out = run_cli(
        dir.path(),
        "decaying",
        &wall(STIFF, true),
        &["--fail-on", "oscillation"],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
