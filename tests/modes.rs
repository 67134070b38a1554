//! Behaviour of the haptic modes through the tick (docs/modes.md), with the probe
//! moved kinematically so that every number has a closed form: surfaces hold with force k times the
//! penetration and yield at s/k, friction resists tangential motion up to mu N, a vortex line keeps the
//! proxy on the core, and a multi-mode tick allocates nothing.

use crate::util::alloc::count_allocations;
use glam::DVec3;
use voxhap::haptics::modes::{ModeConfig, ModeKind, RenderScene, TransferFunction};
use voxhap::haptics::tick::{tick, SolverKind, TickOutput, TickState, TickStatus, TickWorkspace};
use voxhap::haptics::{PrimitiveKind, SolverConfig};
use voxhap::volume::{procedural, AnyVolume, Grid, ScalarVolume};

const K_N_PER_M: f64 = 500.0;
const DT_S: f64 = 1e-3;

/// A slab dense below z = 0: `V = clamp(0.5 - z / 4 mm, 0, 1)`, linear (exact gradient) across |z| < 2 mm.
fn slab() -> AnyVolume {
    let grid = Grid::centred_cube([33; 3], 0.05).unwrap();
    AnyVolume::Scalar(ScalarVolume::from_fn(grid, |p| (0.5 - p.z / 0.004).clamp(0.0, 1.0)).unwrap())
}

/// A surface that holds with `strength_n` wherever V >= 0.05 (ramping in from V = 0.01).
fn surface(volume: &str, strength_n: f64) -> ModeConfig {
    ModeConfig::sampled(
        ModeKind::Surface,
        volume,
        TransferFunction::new(vec![[0.01, 0.0], [0.05, strength_n]]).unwrap(),
    )
}

fn run(
    scene: &RenderScene,
    probes: impl IntoIterator<Item = DVec3>,
    solver: SolverKind,
) -> Vec<(DVec3, TickOutput)> {
    let mut probes = probes.into_iter().peekable();
    let first = *probes.peek().unwrap();
    let mut state = TickState::new(first);
    let mut workspace = TickWorkspace::new(scene, solver, SolverConfig::default());
    probes
        .map(|probe| (probe, tick(&mut state, scene, probe, DT_S, &mut workspace)))
        .collect()
}

