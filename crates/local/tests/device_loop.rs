//! The local loop against protocol/SPEC.md section 10.5, with expected values worked by hand: a probe 1 mm into a
//! wall of stiffness k feels k x 1 mm; the force limit, the engage rule (1 N; kept through a SetForce, restarted
//! by an Enable), the expiry ramp (zero at most 5 ms after the expiry), the watchdog behind it, a model without a
//! solution, and the set-force path left untouched.

#[path = "support/session.rs"]
mod session;

use session::{enabled_session, TestDevice};
use voxhap_local::{LocalLoop, LoopConfig, DEVICE_SOLVER_CONFIG};
use voxhap_protocol::{
    build_local_model, DeviceSample, DeviceSession, DeviceToHost, ForceFlags, HostToDevice,
    LocalKind, LocalModelParams, LocalState, LocalStatus, SetForce, SiPrimitive,
};

const PERIOD_US: u64 = 100;
const K: f64 = 2000.0;

const DEVICE: TestDevice = TestDevice {
    model: "local-test",
    rate_hz: 1000,
    max_force_n: 8.0,
    max_stiffness_n_per_m: 2000.0,
};

/// A floor: the plane z = 0, normal +z, strong enough never to give way.
fn floor_model(sequence: u32, force_limit_n: f64) -> HostToDevice {
    let params = LocalModelParams {
        sequence,
        expiry_us: 5000,
        stiffness_n_per_m: K,
        damping_n_s_per_m: 0.0,
        force_limit_n,
        anchor_m: [0.0, 0.0, 0.0],
        passivity: voxhap_protocol::LocalPassivity::OFF,
    };
    let floor = SiPrimitive {
        kind: LocalKind::Plane,
        position_m: [0.0; 3],
        direction: [0.0, 0.0, 1.0],
        strength_n: 60.0,
    };
    HostToDevice::LocalModel(build_local_model(&params, &[floor]).unwrap())
}

struct Rig {
    session: DeviceSession,
    local: LocalLoop,
    now_us: u64,
    states: Vec<LocalState>,
}

impl Rig {
    fn new(config: LoopConfig) -> Self {
        let session = enabled_session(&DEVICE, 50_000, 1000);
        Rig {
            session,
            local: LocalLoop::new(config),
            now_us: 0,
            states: Vec::new(),
        }
    }

    fn send(&mut self, message: HostToDevice) {
        self.session.on_message(&message, self.now_us);
    }

    fn step(&mut self, z_m: f32) -> [f32; 3] {
        self.now_us += PERIOD_US;
        let sample = DeviceSample {
            position_m: [0.0, 0.0, z_m],
            ..Default::default()
        };
        let force = self.local.step(&mut self.session, self.now_us, &sample);
        while let Some(message) = self.session.poll_transmit() {
            if let DeviceToHost::LocalState(state) = message {
                self.states.push(state);
            }
        }
        force
    }

    /// The local status of the last LocalState the device sent.
    fn last_status(&self) -> LocalStatus {
        self.states.last().expect("no LocalState yet").status
    }

    /// Models every millisecond (a 1 kHz host) for `ms`, the handle at `z_m`; the largest |force| seen.
    fn run(&mut self, ms: u64, z_m: f32, force_limit_n: f64) -> f32 {
        let mut peak = 0.0f32;
        for _ in 0..ms {
            let sequence = (self.now_us / 1000) as u32 + 1;
            self.send(floor_model(sequence, force_limit_n));
            for _ in 0..10 {
                peak = peak.max(norm(self.step(z_m)));
            }
        }
        peak
    }
}

fn norm(f: [f32; 3]) -> f32 {
    f.iter().map(|c| c * c).sum::<f32>().sqrt()
}

