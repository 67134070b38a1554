//! Each tick's truth in `serve`'s servo loop: the energy ledger booked from what the device reported and what
//! was sent (checked against the analytic energy of a spring pressed a known depth), the force-off cause
//! named from what the safety pipeline did, and the age of the rendered sample, with a device that answers
//! late through the real supervisor (positions older than the staleness bound mean zero force,
//! `stale_link`). The loop runs on a mock clock, so every number is deterministic.

use crate::util::late_device::{late_info, late_supervisor, Ages, Answer};
use glam::DVec3;
use std::path::Path;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};
use voxhap::clock::MockClock;
use voxhap::device::plausibility::InputCounters;
use voxhap::device::safety::SafetyFlags;
use voxhap::device::supervisor::{
    ClearFaultOutcome, EventList, OutputState, SupervisorConfig, SupervisorCounters,
    SupervisorOutput, TickInput,
};
use voxhap::device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use voxhap::record::{ForceOffCause, TraceSample};
use voxhap::servo::device::{ConnectError, ServoDevice};
use voxhap::servo::monitor::StopSlot;
use voxhap::servo::runner::{LoopIo, LoopTiming, ServoLoop};
use voxhap::servo::schedule::MockWaiter;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::stats::ServoStats;
use voxhap::servo::Snapshot;

const PERIOD_NS: u64 = 1_000_000;
/// The coupling stiffness (N/m): below the 1 000 N/m cap of a device that declares none.
const K_N_PER_M: f64 = 800.0;

/// A flat wall at z = 0 pushing along +z, far stronger than any force here (the proxy stays on it).
fn wall_scene() -> SceneSetup {
    let text = format!(
        "name = \"wall\"\nk_n_per_m = {K_N_PER_M:?}\nvolumes = []\n\n[[modes]]\nkind = \"support_plane\"\n\
         point_m = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\nstrength_n = 50.0\n"
    );
    SceneSetup::parse(&text, "wall", Path::new(".")).unwrap()
}

/// Runs `ticks` ticks of the servo loop with `device` on the wall scene, from `first` (the state read
/// before the loop); returns every trace sample, the last snapshot and the statistics.
fn run_loop(
    device: Box<dyn ServoDevice>,
    first: Option<DeviceState>,
    ticks: u64,
) -> (Vec<TraceSample>, Snapshot, voxhap::api::StatsReport) {
    let setup = wall_scene();
    let bundle = setup.bundle(PERIOD_NS, 0.3, 1).unwrap();
    let (_commands, command_rx) = rtrb::RingBuffer::new(4);
    let (events, _events_rx) = rtrb::RingBuffer::new(4096);
    let (retire_tx, _retired) = rtrb::RingBuffer::new(4);
    let (sample_tx, mut samples) = rtrb::RingBuffer::new(ticks as usize + 8);
    let (snapshot_in, mut snapshot) = triple_buffer::triple_buffer(&None);
    let (frame_tx, _frames) = rtrb::RingBuffer::new(4096);
    let stats = Arc::new(ServoStats::new(1000.0));
    let mut servo = ServoLoop::new(
        Box::new(bundle),
        device,
        LoopIo {
            commands: command_rx,
            command_claim: Arc::new(AtomicU64::new(0)),
            retired: retire_tx,
            samples: sample_tx,
            snapshot: snapshot_in,
            scene_frames: frame_tx,
            events,
        },
        stats.clone(),
        LoopTiming {
            period_ns: PERIOD_NS,
            compute_budget_ns: u64::MAX,
            warm_lead_ns: 0,
        },
        PERIOD_NS,
        first,
    );
    let mut waiter = MockWaiter::new(Arc::new(MockClock::new(0)));
    for _ in 0..ticks {
        servo.step(&mut waiter);
    }
    let mut out = Vec::new();
    while let Ok(sample) = samples.pop() {
        out.push(sample);
    }
    let last = snapshot.read().unwrap();
    (out, last, stats.report())
}

/// A device whose every tick's output follows a script: the probe position it reports, and what its
/// safety pipeline says (output state, flags, latched faults); the force it sends is the force asked for
/// scaled by `share(tick)` (a ramp) whenever the script says the output is engaged, else zero.
struct ScriptedDevice {
    tick: u64,
    script: Box<dyn FnMut(u64) -> (DVec3, OutputState, SafetyFlags, u16) + Send>,
    share: fn(u64) -> f64,
}