#[test]
fn sphere_force_is_normal_grows_as_k_times_penetration_and_yields_at_s_over_k() {
    let strength_n = 2.0;
    let volume = AnyVolume::Scalar(
        procedural::sphere(0.03, Grid::centred_cube([64; 3], 0.05).unwrap()).unwrap(),
    );
    // The surface holds with s from the V = 0.5 isosurface in. The transfer function ramps in over
    // V in [0.499, 0.5], about 2 um of depth (10 um allowed), so the proxy sinks about that far before the plane is full.
    let sharp = ModeConfig::sampled(
        ModeKind::Surface,
        "density",
        TransferFunction::new(vec![[0.499, 0.0], [0.5, strength_n]]).unwrap(),
    );
    let ramp_depth_m = 1e-5;
    let scene = RenderScene::new(K_N_PER_M, vec![("density".into(), volume)], &[sharp]).unwrap();
    let direction = DVec3::new(1.0, 2.0, -0.5).normalize();
    // The probe comes in radially from 4 cm at 10 um per tick, to 2.45 cm (the proxy then yields about
    // 1.5 mm into the 3 mm edge, where the gradient still defines the normal).
    let probes: Vec<DVec3> = (0..1550)
        .map(|i| direction * (0.04 - 1e-5 * i as f64))
        .collect();
    let mut state = TickState::new(probes[0]);
    let mut workspace = TickWorkspace::new(&scene, SolverKind::Exact, SolverConfig::default());
    let mut contact: Option<(DVec3, DVec3)> = None; // proxy at first contact, surface normal there
    let (mut holding, mut yielding) = (0, 0);
    for probe in probes {
        let out = tick(&mut state, &scene, probe, DT_S, &mut workspace);
        assert_eq!(out.status, TickStatus::Certified);
        let plane = workspace.primitives().first().copied();
        let force = out.coupling_force_n.length();
        if force < 1e-9 {
            assert!(contact.is_none(), "contact lost while pushing in");
            continue;
        }
        let plane = plane.expect("a force needs a plane");
        assert_eq!(plane.kind(), PrimitiveKind::Plane);
        let normal = plane.direction();
        // Normal to the surface: the force is along the plane normal, and the normal is radial.
        assert!(
            out.coupling_force_n.normalize().dot(normal) > 1.0 - 1e-9,
            "force {} normal {normal}",
            out.coupling_force_n
        );
        // The sampled normal of a 64^3 sphere with a 2-voxel edge is radial to within about 10 degrees.
        assert!(
            normal.dot(direction) > 0.98,
            "surface normal {normal} vs radial {direction}"
        );
        assert_eq!(out.flags, 0);
        let (contact_proxy, contact_normal) = *contact.get_or_insert((out.proxy_m, normal));
        let penetration_m = (contact_proxy - probe).dot(contact_normal);
        if K_N_PER_M * penetration_m < 0.95 * strength_n {
            // Holding: the proxy stays at the contact point and the force is k times the penetration.
            // Holding: the proxy stays on the surface (it may slide along it, since the sampled normal is
            // not exactly radial and the surface is frictionless) and the force is k times the penetration.
            let sunk_m = (contact_proxy - out.proxy_m).dot(contact_normal);
            assert!(sunk_m.abs() < ramp_depth_m, "proxy sank by {sunk_m} m");
            assert!(
                (force - K_N_PER_M * penetration_m).abs() < K_N_PER_M * ramp_depth_m,
                "{force} N at {penetration_m} m"
            );
            holding += 1;
        } else if K_N_PER_M * penetration_m > 1.05 * strength_n {
            // Yielding: the force saturates at s, the proxy is s/k outside the probe.
            assert!(
                (force - strength_n).abs() < 1e-9,
                "{force} N while yielding"
            );
            assert!(((out.proxy_m - probe).length() - strength_n / K_N_PER_M).abs() < 1e-9);
            yielding += 1;
        }
    }
    assert!(
        holding > 300 && yielding > 100,
        "holding {holding} ticks, yielding {yielding}"
    );
}

#[test]
fn friction_resists_tangential_motion_up_to_mu_times_the_normal_force() {
    let (mu, strength_n) = (0.4, 5.0);
    let scene = RenderScene::new(
        K_N_PER_M,
        vec![("slab".into(), slab())],
        &[
            surface("slab", strength_n),
            ModeConfig::friction("surface", mu),
        ],
    )
    .unwrap();
    // The proxy rests on the surface where its transfer function is saturated (V = 0.25 at z = 1 mm; a
    // point friction bears normal load too where the surface is weaker, see the modes docs); the probe is
    // 4 mm below it (N = 2 N), still for 100 ticks, then dragged 2 cm along x at 5 um per tick.
    let rest = DVec3::new(0.0, 0.0, 0.001);
    let bottom = rest - DVec3::new(0.0, 0.0, 0.004);
    let mut probes = vec![bottom; 100];
    probes.extend((1..=4000).map(|i| bottom + DVec3::new(5e-6 * i as f64, 0.0, 0.0)));
    let mut state = TickState::new(rest);
    let mut workspace = TickWorkspace::new(&scene, SolverKind::Exact, SolverConfig::default());
    let trace: Vec<(DVec3, TickOutput)> = probes
        .iter()
        .map(|&probe| (probe, tick(&mut state, &scene, probe, DT_S, &mut workspace)))
        .collect();
    let (mut sticking, mut sliding) = (0, 0);
    let mut max_tangential_n: f64 = 0.0;
    for (probe, out) in &trace[100..] {
        let normal_n = out.coupling_force_n.z;
        let tangential_n = out.coupling_force_n.truncate().length();
        assert!(
            (normal_n - 2.0).abs() < 1e-9,
            "normal force changed: {}",
            out.coupling_force_n
        );
        max_tangential_n = max_tangential_n.max(tangential_n / normal_n);
        // Never more than mu N (N from the previous tick, which differs by rounding here).
        assert!(
            tangential_n <= mu * normal_n * (1.0 + 1e-6),
            "{tangential_n} N > mu {normal_n} N"
        );
        let dragged_m = probe.x;
        if K_N_PER_M * dragged_m < 0.9 * mu * normal_n {
            sticking += 1;
            assert!(
                out.proxy_m.x.abs() < 1e-9,
                "the proxy slipped at {dragged_m} m"
            );
        } else if tangential_n > 0.99 * mu * normal_n {
            sliding += 1;
        }
    }
    assert!(
        sticking > 100 && sliding > 2000,
        "sticking {sticking}, sliding {sliding}"
    );
    assert!(max_tangential_n > 0.99 * mu);

    // Control: the same path without friction slides freely.
    let free = RenderScene::new(
        K_N_PER_M,
        vec![("slab".into(), slab())],
        &[surface("slab", strength_n)],
    )
    .unwrap();
    let mut state = TickState::new(rest);
    let mut workspace = TickWorkspace::new(&free, SolverKind::Exact, SolverConfig::default());
    let last = probes
        .iter()
        .map(|&probe| tick(&mut state, &free, probe, DT_S, &mut workspace))
        .last()
        .unwrap();
    assert!(
        last.coupling_force_n.x.abs() < 1e-9,
        "frictionless surface pulled sideways: {}",
        last.coupling_force_n
    );
}

