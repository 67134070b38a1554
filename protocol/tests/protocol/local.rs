//! The local-model capability (SPEC section 10): its vectors (written by vectors/generate.py, an independent
//! implementation), the decoder's refusals of malformed models, the octahedral direction's error bound (derived
//! in SPEC section 10.3, not measured from the code), the host's model builder against hand-worked cases, and the
//! device session with and without the capability.

use voxhap_protocol::local::{oct_decode, oct_encode, LOCAL_MODEL_TYPE};
use voxhap_protocol::{
    decode_report, DeviceInfo, DeviceSample, DeviceSession, DeviceToHost, Enable, ForceFlags,
    Hello, HostSession, HostToDevice, Label, LocalKind, LocalModel, LocalModelParams,
    LocalPassivity, LocalPassivityMode, LocalPrimitive, LocalState, LocalStatus, LocalTick,
    ModelFlags, PayloadError, RateSet, SetForce, SiPrimitive, StatusFlags, PROTOCOL_VERSION,
};

use crate::vectors::Expected;

/// The model of vectors/local/local_model.hex, from its comment line.
fn vector_model() -> LocalModel {
    LocalModel {
        sequence: 1234,
        expiry_us: 5000,
        flags: ModelFlags::TRUNCATED,
        stiffness_n_per_m: 20_000,
        damping_mn_s_per_m: 2500,
        force_limit_mn: 4000,
        anchor_m: [0.01, -0.02, 0.03],
        passivity: LocalPassivity::OFF,
        primitives: [
            Some(LocalPrimitive {
                kind: LocalKind::Directed,
                offset_um: [0; 3],
                direction_oct: [-32767, 0],
                strength_mn: 250,
            }),
            Some(LocalPrimitive {
                kind: LocalKind::Plane,
                offset_um: [0, 0, -150],
                // (0, 0.6, -0.8): L1-normalised (0, 3/7, -4/7), folded (z < 0) to (1 - 3/7, 1) = (4/7, 1).
                direction_oct: [18724, 32767],
                strength_mn: 10_000,
            }),
            Some(LocalPrimitive {
                kind: LocalKind::Point,
                offset_um: [100, -200, 300],
                direction_oct: [0, 0],
                strength_mn: 1500,
            }),
        ],
    }
}

/// The model of vectors/local/local_model_wall.hex, from its comment line: a floor at z = 0.
fn wall_vector_model() -> LocalModel {
    LocalModel {
        sequence: 1,
        expiry_us: 5000,
        flags: ModelFlags::EMPTY,
        stiffness_n_per_m: 2000,
        damping_mn_s_per_m: 0,
        force_limit_mn: 3000,
        anchor_m: [0.0; 3],
        passivity: LocalPassivity::OFF,
        primitives: [
            Some(LocalPrimitive {
                kind: LocalKind::Plane,
                offset_um: [0; 3],
                direction_oct: [0, 0],
                strength_mn: 20_000,
            }),
            None,
            None,
        ],
    }
}

pub(crate) fn expected_local_vectors() -> Vec<(&'static str, Expected)> {
    vec![
        (
            "local/local_model",
            Expected::Host(HostToDevice::LocalModel(vector_model())),
        ),
        (
            "local/local_model_empty",
            Expected::Host(HostToDevice::LocalModel(LocalModel {
                sequence: 7,
                expiry_us: 1000,
                flags: ModelFlags::EMPTY,
                stiffness_n_per_m: 1,
                damping_mn_s_per_m: 0,
                force_limit_mn: 0,
                anchor_m: [0.0; 3],
                passivity: LocalPassivity::OFF,
                primitives: [None; 3],
            })),
        ),
        (
            "local/local_model_wall",
            Expected::Host(HostToDevice::LocalModel(wall_vector_model())),
        ),
        (
            "local/local_model_passivity",
            Expected::Host(HostToDevice::LocalModel(LocalModel {
                sequence: 2,
                stiffness_n_per_m: 40_000,
                passivity: LocalPassivity {
                    mode: LocalPassivityMode::Control,
                    damping_code: 4,
                },
                ..wall_vector_model()
            })),
        ),
        (
            "local/local_state_dissipating",
            Expected::Device(DeviceToHost::LocalState(LocalState {
                state_sequence: 1001,
                model_sequence: 2,
                model_age_us: 300,
                proxy_m: [0.0; 3],
                force_n: [0.0, 0.0, 0.75],
                bound_m: 0.0,
                worst_bound_m: 5e-8,
                peak_force_n: 1.25,
                status: LocalStatus(LocalStatus::ACTIVE.0 | LocalStatus::DISSIPATING.0),
                solves: 10,
            })),
        ),
        (
            "local/local_state",
            Expected::Device(DeviceToHost::LocalState(LocalState {
                state_sequence: 1000,
                model_sequence: 1234,
                model_age_us: 700,
                proxy_m: [0.01, -0.02, 0.0298],
                force_n: [0.0, 0.0, 3.5],
                bound_m: 1e-9,
                worst_bound_m: 2e-9,
                peak_force_n: 3.75,
                status: LocalStatus(LocalStatus::ACTIVE.0 | LocalStatus::CLAMPED.0),
                solves: 10,
            })),
        ),
    ]
}

