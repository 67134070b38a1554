//! Unit tests of `path`.

use super::*;

fn target(path: &HandPath, t_s: f64) -> (DVec3, DVec3) {
    match path.drive_at(t_s) {
        HandDrive::Target {
            position_m,
            velocity_m_per_s,
        } => (position_m, velocity_m_per_s),
        HandDrive::Force { .. } => panic!("expected a target"),
    }
}

#[test]
fn line_moves_then_holds() {
    let path = HandPath::Line {
        from_m: DVec3::ZERO,
        to_m: DVec3::new(0.1, 0.0, 0.0),
        duration_s: 2.0,
    };
    let (p, v) = target(&path, 1.0);
    assert!((p - DVec3::new(0.05, 0.0, 0.0)).length() < 1e-15);
    assert!((v - DVec3::new(0.05, 0.0, 0.0)).length() < 1e-15);
    let (p, v) = target(&path, 5.0);
    assert_eq!(p, DVec3::new(0.1, 0.0, 0.0));
    assert_eq!(v, DVec3::ZERO);
    assert_eq!(target(&path, -1.0).0, DVec3::ZERO);
}

#[test]
fn circle_starts_on_x_for_z_normal_and_velocity_is_derivative() {
    let path = HandPath::Circle {
        center_m: DVec3::new(0.0, 0.0, 0.1),
        radius_m: 0.02,
        normal: DVec3::new(0.0, 0.0, 2.0),
        period_s: 4.0,
    };
    let (p0, _) = target(&path, 0.0);
    assert!((p0 - DVec3::new(0.02, 0.0, 0.1)).length() < 1e-15);
    let (p1, _) = target(&path, 1.0);
    assert!((p1 - DVec3::new(0.0, 0.02, 0.1)).length() < 1e-15);
    let h = 1e-6;
    let (pa, _) = target(&path, 0.7 - h);
    let (pb, _) = target(&path, 0.7 + h);
    let (_, v) = target(&path, 0.7);
    assert!(((pb - pa) / (2.0 * h) - v).length() < 1e-8);
}

#[test]
fn raster_visits_the_corners_in_boustrophedon_order() {
    let path = HandPath::Raster {
        origin_m: DVec3::ZERO,
        sweep_m: DVec3::new(0.04, 0.0, 0.0),
        step_m: DVec3::new(0.0, 0.02, 0.0),
        lines: 3,
        speed_m_per_s: 0.01,
    };
    // Passes of 0.04 m and steps of 0.01 m: corners at 0, 4, 5, 9, 10, 14 s.
    let expected = [
        (0.0, DVec3::new(0.0, 0.0, 0.0)),
        (4.0, DVec3::new(0.04, 0.0, 0.0)),
        (5.0, DVec3::new(0.04, 0.01, 0.0)),
        (9.0, DVec3::new(0.0, 0.01, 0.0)),
        (10.0, DVec3::new(0.0, 0.02, 0.0)),
        (14.0, DVec3::new(0.04, 0.02, 0.0)),
        (100.0, DVec3::new(0.04, 0.02, 0.0)),
    ];
    for (t_s, corner) in expected {
        let (p, _) = target(&path, t_s);
        assert!((p - corner).length() < 1e-12, "t = {t_s}: {p} != {corner}");
    }
    let (_, v) = target(&path, 6.0);
    assert!((v - DVec3::new(-0.01, 0.0, 0.0)).length() < 1e-15);
}

#[test]
fn waypoints_skip_repeated_points_and_hold_at_the_end() {
    let path = HandPath::Waypoints {
        points_m: vec![
            DVec3::ZERO,
            DVec3::ZERO,
            DVec3::new(0.0, 0.0, 0.03),
            DVec3::new(0.04, 0.0, 0.03),
        ],
        speed_m_per_s: 0.01,
    };
    let (p, v) = target(&path, 4.0);
    assert!((p - DVec3::new(0.01, 0.0, 0.03)).length() < 1e-15);
    assert!((v - DVec3::new(0.01, 0.0, 0.0)).length() < 1e-15);
    assert_eq!(target(&path, 8.0).0, DVec3::new(0.04, 0.0, 0.03));
    let single = HandPath::Waypoints {
        points_m: vec![DVec3::ONE],
        speed_m_per_s: 1.0,
    };
    assert_eq!(single.target_at(3.0), Some(DVec3::ONE));
}

#[test]
fn force_profiles() {
    let ramp = ForceProfile::Ramp {
        from_n: DVec3::ZERO,
        to_n: DVec3::new(0.0, 0.0, -2.0),
        duration_s: 1.0,
    };
    assert_eq!(ramp.force_at(0.5), DVec3::new(0.0, 0.0, -1.0));
    assert_eq!(ramp.force_at(3.0), DVec3::new(0.0, 0.0, -2.0));
    let sine = ForceProfile::Sine {
        offset_n: DVec3::X,
        amplitude_n: DVec3::Y,
        frequency_hz: 1.0,
    };
    assert!((sine.force_at(0.25) - DVec3::new(1.0, 1.0, 0.0)).length() < 1e-12);
    let path = HandPath::Force { profile: ramp };
    assert_eq!(path.target_at(0.5), None);
}

#[test]
fn validation_names_the_bad_parameter() {
    let bad = HandPath::Line {
        from_m: DVec3::ZERO,
        to_m: DVec3::X,
        duration_s: 0.0,
    };
    let message = bad.validate().unwrap_err().to_string();
    assert!(message.contains("path.duration_s"), "{message}");
    let bad = HandPath::Circle {
        center_m: DVec3::ZERO,
        radius_m: 0.01,
        normal: DVec3::ZERO,
        period_s: 1.0,
    };
    assert!(bad.validate().unwrap_err().to_string().contains("normal"));
    let bad = HandPath::Waypoints {
        points_m: vec![DVec3::new(f64::NAN, 0.0, 0.0)],
        speed_m_per_s: 1.0,
    };
    assert!(bad.validate().is_err());
    let empty = HandPath::Waypoints {
        points_m: vec![],
        speed_m_per_s: 1.0,
    };
    assert_eq!(empty.validate(), Err(SimError::EmptyWaypoints));
}

#[test]
fn paths_parse_from_toml() {
    #[derive(Deserialize)]
    struct Wrapper {
        path: HandPath,
    }
    let text = r#"
        path = { kind = "circle", center_m = [0.0, 0.0, 0.1], radius_m = 0.02, normal = [0.0, 0.0, 1.0], period_s = 2.0 }
    "#;
    let parsed: Wrapper = toml::from_str(text).expect("circle parses");
    assert!(matches!(parsed.path, HandPath::Circle { .. }));
    let text = r#"
        [path]
        kind = "force"
        profile = { shape = "constant", force_n = [0.0, 0.0, -1.5] }
    "#;
    let parsed: Wrapper = toml::from_str(text).expect("force parses");
    assert_eq!(
        parsed.path,
        HandPath::Force {
            profile: ForceProfile::Constant {
                force_n: DVec3::new(0.0, 0.0, -1.5)
            }
        }
    );
    let typo = r#"path = { kind = "hold", at_m = [0.0, 0.0, 0.0], at_mm = 1 }"#;
    assert!(toml::from_str::<Wrapper>(typo).is_err());
}
