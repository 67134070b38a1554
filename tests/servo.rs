//! The servo runtime: the loop under a mock clock (deterministic: overruns skip, budgets hold the last safe
//! force, commands apply at tick boundaries, a full recorder ring is counted), the zero-allocation proof
//! for 10 000 ticks with mode and volume changes, and a real-time session driven through `SessionApi`.

use crate::util::alloc::count_allocations;
use glam::DVec3;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use voxhap::clock::{Clock, MockClock};
use voxhap::device::supervisor::SupervisorConfig;
use voxhap::device::supervisor::{TickClock, TickInput};
use voxhap::haptics::modes::{ModeConfig, ModeKind, TransferFunction};
use voxhap::record::{TraceSample, FLAG_COMPUTE_OVER_BUDGET, FLAG_OVERRUN, FLAG_SAMPLES_DROPPED};
use voxhap::servo::device::{open_device, DeviceSpec};
use voxhap::servo::passivity::{PassivityController, PassivityMode, PassivitySettings};
use voxhap::servo::runner::{CommandEnvelope, LoopIo, LoopTiming, ServoCommand, ServoLoop};
use voxhap::servo::schedule::{MockWaiter, Waiter};
use voxhap::servo::setup::{load_volume_arg, SceneBundle, SceneSetup};
use voxhap::servo::stats::ServoStats;
use voxhap::servo::Snapshot;

const PERIOD_NS: u64 = 1_000_000;

struct Rig {
    servo: ServoLoop,
    commands: Commands,
    retired: rtrb::Consumer<Box<SceneBundle>>,
    samples: rtrb::Consumer<TraceSample>,
    snapshot: triple_buffer::Output<Option<Snapshot>>,
    /// The snapshots handed to the recorder for the scene topics.
    scene_frames: rtrb::Consumer<Snapshot>,
    stats: Arc<ServoStats>,
    setup: SceneSetup,
}

/// The control side's end of the command ring, numbering commands as the session does.
struct Commands {
    ring: rtrb::Producer<CommandEnvelope>,
    next_id: u64,
}

impl Commands {
    fn push(&mut self, command: ServoCommand) -> Result<(), ()> {
        self.next_id += 1;
        self.ring
            .push(CommandEnvelope {
                id: self.next_id,
                command,
            })
            .map_err(|_| ())
    }
}

fn rig(sample_capacity: usize) -> Rig {
    rig_warming(sample_capacity, 0)
}

/// A rig whose loop warms its caches `warm_lead_ns` before each deadline (0: off).
fn rig_warming(sample_capacity: usize, warm_lead_ns: u64) -> Rig {
    let setup = SceneSetup::builtin().unwrap();
    let bundle = setup.bundle(PERIOD_NS, 0.3, 1).unwrap();
    let opened = open_device(
        &DeviceSpec::Sim,
        SupervisorConfig::default(),
        (setup.arm.clone(), setup.start_m),
        PERIOD_NS as f64 * 1e-9,
    )
    .unwrap();
    let mut device = opened.device;
    device.connect(0).unwrap();
    let first = device.exchange(TickInput::at(DVec3::ZERO, 0)).state;
    let (command_ring, command_rx) = rtrb::RingBuffer::new(64);
    let commands = Commands {
        ring: command_ring,
        next_id: 0,
    };
    let (events, _) = rtrb::RingBuffer::new(256);
    let (retire_tx, retired) = rtrb::RingBuffer::new(64);
    let (sample_tx, samples) = rtrb::RingBuffer::new(sample_capacity);
    let (snapshot_in, snapshot) = triple_buffer::triple_buffer(&None);
    let (frame_tx, scene_frames) = rtrb::RingBuffer::new(256);
    let stats = Arc::new(ServoStats::new(1000.0));
    let servo = ServoLoop::new(
        Box::new(bundle),
        device,
        LoopIo {
            commands: command_rx,
            command_claim: Arc::new(std::sync::atomic::AtomicU64::new(0)),
            retired: retire_tx,
            samples: sample_tx,
            snapshot: snapshot_in,
            scene_frames: frame_tx,
            events,
        },
        stats.clone(),
        LoopTiming {
            period_ns: PERIOD_NS,
            compute_budget_ns: 600_000,
            warm_lead_ns,
        },
        PERIOD_NS,
        first,
    );
    Rig {
        servo,
        commands,
        retired,
        samples,
        snapshot,
        scene_frames,
        stats,
        setup,
    }
}