/// SPEC section 10.3: the octahedral form's angular error is at most sqrt(18) * 0.5 / 32767 rad.
const OCT_BOUND_RAD: f64 = 6.5e-5;

fn angle(a: [f64; 3], b: [f64; 3]) -> f64 {
    let dot: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
    let na = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    let nb = b.iter().map(|x| x * x).sum::<f64>().sqrt();
    let cross = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let nc = cross.iter().map(|x| x * x).sum::<f64>().sqrt();
    nc.atan2(dot) + 0.0 * na * nb
}

#[test]
fn the_vectors_directions_decode_to_the_stated_ones() {
    let model = vector_model();
    let prims: Vec<SiPrimitive> = model.si_primitives().collect();
    assert!(angle(prims[0].direction, [-1.0, 0.0, 0.0]) <= OCT_BOUND_RAD);
    assert!(angle(prims[1].direction, [0.0, 0.6, -0.8]) <= OCT_BOUND_RAD);
    // Anchor plus offset, in metres: the plane's point is 150 um below the anchor.
    let expected_z = f64::from(0.03f32) - 150e-6;
    assert!((prims[1].position_m[2] - expected_z).abs() < 1e-12);
    assert_eq!(prims[2].strength_n, 1.5);
    assert_eq!(model.force_limit_n(), 4.0);
    assert_eq!(model.damping_n_s_per_m(), 2.5);
}

/// SPEC section 10.2: damping code c is at most 1.25 x 2^c N s/m; the builder picks the largest step not
/// above the asked damping, and the request survives the builder, the encoder and the decoder.
#[test]
fn the_passivity_request_travels_in_bits_9_to_13() {
    let steps = [1.25, 2.5, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0];
    for (code, step) in steps.iter().enumerate() {
        let request = LocalPassivity {
            mode: LocalPassivityMode::Observe,
            damping_code: code as u8,
        };
        assert_eq!(request.max_damping_n_s_per_m(), *step);
        assert_eq!(
            LocalPassivity::new(LocalPassivityMode::Observe, *step),
            request
        );
        // Just under the next step: still this one.
        assert_eq!(
            LocalPassivity::new(LocalPassivityMode::Observe, step * 1.99),
            request
        );
    }
    for (asked, code) in [(0.1, 0), (f64::NAN, 0), (1e9, 7)] {
        assert_eq!(
            LocalPassivity::new(LocalPassivityMode::Off, asked).damping_code,
            code
        );
    }
    for (mode, mode_code) in [
        (LocalPassivityMode::Off, 0u8),
        (LocalPassivityMode::Observe, 1),
        (LocalPassivityMode::Control, 2),
    ] {
        let params = LocalModelParams {
            passivity: LocalPassivity::new(mode, 20.0),
            ..params([0.0; 3])
        };
        let model = voxhap_protocol::build_local_model(&params, &[]).unwrap();
        let mut report = [0u8; 64];
        voxhap_protocol::encode_report(&HostToDevice::LocalModel(model), &mut report).unwrap();
        // Payload byte 7 (report byte 9) holds bits 8-15 of kinds_flags: the mode at its bits 1-2, the code
        // (4: 20 N s/m) at 3-5.
        assert_eq!(report[9], (mode_code << 1) | (4 << 3), "{mode:?}");
        assert_eq!(
            decode_report::<HostToDevice>(&report),
            Ok(HostToDevice::LocalModel(model))
        );
    }
}