impl ServoDevice for ScriptedDevice {
    fn exchange(&mut self, input: TickInput) -> SupervisorOutput {
        self.tick += 1;
        let (position_m, output_state, flags, active_faults) = (self.script)(self.tick);
        let connected = output_state != OutputState::Disconnected;
        SupervisorOutput {
            state: connected.then(|| DeviceState::at_rest(position_m)),
            stale: false,
            sent_force_n: if output_state == OutputState::Engaged {
                input.force_n * (self.share)(self.tick)
            } else {
                DVec3::ZERO
            },
            flags,
            connected,
            output_state,
            active_faults,
            events: EventList::default(),
            local: None,
        }
    }
    fn counters(&self) -> SupervisorCounters {
        SupervisorCounters::default()
    }
    fn input_counters(&self) -> InputCounters {
        InputCounters::default()
    }
    fn engaged(&self) -> bool {
        true
    }
    fn output_state(&self) -> OutputState {
        OutputState::Engaged
    }
    fn request_clear_fault(&mut self) -> ClearFaultOutcome {
        ClearFaultOutcome::NothingToClear
    }
    fn stop(&mut self) {}
    fn connect(&mut self, _now_us: u64) -> Result<(), ConnectError> {
        Ok(())
    }
    fn restart_clock(&mut self, _now_us: u64) {}
    fn info(&self) -> Option<DeviceInfo> {
        None
    }
    fn set_period_us(&mut self, _period_us: u64) {}
    fn set_stop_slot(&mut self, _slot: Arc<StopSlot>) {}
    fn max_stiffness_n_per_m(&self) -> Option<f64> {
        None
    }
}

/// A probe pressed quasi-statically into a wall of stiffness k, `dx` per tick, from its surface: the
/// force held over each step is `k x_n` against the motion, so the work on the probe is
/// `W = -k dx^2 (0 + 1 + ... + (N-1)) = -k dx^2 N (N-1) / 2`, the spring holds `E_c = k (N dx)^2 / 2`, and
/// the renderer generated `G = W + E_c = k dx^2 N / 2` (the zero-order hold's excess). These analytic
/// values are what the trace, the snapshot and the statistics must carry.
#[test]
fn serve_books_a_spring_pressed_a_known_depth_exactly() {
    let dx = 1e-5;
    let n: u64 = 100;
    let device = ScriptedDevice {
        tick: 0,
        share: |_| 1.0,
        // Exchange i answers with the position of tick i: x_i = -i dx (below the wall's surface).
        script: Box::new(move |i| {
            let depth = dx * i.min(n) as f64;
            (
                DVec3::new(0.0, 0.0, -depth),
                OutputState::Engaged,
                SafetyFlags::default(),
                0,
            )
        }),
    };
    let first = Some(DeviceState::at_rest(DVec3::ZERO));
    let (samples, snapshot, stats) = run_loop(Box::new(device), first, n + 1);
    assert_eq!(samples.len() as u64, n + 1);
    let k = K_N_PER_M;
    for (i, sample) in samples.iter().enumerate() {
        let depth = dx * i as f64;
        // A spring of stiffness k compressed by the depth: k d^2 / 2 (the proxy stays on the wall).
        let e_c = 0.5 * k * depth * depth;
        let energy = sample.truth.energy;
        assert!(
            (energy.coupling_energy_j - e_c).abs() <= 1e-9 * e_c.max(1e-12),
            "tick {i}: coupling {} J, expected {e_c} J",
            energy.coupling_energy_j
        );
        let steps = i as f64;
        let work = -k * dx * dx * steps * (steps - 1.0).max(0.0) / 2.0;
        assert!(
            (energy.work_on_probe_j - work).abs() <= 1e-9 * work.abs().max(1e-12),
            "tick {i}: work {} J, expected {work} J",
            energy.work_on_probe_j
        );
        let generated = 0.5 * k * dx * dx * steps;
        assert!(
            (energy.generated_j - generated).abs() <= 1e-9 * generated.max(1e-12),
            "tick {i}: generated {} J, expected {generated} J",
            energy.generated_j
        );
        assert_eq!(energy.active_work_j, 0.0);
        assert_eq!(sample.truth.force_off_cause, ForceOffCause::None);
        assert_eq!(sample.truth.sample_age_ticks, 0);
    }
    let last = samples.last().unwrap().truth;
    assert_eq!(snapshot.truth, last);
    assert_eq!(stats.energy.totals, last.energy);
    // 0.04 mJ generated in all: below the 0.1 mJ `--fail-on active` tolerance, one contact, no cycle.
    assert!(
        !stats.energy.active && !stats.energy.oscillating,
        "{stats:?}"
    );
    assert_eq!(stats.energy.contacts, 1);
}