fn mock_waiter() -> (MockWaiter, Arc<MockClock>) {
    let clock = Arc::new(MockClock::new(0));
    (MockWaiter::new(clock.clone()), clock)
}

#[test]
fn on_time_ticks_are_consecutive_and_safe() {
    let mut rig = rig(4096);
    let (mut waiter, clock) = mock_waiter();
    for expected in 0..2000 {
        assert_eq!(rig.servo.step(&mut waiter), expected);
    }
    assert_eq!(
        clock.now_ns(),
        2000 * PERIOD_NS,
        "each tick waited for its own deadline"
    );
    let report = rig.stats.report();
    assert_eq!(
        (report.ticks, report.overruns, report.recorder_drops),
        (2000, 0, 0)
    );
    assert_eq!(report.lateness.max_us, 0.0);
    let mut count = 0;
    let mut max_force: f64 = 0.0;
    while let Ok(sample) = rig.samples.pop() {
        assert_eq!(sample.tick, count);
        assert!(sample.sent_force_n.is_finite() && sample.probe_m.is_finite());
        max_force = max_force.max(sample.sent_force_n.length());
        count += 1;
    }
    assert_eq!(count, 2000);
    // The arm is pulled into the ball: the surface pushes back, within the device limit.
    assert!(
        max_force > 0.1 && max_force <= 10.0,
        "max force {max_force}"
    );
    let snapshot = rig.snapshot.read().unwrap();
    assert_eq!(snapshot.tick, 1999);
    assert!(snapshot.engaged && snapshot.connected);
    // The recorder's scene snapshots: every 17th tick at 1 kHz (58.8 Hz, under the recorded 60 Hz), each
    // the tick's full snapshot, the primitives of the surface the arm is pulled into among them.
    let every = voxhap::record::foxglove_scene::scene_frame_interval_ticks(PERIOD_NS);
    assert_eq!(every, 17);
    let mut frames = Vec::new();
    while let Ok(frame) = rig.scene_frames.pop() {
        frames.push(frame);
    }
    let ticks: Vec<u64> = frames.iter().map(|f| f.tick).collect();
    assert_eq!(ticks, (0..2000).step_by(17).collect::<Vec<u64>>());
    assert!(
        frames.iter().any(|f| f.primitive_count > 0),
        "no scene snapshot carried a primitive"
    );
}

/// Records every deadline the loop asks to wait for.
struct RecordingWaiter {
    inner: MockWaiter,
    waits_ns: Vec<u64>,
}

impl Waiter for RecordingWaiter {
    fn now_ns(&self) -> u64 {
        self.inner.now_ns()
    }
    fn wait_until(&mut self, deadline_ns: u64) {
        self.waits_ns.push(deadline_ns);
        self.inner.wait_until(deadline_ns);
    }
    fn clock(&self) -> &dyn Clock {
        self.inner.clock()
    }
    fn tick_clock(&self) -> TickClock {
        self.inner.tick_clock()
    }
}

