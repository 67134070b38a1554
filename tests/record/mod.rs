//! End-to-end tests of the simulated arm and the force traces: a scripted arm run against a stand-in
//! renderer (a floor at z = 0 felt through a proxy), recorded as CSV and MCAP, read back by voxhap, by
//! the `mcap` Python package and by pandas, and plotted with `voxhap plot`.

mod cli;
mod files;

use glam::DVec3;
use std::path::Path;
use std::process::Command;
use voxhap::device::sim::{ArmParams, HandParams, HandPath, SimArm, SimArmConfig, Workspace};
use voxhap::record::{
    create_trace_writer, read_trace, sidecar_path, ModeBreakdown, SolverStatus, TraceFormat,
    TraceMeta, TraceSample, FLAG_WORKSPACE_LIMIT, MAX_MODES,
};

const RATE_HZ: f64 = 1000.0;
const TICKS: u64 = 2500;
const COUPLING_N_PER_M: f64 = 500.0;

fn scenario() -> SimArmConfig {
    SimArmConfig {
        arm: ArmParams {
            mass_kg: 0.12,
            damping_n_s_per_m: 0.8,
            workspace: Workspace::Sphere {
                center_m: DVec3::ZERO,
                radius_m: 0.03,
            },
            substeps_per_tick: 8,
            wall_stiffness_n_per_m: 4000.0,
            wall_damping_n_s_per_m: 5.0,
            effects: Default::default(),
        },
        hand: HandParams {
            stiffness_n_per_m: 300.0,
            damping_n_s_per_m: 4.0,
        },
        // A circle 5 mm below the floor, partly outside the workspace sphere.
        path: HandPath::Circle {
            center_m: DVec3::new(0.0, 0.0, -0.005),
            radius_m: 0.032,
            normal: DVec3::Z,
            period_s: 1.25,
        },
        local_model: None,
    }
}

/// Runs the scenario and returns one sample per tick. The stand-in renderer keeps the proxy on or
/// above the floor z = 0 and couples it to the probe with a spring.
fn run_scenario() -> Vec<TraceSample> {
    let mut arm = SimArm::new(scenario(), DVec3::new(0.032, 0.0, 0.01)).unwrap();
    let dt_s = 1.0 / RATE_HZ;
    let mut samples = Vec::with_capacity(TICKS as usize);
    let mut force_n = DVec3::ZERO;
    let mut limit_flag = 0;
    for tick in 0..TICKS {
        let t_s = tick as f64 * dt_s;
        let probe_m = arm.position_m();
        let proxy_m = DVec3::new(probe_m.x, probe_m.y, probe_m.z.max(0.0));
        let in_contact = probe_m.z < 0.0;
        let mut primitives_per_mode = [0u16; MAX_MODES];
        primitives_per_mode[0] = u16::from(in_contact);
        let mut mode_force_n = [DVec3::ZERO; MAX_MODES];
        mode_force_n[0] = force_n;
        samples.push(TraceSample {
            tick,
            t_s,
            probe_m,
            probe_velocity_m_per_s: arm.velocity_m_per_s(),
            proxy_m,
            rendered_force_n: force_n,
            sent_force_n: force_n,
            modes: ModeBreakdown::new(1, primitives_per_mode, mode_force_n),
            solver_status: SolverStatus::Certified,
            sweeps: u32::from(in_contact),
            error_bound_m: if in_contact { 1e-12 * (1.0 + t_s) } else { 0.0 },
            device_sequence: Some(tick),
            device_time_us: Some(tick * 1000),
            flags: limit_flag,
            truth: Default::default(),
        });
        force_n = COUPLING_N_PER_M * (proxy_m - probe_m);
        let outcome = arm.step(t_s, dt_s, force_n).unwrap();
        limit_flag = if outcome.workspace_limit_hit {
            FLAG_WORKSPACE_LIMIT
        } else {
            0
        };
    }
    samples
}

fn meta() -> TraceMeta {
    let mut meta = TraceMeta::new(
        vec!["surface".into()],
        RATE_HZ,
        serde_json::json!({"name": "floor-circle", "arm": serde_json::to_value(scenario()).unwrap()}),
        "procedural:floor",
        "stand-in clamp",
    );
    meta.created_utc = "2001-02-03T04:05:06Z".into();
    meta.start_utc_ns = 981_173_106_000_000_000;
    meta
}

/// Wall-clock time of the first sample of the MCAP traces written here (MCAP log times are wall-clock UTC;
/// a fixed start keeps identical runs identical).
const WALL_START_NS: u64 = 1_000_000_000_000_000_000;

fn record(path: &Path, format: TraceFormat, samples: &[TraceSample]) {
    let mut writer: Box<dyn voxhap::record::TraceWriter> = match format {
        TraceFormat::Mcap => Box::new(
            voxhap::record::McapTraceWriter::create_at(path, &meta(), WALL_START_NS).unwrap(),
        ),
        _ => create_trace_writer(path, format, &meta()).unwrap(),
    };
    for sample in samples {
        writer.write_sample(sample).unwrap();
    }
    writer.finish().unwrap();
}

