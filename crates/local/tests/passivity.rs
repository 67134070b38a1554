//! The local loop's passivity observer and controller (protocol/SPEC.md section 10.5 step 4b) with expected
//! values from outside the code: the observer's energy against `sum F . dp` summed here over the forces the loop
//! applied; a directed force's work kept out of it; mode `off` leaving the force `k x depth` as worked by hand;
//! and an arm integrated here in closed form on a wall twice as stiff as the exact zero-order-hold boundary at
//! the device's rate, which gains energy without the controller and stays within a derived bound with it.

#[path = "support/session.rs"]
mod session;

use session::{enabled_session, TestDevice};
use voxhap_local::{LocalLoop, LoopConfig};
use voxhap_protocol::local::PASSIVITY_THRESHOLD_J;
use voxhap_protocol::{
    build_local_model, DeviceSample, DeviceSession, DeviceToHost, HostToDevice, LocalKind,
    LocalModelParams, LocalPassivity, LocalPassivityMode, LocalStatus, SiPrimitive,
};

const PERIOD_US: u64 = 100;
const T_S: f64 = 1e-4;

const DEVICE: TestDevice = TestDevice {
    model: "passivity-test",
    rate_hz: 1000,
    max_force_n: 8.0,
    max_stiffness_n_per_m: 50_000.0,
};

fn model(sequence: u32, k: f64, mode: LocalPassivityMode, slots: &[SiPrimitive]) -> HostToDevice {
    let params = LocalModelParams {
        sequence,
        expiry_us: 5000,
        stiffness_n_per_m: k,
        damping_n_s_per_m: 0.0,
        force_limit_n: 5.0,
        anchor_m: [0.0; 3],
        // 20 N s/m, the host's default most damping.
        passivity: LocalPassivity::new(mode, 20.0),
    };
    HostToDevice::LocalModel(build_local_model(&params, slots).unwrap())
}

/// The floor z = 0, normal +z, strong enough never to give way.
const FLOOR: SiPrimitive = SiPrimitive {
    kind: LocalKind::Plane,
    position_m: [0.0; 3],
    direction: [0.0, 0.0, 1.0],
    strength_n: 60.0,
};

struct Rig {
    session: DeviceSession,
    local: LocalLoop,
    now_us: u64,
    k: f64,
    mode: LocalPassivityMode,
    slots: Vec<SiPrimitive>,
    statuses: LocalStatus,
}

impl Rig {
    fn new(k: f64, mode: LocalPassivityMode, slots: &[SiPrimitive]) -> Self {
        Rig {
            session: enabled_session(&DEVICE, 50_000, 1000),
            local: LocalLoop::new(LoopConfig::default()),
            now_us: 0,
            k,
            mode,
            slots: slots.to_vec(),
            statuses: LocalStatus::EMPTY,
        }
    }

    /// One 10 kHz cycle with the handle at `position_m` moving at `velocity`; a model every 1 ms.
    fn step(&mut self, position_m: [f64; 3], velocity: [f64; 3]) -> [f64; 3] {
        if self.now_us.is_multiple_of(1000) {
            let sequence = (self.now_us / 1000) as u32 + 1;
            let message = model(sequence, self.k, self.mode, &self.slots);
            self.session.on_message(&message, self.now_us);
        }
        self.now_us += PERIOD_US;
        let sample = DeviceSample {
            position_m: position_m.map(|c| c as f32),
            velocity_m_per_s: velocity.map(|c| c as f32),
            buttons: 0,
        };
        let force = self.local.step(&mut self.session, self.now_us, &sample);
        while let Some(message) = self.session.poll_transmit() {
            if let DeviceToHost::LocalState(state) = message {
                self.statuses = self.statuses | state.status;
            }
        }
        force.map(f64::from)
    }

