//! Unit tests of `profile`.

use super::*;
use crate::drivers::falcon::FalconGeometry;
use crate::drivers::woodenhaptics_constants::WoodenHapticsConstants;

fn parse(text: &str) -> Result<DeviceProfile, ProfileError> {
    DeviceProfile::parse(text, "test.toml")
}

#[test]
fn every_builtin_profile_parses() {
    for (name, text) in BUILTIN_PROFILES {
        let profile = DeviceProfile::parse(text, name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(profile.name, *name);
        assert!(DeviceProfile::resolve(name).is_ok());
    }
}

#[test]
fn an_empty_profile_is_the_identity_with_the_devices_limits() {
    let profile = parse("").unwrap();
    assert_eq!(
        profile.mapping,
        MappingChoice::Fixed(WorkspaceMapping::IDENTITY)
    );
    assert_eq!(profile.limits, ProfileLimits::default());
    let mut config = SupervisorConfig::default();
    profile.apply_to(&mut config);
    assert_eq!(config, SupervisorConfig::default());
}

#[test]
fn limits_only_lower() {
    let profile = parse(
        "[limits]\nmax_force_n = 1.5\nslew_n_per_ms = 9.0\nmax_speed_m_per_s = 2\n\
         max_stiffness_n_per_m = 800\n[velocity_filter]\ncutoff_hz = 30\n",
    )
    .unwrap();
    let mut config = SupervisorConfig::default();
    profile.apply_to(&mut config);
    assert_eq!(config.safety.max_force_n, 1.5);
    // 9 N/ms asks for more than the default 0.5: the default holds.
    assert_eq!(config.safety.slew_n_per_ms, 0.5);
    assert_eq!(config.input.max_speed_m_per_s, 2.0);
    assert_eq!(config.input.velocity_cutoff_hz, 30.0);
    assert_eq!(profile.felt_stiffness_limit_n_per_m(1000.0), 800.0);
    assert_eq!(profile.felt_stiffness_limit_n_per_m(500.0), 500.0);
    let mut info = DeviceInfo::basic("x", DVec3::splat(-0.1), DVec3::splat(0.1));
    info.max_force_n = 1.0;
    let notes = profile.notes_against(&info);
    assert_eq!(notes.len(), 1, "{notes:?}");
    assert!(notes[0].contains("limits.max_force_n = 1.5"), "{notes:?}");
}

#[test]
fn bad_values_name_their_key() {
    for (text, key) in [
        ("[limits]\nmax_force_n = -1\n", "limits.max_force_n"),
        ("[limits]\nmax_force_n = nan\n", "limits.max_force_n"),
        (
            "[limits]\nmax_stiffness_n_per_m = 0\n",
            "limits.max_stiffness_n_per_m",
        ),
        (
            "[limits]\nmax_damping_n_s_per_m = -0.1\n",
            "limits.max_damping_n_s_per_m",
        ),
        ("[limits]\nmax_force = 1\n", "limits.max_force"),
        (
            "[velocity_filter]\ncutoff_hz = inf\n",
            "velocity_filter.cutoff_hz",
        ),
        ("[mapping]\nscale = 0\n", "mapping.scale"),
        ("[mapping]\nscale = \"big\"\n", "mapping.scale"),
        (
            "[mapping]\ntranslation_m = [0, 0]\n",
            "mapping.translation_m",
        ),
        (
            "[mapping]\nrotation_matrix = [[1,0,0],[0,1,0],[0,0,-1]]\n",
            "mapping.rotation_matrix",
        ),
        (
            "[mapping]\nrotation_deg = [0, 0, inf]\n",
            "mapping.rotation_deg",
        ),
        (
            "[mapping]\nrotation_deg = [0,0,0]\nrotation_matrix = [[1,0,0],[0,1,0],[0,0,1]]\n",
            "mapping.rotation_matrix",
        ),
        ("[mapping]\nfit_volume = true\nscale = 2\n", "mapping.scale"),
        ("device = \"phantom\"\n", "device"),
        ("base = \"nothing\"\n", "base"),
        ("colour = 3\n", "colour"),
        ("[kinematics]\nproximal_link_m = 0.07\n", "kinematics"),
        (
            "device = \"haply2diy\"\n[kinematics]\nproximal_link_m = -0.07\n",
            "kinematics.proximal_link_m",
        ),
        (
            "device = \"haply2diy\"\n[kinematics]\nlink = 0.07\n",
            "kinematics.link",
        ),
        (
            "device = \"woodenhaptics-hid\"\n[kinematics]\nlink_length_m = [0.08, 0.2]\n",
            "kinematics.link_length_m",
        ),
        (
            "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\ncapstan_diameter_m = [0.01, 0, 0.01]\n",
            "kinematics.woodenhaptics.capstan_diameter_m",
        ),
        (
            "device = \"woodenhaptics\"\n[kinematics.polhem]\ntorque_constant_n_m_per_a = [0.06, -0.05, 0.05]\n",
            "kinematics.polhem.torque_constant_n_m_per_a",
        ),
        (
            "device = \"woodenhaptics\"\n[kinematics.vintage]\nworkspace_origin_m = [0.1, nan, 0]\n",
            "kinematics.vintage.workspace_origin_m",
        ),
        (
            "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\nlink_length_m = [0.08, inf, 0.2]\n",
            "kinematics.woodenhaptics.link_length_m",
        ),
        (
            "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\ncounts_per_revolution = \"2000\"\n",
            "kinematics.woodenhaptics.counts_per_revolution",
        ),
        (
            "device = \"woodenhaptics\"\n[kinematics.woody]\nlink_length_m = [0.08, 0.2, 0.2]\n",
            "kinematics.woody",
        ),
        (
            "device = \"falcon\"\n[kinematics]\na_m = 0\n",
            "kinematics.a_m",
        ),
        (
            "device = \"falcon\"\n[kinematics]\nwheel_slots = -320\n",
            "kinematics.wheel_slots",
        ),
        (
            "device = \"falcon\"\n[kinematics]\ns_m = nan\n",
            "kinematics.s_m",
        ),
        (
            "device = \"falcon\"\n[kinematics]\nlength = 0.06\n",
            "kinematics.length",
        ),
        ("[limits\n", "(syntax)"),
        ("[workspace]\nmin_m = [0, 0, 0]\n", "workspace.max_m"),
        (
            "[workspace]\nmin_m = [0, 0, 0]\nmax_m = [0, -1, 0]\n",
            "workspace.max_m",
        ),
    ] {
        let error = parse(text).expect_err(text).to_string();
        assert!(
            error.starts_with(&format!("device profile test.toml: {key}")),
            "{text:?} gave {error:?}, expected key {key}"
        );
    }
}

/// A value of the wrong type in any table of a profile is refused naming the key's full path.
#[test]
fn every_table_names_the_key_of_a_wrong_typed_value() {
    for (text, expected) in [
        ("name = 3\n", "name: invalid type: integer `3`, expected a string"),
        ("device = [\"sim\"]\n", "device: invalid type: sequence, expected a string"),
        ("base = 3\n", "base: must be a string"),
        (
            "[mapping]\nfit_volume = \"yes\"\n",
            "mapping.fit_volume: invalid type: string \"yes\", expected a boolean",
        ),
        (
            "[mapping]\nrotation_matrix = [[1, 0, 0], [0, 1, 0], [0, 0, \"1\"]]\n",
            "mapping.rotation_matrix[2][2]: invalid type: string \"1\", expected f64",
        ),
        (
            "[limits]\nslew_n_per_ms = \"fast\"\n",
            "limits.slew_n_per_ms: invalid type: string \"fast\", expected f64",
        ),
        (
            "[velocity_filter]\ncutoff_hz = [50]\n",
            "velocity_filter.cutoff_hz: invalid type: sequence, expected f64",
        ),
        (
            "[workspace]\nmin_m = [0, 0, \"low\"]\nmax_m = [1, 1, 1]\n",
            "workspace.min_m[2]: invalid type: string \"low\", expected f64",
        ),
        (
            "device = \"haply2diy\"\n[kinematics]\nencoder_offset_deg = [0.0]\n",
            "kinematics.encoder_offset_deg: invalid length 1, expected an array of length 2",
        ),
        (
            "device = \"falcon\"\n[kinematics]\na_m = \"long\"\n",
            "kinematics.a_m: must be a number or an array of numbers",
        ),
        (
            "device = \"woodenhaptics\"\n[kinematics.polhem]\nencoder_home_counts = [1.5, 0, 0]\n",
            "kinematics.polhem.encoder_home_counts[0]: invalid type: floating point `1.5`, expected i32",
        ),
        (
            "device = \"woodenhaptics-hid\"\n[kinematics]\nencoder_home_counts = [0, 0, 0]\n",
            "kinematics.encoder_home_counts: the legacy HID driver has no encoder home offset",
        ),
    ] {
        let error = parse(text).expect_err(text).to_string();
        let expected = format!("device profile test.toml: {expected}");
        assert!(
            error.starts_with(&expected),
            "{text:?}:\nexpected {expected:?}\n     got {error:?}"
        );
    }
}

#[test]
fn base_profiles_are_overlaid_key_by_key() {
    let profile = parse(
        "base = \"haply2diy\"\nname = \"bench arm\"\n[kinematics]\ndistal_link_m = 0.095\n\
         [limits]\nmax_force_n = 1.0\n",
    )
    .unwrap();
    assert_eq!(profile.name, "bench arm");
    assert_eq!(profile.device.as_deref(), Some("haply2diy"));
    let builtin = DeviceProfile::resolve("haply2diy").unwrap();
    assert_eq!(profile.mapping, builtin.mapping);
    let mut config = Haply2DiyConfig::default();
    profile.apply_haply2diy(&mut config);
    assert_eq!(config.distal_link_m, 0.095);
    assert_eq!(
        config.proximal_link_m,
        Haply2DiyConfig::default().proximal_link_m
    );
    assert_eq!(profile.limits.max_force_n, Some(1.0));
}

#[test]
fn the_docs_example_profile_parses() {
    // docs/workspace.md: a 2DIY rotated a quarter turn, magnified twice, gentler force.
    let profile = parse(
        "base = \"haply2diy\"\n[limits]\nmax_force_n = 1.0\nmax_stiffness_n_per_m = 1500\n\
         [mapping]\nscale = 2.0\ntranslation_m = [0.0, -0.16, 0.0]\nrotation_deg = [0, 0, 90]\n",
    )
    .unwrap();
    let MappingChoice::Fixed(m) = profile.mapping else {
        panic!("fixed mapping expected");
    };
    // The device's +x becomes the scene's +y, doubled; the 2DIY's box middle (0, 0.08) lands at (-0.16, -0.16).
    let p = m.to_scene_position_m(DVec3::new(0.0, 0.08, 0.0));
    assert!((p - DVec3::new(-0.16, -0.16, 0.0)).length() < 1e-12, "{p}");
    assert_eq!(profile.device.as_deref(), Some("haply2diy"));
}

#[test]
fn fit_volume_profiles_fit_and_fixed_ones_do_not() {
    let profile = parse("[mapping]\nfit_volume = true\nrotation_deg = [0, 0, 90]\n").unwrap();
    let device = (DVec3::splat(-0.05), DVec3::splat(0.05));
    let volume = (DVec3::splat(-0.1), DVec3::splat(0.1));
    let m = profile
        .mapping_for(device.0, device.1, Some(volume))
        .unwrap();
    assert!((m.scale() - 2.0).abs() < 1e-12);
    assert!(profile.mapping_for(device.0, device.1, None).is_err());
    // A measured workspace replaces the declared one.
    let measured = parse(
        "[mapping]\nfit_volume = true\n[workspace]\nmin_m = [-0.02, -0.02, -0.02]\nmax_m = [0.02, 0.02, 0.02]\n",
    )
    .unwrap();
    let m = measured
        .mapping_for(device.0, device.1, Some(volume))
        .unwrap();
    assert!((m.scale() - 5.0).abs() < 1e-12, "{}", m.scale());
    let fixed = parse("[mapping]\nscale = 3\ntranslation_m = [0, 0.1, 0]\n").unwrap();
    let m = fixed.mapping_for(device.0, device.1, Some(volume)).unwrap();
    assert_eq!(m.scale(), 3.0);
    assert_eq!(m.translation_m(), DVec3::new(0.0, 0.1, 0.0));
}

#[test]
fn a_real_device_defaults_to_its_builtin_and_fits_only_what_is_out_of_reach() {
    let mut falcon = DeviceProfile::default_for("falcon").unwrap();
    assert_eq!(falcon.device.as_deref(), Some("falcon"));
    assert!(!falcon.mapping_given);
    let builtin = DeviceProfile::resolve("falcon").unwrap();
    assert!(
        builtin.mapping_given,
        "a built-in named on purpose is a mapping given"
    );
    assert_eq!(falcon.mapping, builtin.mapping);
    // No built-in for the voxhap protocol: the identity.
    let mock = DeviceProfile::default_for("mock").unwrap();
    assert_eq!(mock.name, "default (mock)");
    assert_eq!(mock.mapping, DeviceProfile::default().mapping);
    assert_eq!(mock.kinematics, Kinematics::Default);
    falcon.fit_when_out_of_reach();
    let MappingChoice::FitWhenOutOfReach(given) = falcon.mapping else {
        panic!("{:?}", falcon.mapping);
    };
    // The Falcon's box: x, y ±0.06 m, z 0.075 .. 0.175 m; the built-in centres it on the origin.
    let device = (
        DVec3::new(-0.06, -0.06, 0.075),
        DVec3::new(0.06, 0.06, 0.175),
    );
    let small = (DVec3::splat(-0.04), DVec3::splat(0.04));
    assert_eq!(
        falcon.mapping_for(device.0, device.1, Some(small)).unwrap(),
        given
    );
    assert_eq!(falcon.mapping_for(device.0, device.1, None).unwrap(), given);
    let head = (DVec3::new(-0.1, -0.12, 0.2), DVec3::new(0.1, 0.12, 0.4));
    let fitted = falcon.mapping_for(device.0, device.1, Some(head)).unwrap();
    assert!((fitted.scale() - 2.0).abs() < 1e-12, "{}", fitted.scale());
    assert!(fitted.reaches(device.0, device.1, head.0, head.1));
    // Only the user's own [mapping] counts as given; one inherited through base does not.
    assert!(parse("[mapping]\nscale = 2\n").unwrap().mapping_given);
    assert!(
        !parse("base = \"falcon\"\n[limits]\nmax_force_n = 2\n")
            .unwrap()
            .mapping_given
    );
}

#[test]
fn the_woodenhaptics_builtin_lists_hfabapis_published_constants() {
    let profile = DeviceProfile::resolve("woodenhaptics").unwrap();
    let mut config = WoodyConfig::default();
    profile.apply_woodenhaptics(&mut config);
    for model in [
        WoodyModel::WoodenHaptics,
        WoodyModel::Polhem,
        WoodyModel::VintagePhantom,
    ] {
        assert_ne!(
            config.model_constants[model.index()],
            WoodenHapticsConstants::default()
        );
        assert_eq!(
            config.model_constants[model.index()].applied_to(model.config()),
            model.config(),
            "{model:?}"
        );
    }
}

/// Changing a WoodenHaptics constant changes position and current as hfabapi's equations predict
/// (serial chain: x = cos θA (Lb sin θB + Lc sin θC) - origin; current = τ dir d_capstan / d_body / k_t).
#[test]
fn a_woodenhaptics_profile_constant_changes_position_and_current_as_predicted() {
    let profile = parse(
        "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\nlink_length_m = [0.080, 0.250, 0.245]\n\
         torque_constant_n_m_per_a = [0.0518, 0.0259, 0.0259]\nencoder_home_counts = [0, 0, -5000]\n",
    )
    .unwrap();
    let mut config = WoodyConfig::default();
    profile.apply_woodenhaptics(&mut config);
    let published = WoodyModel::WoodenHaptics.config();
    let changed = config.model_constants[WoodyModel::WoodenHaptics.index()].applied_to(published);
    // Body B straight up (θB = π/2), C level (θC = 0), A at 0: x = Lb - origin_x.
    let theta = [0.0, std::f64::consts::FRAC_PI_2, 0.0];
    let before = published.position_m(theta).unwrap();
    let after = changed.position_m(theta).unwrap();
    assert!(
        (after.x - before.x - (0.250 - 0.205)).abs() < 1e-12,
        "{before} {after}"
    );
    assert!((after.y - before.y).abs() < 1e-12 && (after.z - before.z).abs() < 1e-12);
    // A sideways force of 1 N loads joint A only at this pose: τA = reach = Lb, and motor A's current is
    // τA · d_capstan / d_body / k_t (mA, truncated): 0.205 m and 0.0259 N m/A before, 0.250 m and
    // 0.0518 N m/A after.
    let force = DVec3::new(0.0, 1.0, 0.0);
    let ma_before = published.currents_ma(theta, force, 6000);
    let ma_after = changed.currents_ma(theta, force, 6000);
    let predicted = |reach: f64, k_t: f64| (reach * 0.010 / 0.160 / k_t * 1000.0) as i32;
    assert_eq!(ma_before, [predicted(0.205, 0.0259), 0, 0]);
    assert_eq!(ma_after, [predicted(0.250, 0.0518), 0, 0]);
    // The home count moves joint C by 1000 counts through the capstan: 2π·1000/2000 · 10/120 rad.
    let raw = [0, 0, 0];
    let dc = changed.joint_angles_rad(raw)[2] - published.joint_angles_rad(raw)[2];
    let expected = -2.0 * std::f64::consts::PI * 1000.0 / 2000.0 * 0.010 / 0.120;
    assert!((dc - expected).abs() < 1e-12, "{dc} vs {expected}");
    // The other models keep their published constants.
    assert_eq!(
        config.model_constants[WoodyModel::Polhem.index()],
        WoodenHapticsConstants::default()
    );
}

#[test]
fn the_falcon_builtin_lists_libnifalcons_constants_and_a_change_moves_the_handle_as_predicted() {
    let mut config = FalconConfig::default();
    DeviceProfile::resolve("falcon")
        .unwrap()
        .apply_falcon(&mut config);
    assert_eq!(config.geometry, FalconGeometry::LIBNIFALCON);
    assert!(matches!(
        DeviceProfile::resolve("falcon").unwrap().kinematics,
        Kinematics::Falcon(_)
    ));
    // The leg angle is count · (π·shaft / (slots·4)) / (π·arm / 360) + offset (FalconKinematic.h:59-62):
    // doubling the shaft diameter doubles the angle per count; moving the offset moves every angle.
    let profile = parse(
        "device = \"falcon\"\n[kinematics]\nshaft_diameter_m = 0.0285\ntheta_offset_deg = 30\n",
    )
    .unwrap();
    let mut changed = FalconConfig::default();
    profile.apply_falcon(&mut changed);
    let (published, changed) = (FalconGeometry::LIBNIFALCON, changed.geometry);
    assert_eq!(
        changed.a_m, published.a_m,
        "keys not given keep libnifalcon's"
    );
    let per_count = |g: &FalconGeometry| g.leg_angle_rad(100) - g.leg_angle_rad(0);
    assert!((per_count(&changed) - 2.0 * per_count(&published)).abs() < 1e-12);
    assert!((changed.leg_angle_rad(0) - 30f64.to_radians()).abs() < 1e-12);
    // A longer thigh changes the inverse kinematics and so the torque for the same force.
    let longer = parse("device = \"falcon\"\n[kinematics]\na_m = 0.065\n").unwrap();
    let mut longer_config = FalconConfig::default();
    longer.apply_falcon(&mut longer_config);
    let p = DVec3::new(0.0, 0.0, 0.11);
    let up = DVec3::new(0.0, 0.0, 1.0);
    assert_ne!(
        longer_config.geometry.motor_commands(p, up),
        published.motor_commands(p, up)
    );
    // Round trip with the changed geometry: forward kinematics inverts its own inverse kinematics.
    let theta = longer_config.geometry.inverse_kinematics(p).theta1;
    let (found, converged) = longer_config
        .geometry
        .forward_kinematics(theta, DVec3::new(0.0, 0.0, 0.1));
    assert!(converged && (found - p).length() < 0.005, "{found}");
}

#[test]
fn the_device_pages_example_profiles_parse() {
    // docs/devices/woodenhaptics.md: only the keys given change, the base's other keys and models stay.
    let profile = parse(
        "base = \"woodenhaptics\"\n[kinematics.woodenhaptics]\nlink_length_m = [0.080, 0.207, 0.245]\n\
         encoder_home_counts = [0, 0, -5980]\n",
    )
    .unwrap();
    let mut config = WoodyConfig::default();
    profile.apply_woodenhaptics(&mut config);
    let woody = config.model_constants[WoodyModel::WoodenHaptics.index()]
        .applied_to(WoodyModel::WoodenHaptics.config());
    assert_eq!(woody.link_length_m, [0.080, 0.207, 0.245]);
    assert_eq!(woody.encoder_home, [0, 0, -5980]);
    assert_eq!(woody.capstan_diameter_m, [0.010; 3]);
    let polhem =
        config.model_constants[WoodyModel::Polhem.index()].applied_to(WoodyModel::Polhem.config());
    assert_eq!(polhem, WoodyModel::Polhem.config());
}

#[test]
fn unknown_names_list_the_builtins_and_files_are_read() {
    let error = DeviceProfile::resolve("no-such-profile")
        .unwrap_err()
        .to_string();
    assert!(error.contains("haply-inverse"), "{error}");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lab.toml");
    std::fs::write(&path, "name = \"lab\"\n[mapping]\nscale = 2\n").unwrap();
    let profile = DeviceProfile::resolve(path.to_str().unwrap()).unwrap();
    assert_eq!(profile.name, "lab");
    std::fs::write(&path, vec![b'#'; MAX_PROFILE_BYTES as usize + 1]).unwrap();
    let error = DeviceProfile::read(&path).unwrap_err().to_string();
    assert!(error.contains("too long"), "{error}");
}