#[test]
fn vortex_proxy_stays_near_the_core() {
    let volumes = procedural::builtin("burgers").unwrap().into_volumes();
    let flow = volumes.into_iter().next().unwrap();
    let vortex = ModeConfig::sampled(
        ModeKind::Vortex,
        "flow",
        // |curl| on the axis is Gamma / (pi delta^2) = 31.8 /s; saturate at 1.5 N from 10 /s.
        TransferFunction::ramp(0.0, 10.0, 1.5).unwrap(),
    );
    let scene =
        RenderScene::new(K_N_PER_M, vec![("flow".into(), flow.clone())], &[vortex]).unwrap();
    // The hand circles the axis at 2 mm (a 1 N pull, below the 1.5 N hold) while moving 2 cm along it.
    let probes: Vec<DVec3> = (0..3000)
        .map(|i| {
            let t = i as f64 * DT_S;
            let radius = 0.002 * (t / 0.5).min(1.0);
            DVec3::new(
                radius * (4.0 * t).cos(),
                radius * (4.0 * t).sin(),
                -0.01 + 0.02 * t / 3.0,
            )
        })
        .collect();
    let trace = run(&scene, probes.clone(), SolverKind::Exact);
    for (probe, out) in &trace {
        let off_axis_m = out.proxy_m.truncate().length();
        assert!(
            off_axis_m < 2e-4,
            "proxy {off_axis_m} m off the core (probe {probe})"
        );
        assert!(
            (out.proxy_m.z - probe.z).abs() < 1e-6,
            "motion along the core is free"
        );
    }
    // Control: with no modes the proxy follows the probe off the core.
    let empty = RenderScene::new(K_N_PER_M, vec![("flow".into(), flow)], &[]).unwrap();
    let free = run(&empty, probes, SolverKind::Exact);
    assert!(free.last().unwrap().1.proxy_m.truncate().length() > 1.9e-3);
}

