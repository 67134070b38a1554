//! Unit tests of the modes: what each emits for known fields.

use super::*;
use crate::haptics::Primitive;
use crate::volume::{procedural, AnyVolume, Grid, ScalarVolume, VectorVolume};
use glam::DVec3;

fn sphere_volume() -> AnyVolume {
    AnyVolume::Scalar(procedural::sphere(0.03, Grid::centred_cube([32; 3], 0.05).unwrap()).unwrap())
}

/// Solid-body rotation about the axis through `centre` along z, angular speed `omega` (curl 2 omega z).
fn rotation_volume(centre: DVec3, omega: f64) -> AnyVolume {
    let grid = Grid::centred_cube([24; 3], 0.05).unwrap();
    AnyVolume::Vector(
        VectorVolume::from_fn(grid, |p| {
            let r = p - centre;
            DVec3::new(-omega * r.y, omega * r.x, 0.3)
        })
        .unwrap(),
    )
}

fn emit_one(
    scene: &RenderScene,
    index: usize,
    proxy: DVec3,
    memory: &ModeMemory,
) -> Vec<Primitive> {
    let mut out = Vec::new();
    let (count, _) = scene.emit(index, &ModeInput::at_rest(proxy), memory, &mut out);
    assert_eq!(usize::from(count), out.len());
    out
}

#[test]
fn surface_plane_faces_out_of_the_sphere_with_tf_strength() {
    let tf = TransferFunction::ramp(0.0, 1.0, 2.0).unwrap();
    let scene = RenderScene::new(
        500.0,
        vec![("density".into(), sphere_volume())],
        &[
            ModeConfig::sampled(ModeKind::Surface, "density", tf.clone()),
            ModeConfig::sampled(ModeKind::Surface, "density", tf.clone())
                .named("inner")
                .with_side(SurfaceSide::Inward),
        ],
    )
    .unwrap();
    let direction = DVec3::new(1.0, 2.0, -0.5).normalize();
    let proxy = direction * 0.03;
    let out = emit_one(&scene, 0, proxy, &ModeMemory::default());
    assert_eq!(out.len(), 1);
    let plane = out[0];
    assert_eq!(plane.kind(), crate::haptics::PrimitiveKind::Plane);
    assert!(
        plane.direction().dot(direction) > 0.99,
        "{:?}",
        plane.direction()
    );
    assert_eq!(plane.position_m(), proxy);
    let value = match &scene.volumes()[0].1 {
        AnyVolume::Scalar(v) => v.sample_with_gradient(proxy).0,
        _ => unreachable!(),
    };
    assert!((plane.strength_n() - tf.eval(value)).abs() < 1e-12);
    let inner = emit_one(&scene, 1, proxy, &ModeMemory::default());
    assert!(inner[0].direction().dot(direction) < -0.99);
    // Far outside the sphere the gradient is zero: no plane.
    assert!(emit_one(
        &scene,
        0,
        DVec3::new(0.045, 0.0, 0.0),
        &ModeMemory::default()
    )
    .is_empty());
}

#[test]
fn friction_scales_the_previous_normal_force() {
    let tf = TransferFunction::constant(2.0).unwrap();
    let scene = RenderScene::new(
        500.0,
        vec![("density".into(), sphere_volume())],
        &[
            ModeConfig::sampled(ModeKind::Surface, "density", tf),
            ModeConfig::friction("surface", 0.5),
        ],
    )
    .unwrap();
    let mut memory = ModeMemory::default();
    let proxy = DVec3::new(0.03, 0.0, 0.0);
    assert!(
        emit_one(&scene, 1, proxy, &memory).is_empty(),
        "no contact, no friction"
    );
    memory.plane_normals[0] = DVec3::X;
    memory.previous_force_n = DVec3::new(1.2, 0.7, 0.0);
    let out = emit_one(&scene, 1, proxy, &memory);
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].kind(), crate::haptics::PrimitiveKind::Point);
    assert_eq!(out[0].position_m(), proxy);
    assert!((out[0].strength_n() - 0.6).abs() < 1e-15);
    // A force pulling away from the surface is no normal force.
    memory.previous_force_n = DVec3::new(-1.0, 0.0, 0.0);
    assert!(emit_one(&scene, 1, proxy, &memory).is_empty());
}

#[test]
fn vortex_line_sits_on_the_core_and_follow_line_along_the_flow() {
    let centre = DVec3::new(0.004, -0.003, 0.0);
    let tf = TransferFunction::constant(1.0).unwrap();
    let scene = RenderScene::new(
        500.0,
        vec![("flow".into(), rotation_volume(centre, 3.0))],
        &[
            ModeConfig::sampled(ModeKind::Vortex, "flow", tf.clone()),
            ModeConfig::sampled(ModeKind::VectorFollow, "flow", tf.clone()),
            ModeConfig::sampled(ModeKind::VectorForce, "flow", tf),
        ],
    )
    .unwrap();
    let proxy = DVec3::new(0.012, 0.005, 0.01);
    let line = emit_one(&scene, 0, proxy, &ModeMemory::default())[0];
    assert!(
        line.direction().z.abs() > 1.0 - 1e-9,
        "{:?}",
        line.direction()
    );
    // The line passes through the rotation axis: its distance to (centre.x, centre.y, any z) is ~0.
    assert!(line.distance_m(DVec3::new(centre.x, centre.y, 0.02)) < 1e-9);
    let follow = emit_one(&scene, 1, proxy, &ModeMemory::default())[0];
    let r = proxy - centre;
    let v = DVec3::new(-3.0 * r.y, 3.0 * r.x, 0.3);
    assert!(follow.direction().dot(v.normalize()) > 1.0 - 1e-6);
    assert_eq!(follow.position_m(), proxy);
    let push = emit_one(&scene, 2, proxy, &ModeMemory::default())[0];
    assert_eq!(push.kind(), crate::haptics::PrimitiveKind::Directed);
    assert!(push.direction().dot(v.normalize()) > 1.0 - 1e-6);
}