/// While the safety pipeline ramps the force in, the spring holds only what the sent force can give back:
/// a probe held a depth `d` into a wall of stiffness `k` renders `k d`; with a share `s` of it sent
/// (`F_sent = s k d`) the coupling energy booked is `|F_sent|^2 / 2k = s^2 k d^2 / 2`, not the whole
/// virtual spring's `k d^2 / 2`. The share ramps from 0 to 1 over 50 ticks as a linear ramp-in would.
#[test]
fn while_ramping_in_the_spring_holds_what_the_sent_force_can_give_back() {
    let depth = 0.001;
    let ramp = |tick: u64| (tick as f64 / 50.0).min(1.0);
    let device = ScriptedDevice {
        tick: 0,
        share: ramp,
        script: Box::new(move |_| {
            (
                DVec3::new(0.0, 0.0, -depth),
                OutputState::Engaged,
                SafetyFlags::default(),
                0,
            )
        }),
    };
    let first = Some(DeviceState::at_rest(DVec3::new(0.0, 0.0, -depth)));
    let (samples, _, _) = run_loop(Box::new(device), first, 80);
    let k = K_N_PER_M;
    for (i, sample) in samples.iter().enumerate() {
        // Tick i's force goes out in exchange i + 1.
        let s = ramp(i as u64 + 1);
        let sent = s * k * depth;
        assert!(
            (sample.sent_force_n.z - sent).abs() <= 1e-12,
            "tick {i}: sent {:?}, expected {sent} N",
            sample.sent_force_n
        );
        let expected = sent * sent / (2.0 * k);
        let booked = sample.truth.energy.coupling_energy_j;
        assert!(
            (booked - expected).abs() <= 1e-12 * expected.max(1e-12),
            "tick {i}: share {s}, coupling {booked} J, expected {expected} J"
        );
    }
}

fn both(mut a: SafetyFlags, b: SafetyFlags) -> SafetyFlags {
    a |= b;
    a
}

/// The cause the trace names for each thing the safety pipeline reports, in its documented precedence
/// (docs/safety.md): the device's faults with their bits, a stale state, the engage rule, the enable wait,
/// a lost link.
#[test]
fn the_force_off_cause_names_what_the_safety_pipeline_did() {
    type Step = (OutputState, SafetyFlags, u16, ForceOffCause);
    let steps: Vec<Step> = vec![
        (
            OutputState::Starting,
            SafetyFlags::DEVICE_NOT_ENABLED,
            0,
            ForceOffCause::NotEnabled,
        ),
        (
            OutputState::WaitingToEngage,
            SafetyFlags::WAITING_TO_ENGAGE,
            0,
            ForceOffCause::NotEngaged,
        ),
        (
            OutputState::Engaged,
            SafetyFlags::default(),
            0,
            ForceOffCause::None,
        ),
        (
            OutputState::Engaged,
            SafetyFlags::STALE_STATE,
            0,
            ForceOffCause::StaleLink,
        ),
        (
            OutputState::StaleState,
            SafetyFlags::STALE_STATE,
            0,
            ForceOffCause::StaleLink,
        ),
        (
            OutputState::Engaged,
            SafetyFlags::WATCHDOG,
            0,
            ForceOffCause::Watchdog,
        ),
        (
            OutputState::Faulted,
            both(SafetyFlags::DEVICE_NOT_ENABLED, SafetyFlags::DEVICE_FAULTED),
            0b100,
            ForceOffCause::DeviceFault,
        ),
        (
            OutputState::EnableRefused,
            SafetyFlags::DEVICE_NOT_ENABLED,
            0,
            ForceOffCause::EnableRefused,
        ),
        (
            OutputState::Disconnected,
            SafetyFlags::OUTPUT_OFF,
            0,
            ForceOffCause::Disconnected,
        ),
    ];
    let script_steps = steps.clone();
    let device = ScriptedDevice {
        tick: 0,
        share: |_| 1.0,
        // Exchange i's output is step i - 1 (tick i - 1's sample).
        script: Box::new(move |i| {
            let (state, flags, faults, _) =
                script_steps[(i as usize - 1).min(script_steps.len() - 1)];
            (DVec3::new(0.0, 0.0, 0.001), state, flags, faults)
        }),
    };
    let first = Some(DeviceState::at_rest(DVec3::new(0.0, 0.0, 0.001)));
    let (samples, snapshot, _) = run_loop(Box::new(device), first, steps.len() as u64);
    for (sample, (state, _, faults, cause)) in samples.iter().zip(&steps) {
        assert_eq!(sample.truth.force_off_cause, *cause, "{state:?}");
        assert_eq!(sample.truth.device_fault_bits, *faults, "{state:?}");
    }
    assert_eq!(snapshot.truth.force_off_cause, ForceOffCause::Disconnected);
}