fn python_has(module: &str) -> bool {
    Command::new("python3")
        .args(["-c", &format!("import {module}")])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

#[test]
fn scenario_touches_the_floor_and_the_workspace_limit() {
    let samples = run_scenario();
    assert!(samples.iter().any(|s| s.modes.primitives()[0] == 1));
    assert!(samples.iter().any(|s| s.flags & FLAG_WORKSPACE_LIMIT != 0));
    // Resting on the floor the hand spring (pulling 5 mm down) and the coupling share the load:
    // the probe sinks to z = -k_h 5 mm / (k_h + k).
    let expected_z = -300.0 * 0.005 / (300.0 + COUPLING_N_PER_M);
    let late = &samples[2000..];
    let mean_z = late.iter().map(|s| s.probe_m.z).sum::<f64>() / late.len() as f64;
    assert!(
        (mean_z - expected_z).abs() < 2e-4,
        "mean z {mean_z} vs {expected_z}"
    );
}

#[test]
fn identical_runs_write_identical_csv_and_mcap() {
    let dir = tempfile::tempdir().unwrap();
    for format in [TraceFormat::Csv, TraceFormat::Mcap] {
        let a = dir.path().join(format!("a.{format}"));
        let b = dir.path().join(format!("b.{format}"));
        record(&a, format, &run_scenario());
        record(&b, format, &run_scenario());
        let bytes = std::fs::read(&a).unwrap();
        assert!(bytes.len() > 1000);
        assert_eq!(bytes, std::fs::read(&b).unwrap(), "{format} differs");
        let trace = read_trace(&a).unwrap();
        assert_eq!(trace.samples, run_scenario(), "{format} read back");
    }
}

#[test]
fn python_mcap_package_reads_the_trace() {
    if !python_has("mcap") {
        eprintln!("SKIPPED python_mcap_package_reads_the_trace: python3 with the `mcap` package is not available (pip install mcap)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let samples = run_scenario();
    record(&path, TraceFormat::Mcap, &samples);
    let script = r#"
import json, sys
from mcap.reader import make_reader
counts, first, log_times_ok, schemas = {}, {}, True, {}
wall_start_ns, t0 = int(sys.argv[2]), None
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    for schema, channel, message in reader.iter_messages():
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
        schemas[channel.topic] = [schema.name, schema.encoding, channel.message_encoding]
        if channel.topic not in ("/voxhap/state", "/voxhap/solver"):
            continue  # the Foxglove topics are protobuf
        assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
        json.loads(schema.data)
        data = json.loads(message.data)
        first.setdefault(channel.topic, data)
        t0 = data["t_s"] if t0 is None else t0
        log_times_ok &= message.log_time == wall_start_ns + round((data["t_s"] - t0) * 1e9)
print(json.dumps({"counts": counts, "metadata": metadata, "first": first, "log_times_ok": log_times_ok,
                  "schemas": schemas}))
"#;
    let output = Command::new("python3")
        .args(["-c", script])
        .arg(&path)
        .arg(WALL_START_NS.to_string())
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["counts"]["/voxhap/state"], TICKS);
    assert_eq!(report["counts"]["/voxhap/solver"], TICKS);
    // The Foxglove topics, one message per tick, with the SDK's protobuf schemas.
    for (topic, schema) in [
        ("/voxhap/measured_cp", "foxglove.FrameTransform"),
        ("/voxhap/setpoint_cp", "foxglove.FrameTransform"),
        ("/voxhap/setpoint_cf", "foxglove.Vector3"),
    ] {
        assert_eq!(report["counts"][topic], TICKS, "{topic}");
        assert_eq!(
            report["schemas"][topic],
            serde_json::json!([schema, "protobuf", "protobuf"]),
            "{topic}"
        );
    }
    assert_eq!(report["log_times_ok"], true);
    let metadata = &report["metadata"]["voxhap_trace"];
    assert_eq!(metadata["mode_names"], "[\"surface\"]");
    assert_eq!(metadata["rate_hz"], "1000.0");
    assert_eq!(metadata["created_utc"], "2001-02-03T04:05:06Z");
    let state = &report["first"]["/voxhap/state"];
    let probe: Vec<f64> = serde_json::from_value(state["probe_m"].clone()).unwrap();
    assert_eq!(probe, samples[0].probe_m.to_array());
}

#[test]
fn pandas_reads_the_csv_exactly() {
    if !python_has("pandas") {
        eprintln!("SKIPPED pandas_reads_the_csv_exactly: python3 with pandas is not available");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.csv");
    let samples = run_scenario();
    record(&path, TraceFormat::Csv, &samples);
    let script = r#"
import json, sys
import pandas as pd
# pandas 3 parses floats exactly by default; older versions need round_trip.
exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
df = pd.read_csv(sys.argv[1], **exact)
print(json.dumps({"rows": len(df), "columns": list(df.columns),
                  "min_probe_z_m": float(df["probe_z_m"].min()),
                  "contacts": int(df["primitives_surface"].sum()),
                  "flag_dtype": str(df["flag_workspace_limit"].dtype),
                  "limit_ticks": int(df["flag_workspace_limit"].sum()),
                  "utc_span_ns": int(df["utc_ns"].iloc[-1] - df["utc_ns"].iloc[0]),
                  "flags_attr_is_pandas": type(df.flags).__module__.startswith("pandas")}))
"#;
    let output = Command::new("python3")
        .args(["-c", script])
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["rows"], TICKS);
    let columns: Vec<String> = serde_json::from_value(report["columns"].clone()).unwrap();
    assert!(columns.contains(&"primitives_surface".to_owned()));
    assert!(columns.contains(&"flag_bits".to_owned()));
    assert!(!columns.contains(&"flags".to_owned()));
    // Flags come out as booleans without numpy bit twiddling, and `df.flags` is still pandas' own.
    assert_eq!(report["flag_dtype"], "bool");
    let limit_ticks = samples
        .iter()
        .filter(|s| s.flags & FLAG_WORKSPACE_LIMIT != 0)
        .count();
    assert_eq!(report["limit_ticks"], limit_ticks);
    assert_eq!(report["flags_attr_is_pandas"], true);
    assert_eq!(report["utc_span_ns"], (TICKS - 1) * 1_000_000);
    let min_z = samples
        .iter()
        .map(|s| s.probe_m.z)
        .fold(f64::INFINITY, f64::min);
    assert_eq!(
        report["min_probe_z_m"].as_f64().unwrap().to_bits(),
        min_z.to_bits()
    );
    let contacts: u64 = samples
        .iter()
        .map(|s| u64::from(s.modes.primitives()[0]))
        .sum();
    assert_eq!(report["contacts"], contacts);
}

#[test]
fn voxhap_plot_draws_csv_and_mcap_traces() {
    let dir = tempfile::tempdir().unwrap();
    let samples = run_scenario();
    for (trace_name, image_name) in [("run.csv", "csv.png"), ("run.mcap", "mcap.svg")] {
        let trace = dir.path().join(trace_name);
        record(&trace, TraceFormat::from_path(&trace), &samples);
        assert!(sidecar_path(&trace).exists());
        let image = dir.path().join(image_name);
        let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
            .arg("plot")
            .arg(&trace)
            .arg("--out")
            .arg(&image)
            .args(["--width", "900", "--height", "800"])
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "voxhap plot failed: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        let bytes = std::fs::read(&image).unwrap();
        assert!(bytes.len() > 1000);
        // Set VOXHAP_KEEP_OUTPUT=DIR to keep the traces and images for a look.
        if let Ok(keep) = std::env::var("VOXHAP_KEEP_OUTPUT") {
            for file in [image.clone(), trace.clone(), sidecar_path(&trace)] {
                std::fs::copy(&file, Path::new(&keep).join(file.file_name().unwrap())).unwrap();
            }
        }
    }
    // A missing trace is an error naming the file, not a panic.
    let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(["plot", "no-such-trace.csv", "--out"])
        .arg(dir.path().join("x.png"))
        .output()
        .unwrap();
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("no-such-trace.csv"));
}

#[test]
fn sim_arm_step_does_not_allocate() {
    // Every path kind, including waypoints (a Vec walked in place) and a force profile.
    let paths = [
        scenario().path,
        HandPath::Waypoints {
            points_m: vec![
                DVec3::ZERO,
                DVec3::new(0.01, 0.0, 0.0),
                DVec3::new(0.01, 0.01, 0.0),
            ],
            speed_m_per_s: 0.02,
        },
        HandPath::Raster {
            origin_m: DVec3::ZERO,
            sweep_m: DVec3::new(0.02, 0.0, 0.0),
            step_m: DVec3::new(0.0, 0.02, 0.0),
            lines: 5,
            speed_m_per_s: 0.05,
        },
        HandPath::Force {
            profile: voxhap::device::sim::ForceProfile::Sine {
                offset_n: DVec3::ZERO,
                amplitude_n: DVec3::X,
                frequency_hz: 3.0,
            },
        },
    ];
    for path in paths {
        let mut config = scenario();
        config.path = path;
        let mut arm = SimArm::new(config, DVec3::ZERO).unwrap();
        let allocations = crate::util::count_allocations(|| {
            for tick in 0..500u64 {
                let force = if tick % 97 == 0 {
                    DVec3::NAN
                } else {
                    DVec3::new(0.0, 0.0, 0.5)
                };
                arm.step(tick as f64 * 1e-3, 1e-3, force).unwrap();
            }
        });
        assert_eq!(allocations, 0, "SimArm::step allocated");
        assert!(arm.position_m().is_finite());
    }
    // The counter does see allocations (so the zero above means something).
    assert!(crate::util::count_allocations(|| drop(std::hint::black_box(vec![1u8; 16]))) > 0);
}