#[test]
fn gradient_force_points_up_hill_and_support_plane_is_fixed() {
    let grid = Grid::centred_cube([8; 3], 0.05).unwrap();
    let ramp = AnyVolume::Scalar(ScalarVolume::from_fn(grid, |p| 10.0 * p.y).unwrap());
    let scene = RenderScene::new(
        500.0,
        vec![("ramp".into(), ramp)],
        &[
            ModeConfig::sampled(
                ModeKind::GradientForce,
                "ramp",
                TransferFunction::ramp(0.0, 20.0, 1.0).unwrap(),
            ),
            ModeConfig::support_plane(DVec3::new(0.0, 0.0, -0.01), DVec3::new(0.0, 0.0, 2.0), 3.0),
        ],
    )
    .unwrap();
    let force = emit_one(&scene, 0, DVec3::ZERO, &ModeMemory::default())[0];
    assert!((force.direction() - DVec3::Y).length() < 1e-9);
    assert!(
        (force.strength_n() - 0.5).abs() < 1e-6,
        "{}",
        force.strength_n()
    );
    let plane = emit_one(&scene, 1, DVec3::splat(0.02), &ModeMemory::default())[0];
    assert_eq!(plane.position_m(), DVec3::new(0.0, 0.0, -0.01));
    assert_eq!(plane.direction(), DVec3::Z);
}

#[test]
fn build_errors_name_the_key() {
    let volumes = || {
        vec![
            ("density".to_owned(), sphere_volume()),
            ("flow".to_owned(), rotation_volume(DVec3::ZERO, 1.0)),
        ]
    };
    let tf = TransferFunction::constant(1.0).unwrap();
    let err = |modes: &[ModeConfig]| {
        RenderScene::new(500.0, volumes(), modes)
            .unwrap_err()
            .to_string()
    };
    assert_eq!(
        err(&[ModeConfig::sampled(ModeKind::Surface, "flow", tf.clone())]),
        "modes[0].volume: a surface mode needs a scalar volume, but \"flow\" is a vector volume"
    );
    assert!(
        err(&[ModeConfig::sampled(ModeKind::Vortex, "nothing", tf.clone())])
            .starts_with("modes[0].volume: no volume named \"nothing\"")
    );
    let mut with_mu = ModeConfig::sampled(ModeKind::Surface, "density", tf.clone());
    with_mu.mu = Some(0.3);
    assert_eq!(
        err(&[with_mu]),
        "modes[0].mu: a surface mode does not use this key"
    );
    assert_eq!(
        err(&[ModeConfig::new(ModeKind::Viscosity)]),
        "modes[0].volume: a viscosity mode needs this key"
    );
    assert_eq!(
        err(&[
            ModeConfig::sampled(ModeKind::Viscosity, "density", tf.clone()),
            ModeConfig::friction("viscosity", 0.2)
        ]),
        "modes[1].surface: mode \"viscosity\" is a viscosity mode, not a surface mode"
    );
    assert!(err(&[
        ModeConfig::sampled(ModeKind::Surface, "density", tf.clone()),
        ModeConfig::sampled(ModeKind::Surface, "density", tf.clone()),
    ])
    .starts_with("modes[1].name: \"surface\" is used by another mode"));
    assert!(err(&[ModeConfig::friction("surface", -1.0)]).starts_with("modes[0].mu"));
    // The documented limits (docs/reference/scene.md): mu up to 10, a support plane up to 1e6 N and 1000 m.
    assert_eq!(
        err(&[ModeConfig::friction("surface", 1e300)]),
        "modes[0].mu: must be a finite number from 0 to 10, got 1e300"
    );
    assert_eq!(
        err(&[ModeConfig::friction("surface", 10.5)]),
        "modes[0].mu: must be a finite number from 0 to 10, got 10.5"
    );
    let plane = |point: DVec3, strength: f64| ModeConfig::support_plane(point, DVec3::Z, strength);
    assert_eq!(
        err(&[plane(DVec3::ZERO, 2e6)]),
        "modes[0].strength_n: must be a finite number from 0 to 1000000 N, got 2000000"
    );
    assert_eq!(
        err(&[plane(DVec3::ZERO, f64::INFINITY)]),
        "modes[0].strength_n: must be a finite number from 0 to 1000000 N, got inf"
    );
    assert_eq!(
        err(&[plane(DVec3::new(0.0, 0.0, -1e300), 1.0)]),
        "modes[0].point_m: must be three finite numbers, each from -1000 to 1000 m, got [0, 0, -1e300]"
    );
    assert!(RenderScene::new(500.0, volumes(), &[plane(DVec3::splat(1e3), 1e6)]).is_ok());
    // A switched-off mode keeps its settings, so they are checked too.
    let off = ModeConfig {
        enabled: Some(false),
        ..plane(DVec3::ZERO, 1e300)
    };
    assert!(err(&[off]).starts_with("modes[0].strength_n"));
    assert!(
        err(&[ModeConfig::support_plane(DVec3::ZERO, DVec3::ZERO, 1.0)])
            .starts_with("modes[0].normal")
    );
    assert!(err(&vec![
        ModeConfig::support_plane(DVec3::ZERO, DVec3::Z, 1.0);
        9
    ])
    .contains("more than the 8"));
    assert!(RenderScene::new(f64::NAN, volumes(), &[]).is_err());
}
