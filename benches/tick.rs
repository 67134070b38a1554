//! Per-tick compute of the servo tick (sampling, modes and solve) for a three-mode scene on 256^3 volumes:
//! a surface on a density ball and viscosity inside it (scalar, 64 MB) and a flow line along a Burgers
//! vortex (vector, 200 MB), the multi-modal case. Target: median under 5 us per tick.
//!
//! The probe circles 2 mm inside the ball's 3 cm surface at 45 degrees latitude, about 0.05 mm per tick
//! (a 50 mm/s stroke at 1 kHz), so the proxy rides the surface with all three modes active, warm-started
//! from the previous tick as on the servo thread. Variants: the exact solver, the two baselines, and the
//! exact solver with only the surface mode (the single-mode cost).

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use std::hint::black_box;
use voxhap::haptics::modes::{ModeConfig, ModeKind, RenderScene, TransferFunction};
use voxhap::haptics::tick::{tick, SolverKind, TickState, TickWorkspace};
use voxhap::haptics::SolverConfig;
use voxhap::volume::{procedural, AnyVolume};

const DT_S: f64 = 1e-3;

fn probes() -> Vec<DVec3> {
    (0..4096)
        .map(|n| {
            let t = n as f64 / 4096.0 * std::f64::consts::TAU;
            DVec3::new(0.02 * t.cos(), 0.02 * t.sin(), 0.0195)
        })
        .collect()
}

fn scene(volumes: &[(String, AnyVolume)], modes: &[ModeConfig]) -> RenderScene {
    RenderScene::new(500.0, volumes.to_vec(), modes).unwrap()
}

fn bench_tick(c: &mut Criterion) {
    let (density, flow) = procedural::density_and_flow([256; 3], 0.05).unwrap();
    let volumes = vec![
        ("density".to_owned(), AnyVolume::Scalar(density)),
        ("flow".to_owned(), AnyVolume::Vector(flow)),
    ];
    let surface = ModeConfig::sampled(
        ModeKind::Surface,
        "density",
        TransferFunction::new(vec![[0.45, 0.0], [0.5, 2.0]]).unwrap(),
    );
    let three = [
        surface.clone(),
        ModeConfig::sampled(
            ModeKind::VectorFollow,
            "flow",
            TransferFunction::ramp(0.0, 0.1, 0.4).unwrap(),
        ),
        ModeConfig::sampled(
            ModeKind::Viscosity,
            "density",
            TransferFunction::ramp(0.0, 1.0, 0.3).unwrap(),
        ),
    ];
    let probes = probes();
    let mut group = c.benchmark_group("tick");
    let cases = [
        ("three_modes_exact", &three[..], SolverKind::Exact),
        ("three_modes_euler", &three[..], SolverKind::Euler),
        ("three_modes_constraint", &three[..], SolverKind::Constraint),
        ("surface_only_exact", &three[..1], SolverKind::Exact),
    ];
    for (name, modes, solver) in cases {
        let scene = scene(&volumes, modes);
        let mut workspace = TickWorkspace::new(&scene, solver, SolverConfig::default());
        // Start on the surface: run one lap first so the proxy rides it.
        let mut state = TickState::new(DVec3::new(0.02, 0.0, 0.04));
        for &probe in probes.iter().chain(&probes) {
            tick(&mut state, &scene, probe, DT_S, &mut workspace);
        }
        let mut n = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                let probe = probes[n % probes.len()];
                n += 1;
                black_box(tick(
                    &mut state,
                    &scene,
                    black_box(probe),
                    DT_S,
                    &mut workspace,
                ))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_tick);
criterion_main!(benches);
