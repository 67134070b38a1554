//! The body of the cargo-fuzz target `local_model` (fuzz/fuzz_targets/local_model.rs includes this file), also run
//! by proptest in this crate's tests (tests/fuzz.rs) so it keeps compiling where no nightly toolchain exists.
//!
//! Arbitrary bytes become (1) a LocalModel payload for the decoder: what decodes re-encodes to the same bytes and
//! has finite, unit directions; (2) parameters and primitives for the host's builder: what it builds encodes and
//! decodes back unchanged; (3) a run of the device loop on whatever decoded, with handle positions from the bytes:
//! every force is finite, within the model's limit and the device's maximum, and rises no faster than the slew
//! limit.

#[path = "support/session.rs"]
mod session;

use session::{enabled_session, TestDevice};
use voxhap_local::{LocalLoop, LoopConfig, SLEW_N_PER_S};
use voxhap_protocol::{
    build_local_model, decode_report, encode_report, DeviceSample, HostToDevice, LocalKind,
    LocalModel, LocalModelParams, LocalPassivity, LocalPassivityMode, SiPrimitive,
};

const MAX_FORCE_N: f32 = 6.0;

/// Runs the three checks on `data`; panics if an invariant breaks.
pub fn run(data: &[u8]) {
    let decoded = decode_model(data);
    let built = build_from(data);
    for model in [decoded, built].into_iter().flatten() {
        drive(&model, data);
    }
}

fn decode_model(data: &[u8]) -> Option<LocalModel> {
    let mut report = [0u8; 64];
    report[0] = 0x01;
    report[1] = 0x08;
    let n = data.len().min(62);
    report[2..2 + n].copy_from_slice(&data[..n]);
    let Ok(HostToDevice::LocalModel(model)) = decode_report::<HostToDevice>(&report) else {
        return None;
    };
    let mut again = [0u8; 64];
    encode_report(&HostToDevice::LocalModel(model), &mut again).expect("a decoded model encodes");
    assert_eq!(again, report, "re-encoding changed the bytes");
    for p in model.si_primitives() {
        assert!(p.position_m.iter().all(|c| c.is_finite()) && p.strength_n >= 0.0);
        if p.kind != LocalKind::Point {
            let n = p.direction.iter().map(|c| c * c).sum::<f64>().sqrt();
            assert!((n - 1.0).abs() < 1e-12, "direction {:?}", p.direction);
        }
    }
    Some(model)
}

fn f64_at(data: &[u8], i: usize) -> f64 {
    let mut b = [0u8; 8];
    for (k, byte) in b.iter_mut().enumerate() {
        *byte = data.get(i * 8 + k).copied().unwrap_or(0);
    }
    f64::from_le_bytes(b)
}

fn build_from(data: &[u8]) -> Option<LocalModel> {
    let params = LocalModelParams {
        sequence: 1,
        expiry_us: u16::from_le_bytes([
            data.first().copied().unwrap_or(0),
            data.get(1).copied().unwrap_or(0),
        ]),
        stiffness_n_per_m: f64_at(data, 1),
        damping_n_s_per_m: f64_at(data, 2),
        force_limit_n: f64_at(data, 3),
        anchor_m: [f64_at(data, 4), f64_at(data, 5), f64_at(data, 6)],
        passivity: LocalPassivity::new(
            [
                LocalPassivityMode::Off,
                LocalPassivityMode::Observe,
                LocalPassivityMode::Control,
            ][usize::from(data.get(2).copied().unwrap_or(0) % 3)],
            f64_at(data, 7),
        ),
    };
    let kinds = [
        LocalKind::Directed,
        LocalKind::Point,
        LocalKind::Line,
        LocalKind::Plane,
    ];
    let primitives: Vec<SiPrimitive> = (0..(data.len() / 64).min(8))
        .map(|j| {
            let base = 7 + j * 7;
            SiPrimitive {
                kind: kinds[data[j] as usize % 4],
                position_m: [
                    f64_at(data, base),
                    f64_at(data, base + 1),
                    f64_at(data, base + 2),
                ],
                direction: [
                    f64_at(data, base + 3),
                    f64_at(data, base + 4),
                    f64_at(data, base + 5),
                ],
                strength_n: f64_at(data, base + 6),
            }
        })
        .collect();
    let model = build_local_model(&params, &primitives).ok()?;
    let mut report = [0u8; 64];
    encode_report(&HostToDevice::LocalModel(model), &mut report).expect("a built model encodes");
    assert_eq!(
        decode_report::<HostToDevice>(&report),
        Ok(HostToDevice::LocalModel(model)),
        "a built model decodes back"
    );
    Some(model)
}

fn drive(model: &LocalModel, data: &[u8]) {
    let device = TestDevice {
        model: "fuzz",
        rate_hz: 1000,
        max_force_n: MAX_FORCE_N,
        max_stiffness_n_per_m: 2000.0,
    };
    let mut session = enabled_session(&device, 0, 0);
    let mut local = LocalLoop::new(LoopConfig::default());
    let limit = (model.force_limit_n() as f32).min(MAX_FORCE_N) * (1.0 + 1e-6);
    let mut previous = 0.0f32;
    let mut now_us = 0u64;
    for (i, chunk) in data.chunks(3).take(64).enumerate() {
        if i % 10 == 0 {
            session.on_message(&HostToDevice::LocalModel(*model), now_us);
        }
        now_us += 100;
        let c = |k: usize| f32::from(chunk.get(k).copied().unwrap_or(128) as i8) * 1e-4;
        let sample = DeviceSample {
            position_m: [c(0), c(1), c(2)],
            velocity_m_per_s: [c(1) * 10.0, 0.0, 0.0],
            buttons: 0,
        };
        let force = local.step(&mut session, now_us, &sample);
        let magnitude = force.iter().map(|f| f * f).sum::<f32>().sqrt();
        assert!(force.iter().all(|f| f.is_finite()), "{force:?}");
        assert!(
            magnitude <= limit + 1e-6,
            "{magnitude} N above the limit {limit} N"
        );
        let slew = (SLEW_N_PER_S * 100e-6) as f32;
        assert!(
            magnitude <= previous + slew * (1.0 + 1e-5) + 1e-6,
            "{previous} -> {magnitude} N"
        );
        previous = magnitude;
        while session.poll_transmit().is_some() {}
    }
}
