//! Deterministic synthetic traces for the writer and reader tests.

use crate::flags::FLAG_DEVICE_NOT_ENABLED;
use crate::meta::{TraceMeta, TraceSummary};
use crate::sample::{SolverStatus, TraceSample};
use glam::DVec3;
use std::path::{Path, PathBuf};
use voxhap_api::TraceFormat;
use voxhap_core::haptics::tick::ModeBreakdown;

/// A `TraceMeta` with a fixed creation time, so files are comparable byte for byte.
pub fn meta(mode_names: &[&str]) -> TraceMeta {
    let mut meta = TraceMeta::new(
        mode_names.iter().map(|s| s.to_string()).collect(),
        1000.0,
        serde_json::json!({"name": "unit-test", "arm": {"mass_kg": 0.1}}),
        "procedural:sphere",
        "exact-dual",
    );
    meta.created_utc = "2000-01-01T00:00:00Z".to_string();
    meta.start_utc_ns = 946_684_800_000_000_000;
    meta
}

/// Writes `data` for `modes` (with [`meta`]) to `path` in the format its ending names and finishes the file;
/// every sample must be written.
pub fn write_trace(path: &Path, modes: &[&str], data: &[TraceSample]) -> TraceSummary {
    let format = TraceFormat::from_path(path);
    let mut writer = crate::create_trace_writer(path, format, &meta(modes)).unwrap();
    for sample in data {
        writer.write_sample(sample).unwrap();
    }
    let summary = writer.finish().unwrap();
    assert_eq!(summary.sample_count, data.len() as u64);
    summary
}

/// A new temporary folder holding the trace `name`, written by [`write_trace`] (the folder goes when the
/// returned guard is dropped).
pub fn temp_trace(
    name: &str,
    modes: &[&str],
    data: &[TraceSample],
) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    write_trace(&path, modes, data);
    (dir, path)
}

/// `count` samples of a probe circling a plane, with awkward floats (negative zero, tiny bounds,
/// an infinite bound) to exercise exact round-trips.
pub fn samples(count: u64, mode_count: u8) -> Vec<TraceSample> {
    (0..count)
        .map(|i| {
            let t_s = i as f64 * 1e-3;
            let angle = t_s * 7.0;
            let probe_m = DVec3::new(0.02 * angle.cos(), 0.02 * angle.sin(), -0.001 * t_s);
            let proxy_m = DVec3::new(probe_m.x, probe_m.y, probe_m.z.max(0.0));
            let force_n = (proxy_m - probe_m) * 500.0 + DVec3::new(-0.0, 1e-300, 0.1);
            let mut modes = ModeBreakdown::zeroed(mode_count);
            for (m, (primitives, mode_force_n)) in modes.slots_mut().enumerate() {
                *primitives = ((i as usize + m) % 3) as u16;
                *mode_force_n = force_n * (m as f64 + 1.0) / 3.0;
            }
            TraceSample {
                tick: i * 2,
                t_s,
                probe_m,
                probe_velocity_m_per_s: DVec3::new(-0.14 * angle.sin(), 0.14 * angle.cos(), -0.001),
                proxy_m,
                rendered_force_n: force_n * 1.5,
                sent_force_n: force_n,
                modes,
                solver_status: SolverStatus::ALL[(i % 6) as usize],
                sweeps: (i % 5) as u32,
                error_bound_m: if i % 7 == 3 {
                    f64::INFINITY
                } else {
                    1e-17 * (i as f64 + 1.0).powi(3)
                },
                device_sequence: (i % 3 != 0).then_some(i * 10),
                device_time_us: (i % 2 == 0).then_some(i * 1000 + 17),
                flags: (i % 4) as u32
                    | if i % 11 == 5 {
                        FLAG_DEVICE_NOT_ENABLED
                    } else {
                        0
                    },
                truth: voxhap_api::TickTruth {
                    energy: voxhap_api::TickEnergy {
                        work_on_probe_j: -1e-3 * i as f64,
                        coupling_energy_j: 1e-4 * (i % 9) as f64,
                        generated_j: 1e-5 * i as f64 - 0.1,
                        active_work_j: 0.0,
                        device_dissipation_j: 2.5e-6 * i as f64,
                        net_generated_j: -1e-7 * (i as f64).sqrt(),
                        passivity_dissipated_j: 3e-6 * i as f64,
                    },
                    force_off_cause: voxhap_api::ForceOffCause::ALL
                        [(i % voxhap_api::ForceOffCause::ALL.len() as u64) as usize],
                    device_fault_bits: (i % 5) as u16,
                    sample_age_ticks: (i % 4) as u32,
                    device_force_n: (i % 3 != 1)
                        .then(|| glam::DVec3::new(0.1 * i as f64, -0.0, 1.5e-9)),
                    external_force_n: glam::DVec3::new(
                        0.25 * (i % 3) as f64,
                        -1.5,
                        1e-3 * i as f64,
                    ),
                    device_local: (i % 4 != 2).then(|| voxhap_api::DeviceLocal {
                        proxy_m: glam::DVec3::new(1e-3 * i as f64, -0.0, 2.5e-7),
                        proxy_bound_m: 1e-9 * (i % 5) as f64,
                        model_sequence: i as u32 * 3,
                        model_age_s: 1e-6 * (i % 7) as f64,
                    }),
                },
            }
        })
        .collect()
}
