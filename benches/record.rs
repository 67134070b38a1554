//! Benchmarks of the simulated arm (one servo tick of physics) and the trace writers (one sample).
//!
//! `SimArm::step` runs on the servo thread, so its cost per tick is part of the 1 ms budget in
//! simulations; the writers run on the recorder thread and must keep up with the servo rate.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use std::hint::black_box;
use voxhap::device::sim::{ArmParams, HandParams, HandPath, SimArm, SimArmConfig, Workspace};
use voxhap::record::{create_trace_writer, TraceFormat, TraceMeta, TraceSample};

fn arm(path: HandPath, substeps_per_tick: u32) -> SimArm {
    let config = SimArmConfig {
        arm: ArmParams {
            mass_kg: 0.1,
            damping_n_s_per_m: 1.0,
            workspace: Workspace::Sphere {
                center_m: DVec3::ZERO,
                radius_m: 0.05,
            },
            substeps_per_tick,
            wall_stiffness_n_per_m: 5000.0,
            wall_damping_n_s_per_m: 10.0,
            effects: Default::default(),
        },
        hand: HandParams {
            stiffness_n_per_m: 400.0,
            damping_n_s_per_m: 8.0,
        },
        path,
        local_model: None,
    };
    SimArm::new(config, DVec3::ZERO).expect("valid benchmark arm")
}

fn bench_sim_arm(c: &mut Criterion) {
    let circle = HandPath::Circle {
        center_m: DVec3::ZERO,
        radius_m: 0.03,
        normal: DVec3::Z,
        period_s: 1.0,
    };
    let waypoints = HandPath::Waypoints {
        points_m: (0..32)
            .map(|i| DVec3::new(0.001 * f64::from(i), 0.0, 0.0))
            .collect(),
        speed_m_per_s: 0.001,
    };
    for (name, path, substeps) in [
        ("sim_arm_step/circle_10_substeps", circle.clone(), 10),
        ("sim_arm_step/circle_1_substep", circle, 1),
        ("sim_arm_step/waypoints32_10_substeps", waypoints, 10),
    ] {
        let mut sim = arm(path, substeps);
        let mut tick = 0u64;
        c.bench_function(name, |b| {
            b.iter(|| {
                let t_s = (tick % 10_000) as f64 * 1e-3;
                tick += 1;
                sim.step(black_box(t_s), 1e-3, black_box(DVec3::new(0.0, 0.0, 0.1)))
                    .expect("stable step")
            })
        });
    }
}

fn bench_writers(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let meta = TraceMeta::new(
        vec!["surface".into(), "friction".into()],
        1000.0,
        serde_json::json!({"name": "bench"}),
        "procedural:sphere",
        "bench",
    );
    for format in [TraceFormat::Csv, TraceFormat::Mcap] {
        let path = dir.path().join(format!("bench.{format}"));
        let mut writer = create_trace_writer(&path, format, &meta).expect("writer");
        let mut sample = TraceSample::zeroed(2);
        c.bench_function(&format!("trace_write_sample/{format}"), |b| {
            b.iter(|| {
                sample.tick += 1;
                sample.t_s = sample.tick as f64 * 1e-3;
                sample.probe_m =
                    DVec3::new(0.01 * sample.t_s.cos(), 0.01 * sample.t_s.sin(), -1e-3);
                sample.sent_force_n = DVec3::new(0.1, -0.2, 0.51234567);
                sample.error_bound_m = 1.234e-15;
                writer.write_sample(black_box(&sample)).expect("write")
            })
        });
        writer.finish().expect("finish");
    }
}

criterion_group!(benches, bench_sim_arm, bench_writers);
criterion_main!(benches);