/// A device that answers late following a script (a loaded PC, a service behind a socket): it knows how old
/// the newest state it handed out is, and logs every force it receives with that age.
struct LateDevice {
    info: DeviceInfo,
    script: fn(u64) -> Answer,
    reads: u64,
    ages: Ages,
    log: Arc<Mutex<Vec<(DVec3, u32)>>>,
}

impl HapticDevice for LateDevice {
    type Error = DeviceError;
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        self.log
            .lock()
            .unwrap()
            .push((force_n, self.ages.information));
        Ok(())
    }
    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.reads += 1;
        self.ages.read((self.script)(self.reads))?;
        // Half a millimetre into the wall: 0.4 N rendered, small enough to engage.
        Ok(DeviceState::at_rest(DVec3::new(0.0, 0.0, -0.0005)))
    }
    fn state_age_ticks(&self) -> u32 {
        self.ages.last
    }
}

/// Fresh answers to engage, then answers 5 ticks old, then none for 8 ticks, then fresh again.
fn late_script(read: u64) -> Answer {
    match read {
        0..=400 => Answer::Aged(0),
        401..=420 => Answer::Aged(5),
        421..=428 => Answer::Late,
        _ => Answer::Aged(0),
    }
}

/// Through the real supervisor: the trace's `sample_age_ticks` is the age the driver reports (counted on
/// while no answer comes), and every tick whose state is older than the staleness bound (3 periods,
/// docs/safety.md) sends exactly zero with the cause `stale_link`; the device's own log agrees.
#[test]
fn a_device_that_answers_late_renders_nothing_from_old_positions() {
    let log = Arc::new(Mutex::new(Vec::new()));
    let bound = SupervisorConfig::default().stale_state_ticks;
    assert_eq!(bound, 3, "docs/safety.md documents 3 periods");
    let mut supervisor = late_supervisor(LateDevice {
        info: late_info(),
        script: late_script,
        reads: 0,
        ages: Ages::new(),
        log: log.clone(),
    });
    let first = supervisor.tick(TickInput::at(DVec3::ZERO, 0)).state;
    let (samples, _, _) = run_loop(Box::new(supervisor), first, 600);
    let mut stale = 0;
    let mut max_age = 0;
    let mut engaged_full = 0;
    for sample in &samples {
        let age = sample.truth.sample_age_ticks;
        max_age = max_age.max(age);
        if age > bound {
            stale += 1;
            assert_eq!(
                sample.sent_force_n,
                DVec3::ZERO,
                "tick {}: age {age}",
                sample.tick
            );
            assert_eq!(
                sample.truth.force_off_cause,
                ForceOffCause::StaleLink,
                "tick {}: age {age}",
                sample.tick
            );
        } else if sample.truth.force_off_cause == ForceOffCause::None {
            engaged_full += u32::from(sample.sent_force_n != DVec3::ZERO);
        }
    }
    // 20 answers 5 ticks old, then 8 missing ones counting up from there.
    assert!(max_age >= 5 + 8 - 1, "largest age {max_age}");
    assert!(stale >= 28, "{stale} stale ticks");
    assert!(engaged_full > 100, "{engaged_full} ticks with force on");
    // The device's side: no force while the newest state it had handed out was older than the bound.
    for (force, age) in log.lock().unwrap().iter() {
        assert!(
            *force == DVec3::ZERO || *age <= bound,
            "{force:?} at age {age}"
        );
    }
}