#[test]
fn cache_warming_wakes_before_each_deadline_and_changes_no_output() {
    const LEAD_NS: u64 = 30_000;
    let mut plain = rig(4096);
    let mut warmed = rig_warming(4096, LEAD_NS);
    let (mut plain_waiter, _) = mock_waiter();
    let mut waiter = RecordingWaiter {
        inner: mock_waiter().0,
        waits_ns: Vec::new(),
    };
    for _ in 0..500 {
        plain.servo.step(&mut plain_waiter);
        warmed.servo.step(&mut waiter);
    }
    // Two waits per tick: the warm-up point, then the deadline itself.
    assert_eq!(waiter.waits_ns.len(), 1000);
    for (tick, pair) in waiter.waits_ns.chunks(2).enumerate() {
        let deadline = (tick as u64 + 1) * PERIOD_NS; // the rig starts one period in
        assert_eq!(
            pair,
            [deadline.saturating_sub(LEAD_NS), deadline],
            "tick {tick}"
        );
    }
    // Warming only reads the volumes: every tick's output is bit for bit what it is without it.
    let mut compared = 0;
    while let (Ok(a), Ok(b)) = (plain.samples.pop(), warmed.samples.pop()) {
        assert_eq!(
            (a.tick, a.probe_m, a.proxy_m, a.sent_force_n),
            (b.tick, b.probe_m, b.proxy_m, b.sent_force_n)
        );
        compared += 1;
    }
    assert_eq!(compared, 500);
}

#[test]
fn a_late_tick_is_counted_and_skipped_not_caught_up() {
    let mut rig = rig(4096);
    let (mut waiter, clock) = mock_waiter();
    // Tick 3 wakes 3.5 periods late; the ticks whose deadlines passed meanwhile are skipped.
    waiter.script_lateness(&[0, 0, 0, 3_500_000]);
    let ticks: Vec<u64> = (0..6).map(|_| rig.servo.step(&mut waiter)).collect();
    assert_eq!(ticks, vec![0, 1, 2, 3, 7, 8]);
    let report = rig.stats.report();
    assert_eq!((report.overruns, report.skipped_ticks), (1, 3));
    assert!(report.lateness.max_us >= 3500.0);
    assert_eq!(
        clock.now_ns(),
        9 * PERIOD_NS,
        "tick 8 is due at 9 ms (tick 0 at 1 ms)"
    );
    let samples: Vec<TraceSample> = std::iter::from_fn(|| rig.samples.pop().ok()).collect();
    let flagged: Vec<u64> = samples
        .iter()
        .filter(|s| s.flags & FLAG_OVERRUN != 0)
        .map(|s| s.tick)
        .collect();
    assert_eq!(
        flagged,
        vec![7],
        "the first tick after the gap carries the overrun flag"
    );
}

/// A waiter whose clock moves by `step_ns` every time it is read: a tick that reads the clock n times
/// "takes" n * step_ns.
struct SlowClockWaiter {
    now_ns: std::cell::Cell<u64>,
    step_ns: u64,
}

// SAFETY-free: the waiter lives on one thread; `Send` is needed by the trait only.
unsafe impl Send for SlowClockWaiter {}

impl Clock for SlowClockWaiter {
    fn now_ns(&self) -> u64 {
        let now = self.now_ns.get() + self.step_ns;
        self.now_ns.set(now);
        now
    }
}

impl Waiter for SlowClockWaiter {
    fn now_ns(&self) -> u64 {
        Clock::now_ns(self)
    }
    fn wait_until(&mut self, deadline_ns: u64) {
        if self.now_ns.get() < deadline_ns {
            self.now_ns.set(deadline_ns);
        }
    }
    fn clock(&self) -> &dyn Clock {
        self
    }
    fn tick_clock(&self) -> TickClock {
        // Simulated: its time passes only where the loop reads it, never inside the exchange.
        TickClock::Virtual
    }
}

#[test]
fn compute_over_budget_sends_the_last_safe_force() {
    let mut rig = rig(4096);
    let (mut waiter, _) = mock_waiter();
    // Enabled after 50 steady ticks, engaged once the force is small, ramped in over 0.5 s.
    for _ in 0..1500 {
        rig.servo.step(&mut waiter);
    }
    assert!(rig.snapshot.read().unwrap().engaged);
    let before: Vec<TraceSample> = std::iter::from_fn(|| rig.samples.pop().ok()).collect();
    let last_safe = before.last().unwrap().sent_force_n;
    // Now every clock read costs 700 us: the compute check (budget 600 us) fails.
    let mut slow = SlowClockWaiter {
        now_ns: std::cell::Cell::new(1500 * PERIOD_NS),
        step_ns: 700_000,
    };
    rig.servo.step(&mut slow);
    let sample = rig.samples.pop().unwrap();
    assert!(sample.flags & FLAG_COMPUTE_OVER_BUDGET != 0);
    assert_eq!(rig.stats.report().budget_overruns, 1);
    // The safety pipeline passes the repeated force (it was already safe): same force as the last tick.
    assert!(
        (sample.sent_force_n - last_safe).length() < 1e-12,
        "sent {:?}, last safe {:?}",
        sample.sent_force_n,
        last_safe
    );
}