#[test]
fn a_probe_in_a_wall_feels_k_times_the_depth_after_engaging() {
    let mut rig = Rig::new(LoopConfig::default());
    // Free space above the floor: the force is zero, so the engage ramp runs its 0.5 s.
    assert_eq!(rig.run(510, 0.002, 5.0), 0.0);
    assert_eq!(rig.local.ramp_factor(), 1.0);
    // 1 mm in: k x 1 mm = 2 N along +z, reached through the slew limit (0.05 N per 0.1 ms cycle).
    rig.run(20, -0.001, 5.0);
    let force = rig.step(-0.001);
    let bound = rig.states.last().unwrap().bound_m as f64;
    let tolerance = K * (bound + 1e-6);
    assert!((f64::from(force[2]) - 2.0).abs() <= tolerance, "{force:?}");
    assert!(force[0].abs() <= 1e-6 && force[1].abs() <= 1e-6);
    let proxy = rig.local.proxy_m().unwrap();
    assert!(
        proxy[2].abs() <= 1e-6,
        "the proxy stays on the floor: {proxy:?}"
    );
}

#[test]
fn the_force_never_exceeds_the_model_limit() {
    let mut rig = Rig::new(LoopConfig::default());
    rig.run(510, 0.002, 3.0);
    // 10 mm in asks for 20 N; the model allows 3 N.
    let peak = rig.run(50, -0.01, 3.0);
    assert!(peak <= 3.0 * (1.0 + 1e-6), "{peak}");
    assert!(peak >= 2.99, "{peak}");
    assert!(rig
        .states
        .iter()
        .any(|s| s.status.contains(LocalStatus::CLAMPED)));
    assert!(rig
        .states
        .iter()
        .all(|s| s.peak_force_n <= 3.0 * (1.0 + 1e-6)));
}

#[test]
fn a_handle_inside_the_wall_at_engage_gets_no_force_until_it_leaves() {
    let mut rig = Rig::new(LoopConfig::default());
    assert_eq!(rig.run(100, -0.001, 5.0), 0.0);
    assert!(rig.last_status().contains(LocalStatus::ENGAGING));
    rig.run(10, 0.001, 5.0);
    assert!(rig.local.ramp_factor() > 0.0);
}

#[test]
fn the_engage_ramp_starts_below_1_n_and_not_at_or_above_it() {
    // SPEC 10.5 step 6: at r = 0, a clamped force of 1 N or more holds r at 0. The floor at k = 2000 N/m:
    // 0.55 mm in is 1.1 N (waits), 0.45 mm in is 0.9 N (the ramp starts).
    let mut rig = Rig::new(LoopConfig::default());
    assert_eq!(rig.run(50, -0.00055, 5.0), 0.0);
    assert_eq!(rig.local.ramp_factor(), 0.0);
    rig.run(10, -0.00045, 5.0);
    assert!(rig.local.ramp_factor() > 0.0);
}

#[test]
fn a_set_force_between_models_keeps_the_engage_ramp_and_the_slew_limit_runs_from_it() {
    // Engaged, the handle 0.5 mm into the floor: k d = 1 N.
    let mut rig = Rig::new(LoopConfig::default());
    rig.run(510, 0.002, 5.0);
    rig.run(10, -0.0005, 5.0);
    assert_eq!(rig.local.ramp_factor(), 1.0);
    // The host falls back to SetForce for one millisecond (a late State, say) and sends zero: the device applies
    // it (SPEC 10.1)...
    rig.send(HostToDevice::SetForce(SetForce {
        sequence: 10_000,
        force_n: [0.0; 3],
        flags: ForceFlags::EMPTY,
    }));
    for _ in 0..10 {
        assert_eq!(rig.step(-0.0005), [0.0; 3]);
    }
    // ...and when models resume the engage ramp is not restarted (SPEC 10.5 step 6: r changes only in local mode
    // and is 0 only while the drive is not Enabled): the force climbs back from the applied zero at the slew
    // limit, 0.5 N per ms (0.05 N per 100 us cycle), to 1 N within 2.5 ms.
    let mut previous = 0.0f32;
    let mut forces = Vec::new();
    for _ in 0..3 {
        let sequence = (rig.now_us / 1000) as u32 + 20_000;
        rig.send(floor_model(sequence, 5.0));
        for _ in 0..10 {
            let force = norm(rig.step(-0.0005));
            assert!(force - previous <= 0.05 + 1e-6, "{previous} -> {force}");
            previous = force;
            forces.push(force);
        }
    }
    assert_eq!(rig.local.ramp_factor(), 1.0);
    assert!(
        forces[0] > 0.0,
        "the first local cycle rose from zero: {forces:?}"
    );
    let tolerance = (K * 1.1e-6) as f32;
    assert!((previous - 1.0).abs() <= tolerance, "{forces:?}");
}