/// A scene with every kind of mode over two volumes.
fn every_mode_scene() -> RenderScene {
    let both = procedural::builtin("density-flow").unwrap();
    let density = AnyVolume::Scalar(both.scalar.unwrap());
    let flow = AnyVolume::Vector(both.vector.unwrap());
    let tf = |x1: f64, s: f64| TransferFunction::ramp(0.0, x1, s).unwrap();
    RenderScene::new(
        K_N_PER_M,
        vec![("density".into(), density), ("flow".into(), flow)],
        &[
            surface("density", 2.0),
            ModeConfig::friction("surface", 0.3),
            ModeConfig::sampled(ModeKind::Viscosity, "density", tf(1.0, 0.2)),
            ModeConfig::sampled(ModeKind::VectorFollow, "flow", tf(0.1, 0.5)),
            ModeConfig::sampled(ModeKind::Vortex, "flow", tf(10.0, 0.8)),
            ModeConfig::sampled(ModeKind::VectorForce, "flow", tf(0.1, 0.1)),
            ModeConfig::sampled(ModeKind::GradientForce, "density", tf(300.0, 0.1)),
            ModeConfig::support_plane(DVec3::new(0.0, 0.0, -0.04), DVec3::Z, 3.0),
        ],
    )
    .unwrap()
}

#[test]
fn ticks_allocate_nothing_for_every_solver() {
    let scene = every_mode_scene();
    for solver in [SolverKind::Exact, SolverKind::Euler, SolverKind::Constraint] {
        let mut state = TickState::new(DVec3::new(0.045, 0.0, 0.0));
        let mut workspace = TickWorkspace::new(&scene, solver, SolverConfig::default());
        let ticks = 5000;
        let ((emitted, certified), events) = count_allocations(|| {
            let (mut emitted, mut certified) = (0u64, 0u64);
            for i in 0..ticks {
                let t = i as f64 * DT_S;
                // In through the ball's surface to near the vortex core, round and back out.
                let r = 0.045 - 0.04 * (std::f64::consts::PI * t / 5.0).sin();
                let probe = DVec3::new(
                    r * (2.0 * t).cos(),
                    r * (2.0 * t).sin(),
                    0.01 * (3.0 * t).sin(),
                );
                let out = tick(&mut state, &scene, probe, DT_S, &mut workspace);
                emitted += out
                    .modes
                    .primitives()
                    .iter()
                    .map(|&c| u64::from(c))
                    .sum::<u64>();
                // Every exact tick carries a certificate; a few degenerate ticks (a plane, a point and a
                // line through the same point) stall near 1e-9 m instead of reaching the 1e-12 m tolerance.
                certified += u64::from(out.error_bound_m < 1e-8);
            }
            (emitted, certified)
        });
        assert_eq!(events, 0, "{solver:?}: the tick allocated");
        // The scene really was multi-modal: on average more than 3 primitives per tick.
        assert!(emitted > 3 * ticks, "{solver:?}: only {emitted} primitives");
        if solver == SolverKind::Exact {
            assert_eq!(certified, ticks, "every exact tick certified to 1e-8 m");
        } else {
            assert_eq!(certified, 0, "baselines have no certificate");
        }
    }
}

#[test]
fn a_non_finite_probe_holds_the_proxy_and_sends_no_force() {
    let scene = every_mode_scene();
    let mut state = TickState::new(DVec3::new(0.029, 0.0, 0.0));
    let mut workspace = TickWorkspace::new(&scene, SolverKind::Exact, SolverConfig::default());
    let before = tick(
        &mut state,
        &scene,
        DVec3::new(0.027, 0.0, 0.0),
        DT_S,
        &mut workspace,
    );
    let out = tick(
        &mut state,
        &scene,
        DVec3::new(f64::NAN, 0.0, 0.0),
        DT_S,
        &mut workspace,
    );
    assert_eq!(out.coupling_force_n, DVec3::ZERO);
    assert_eq!(out.proxy_m, before.proxy_m);
    assert_eq!(out.status, TickStatus::InputRejected);
    assert_ne!(
        out.flags & voxhap::haptics::tick::FLAG_NON_FINITE_REPLACED,
        0
    );
    let bad_dt = tick(
        &mut state,
        &scene,
        DVec3::new(0.027, 0.0, 0.0),
        0.0,
        &mut workspace,
    );
    assert_eq!(bad_dt.status, TickStatus::InputRejected);
}