proptest::proptest! {
    #[test]
    fn octahedral_directions_stay_within_the_spec_bound(
        x in -1.0f64..1.0, y in -1.0f64..1.0, z in -1.0f64..1.0,
    ) {
        proptest::prop_assume!(x.abs() + y.abs() + z.abs() > 1e-3);
        let oct = oct_encode([x, y, z]).expect("non-zero");
        proptest::prop_assert!(oct.iter().all(|&c| c >= -32767));
        let decoded = oct_decode(oct);
        proptest::prop_assert!(angle(decoded, [x, y, z]) <= OCT_BOUND_RAD, "{oct:?} -> {decoded:?}");
        let norm = decoded.iter().map(|c| c * c).sum::<f64>().sqrt();
        proptest::prop_assert!((norm - 1.0).abs() < 1e-12);
    }
}

#[test]
fn the_bound_is_tight_enough_to_fail_on_a_wrong_fold() {
    // The negative hemisphere decoded without the fold is far off: the bound above can fail.
    let oct = oct_encode([0.0, 0.6, -0.8]).expect("non-zero");
    let s = 32767.0;
    let (u, v) = (f64::from(oct[0]) / s, f64::from(oct[1]) / s);
    let unfolded = [u, v, 1.0 - u.abs() - v.abs()];
    assert!(angle(unfolded, [0.0, 0.6, -0.8]) > 0.1);
}

/// The HID report of the local_model vector, patched by `patch` (HID: no CRC to redo).
fn patched_report(patch: impl FnOnce(&mut [u8])) -> Result<HostToDevice, PayloadError> {
    let mut report = [0u8; 64];
    report[0] = 0x01;
    let mut payload = [0u8; voxhap_protocol::MAX_PAYLOAD_LEN];
    let len = voxhap_protocol::Message::write_payload(
        &HostToDevice::LocalModel(vector_model()),
        &mut payload,
    );
    report[1] = LOCAL_MODEL_TYPE;
    report[2..2 + len].copy_from_slice(&payload[..len]);
    patch(&mut report[2..2 + len]);
    decode_report::<HostToDevice>(&report).map_err(|e| match e {
        voxhap_protocol::ReportError::Payload(p) => p,
        other => panic!("{other:?}"),
    })
}

fn invalid(field: &'static str) -> Result<HostToDevice, PayloadError> {
    Err(PayloadError::InvalidValue {
        message_type: LOCAL_MODEL_TYPE,
        field,
    })
}

#[test]
fn malformed_models_are_refused_with_the_field_named() {
    assert_eq!(
        patched_report(|_| {}),
        Ok(HostToDevice::LocalModel(vector_model()))
    );
    // SPEC section 10.2, offsets: expiry at 4, kinds at 6, stiffness at 8, anchor at 14, slots at 26 + 12 i.
    type Patch = Box<dyn Fn(&mut [u8])>;
    let cases: Vec<(&str, Patch, Result<HostToDevice, PayloadError>)> = vec![
        (
            "expiry 999",
            Box::new(|p| p[4..6].copy_from_slice(&999u16.to_le_bytes())),
            invalid("expiry_us"),
        ),
        (
            "expiry 50001",
            Box::new(|p| p[4..6].copy_from_slice(&50_001u16.to_le_bytes())),
            invalid("expiry_us"),
        ),
        (
            "stiffness 0",
            Box::new(|p| p[8..10].copy_from_slice(&[0, 0])),
            invalid("stiffness_n_per_m"),
        ),
        (
            "kind 5 in slot 0",
            Box::new(|p| p[6] = (p[6] & !0b111) | 5),
            invalid("kind"),
        ),
        (
            "kind 7 in slot 2",
            Box::new(|p| {
                p[6] |= 0b11 << 6;
                p[7] |= 1;
            }),
            invalid("kind"),
        ),
        (
            "slot 0 empty, slot 1 filled",
            Box::new(|p| {
                p[6] &= !0b111;
                p[26..38].fill(0);
            }),
            invalid("primitives"),
        ),
        (
            "empty slot with data",
            Box::new(|p| {
                p[6] &= !(0b11 << 6);
                p[7] &= !1;
            }),
            invalid("primitives"),
        ),
        (
            "passivity mode 3 (bits 9-10)",
            Box::new(|p| p[7] |= 0b11 << 1),
            invalid("passivity"),
        ),
        (
            "direction -32768",
            Box::new(|p| p[32..34].copy_from_slice(&i16::MIN.to_le_bytes())),
            invalid("direction_oct"),
        ),
        (
            "NaN anchor",
            Box::new(|p| p[14..18].copy_from_slice(&f32::NAN.to_le_bytes())),
            Err(PayloadError::NonFinite {
                message_type: LOCAL_MODEL_TYPE,
                field: "anchor_m",
            }),
        ),
    ];
    for (what, patch, expected) in cases {
        assert_eq!(patched_report(patch), expected, "{what}");
    }
}