#[test]
fn after_a_disable_the_next_enable_engages_from_zero() {
    let mut rig = Rig::new(LoopConfig::default());
    rig.run(510, 0.002, 5.0);
    assert_eq!(rig.local.ramp_factor(), 1.0);
    rig.send(HostToDevice::Disable);
    assert_eq!(rig.step(-0.002), [0.0; 3]);
    rig.send(HostToDevice::Enable(voxhap_protocol::Enable {
        watchdog_timeout_us: 50_000,
    }));
    // 2 mm in (4 N): r = 0 waits (SPEC 10.5 step 6), the handle gets no force.
    assert_eq!(rig.run(20, -0.002, 5.0), 0.0);
    assert_eq!(rig.local.ramp_factor(), 0.0);
    assert!(rig.last_status().contains(LocalStatus::ENGAGING));
}

#[test]
fn a_silenced_host_sees_the_force_ramp_to_zero_within_expiry_plus_5_ms() {
    let mut rig = Rig::new(LoopConfig::default());
    rig.run(510, 0.002, 5.0);
    rig.run(20, -0.001, 5.0);
    // The last model arrived at the start of the last millisecond.
    let last_model_us = rig.now_us - 1000;
    // Silence: no more models. Until the 5 ms expiry the force holds; 5 ms later it is zero.
    let mut zero_at = None;
    while rig.now_us < last_model_us + 60_000 {
        let force = norm(rig.step(-0.001));
        let age = rig.now_us - last_model_us;
        if age <= 5000 {
            assert!(force > 1.9, "at {age} us: {force}");
        }
        if force == 0.0 && zero_at.is_none() {
            zero_at = Some(age);
        }
        if age >= 10_000 + PERIOD_US {
            assert_eq!(force, 0.0, "at {age} us");
        }
    }
    assert!(
        zero_at.is_some_and(|t| t <= 10_000 + PERIOD_US),
        "{zero_at:?}"
    );
    assert!(rig
        .states
        .iter()
        .any(|s| s.status.contains(LocalStatus::EXPIRED)));
    // The watchdog (50 ms) then drops the drive to Idle.
    assert_eq!(rig.session.stats().watchdog_trips, 1);
    assert!(rig.session.local_model().is_none());
}

#[test]
fn a_model_without_a_solution_in_the_budget_ramps_down() {
    // No pass allowed: the start (the probe, 1 mm inside) is certified as it is, far above 10 um.
    let config = LoopConfig {
        solver: voxhap_solver::SolverConfig {
            max_sweeps: 0,
            ..DEVICE_SOLVER_CONFIG
        },
        ..LoopConfig::default()
    };
    let mut rig = Rig::new(config);
    rig.run(30, -0.001, 5.0);
    assert!(rig
        .states
        .iter()
        .all(|s| s.status.contains(LocalStatus::NO_SOLUTION)));
    assert!(rig.states.iter().all(|s| s.peak_force_n == 0.0));
}

#[test]
fn set_force_still_drives_a_capable_device() {
    let mut rig = Rig::new(LoopConfig::default());
    rig.run(10, 0.001, 5.0);
    rig.send(HostToDevice::SetForce(SetForce {
        sequence: 100,
        force_n: [0.0, 1.5, 0.0],
        flags: ForceFlags::EMPTY,
    }));
    assert_eq!(rig.step(-0.001), [0.0, 1.5, 0.0]);
    assert!(rig.local.proxy_m().is_some());
}