    /// Holds the handle at `position_m` through the 0.5 s engage ramp.
    fn engage(&mut self, position_m: [f64; 3]) {
        for _ in 0..5100 {
            self.step(position_m, [0.0; 3]);
        }
        assert_eq!(self.local.ramp_factor(), 1.0);
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// A hand-made press and release, 10 µm per cycle in and out of the floor, then faster steps of 20 µm: the
/// observer's generated energy and excess equal `sum F_(n-1) . (p_n - p_(n-1))` plus the spring energy
/// `k/2 |proxy - p|^2` (SPEC 10.5 step 4b, the energy ledger's books), summed here from the forces the loop
/// returned and the positions given. Checked to fail with the step's work left out of the observer's books.
#[test]
fn the_observer_books_the_applied_force_over_each_step_and_the_spring_energy() {
    let k = 2000.0;
    let mut rig = Rig::new(k, LocalPassivityMode::Observe, &[FLOOR]);
    rig.engage([0.0, 0.0, 0.001]);
    let start = rig.local.passivity_totals();
    assert_eq!(start.generated_j, 0.0, "nothing moved yet");
    let mut zs = Vec::new();
    let mut z = 0.001f64;
    // (cycles, step per cycle): down 1.5 mm, up 1 mm, down and up 0.8 mm twice as fast.
    for (cycles, step) in [(150, -10e-6), (100, 10e-6), (40, -20e-6), (40, 20e-6)] {
        for _ in 0..cycles {
            z += step;
            zs.push(z);
        }
    }
    let (mut generated, mut excess) = (0.0f64, 0.0f64);
    let mut previous: Option<([f64; 3], [f64; 3], f64)> = None;
    for &z in &zs {
        let p = [0.0, 0.0, f64::from(z as f32)];
        let force = rig.step([0.0, 0.0, z], [0.0; 3]);
        let proxy = rig.local.proxy_m().unwrap();
        let stretch = [proxy[0] - p[0], proxy[1] - p[1], proxy[2] - p[2]];
        let reference = 0.5 * k * dot(stretch, stretch);
        if let Some((p0, f0, r0)) = previous {
            let g = dot(f0, [p[0] - p0[0], p[1] - p0[1], p[2] - p0[2]]) + reference - r0;
            generated += g;
            excess = (excess + g).max(0.0);
        }
        // Never clamped nor slew-limited here (2 N at most, 0.02 N per cycle at most): the share is 1.
        assert!(force[2] <= 4.0 && force[2] >= 0.0);
        previous = Some((p, force, reference));
        let t = rig.local.passivity_totals();
        // The loop's share is |applied| / |asked| with the applied force rounded to f32 (a relative 6e-8), so
        // its reference is off the share-1 one here by at most 1.2e-7 of k/2 (1.5 mm)^2: 3e-10 J.
        assert!(
            (t.generated_j - generated).abs() <= 1e-9 && (t.excess_j - excess).abs() <= 1e-9,
            "{t:?}, expected generated {generated} J, excess {excess} J"
        );
    }
    // The zero-order hold's excess, k dp^2 / 2 a step while in contact: positive, and no controller acted.
    assert!(generated > 0.0, "{generated}");
    assert_eq!(rig.local.passivity_totals().active_cycles, 0);
    assert!(!rig.statuses.contains(LocalStatus::DISSIPATING));
}

/// A directed force of 0.5 N along +x in free space, the handle moving with it at 0.1 m/s for 10 mm: the force
/// does 5 mJ of work, all of it intended (SPEC 10.5 step 4b leaves the directed slot out of the coupling's books).
/// The observer books none of it and the controller, in mode `control`, never acts: the force stays 0.5 N
/// (the proxy sits at `p + d/k`, the spring's force is `d`). Checked to fail with the directed part booked as
/// coupling (`sigma d` not subtracted): the controller then cancels the force (about 0 N from the first cycle).
#[test]
fn a_directed_force_does_its_work_without_the_controller_damping_it() {
    let k = 2000.0;
    let push = SiPrimitive {
        kind: LocalKind::Directed,
        position_m: [0.0; 3],
        direction: [1.0, 0.0, 0.0],
        strength_n: 0.5,
    };
    let mut rig = Rig::new(k, LocalPassivityMode::Control, &[push]);
    rig.engage([0.0; 3]);
    let mut work = 0.0;
    let mut last: Option<(f64, f64)> = None;
    for i in 1..=1000 {
        let x = i as f64 * 10e-6;
        let force = rig.step([x, 0.0, 0.0], [0.1, 0.0, 0.0]);
        if let Some((x0, f0)) = last {
            work += f0 * (f64::from(x as f32) - x0);
        }
        last = Some((f64::from(x as f32), force[0]));
        // The SPEC's tolerance k (bound + 1 um) around the coupling force d.
        assert!((force[0] - 0.5).abs() <= k * 1.1e-6, "cycle {i}: {force:?}");
    }
    assert!((work - 0.5 * 0.00999).abs() < 1e-5, "{work} J");
    let t = rig.local.passivity_totals();
    assert!(t.excess_j <= PASSIVITY_THRESHOLD_J, "{t:?}");
    assert_eq!(t.active_cycles, 0, "{t:?}");
    assert!(!rig.statuses.contains(LocalStatus::DISSIPATING));
}

/// Mode `off`: the handle oscillates 0.5 mm deep in the floor at 2 000 N/m, fast enough for the sampled spring
/// to generate energy, and every force is `k x depth` (worked by hand: 2 000 N/m x depth, within the SPEC's
/// `k (bound + 1 um)`); nothing is booked and `DISSIPATING` is never reported. The same motion in mode `control`
/// gets forces that differ from it (the controller's damping), so the comparison can fail. Checked to fail with
/// mode `off` run as `control`, and with the controller's force left out of the applied force.
#[test]
fn mode_off_leaves_the_force_the_coupling_force() {
    let k = 2000.0;
    let motion = |i: usize| {
        let w = 2.0 * std::f64::consts::PI * 20.0;
        let t = i as f64 * T_S;
        (-0.0005 + 0.0004 * (w * t).sin(), 0.0004 * w * (w * t).cos())
    };
    let mut largest_difference = [0.0f64; 2];
    for (run, mode) in [LocalPassivityMode::Off, LocalPassivityMode::Control]
        .into_iter()
        .enumerate()
    {
        let mut rig = Rig::new(k, mode, &[FLOOR]);
        rig.engage([0.0, 0.0, 0.001]);
        // Into the floor at 10 um a cycle (0.02 N a cycle, under the slew limit), then the oscillation.
        let mut z = 0.001;
        while z > -0.0005 {
            z -= 10e-6;
            rig.step([0.0, 0.0, z], [0.0, 0.0, -0.1]);
        }
        for i in 0..5000 {
            let (z, v) = motion(i);
            let force = rig.step([0.0, 0.0, z], [0.0, 0.0, v]);
            let depth = -f64::from(z as f32);
            let expected = k * depth;
            largest_difference[run] = largest_difference[run].max((force[2] - expected).abs());
        }
        if mode == LocalPassivityMode::Off {
            assert_eq!(rig.local.passivity_totals(), Default::default());
            assert!(!rig.statuses.contains(LocalStatus::DISSIPATING));
        } else {
            assert!(rig.statuses.contains(LocalStatus::DISSIPATING));
        }
    }
    assert!(
        largest_difference[0] <= k * 1.1e-6,
        "off: {largest_difference:?}"
    );
    assert!(
        largest_difference[1] > 0.01,
        "control: {largest_difference:?}"
    );
}

/// An arm of 0.1 kg with 1 N s/m of its own damping, integrated here in closed form under each cycle's held
/// force (a zero-order hold: `m dv/dt = F - b v` with `F` constant over the 100 us cycle), pushed onto the floor
/// by a hand with 0.5 N and released from its resting depth with a 5 mm/s kick. The wall is 40 000 N/m, twice
/// the exact zero-order-hold boundary of this arm at 10 kHz, 20 003 N/m (docs/local-model.md's stability table,
/// the default arm at 10 000 Hz; Colgate's `2 b / T` is 20 000 N/m): past it the sampled wall is active.
///
/// The arm's energy `E = m v^2 / 2 + k depth^2 / 2 + F_hand z` (kinetic, wall spring, hand's potential). Without
/// the controller (mode `observe`) it grows: the contact bounces. With it (mode `control`) the bound is derived
/// from the observer's books: over any stretch the energy the device gave the arm plus the spring's rise is the
/// observer's generated energy `G`, and `G <= e` (the excess is `G` less its running minimum, which starts at 0),
/// so `E(n) - E(0) <= e(n) - (the arm's own dissipation) <= max e`. The controller dissipates the excess each
/// cycle it exceeds the threshold, so `e` stays below the threshold plus what one cycle can generate before the
/// controller answers, `k (v T)^2 / 2` for the sampled spring, plus what the solver's 0.1 um tolerance moves the
/// spring's energy, `k depth 0.1 um` twice. The test asserts `E(n) - E(0) <= 1 uJ + k (v_max T)^2 / 2 +
/// 2 k depth_max 1e-7 m`, and for the run without control that the energy rose above 100 times that bound.
/// Checked to fail with the controller's force left out of the applied force (the energy then rises by 64 mJ as
/// in `observe`). Measured: 64 mJ without the controller, never above the start with it (bound 1.2 uJ).
#[test]
fn a_wall_past_the_zoh_boundary_gains_energy_without_the_controller_and_not_with_it() {
    let (m, b, f_hand, k) = (0.1, 1.0, 0.5, 40_000.0);
    let decay = (-b * T_S / m).exp();
    let energy = |z: f64, v: f64| 0.5 * m * v * v + 0.5 * k * z.min(0.0).powi(2) + f_hand * z;
    let mut rise = [0.0f64; 2];
    let mut bound = 0.0f64;
    for (run, mode) in [LocalPassivityMode::Observe, LocalPassivityMode::Control]
        .into_iter()
        .enumerate()
    {
        let mut rig = Rig::new(k, mode, &[FLOOR]);
        let rest = -f_hand / k;
        rig.engage([0.0, 0.0, rest]);
        let (mut z, mut v) = (rest, -0.005);
        let e0 = energy(z, v);
        let (mut v_max, mut depth_max) = (0.0f64, 0.0f64);
        for _ in 0..10_000 {
            let f_device = rig.step([0.0, 0.0, z], [0.0, 0.0, v])[2];
            // m dv/dt = F - b v, F = f_device - f_hand held over the cycle: exact solution.
            let f = f_device - f_hand;
            let v_end = f / b + (v - f / b) * decay;
            z += f / b * T_S + (v - f / b) * (m / b) * (1.0 - decay);
            v = v_end;
            v_max = v_max.max(v.abs());
            depth_max = depth_max.max(-z);
            rise[run] = rise[run].max(energy(z, v) - e0);
        }
        if mode == LocalPassivityMode::Control {
            bound = PASSIVITY_THRESHOLD_J
                + 0.5 * k * (v_max * T_S).powi(2)
                + 2.0 * k * depth_max * 1e-7;
            assert!(rig.statuses.contains(LocalStatus::DISSIPATING));
        }
    }
    eprintln!(
        "energy rise: without the controller {:.3e} J, with it {:.3e} J (bound {:.3e} J)",
        rise[0], rise[1], bound
    );
    assert!(
        rise[1] <= bound,
        "with the controller: {rise:?}, bound {bound}"
    );
    assert!(
        rise[0] > 100.0 * bound,
        "without it: {rise:?}, bound {bound}"
    );
}

/// What the coupling generated before a Disable is not dissipated after the next Enable (SPEC 10.5 step 4b:
/// the excess starts again at 0, and the share at 0, when the drive leaves Enabled, as the engage ramp does).
/// In mode `observe` the arm of the test above bounces on the wall past the boundary and the excess grows to
/// millijoules; then Disable, Enable, and models in mode `control` with the handle held still inside the wall
/// but reported moving: a still handle generates nothing, so no damping may act. Checked to fail without the
/// reset: the stale excess is dissipated on the first cycles after the Enable (`DISSIPATING`).
#[test]
fn an_enable_starts_the_passivity_books_afresh() {
    let (m, b, f_hand, k) = (0.1, 1.0, 0.5, 40_000.0);
    let decay = (-b * T_S / m).exp();
    let mut rig = Rig::new(k, LocalPassivityMode::Observe, &[FLOOR]);
    let rest = -f_hand / k;
    rig.engage([0.0, 0.0, rest]);
    let (mut z, mut v) = (rest, -0.005);
    for _ in 0..5_000 {
        let f = rig.step([0.0, 0.0, z], [0.0, 0.0, v])[2] - f_hand;
        let v_end = f / b + (v - f / b) * decay;
        z += f / b * T_S + (v - f / b) * (m / b) * (1.0 - decay);
        v = v_end;
    }
    let excess = rig.local.passivity_totals().excess_j;
    assert!(excess > 100.0 * PASSIVITY_THRESHOLD_J, "excess {excess} J");
    rig.session.on_message(&HostToDevice::Disable, rig.now_us);
    rig.step([0.0, 0.0, rest], [0.0; 3]);
    rig.session.on_message(
        &HostToDevice::Enable(voxhap_protocol::Enable {
            watchdog_timeout_us: 50_000,
        }),
        rig.now_us,
    );
    rig.mode = LocalPassivityMode::Control;
    rig.statuses = LocalStatus::EMPTY;
    // Held 2 mm inside the wall for 0.6 s: r waits at 0 (80 N asked), so the ramp never starts.
    for _ in 0..6_000 {
        rig.step([0.0, 0.0, -0.002], [0.0, 0.0, 0.01]);
    }
    assert!(
        !rig.statuses.contains(LocalStatus::DISSIPATING),
        "{:?}, totals {:?}",
        rig.statuses,
        rig.local.passivity_totals()
    );
    assert_eq!(rig.local.passivity_totals().excess_j, 0.0);
}