fn params(anchor_m: [f64; 3]) -> LocalModelParams {
    LocalModelParams {
        sequence: 1,
        expiry_us: 5000,
        stiffness_n_per_m: 2000.0,
        damping_n_s_per_m: 1.0,
        force_limit_n: 5.0,
        anchor_m,
        passivity: LocalPassivity::OFF,
    }
}

fn si(kind: LocalKind, position_m: [f64; 3], direction: [f64; 3], strength_n: f64) -> SiPrimitive {
    SiPrimitive {
        kind,
        position_m,
        direction,
        strength_n,
    }
}

#[test]
fn directed_forces_are_summed_into_one_slot() {
    let prims = [
        si(LocalKind::Directed, [0.0; 3], [2.0, 0.0, 0.0], 1.0),
        si(LocalKind::Directed, [0.0; 3], [0.0, 1.0, 0.0], 1.0),
    ];
    let model = voxhap_protocol::build_local_model(&params([0.0; 3]), &prims).unwrap();
    assert_eq!(model.primitive_count(), 1);
    let slot = model.si_primitives().next().unwrap();
    assert_eq!(slot.kind, LocalKind::Directed);
    // |(1, 1, 0)| = sqrt 2 N = 1414.2 mN, sent as 1414 mN.
    assert_eq!(slot.strength_n, 1.414);
    let half = std::f64::consts::FRAC_1_SQRT_2;
    assert!(angle(slot.direction, [half, half, 0.0]) <= OCT_BOUND_RAD);
    assert!(model.flags.is_empty());
}

#[test]
fn the_nearest_primitives_are_kept_and_the_rest_flagged() {
    let point = |mm: f64| si(LocalKind::Point, [mm * 1e-3, 0.0, 0.0], [0.0; 3], 1.0);
    let prims = [point(5.0), point(1.0), point(4.0), point(2.0), point(3.0)];
    let model = voxhap_protocol::build_local_model(&params([0.0; 3]), &prims).unwrap();
    let xs: Vec<i16> = model
        .primitives
        .iter()
        .flatten()
        .map(|p| p.offset_um[0])
        .collect();
    assert_eq!(xs, [1000, 2000, 3000]);
    assert!(model.flags.contains(ModelFlags::TRUNCATED));
    // Exactly three: nothing dropped, no flag.
    let model = voxhap_protocol::build_local_model(&params([0.0; 3]), &prims[..3]).unwrap();
    assert!(!model.flags.contains(ModelFlags::TRUNCATED));
    // A directed force takes a slot: three points and a directed one drop the farthest point.
    let mut with_directed = prims[..3].to_vec();
    with_directed.push(si(LocalKind::Directed, [0.0; 3], [0.0, 0.0, 1.0], 0.5));
    let model = voxhap_protocol::build_local_model(&params([0.0; 3]), &with_directed).unwrap();
    let kinds: Vec<LocalKind> = model.primitives.iter().flatten().map(|p| p.kind).collect();
    assert_eq!(
        kinds,
        [LocalKind::Directed, LocalKind::Point, LocalKind::Point]
    );
    assert_eq!(model.primitives[1].unwrap().offset_um[0], 1000);
    assert_eq!(model.primitives[2].unwrap().offset_um[0], 4000);
    assert!(model.flags.contains(ModelFlags::TRUNCATED));
}

