//! Late device answers: the supervisor with a device double whose answers come late or not at all,
//! following a script. A lab user's PC is loaded now and then, and a device behind a service (the Haply Inverse
//! Service) then answers a tick or two late. The host must still enable the output on such a link, and must
//! never send force computed from a state older than the staleness bound (3 periods, docs/safety.md), counted
//! from the force the state answers. Checked from the device's side: the double knows how old the newest
//! state it handed out is, and logs every force with that age.

use crate::util::late_device::{late_info, late_supervisor, Ages, Answer};
use glam::DVec3;
use std::cell::RefCell;
use std::rc::Rc;
use voxhap::device::supervisor::TickInput;
use voxhap::device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};

/// The double's log: per force received, the force and how old (ticks) the newest state the host had was.
#[derive(Debug, Default)]
struct Log {
    forces: Vec<(DVec3, u32)>,
    enables: u32,
    /// Per force received: whether the device was enabled (an Enable since the last Disable).
    enabled: Vec<bool>,
    /// Enabled now (the double's own state).
    is_enabled: bool,
}

struct LateDevice {
    info: DeviceInfo,
    script: Box<dyn FnMut(u64) -> Answer>,
    tick: u64,
    ages: Ages,
    log: Rc<RefCell<Log>>,
}

impl HapticDevice for LateDevice {
    type Error = DeviceError;
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
    fn enable(&mut self) -> Result<(), DeviceError> {
        let mut log = self.log.borrow_mut();
        log.enables += 1;
        log.is_enabled = true;
        Ok(())
    }
    fn disable(&mut self) -> Result<(), DeviceError> {
        self.log.borrow_mut().is_enabled = false;
        Ok(())
    }
    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let mut log = self.log.borrow_mut();
        log.forces.push((force_n, self.ages.information));
        let enabled = log.is_enabled;
        log.enabled.push(enabled);
        Ok(())
    }
    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.tick += 1;
        self.ages.read((self.script)(self.tick))?;
        Ok(DeviceState::at_rest(DVec3::ZERO))
    }
    fn state_age_ticks(&self) -> u32 {
        self.ages.last
    }
}

/// Runs `ticks` supervisor ticks asking for 0.5 N against a device following `script`; returns its log.
fn run(ticks: u64, script: impl FnMut(u64) -> Answer + 'static) -> Log {
    let log = Rc::new(RefCell::new(Log::default()));
    let mut supervisor = late_supervisor(LateDevice {
        info: late_info(),
        script: Box::new(script),
        tick: 0,
        ages: Ages::new(),
        log: log.clone(),
    });
    for tick in 1..=ticks {
        // Small at first (the engage rule), then a push.
        let force = if tick < 300 {
            DVec3::ZERO
        } else {
            DVec3::new(0.5, 0.0, 0.0)
        };
        supervisor.tick(TickInput::at(force, tick * 1_000));
    }
    supervisor.stop();
    drop(supervisor);
    Rc::try_unwrap(log).unwrap().into_inner()
}

fn assert_no_force_on_old_states(log: &Log) {
    for (i, (force, age)) in log.forces.iter().enumerate() {
        assert!(
            *force == DVec3::ZERO || *age <= 3,
            "force {force:?} at write {i} while the newest state was {age} ticks old"
        );
    }
    assert_device_invariants(log);
}

/// The invariants every force the device receives keeps (docs/safety.md): finite, at most the device's 2 N,
/// rising at most the default slew of 0.5 N per 1 ms tick, and zero while the device is not enabled.
fn assert_device_invariants(log: &Log) {
    let mut previous = 0.0;
    for (i, ((force, _), enabled)) in log.forces.iter().zip(&log.enabled).enumerate() {
        let magnitude = force.length();
        assert!(force.is_finite(), "force {force:?} at write {i}");
        assert!(
            magnitude <= 2.0 + 1e-9,
            "force {force:?} above 2 N at write {i}"
        );
        assert!(
            magnitude <= previous + 0.5 + 1e-9,
            "force {force:?} at write {i} rose from {previous} N"
        );
        assert!(
            *enabled || *force == DVec3::ZERO,
            "force {force:?} at write {i} while the device was not enabled"
        );
        previous = magnitude;
    }
}

#[test]
fn answers_a_tick_or_two_late_still_enable_the_output() {
    // Every third answer is missing, every fifth is two ticks old, the rest answer this tick's force: the
    // strictly-fresh rule this replaces never saw 50 good ticks in a row on such a link.
    let log = run(1000, |tick| match tick {
        _ if tick % 3 == 0 => Answer::Late,
        _ if tick % 5 == 0 => Answer::Aged(2),
        _ => Answer::Aged(0),
    });
    assert_eq!(log.enables, 1);
    let full = log
        .forces
        .iter()
        .filter(|(f, _)| (f.x - 0.5).abs() < 1e-12)
        .count();
    assert!(full > 500, "{full} forces at full strength");
    assert_no_force_on_old_states(&log);
}

#[test]
fn a_state_older_than_the_bound_never_drives_force() {
    // Steady at first, then 4-tick-old answers (and gaps of four) in bursts: the output may be enabled, but
    // no force leaves while the newest state is older than 3 ticks, and forces come back after each burst.
    let log = run(3000, |tick| match tick % 200 {
        100..=119 => Answer::Aged(4),
        120..=139 if tick % 5 != 0 => Answer::Late,
        _ => Answer::Aged(1),
    });
    assert!(log.enables >= 1);
    assert_no_force_on_old_states(&log);
    let during_bursts = log
        .forces
        .iter()
        .filter(|(f, age)| *age > 3 && *f != DVec3::ZERO)
        .count();
    assert_eq!(during_bursts, 0);
    let late_full = log.forces[2000..]
        .iter()
        .filter(|(f, _)| (f.x - 0.5).abs() < 1e-12)
        .count();
    assert!(
        late_full > 300,
        "{late_full} forces at full strength after the bursts"
    );
}

#[test]
fn a_link_that_is_never_within_the_bound_is_never_enabled() {
    // Every answer is four ticks old: usable by no rule, so the output stays off and only zeros go out.
    let log = run(1000, |_| Answer::Aged(4));
    assert_eq!(log.enables, 0);
    assert!(log.forces.iter().all(|(f, _)| *f == DVec3::ZERO));
    assert_device_invariants(&log);
}
