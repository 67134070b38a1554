//! Helpers shared by the serial-arm tests that run a real driver on a pseudo-terminal under the supervisor
//! (tests/falcon.rs, tests/falcon_late.rs, tests/woodenhaptics_serial.rs, tests/haply_2diy_pty.rs): the
//! supervisor's configuration for a test, the glitch drive that asks for a force far above the limit while the
//! double's replies carry bad readings, the angle between two forces, and a bounded wait on the double.

use glam::DVec3;
use std::time::{Duration, Instant};
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{OutputState, Supervisor, SupervisorConfig, TickInput};
use voxhap::device::{DeviceError, HapticDevice};

/// The supervisor's configuration in these tests: forces capped at `max_force_n`, ramped in over `ramp_time_us`,
/// and enable after 5 steady ticks (the default 50 is for real sessions).
pub fn supervisor_config(max_force_n: f64, ramp_time_us: u64) -> SupervisorConfig {
    SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us,
            max_force_n,
            ..SafetyConfig::default()
        },
        steady_ticks_before_enable: 5,
        ..SupervisorConfig::default()
    }
}

/// Ticks `supervisor` on a virtual 1 kHz clock (tick n at n ms), asking for `asked` × 500 N (far above any limit)
/// while the output ramps in or is engaged and for zero otherwise, until force was on for 600 ticks (200 000
/// ticks at most). Before each tick `set_truth(tick)` sets the double's true pose and injects its glitches. Then
/// stops the supervisor and checks that force was on for all 600 ticks and that the input guard rejected at
/// least 5 readings (so the glitches did reach it).
pub fn drive_through_glitches<D, F>(
    supervisor: &mut Supervisor<D, F>,
    asked: DVec3,
    mut set_truth: impl FnMut(u64),
) where
    D: HapticDevice,
    F: FnMut() -> Result<D, DeviceError>,
{
    let mut output = OutputState::Starting;
    let mut forced_ticks = 0;
    let mut tick = 0u64;
    while forced_ticks < 600 && tick < 200_000 {
        set_truth(tick);
        let on = matches!(output, OutputState::RampingIn | OutputState::Engaged);
        let force = if on { asked * 500.0 } else { DVec3::ZERO };
        output = supervisor
            .tick(TickInput::at(force, tick * 1000))
            .output_state;
        forced_ticks += u32::from(on);
        tick += 1;
    }
    supervisor.stop();
    assert_eq!(
        forced_ticks, 600,
        "force was on for only {forced_ticks} of {tick} ticks"
    );
    assert!(
        supervisor.input_counters().positions_rejected >= 5,
        "{:?}",
        supervisor.input_counters()
    );
}

/// The angle between `a` and `b`, in degrees.
pub fn angle_deg(a: DVec3, b: DVec3) -> f64 {
    a.normalize()
        .dot(b.normalize())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// Polls `done` every millisecond; fails after 20 s naming `what`.
pub fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while !done() {
        assert!(Instant::now() < deadline, "waited 20 s for {what}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// What [`check_exerted_forces`] holds every command to.
pub struct ExertedBounds {
    /// The force limit the supervisor enforces (N).
    pub limit_n: f64,
    /// What the limit may be exceeded by: rounding of whole milliamperes, a kinematic estimate's error (N).
    pub tolerance_n: f64,
    /// Forces above this are checked for direction (N).
    pub direction_from_n: f64,
    /// The largest angle to the request allowed above `direction_from_n` (degrees).
    pub max_angle_deg: f64,
    /// A force above this counts as near the limit (N); at least 100 commands must be.
    pub strong_from_n: f64,
}

/// Checks the force the arm exerted at its true pose for every command a double logged: `exerted` gives it
/// (`None` for a command sent before the test set a true pose; those must have been zero, which the caller's
/// closure checks) and `describe` says where, for the failure message. Every force stays within the limit and,
/// when not small, within `max_angle_deg` of `asked`; at least 100 commands come near the limit (so the glitch
/// drive really pushed). Prints the worst angle and the largest force.
pub fn check_exerted_forces<C>(
    commands: &[C],
    asked: DVec3,
    bounds: &ExertedBounds,
    exerted: impl Fn(&C) -> Option<DVec3>,
    describe: impl Fn(&C) -> String,
) {
    let mut strong = 0;
    let mut worst_angle = 0.0f64;
    let mut largest = 0.0f64;
    for command in commands {
        let Some(force) = exerted(command) else {
            continue;
        };
        largest = largest.max(force.length());
        assert!(
            force.length() <= bounds.limit_n + bounds.tolerance_n,
            "{force} ({} N) {}",
            force.length(),
            describe(command)
        );
        if force.length() > bounds.direction_from_n {
            let angle = angle_deg(force, asked);
            worst_angle = worst_angle.max(angle);
            assert!(
                angle < bounds.max_angle_deg,
                "{force} is {angle:.1}° off the request {}",
                describe(command)
            );
        }
        strong += u32::from(force.length() > bounds.strong_from_n);
    }
    assert!(
        strong >= 100,
        "only {strong} commands near the limit (largest {largest} N)"
    );
    eprintln!(
        "worst angle {worst_angle:.3}°, largest {largest:.3} N, {strong} commands near {} N",
        bounds.limit_n
    );
}