#[test]
fn planes_travel_as_their_point_nearest_the_anchor_and_far_points_are_dropped() {
    // The plane z = 0 through (0.05, 0.05, 0): nearest the anchor (0.01, 0.02, 0.001) is 1 mm straight below it.
    let anchor = [0.01, 0.02, 0.001];
    let prims = [
        si(LocalKind::Plane, [0.05, 0.05, 0.0], [0.0, 0.0, 3.0], 10.0),
        si(LocalKind::Point, [0.05, 0.0, 0.0], [0.0; 3], 1.0),
    ];
    let model = voxhap_protocol::build_local_model(&params(anchor), &prims).unwrap();
    assert_eq!(
        model.primitive_count(),
        1,
        "the point is 40 mm away: beyond the offset range"
    );
    let plane = model.primitives[0].unwrap();
    assert_eq!(plane.offset_um, [0, 0, -1000]);
    assert_eq!(plane.direction_oct, [0, 0]);
    assert!(model.flags.contains(ModelFlags::TRUNCATED));
}

#[test]
fn values_beyond_their_field_saturate_and_bad_ones_are_refused() {
    let prims = [si(LocalKind::Plane, [0.0; 3], [0.0, 0.0, 1.0], 100.0)];
    let mut p = params([0.0; 3]);
    p.force_limit_n = 70.0;
    let model = voxhap_protocol::build_local_model(&p, &prims).unwrap();
    assert_eq!(model.primitives[0].unwrap().strength_mn, 65_535);
    assert_eq!(model.force_limit_mn, 65_535);
    assert!(model.flags.contains(ModelFlags::SATURATED));
    for (what, bad) in [
        (
            "expiry",
            LocalModelParams {
                expiry_us: 999,
                ..params([0.0; 3])
            },
        ),
        (
            "stiffness",
            LocalModelParams {
                stiffness_n_per_m: f64::NAN,
                ..params([0.0; 3])
            },
        ),
        (
            "anchor",
            LocalModelParams {
                anchor_m: [0.0, f64::INFINITY, 0.0],
                ..params([0.0; 3])
            },
        ),
        (
            "limit",
            LocalModelParams {
                force_limit_n: -1.0,
                ..params([0.0; 3])
            },
        ),
    ] {
        let error = voxhap_protocol::build_local_model(&bad, &prims).unwrap_err();
        assert!(
            error.to_string().contains("out of range"),
            "{what}: {error}"
        );
    }
    let zero_direction = [si(LocalKind::Line, [0.0; 3], [0.0; 3], 1.0)];
    assert!(voxhap_protocol::build_local_model(&params([0.0; 3]), &zero_direction).is_err());
}

fn info() -> DeviceInfo {
    DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new("local").unwrap(),
        serial_number: Label::new("1").unwrap(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        supported_rates: RateSet::from_rates_hz(&[1000]).unwrap(),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 2000.0,
    }
}

fn drain(device: &mut DeviceSession) -> Vec<DeviceToHost> {
    std::iter::from_fn(|| device.poll_transmit()).collect()
}

fn open_and_enable(device: &mut DeviceSession, watchdog_timeout_us: u32) {
    device.on_message(
        &HostToDevice::Hello(Hello {
            version: PROTOCOL_VERSION,
        }),
        0,
    );
    device.on_message(
        &HostToDevice::Enable(Enable {
            watchdog_timeout_us,
        }),
        10,
    );
    drain(device);
}