#[test]
fn commands_apply_at_the_next_tick_boundary() {
    let mut rig = rig(4096);
    let (mut waiter, _) = mock_waiter();
    rig.servo.step(&mut waiter);
    assert_eq!(rig.snapshot.read().unwrap().stiffness_n_per_m, 500.0);
    rig.commands
        .push(ServoCommand::SetCoupling {
            stiffness_n_per_m: 250.0,
            // Below the simulated arm's damping cap b - K T / 2 = 1 - 0.125 N s/m.
            damping_n_s_per_m: 0.5,
            generation: 2,
        })
        .unwrap();
    // Nothing changes until the servo's next tick.
    assert_eq!(rig.snapshot.read().unwrap().stiffness_n_per_m, 500.0);
    rig.servo.step(&mut waiter);
    let snapshot = *rig.snapshot.read();
    let snapshot = snapshot.unwrap();
    assert_eq!(
        (
            snapshot.stiffness_n_per_m,
            snapshot.damping_n_s_per_m,
            snapshot.scene_generation
        ),
        (250.0, 0.5, 2)
    );
    // A bad value slipped past the control side is still refused by the servo.
    rig.commands
        .push(ServoCommand::SetCoupling {
            stiffness_n_per_m: f64::NAN,
            damping_n_s_per_m: 0.0,
            generation: 3,
        })
        .unwrap();
    rig.servo.step(&mut waiter);
    assert_eq!(rig.snapshot.read().unwrap().stiffness_n_per_m, 250.0);
    // A scene swap: the old bundle comes back through the retire ring.
    let mut setup = rig.setup.clone();
    setup.modes.pop();
    rig.commands
        .push(ServoCommand::SwapScene(Box::new(
            setup.bundle(PERIOD_NS, 0.3, 4).unwrap(),
        )))
        .unwrap();
    rig.servo.step(&mut waiter);
    assert_eq!(rig.servo.bundle().scene.modes().len(), 2);
    assert_eq!(rig.snapshot.read().unwrap().scene_generation, 4);
    let retired = rig
        .retired
        .pop()
        .expect("old scene returned for dropping off the servo thread");
    assert_eq!(retired.scene.modes().len(), 3);
    assert_eq!(rig.stats.commands_applied.load(Ordering::Relaxed), 3);
}

#[test]
fn a_full_recorder_ring_is_counted_and_flagged_never_waited_on() {
    let mut rig = rig(16);
    let (mut waiter, _) = mock_waiter();
    for _ in 0..20 {
        rig.servo.step(&mut waiter);
    }
    assert_eq!(rig.stats.report().recorder_drops, 4);
    let kept: Vec<TraceSample> = std::iter::from_fn(|| rig.samples.pop().ok()).collect();
    assert_eq!(kept.len(), 16);
    rig.servo.step(&mut waiter);
    let next = rig.samples.pop().unwrap();
    assert_eq!(next.tick, 20);
    assert!(
        next.flags & FLAG_SAMPLES_DROPPED != 0,
        "the sample after a gap says samples were lost"
    );
}

