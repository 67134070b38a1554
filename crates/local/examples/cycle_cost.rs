//! Instructions per cycle of the local loop, for docs/local-model.md: runs the loop over scene families with the
//! maximum primitive count (3) and calls every cycle through `voxhap_local_measured_cycle`, which
//! crates/local/measure-cost.sh has callgrind count one call at a time. Run alone it prints, per family, how the
//! solves ended (so the budget-bound family can be seen to hit its budget).
//!
//! `cargo run --release -p voxhap-local --example cycle_cost -- FAMILY CYCLES`, FAMILY one of `corner`, `wedge`,
//! `mixed`, `cold`, `budget`.

#[path = "../tests/support/session.rs"]
mod session;

use session::{enabled_session, TestDevice};
use voxhap_local::{LocalLoop, LoopConfig};
use voxhap_protocol::{
    build_local_model, DeviceSample, DeviceSession, DeviceToHost, HostToDevice, LocalKind,
    LocalModelParams, LocalStatus, SiPrimitive,
};

/// One control cycle; its own symbol so that callgrind can count it alone.
#[no_mangle]
#[inline(never)]
pub extern "Rust" fn voxhap_local_measured_cycle(
    local: &mut LocalLoop,
    session: &mut DeviceSession,
    now_us: u64,
    sample: &DeviceSample,
) -> [f32; 3] {
    local.step(session, now_us, sample)
}

/// SplitMix64, so runs repeat.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

fn prim(
    kind: LocalKind,
    position_m: [f64; 3],
    direction: [f64; 3],
    strength_n: f64,
) -> SiPrimitive {
    SiPrimitive {
        kind,
        position_m,
        direction,
        strength_n,
    }
}

/// The family's primitives and probe for cycle `i`.
fn scene(family: &str, i: u64, rng: &mut Rng) -> (Vec<SiPrimitive>, [f64; 3]) {
    let t = i as f64 * 1e-4;
    let circle = [0.002 * (t * 6.0).cos(), 0.002 * (t * 6.0).sin(), -0.001];
    match family {
        // Three walls meeting in a corner, the probe 1 mm into all three: three active constraints.
        "corner" => (
            vec![
                prim(LocalKind::Plane, [0.0; 3], [1.0, 0.0, 0.0], 20.0),
                prim(LocalKind::Plane, [0.0; 3], [0.0, 1.0, 0.0], 20.0),
                prim(LocalKind::Plane, [0.0; 3], [0.0, 0.0, 1.0], 20.0),
            ],
            [-0.001 + circle[0] * 0.2, -0.001 + circle[1] * 0.2, -0.001],
        ),
        // Two planes 1 degree apart (a thin wedge) and a friction point: near-parallel constraints.
        "wedge" => {
            let a = 1f64.to_radians();
            (
                vec![
                    prim(LocalKind::Plane, [0.0; 3], [0.0, 0.0, 1.0], 20.0),
                    prim(LocalKind::Plane, [0.0; 3], [a.sin(), 0.0, a.cos()], 20.0),
                    prim(LocalKind::Point, [circle[0], circle[1], 0.0], [0.0; 3], 0.5),
                ],
                circle,
            )
        }
        // A line, a point and a plane near the probe, moving with it (a surface-following tick).
        "mixed" => (
            vec![
                prim(LocalKind::Line, [0.0, 0.0, 0.0], [1.0, 1.0, 0.0], 2.0),
                prim(LocalKind::Point, [0.001, -0.001, 0.0], [0.0; 3], 1.0),
                prim(LocalKind::Plane, [0.0; 3], [0.0, 0.2, 1.0], 20.0),
            ],
            circle,
        ),
        // Random kinds, places, directions and strengths within 5 mm: a new scene every cycle (no warm start).
        "cold" | "budget" => {
            fn v(rng: &mut Rng) -> [f64; 3] {
                [
                    rng.range(-0.005, 0.005),
                    rng.range(-0.005, 0.005),
                    rng.range(-0.005, 0.005),
                ]
            }
            let kinds = [LocalKind::Point, LocalKind::Line, LocalKind::Plane];
            let prims = (0..3)
                .map(|_| {
                    let kind = kinds[(rng.next() * 3.0) as usize % 3];
                    let (p, d) = (v(rng), v(rng));
                    prim(kind, p, d, rng.range(0.1, 30.0))
                })
                .collect();
            (prims, v(rng))
        }
        other => panic!("unknown family {other}"),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let family = args.get(1).map_or("corner", String::as_str).to_owned();
    let cycles: u64 = args.get(2).and_then(|c| c.parse().ok()).unwrap_or(1000);
    let device = TestDevice {
        model: "cost",
        rate_hz: 8000,
        max_force_n: 10.0,
        max_stiffness_n_per_m: 20_000.0,
    };
    // States (and so LocalStates, which carry each interval's worst bound) at 8 kHz.
    let mut session = enabled_session(&device, 1_000_000, 8000);
    let mut config = LoopConfig::default();
    if family == "budget" {
        // A tolerance no f64 solve reaches: every solve runs its whole pass budget (the worst case).
        config.solver.tolerance_m = 0.0;
    }
    let mut local = LocalLoop::new(config);
    let mut rng = Rng(7);
    let mut no_solution = 0;
    let mut max_bound = 0.0f32;
    let mut last_probe = [0.0f64; 3];
    for i in 0..cycles {
        let now_us = 100 * (i + 1);
        // A new model every 10 cycles (1 kHz host, 10 kHz loop), or every cycle for the cold families.
        let cold = family == "cold" || family == "budget";
        let (prims, probe) = scene(&family, i, &mut rng);
        if cold || i % 10 == 0 {
            let params = LocalModelParams {
                sequence: i as u32 + 1,
                expiry_us: 5000,
                stiffness_n_per_m: 20_000.0,
                damping_n_s_per_m: 0.0,
                force_limit_n: 10.0,
                anchor_m: probe,
                // The passivity controller on (what serve sends a real device by default), so that its
                // observer and controller are in every cycle's count.
                passivity: voxhap_protocol::LocalPassivity::new(
                    voxhap_protocol::LocalPassivityMode::Control,
                    20.0,
                ),
            };
            if let Ok(model) = build_local_model(&params, &prims) {
                session.on_message(&HostToDevice::LocalModel(model), now_us);
            }
        }
        // The velocity is the step from the last cycle's probe (the controller damps a moving handle).
        let velocity = core::array::from_fn(|k| ((probe[k] - last_probe[k]) / 1e-4) as f32);
        last_probe = probe;
        let sample = DeviceSample {
            position_m: probe.map(|c| c as f32),
            velocity_m_per_s: velocity,
            ..Default::default()
        };
        let force = voxhap_local_measured_cycle(&mut local, &mut session, now_us, &sample);
        std::hint::black_box(force);
        while let Some(message) = session.poll_transmit() {
            if let DeviceToHost::LocalState(state) = message {
                no_solution += usize::from(state.status.contains(LocalStatus::NO_SOLUTION));
                max_bound = max_bound.max(state.worst_bound_m);
            }
        }
    }
    println!("{family}: {cycles} cycles, {no_solution} reports with NO_SOLUTION, largest bound {max_bound:.3e} m");
}