#[test]
fn a_capable_device_takes_models_and_reports_its_loop_after_each_state() {
    let mut device = DeviceSession::with_local_model(info());
    open_and_enable(&mut device, 1000);
    assert!(device.status().contains(StatusFlags::LOCAL_MODEL));
    let mut model = vector_model();
    model.sequence = 5;
    device.on_message(&HostToDevice::LocalModel(model), 100);
    assert_eq!(
        device.local_model().map(|(m, at)| (m.sequence, at)),
        Some((5, 100))
    );
    // Two loop cycles, then the lockstep State: a LocalState follows it, summarising both cycles.
    for (force, bound) in [(3.0f32, 1e-9f32), (4.0, 3e-9)] {
        device.record_local_tick(&LocalTick {
            model_sequence: 5,
            model_age_us: 50,
            proxy_m: [0.0, 0.0, 0.001],
            force_n: [0.0, 0.0, force],
            bound_m: bound,
            status: LocalStatus::ACTIVE,
        });
    }
    device.poll(150, &DeviceSample::default());
    let sent = drain(&mut device);
    let [DeviceToHost::State(state), DeviceToHost::LocalState(local)] = sent[..] else {
        panic!("{sent:?}");
    };
    assert_eq!(state.last_force_sequence, 5);
    assert_eq!(local.state_sequence, state.sequence);
    assert_eq!(
        (local.peak_force_n, local.worst_bound_m, local.solves),
        (4.0, 3e-9, 2)
    );
    assert_eq!(local.force_n, [0.0, 0.0, 4.0]);
    // Models feed the watchdog; silence trips it, and the model is gone.
    for t in (600..5000).step_by(500) {
        device.on_message(&HostToDevice::LocalModel(model), t);
        device.poll(t, &DeviceSample::default());
    }
    assert_eq!(device.stats().watchdog_trips, 0);
    device.poll(6600, &DeviceSample::default());
    assert_eq!(device.stats().watchdog_trips, 1);
    assert!(device.local_model().is_none());
}

#[test]
fn a_set_force_returns_a_capable_device_to_the_set_force_path() {
    let mut device = DeviceSession::with_local_model(info());
    open_and_enable(&mut device, 0);
    device.on_message(&HostToDevice::LocalModel(vector_model()), 100);
    assert!(device.local_model().is_some());
    let set_force = SetForce {
        sequence: 9,
        force_n: [1.0, 0.0, 0.0],
        flags: ForceFlags::EMPTY,
    };
    device.on_message(&HostToDevice::SetForce(set_force), 200);
    assert!(device.local_model().is_none());
    assert_eq!(device.poll(210, &DeviceSample::default()), [1.0, 0.0, 0.0]);
}

#[test]
fn a_device_without_the_capability_ignores_models_and_keeps_set_force() {
    let mut device = DeviceSession::new(info());
    open_and_enable(&mut device, 0);
    assert!(!device.status().contains(StatusFlags::LOCAL_MODEL));
    device.on_message(&HostToDevice::LocalModel(vector_model()), 100);
    assert!(device.local_model().is_none());
    assert_eq!(device.stats().local_models_ignored, 1);
    // Not answered (a firmware without the capability drops the type unread), and the force path is untouched.
    device.poll(110, &DeviceSample::default());
    assert!(drain(&mut device).is_empty());
    let set_force = SetForce {
        sequence: 2,
        force_n: [0.0, 2.0, 0.0],
        flags: ForceFlags::EMPTY,
    };
    device.on_message(&HostToDevice::SetForce(set_force), 120);
    assert_eq!(device.poll(130, &DeviceSample::default()), [0.0, 2.0, 0.0]);
    drain(&mut device);
    // Even a recorded local cycle adds no LocalState to its States.
    device.record_local_tick(&LocalTick::default());
    device.on_message(&HostToDevice::SetForce(set_force), 140);
    device.poll(150, &DeviceSample::default());
    let sent = drain(&mut device);
    assert!(matches!(sent[..], [DeviceToHost::State(_)]), "{sent:?}");
}

#[test]
fn the_host_numbers_models_in_the_set_force_sequence() {
    let mut host = HostSession::new();
    let HostToDevice::SetForce(first) = host.set_force([0.0; 3], ForceFlags::EMPTY) else {
        panic!()
    };
    let prims = [si(LocalKind::Plane, [0.0; 3], [0.0, 0.0, 1.0], 1.0)];
    let Ok(HostToDevice::LocalModel(model)) = host.local_model(&params([0.0; 3]), &prims) else {
        panic!()
    };
    let bad = LocalModelParams {
        expiry_us: 0,
        ..params([0.0; 3])
    };
    assert!(host.local_model(&bad, &prims).is_err());
    let HostToDevice::SetForce(third) = host.set_force([0.0; 3], ForceFlags::EMPTY) else {
        panic!()
    };
    assert_eq!((first.sequence, model.sequence, third.sequence), (1, 2, 3));
    assert_eq!(host.forces_in_flight(), 3);
}