#[test]
fn ten_thousand_servo_ticks_with_mode_and_volume_changes_allocate_nothing() {
    // With cache warming on, as sessions run by default: the warm-up reads are on the servo thread too.
    let mut rig = rig_warming(16_384, 30_000);
    let (mut waiter, _) = mock_waiter();
    // Scenes prepared off the servo thread: remove a mode, add one back with another transfer function,
    // swap the density volume for a torus, and back.
    let base = rig.setup.clone();
    let mut fewer = base.clone();
    fewer.modes.pop();
    let mut more = base.clone();
    more.modes.push(ModeConfig {
        name: Some("gradient".to_owned()),
        volume: Some("density".to_owned()),
        transfer: Some(TransferFunction::new(vec![[0.0, 0.0], [1.0, 0.2]]).unwrap()),
        ..ModeConfig::new(ModeKind::GradientForce)
    });
    let mut torus = base.clone();
    let (volume, source) = load_volume_arg("builtin:torus").unwrap();
    torus
        .replace_volume(Some("density"), volume, source)
        .unwrap();
    let setups = [fewer, more, torus, base];
    let mut bundles: Vec<Box<SceneBundle>> = (0..20)
        .map(|i| Box::new(setups[i % 4].bundle(PERIOD_NS, 0.3, i as u64 + 2).unwrap()))
        .collect();
    bundles.reverse();
    let mut graveyard: Vec<Box<SceneBundle>> = Vec::with_capacity(64);
    // The passivity controller on, as on a real device, with a tick of latency: its observer, controller and
    // the passive introduction of the changes below run inside the count.
    rig.servo.set_passivity(PassivityController::new(
        PassivityMode::Control,
        &PassivitySettings::default(),
        1,
    ));
    // The external force input on, fed from this (the control) side every 40 ticks with a 30-tick timeout:
    // the servo thread reads it, ages it and drops it inside the count.
    let (mut external, receiver) =
        voxhap::servo::external_force::channel(Duration::from_millis(30), PERIOD_NS);
    rig.servo.set_external_force(receiver);
    let mut external_seen = 0u64;
    let mut samples_seen = 0u64;
    let mut generations_seen = 0u64;
    let mut last_generation = 0;
    let ((), allocations) = count_allocations(|| {
        for tick in 0..10_000u64 {
            if tick % 40 == 0 {
                let _ = external.send([0.0, 0.2 * (tick % 3) as f64, 0.1]);
            }
            if tick % 500 == 250 {
                if let Some(bundle) = bundles.pop() {
                    let _ = rig.commands.push(ServoCommand::SwapScene(bundle));
                }
            }
            if tick % 1000 == 700 {
                let _ = rig.commands.push(ServoCommand::SetCoupling {
                    stiffness_n_per_m: 300.0 + tick as f64 / 100.0,
                    damping_n_s_per_m: 0.5,
                    generation: 100 + tick,
                });
            }
            rig.servo.step(&mut waiter);
            while let Ok(old) = rig.retired.pop() {
                if graveyard.len() < graveyard.capacity() {
                    graveyard.push(old);
                }
            }
            while let Ok(sample) = rig.samples.pop() {
                samples_seen += 1;
                external_seen += u64::from(sample.truth.external_force_n != DVec3::ZERO);
            }
            if let Some(snapshot) = *rig.snapshot.read() {
                if snapshot.scene_generation != last_generation {
                    last_generation = snapshot.scene_generation;
                    generations_seen += 1;
                }
            }
        }
    });
    assert_eq!(allocations, 0, "the servo loop allocated or freed");
    let passivity = rig.servo.passivity().totals();
    assert!(
        passivity.generated_j != 0.0 && passivity.generated_j.is_finite(),
        "the observer ran: {passivity:?}"
    );
    assert_eq!(samples_seen, 10_000);
    // 30 of every 40 ticks carry the force (the timeout), the others none.
    assert_eq!(
        external_seen,
        10_000 / 40 * 30,
        "the external force was applied"
    );
    assert_eq!(rig.stats.commands_applied.load(Ordering::Relaxed), 30);
    assert_eq!(
        graveyard.len(),
        20,
        "every replaced scene was returned, none dropped on the loop"
    );
    assert!(
        generations_seen >= 30,
        "saw {generations_seen} scene generations"
    );
    assert_eq!(rig.stats.report().recorder_drops, 0);
}
