//! The servo loop itself: what happens in one tick, and nothing that may block.
//!
//! [`ServoLoop::step`] is one tick: wait for the deadline, apply pending commands, read the probe from the
//! previous exchange, run the pure tick ([`tick_timed`]: modes, exact solve under a time budget, coupling
//! force), add the coupling damping, check the compute budget, hand the force to the device (the supervisor:
//! device status, safety pipeline, write, read, input checks), report the device's events (SPSC ring to the
//! monitor thread, which prints them), then publish the snapshot (triple buffer; every few ticks also into
//! an SPSC ring for the recorder's scene topics), push the trace sample (SPSC ring; a full ring is counted,
//! never waited on), record statistics and advance the schedule (skipping after an overrun). The servo thread calls `step` in a loop; tests call it directly with a [`MockWaiter`], so the
//! loop runs deterministically and faster than real time.
//!
//! Coupling caps: the stiffness and damping in use are capped by the connected device's declared limits
//! ([`CouplingCaps`]: the stiffness it renders stably at 1 kHz, scaled to this rate, and the damping the
//! passivity bound leaves), at start, on every reconnect, and on every command that changes them.
//!
//! Commands are atomic: each carries an id, and the servo thread applies command `n` only if it wins the
//! claim `n - 1 → n` on a shared counter; a control thread that gave up waiting wins it instead, so the
//! command is dropped unapplied (a replaced scene still goes back through the retire ring).
//!
//! Nothing in `step` allocates, locks or frees: scenes arrive ready-built in a `Box` through the command
//! ring and the replaced one goes back through the retire ring, to be dropped by the control side. The
//! counting-allocator integration test runs 10 000 steps with scene swaps to prove it.
//!
//! [`MockWaiter`]: super::schedule::MockWaiter

use super::device::ServoDevice;
use super::energy::{EnergyLedger, SentShare};
use super::external_force::ExternalForceReceiver;
use super::force_off::ForceOffTracker;
use super::monitor::DeviceReport;
use super::passivity::{
    CouplingTransition, LinkFollower, PassivityController, PassivityMode, PassivitySettings,
};
use super::schedule::{Schedule, Waiter};
use super::setup::SceneBundle;
use super::stats::ServoStats;
use glam::DVec3;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use voxhap_api::{PrimitiveView, Snapshot, TickTruth};
use voxhap_core::haptics::modes::{Mode, ModeMemory, MAX_MODES};
use voxhap_core::haptics::tick::{tick_timed, TickState, TickStatus};
use voxhap_device::safety::{CouplingCaps, SafetyFlags};
use voxhap_device::supervisor::{ClearFaultOutcome, SupervisorEvent, TickInput};
use voxhap_device::DeviceState;
use voxhap_record::foxglove_scene::scene_frame_interval_ticks;
use voxhap_record::{
    TraceSample, FLAG_COMPUTE_OVER_BUDGET, FLAG_DEVICE_DISCONNECTED, FLAG_DEVICE_FAULTED,
    FLAG_DEVICE_NOT_ENABLED, FLAG_FORCE_CLAMPED, FLAG_FORCE_LIMITED_BY_SAFETY,
    FLAG_FORCE_SLEW_LIMITED, FLAG_NON_FINITE_REPLACED, FLAG_OVERRUN, FLAG_POSITION_REJECTED,
    FLAG_SAMPLES_DROPPED, FLAG_STALE_STATE, FLAG_VELOCITY_ESTIMATED, FLAG_VELOCITY_REPLACED,
};

/// A command for the servo thread, applied at the start of a tick.
#[derive(Debug)]
pub enum ServoCommand {
    /// New coupling stiffness (N/m) and damping (N s/m); the scene keeps its modes.
    SetCoupling {
        stiffness_n_per_m: f64,
        damping_n_s_per_m: f64,
        generation: u64,
    },
    /// A new scene (modes, transfer functions, volumes), built off the servo thread.
    SwapScene(Box<SceneBundle>),
    /// The operator's `clear_fault`: ClearFault to the device, then enable again once the link is healthy.
    ClearFault,
}

/// A command with its id (1, 2, 3, ... in the order sent).
#[derive(Debug)]
pub struct CommandEnvelope {
    pub id: u64,
    pub command: ServoCommand,
}

/// Outcome codes of the last `ClearFault` command, for the control side (`ServoStats::clear_fault_outcome`).
pub const CLEAR_FAULT_REQUESTED: u8 = 1;
/// No fault to clear.
pub const CLEAR_FAULT_NOTHING: u8 = 2;
/// No device connected.
pub const CLEAR_FAULT_NO_DEVICE: u8 = 3;

/// The ends of the rings and buffers the loop owns.
pub struct LoopIo {
    pub commands: rtrb::Consumer<CommandEnvelope>,
    /// The id of the last command decided (applied by this thread, or cancelled by the control side).
    pub command_claim: Arc<AtomicU64>,
    pub retired: rtrb::Producer<Box<SceneBundle>>,
    pub samples: rtrb::Producer<TraceSample>,
    pub snapshot: triple_buffer::Input<Option<Snapshot>>,
    /// Every [`scene_frame_interval_ticks`]-th tick's snapshot, for the recorder's scene topics (MCAP); a
    /// full ring skips the frame (the trace writer draws those markers from the sample and counts them).
    pub scene_frames: rtrb::Producer<Snapshot>,
    /// Device events for the monitor thread to print.
    pub events: rtrb::Producer<DeviceReport>,
}

/// Timing settings of the loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopTiming {
    /// Servo period (ns).
    pub period_ns: u64,
    /// Longest the tick's compute (modes + solve) may take before the last safe force is sent instead (ns).
    pub compute_budget_ns: u64,
    /// How long before the deadline the loop wakes to warm the caches for the coming tick (reads the
    /// volumes around the proxy; see `RenderScene::warm_caches`); 0 turns warming off.
    pub warm_lead_ns: u64,
}

/// The servo thread's state. Everything it needs is owned here; see the module docs.
pub struct ServoLoop {
    bundle: Box<SceneBundle>,
    pending_retire: Option<Box<SceneBundle>>,
    state: TickState,
    device: Box<dyn ServoDevice>,
    io: LoopIo,
    stats: Arc<ServoStats>,
    schedule: Schedule,
    timing: LoopTiming,
    origin_ns: u64,
    last_state: Option<DeviceState>,
    last_safe_force_n: DVec3,
    last_tick: Option<u64>,
    overrun_pending: bool,
    samples_dropped_pending: bool,
    last_disconnects: u64,
    last_errors: u64,
    caps: CouplingCaps,
    last_state_fresh: bool,
    /// Ticks between two snapshots handed to the recorder ([`scene_frame_interval_ticks`]).
    scene_frame_every_ticks: u64,
    /// The energy ledger of the run (crate::energy).
    ledger: EnergyLedger,
    /// Why the force is off (crate::force_off).
    force_off: ForceOffTracker,
    /// The passivity observer and controller (crate::passivity; off unless [`ServoLoop::set_passivity`]).
    passivity: PassivityController,
    /// What a capable device's own passivity observer and controller run (crate::local_model).
    local_passivity: voxhap_device::local_offer::PassivityOffer,
    /// The observer's pairing, following the link's delay (crate::passivity::link_delay).
    link: LinkFollower,
    /// The share of last tick's rendered force that the safety pipeline sent (crate::energy).
    sent_share: SentShare,
    /// The passive introduction of a change applied in contact (crate::passivity::transition).
    transition: CouplingTransition,
    /// A command changed the coupling or the scene at the start of this tick.
    changed: bool,
    /// The point the coupling spring pulled towards last tick, and its stiffness then.
    last_anchor_m: DVec3,
    last_k: f64,
    /// The external force input (crate::external_force; off unless [`ServoLoop::set_external_force`]).
    external_force: Option<ExternalForceReceiver>,
}

impl ServoLoop {
    /// A loop starting its schedule at `origin_ns` (on the waiter's clock). `first_state` is the device
    /// state read before the loop (the proxy starts there).
    pub fn new(
        bundle: Box<SceneBundle>,
        device: Box<dyn ServoDevice>,
        io: LoopIo,
        stats: Arc<ServoStats>,
        timing: LoopTiming,
        origin_ns: u64,
        first_state: Option<DeviceState>,
    ) -> Self {
        let start_m = first_state.map_or(DVec3::ZERO, |s| s.position_m);
        let period_s = timing.period_ns as f64 * 1e-9;
        let caps = CouplingCaps::new(device.max_stiffness_n_per_m().unwrap_or(0.0), period_s)
            .with_damping_limit(device.max_damping_n_s_per_m());
        let mut device = device;
        device.set_period_us((timing.period_ns / 1000).max(1));
        let mut servo = ServoLoop {
            bundle,
            pending_retire: None,
            state: TickState::new(start_m),
            device,
            io,
            stats,
            schedule: Schedule::new(origin_ns, timing.period_ns),
            timing,
            origin_ns,
            last_state: first_state,
            last_safe_force_n: DVec3::ZERO,
            last_tick: None,
            overrun_pending: false,
            samples_dropped_pending: false,
            last_disconnects: 0,
            last_errors: 0,
            caps,
            last_state_fresh: false,
            scene_frame_every_ticks: scene_frame_interval_ticks(timing.period_ns),
            ledger: EnergyLedger::new(caps.device_damping_n_s_per_m),
            force_off: ForceOffTracker::default(),
            sent_share: SentShare::NOTHING,
            passivity: PassivityController::new(
                PassivityMode::Off,
                &PassivitySettings::default(),
                0,
            ),
            local_passivity: voxhap_device::local_offer::PassivityOffer::default(),
            link: LinkFollower::fixed(),
            transition: CouplingTransition::new(),
            changed: false,
            last_anchor_m: start_m,
            last_k: 0.0,
            external_force: None,
        };
        servo.apply_caps();
        servo.last_k = servo.bundle.scene.stiffness_n_per_m();
        servo
    }

    /// Runs `controller` in every tick (crate::passivity): its observer books what was sent and reported,
    /// its controller's force is added before the safety pipeline, and (unless its mode is `off`) changes
    /// applied in contact are introduced passively.
    pub fn set_passivity(&mut self, controller: PassivityController) {
        self.passivity = controller;
    }

    /// What a device rendering local models runs as its own passivity observer and controller (the scene's
    /// `[passivity]` mode and most damping; protocol/SPEC.md section 10.5 step 4b). Off unless set.
    pub fn set_local_passivity(&mut self, request: voxhap_device::local_offer::PassivityOffer) {
        self.local_passivity = request;
    }

    /// The observer's pairing follows the link's delay as `follower` says (crate::passivity::link_delay).
    pub fn set_link_follower(&mut self, follower: LinkFollower) {
        self.link = follower;
    }

    /// Adds the force `receiver` hands over to the rendered force of every tick, before the passivity
    /// controller and the safety pipeline (crate::external_force).
    pub fn set_external_force(&mut self, receiver: ExternalForceReceiver) {
        self.external_force = Some(receiver);
    }

    /// The passivity observer's and controller's totals (for tests and the summary).
    pub fn passivity(&self) -> &PassivityController {
        &self.passivity
    }

    /// Caps the scene's coupling by the device's limits.
    fn apply_caps(&mut self) {
        let scene = &mut self.bundle.scene;
        let (k, damping) = self
            .caps
            .cap(scene.stiffness_n_per_m(), self.bundle.damping_n_s_per_m);
        if k < scene.stiffness_n_per_m() {
            let _ = scene.set_stiffness_n_per_m(k);
        }
        self.bundle.damping_n_s_per_m = damping;
    }

    /// The caps in force (device limits at this rate).
    pub fn caps(&self) -> CouplingCaps {
        self.caps
    }

    /// The schedule (for tests).
    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }

    /// The scene in use (for tests).
    pub fn bundle(&self) -> &SceneBundle {
        &self.bundle
    }

    fn apply_commands(&mut self) {
        // A replaced scene waits here until the retire ring has room; no new scene is taken meanwhile, so
        // nothing is ever dropped on this thread.
        if let Some(old) = self.pending_retire.take() {
            if let Err(rtrb::PushError::Full(old)) = self.io.retired.push(old) {
                self.pending_retire = Some(old);
                return;
            }
        }
        while let Ok(CommandEnvelope { id, command }) = self.io.commands.pop() {
            // Atomic with the control side: apply only if this thread decides the command.
            let claimed = self
                .io
                .command_claim
                .compare_exchange(id.wrapping_sub(1), id, Ordering::AcqRel, Ordering::Acquire)
                .is_ok();
            match command {
                ServoCommand::SetCoupling {
                    stiffness_n_per_m,
                    damping_n_s_per_m,
                    generation,
                } if claimed
                    // Validated by the sender; checked again so a bad value can never reach the device,
                    // and capped by the device's limits.
                    && stiffness_n_per_m.is_finite()
                    && stiffness_n_per_m > 0.0
                    && damping_n_s_per_m.is_finite()
                    && damping_n_s_per_m >= 0.0 =>
                {
                    let (k, damping) = self.caps.cap(stiffness_n_per_m, damping_n_s_per_m);
                    if self.bundle.scene.set_stiffness_n_per_m(k).is_ok() {
                        self.bundle.damping_n_s_per_m = damping;
                        self.bundle.generation = generation;
                        self.changed = true;
                    }
                }
                ServoCommand::ClearFault if claimed => {
                    let outcome = match self.device.request_clear_fault() {
                        ClearFaultOutcome::Requested => CLEAR_FAULT_REQUESTED,
                        ClearFaultOutcome::NothingToClear => CLEAR_FAULT_NOTHING,
                        ClearFaultOutcome::NoDevice => CLEAR_FAULT_NO_DEVICE,
                    };
                    self.stats
                        .clear_fault_outcome
                        .store(outcome, Ordering::Release);
                }
                ServoCommand::SwapScene(bundle) => {
                    let retire = if claimed {
                        let old = std::mem::replace(&mut self.bundle, bundle);
                        self.apply_caps();
                        self.changed = true;
                        // Modes changed: what they remembered (surface normals) no longer applies.
                        self.state.memory = ModeMemory {
                            previous_force_n: self.state.memory.previous_force_n,
                            ..ModeMemory::default()
                        };
                        old
                    } else {
                        // Cancelled: the new scene is never used, and goes back to be dropped off this thread.
                        bundle
                    };
                    if claimed {
                        self.stats.commands_applied.fetch_add(1, Ordering::Release);
                    }
                    if let Err(rtrb::PushError::Full(retire)) = self.io.retired.push(retire) {
                        self.pending_retire = Some(retire);
                        return;
                    }
                    continue;
                }
                _ => {}
            }
            if claimed {
                self.stats.commands_applied.fetch_add(1, Ordering::Release);
            }
        }
    }

    /// Runs one tick (module docs). Returns the tick number it ran.
    pub fn step(&mut self, waiter: &mut dyn Waiter) -> u64 {
        let deadline_ns = self.schedule.next_deadline_ns();
        let tick_index = self.schedule.next_tick();
        if self.timing.warm_lead_ns > 0 {
            let warm_at_ns = deadline_ns.saturating_sub(self.timing.warm_lead_ns);
            waiter.wait_until(warm_at_ns);
            // Only when there is time left: a late wake-up goes straight to the tick.
            if waiter.now_ns() < warm_at_ns + self.timing.warm_lead_ns / 2 {
                std::hint::black_box(self.bundle.scene.warm_caches(self.state.proxy_m));
            }
        }
        waiter.wait_until(deadline_ns);
        let start_ns = waiter.now_ns();
        let lateness_ns = start_ns.saturating_sub(deadline_ns);
        self.apply_commands();

        let period_s = self.timing.period_ns as f64 * 1e-9;
        let ticks_since = self
            .last_tick
            .map_or(1, |last| tick_index.saturating_sub(last).max(1));
        let dt_s = period_s * ticks_since as f64;
        let mut flags = 0;
        if std::mem::take(&mut self.overrun_pending) {
            flags |= FLAG_OVERRUN;
        }

        let (probe_m, probe_velocity) = match self.last_state {
            Some(state) => (state.position_m, state.velocity_m_per_s),
            None => (self.state.proxy_m, DVec3::ZERO),
        };
        // On time: started before the next deadline (an overrun is the loop not keeping its rate).
        let on_time = lateness_ns < self.timing.period_ns;
        let bundle = &mut *self.bundle;
        let out = tick_timed(
            &mut self.state,
            &bundle.scene,
            probe_m,
            dt_s,
            &mut bundle.workspace,
            waiter.clock(),
        );
        flags |= out.flags;
        let damping = bundle.damping_n_s_per_m;
        // A change applied in contact is introduced passively (crate::passivity::transition).
        let k = bundle.scene.stiffness_n_per_m();
        if std::mem::take(&mut self.changed) && self.passivity.mode() != PassivityMode::Off {
            self.transition
                .begin(probe_m, self.last_anchor_m, self.last_k, out.proxy_m, k);
        }
        let (anchor_m, spring_n, anchor_velocity) =
            match self.transition.anchor(probe_m, out.proxy_m, dt_s) {
                Some((anchor_m, velocity)) => (anchor_m, k * (anchor_m - probe_m), velocity),
                None => (
                    out.proxy_m,
                    out.coupling_force_n,
                    out.proxy_velocity_m_per_s,
                ),
            };
        self.last_anchor_m = anchor_m;
        self.last_k = k;
        let mut rendered_n = spring_n + damping * (anchor_velocity - probe_velocity);
        let directed_n = self.directed_force_n(&out);
        // Read every tick, so a force ages on the servo's clock whether or not it can be applied.
        let mut external_n = self
            .external_force
            .as_mut()
            .map_or(DVec3::ZERO, |e| e.force_at(tick_index));
        if self.last_state.is_none() || out.status == TickStatus::InputRejected {
            rendered_n = DVec3::ZERO;
            external_n = DVec3::ZERO;
        } else {
            rendered_n += external_n;
            // The passivity controller, before the safety pipeline (docs/safety.md). Its reference is the
            // energy the force sent can give back, as the energy ledger books it (at last tick's share): before
            // engaging, a spring stretched by a moving handle generates nothing, and damping it would hold the
            // rendered force above the engage threshold. The directed-force modes' part of the stretch (their
            // force over k) is intended work, not coupling energy (crate::passivity::controller).
            let share = self.sent_share;
            let reference_j = share.reaction_energy_j(k, anchor_m - probe_m, directed_n);
            let control_n =
                self.passivity
                    .observe_and_control(probe_m, probe_velocity, reference_j, dt_s);
            if control_n != DVec3::ZERO && share.fraction() > 0.0 {
                rendered_n += control_n;
            }
        }
        if !rendered_n.is_finite() {
            rendered_n = DVec3::ZERO;
            flags |= FLAG_NON_FINITE_REPLACED;
        }
        let compute_ns = waiter.now_ns().saturating_sub(start_ns);
        if compute_ns > self.timing.compute_budget_ns {
            // Too late to trust: repeat the last force that went out safely.
            rendered_n = self.last_safe_force_n;
            flags |= FLAG_COMPUTE_OVER_BUDGET;
            self.stats.budget_overruns.fetch_add(1, Ordering::Relaxed);
        }

        let force_valid = crate::local_model::force_valid(crate::local_model::ForceChecks {
            state_fresh: self.last_state.is_some() && self.last_state_fresh,
            status: out.status,
            force_finite: flags & FLAG_NON_FINITE_REPLACED == 0,
            on_budget: flags & FLAG_COMPUTE_OVER_BUDGET == 0,
        });

        // The state this tick rendered from, and its age, before the exchange replaces it.
        let rendered_from_state = self.last_state.is_some();
        let sample_age_ticks = self.device.state_age_ticks();
        // The tick's local model: a capable device renders it itself at its own rate (crate::local_model).
        let local =
            crate::local_model::offer(self.bundle.workspace.primitives(), k, damping, out.proxy_m)
                .with_passivity(self.local_passivity);
        // Read just before the exchange: the supervisor times the states it reads from here, on this clock.
        let exchange_start_ns = waiter.now_ns();
        let now_us = exchange_start_ns.saturating_sub(self.origin_ns) / 1000;
        let device_out = self.device.exchange(TickInput {
            force_n: rendered_n,
            now_us,
            clock: waiter.tick_clock(),
            on_time,
            force_valid,
            local: Some(local),
        });
        self.last_safe_force_n = device_out.sent_force_n;
        self.passivity.sent_with_active(
            rendered_n,
            device_out.sent_force_n,
            directed_n + external_n,
        );
        self.sent_share = SentShare::of(device_out.sent_force_n, rendered_n);
        if device_out.state.is_some() {
            self.last_state = device_out.state;
        }
        self.last_state_fresh = device_out.state.is_some() && !device_out.stale;
        if !device_out.connected {
            self.last_state = None;
        }
        flags |= trace_flags(device_out.flags);
        let end_ns = waiter.now_ns();
        let t_s = tick_index as f64 * period_s;
        let truth = self.book_truth(
            &device_out,
            &out,
            TruthInput {
                t_s,
                dt_s,
                probe_m,
                stretch_m: anchor_m - probe_m,
                directed_n,
                k_n_per_m: k,
                rendered_from_state,
                sample_age_ticks,
                force_replaced: flags & FLAG_NON_FINITE_REPLACED != 0,
                external_force_n: external_n,
            },
        );
        let bundle = &mut *self.bundle;

        // Statistics.
        let stats = &*self.stats;
        stats.ticks.fetch_add(1, Ordering::Relaxed);
        stats.lateness.record(lateness_ns);
        stats.compute.record(compute_ns);
        stats
            .device
            .record(end_ns.saturating_sub(exchange_start_ns));
        stats.max_sweeps.fetch_max(out.sweeps, Ordering::Relaxed);
        stats.note_bound(out.error_bound_m);
        let counters = self.device.counters();
        let errors = counters.timeouts + counters.errors + counters.failed_reconnects;
        stats
            .device_errors
            .fetch_add(errors.saturating_sub(self.last_errors), Ordering::Relaxed);
        stats.disconnects.fetch_add(
            counters.disconnects.saturating_sub(self.last_disconnects),
            Ordering::Relaxed,
        );
        self.last_errors = errors;
        self.last_disconnects = counters.disconnects;

        // Publish.
        let workspace_primitives = bundle.workspace.primitives();
        let mut primitive_slots = [None; MAX_MODES];
        let mut slot = 0;
        let mut emitted = 0usize;
        for (mode, &count) in out.modes.primitives().iter().enumerate() {
            for primitive in workspace_primitives
                .iter()
                .skip(emitted)
                .take(usize::from(count))
            {
                if slot < MAX_MODES {
                    primitive_slots[slot] = Some(PrimitiveView::new(primitive, mode as u8));
                    slot += 1;
                }
            }
            emitted += usize::from(count);
        }
        let snapshot = Snapshot {
            tick: tick_index,
            t_s,
            probe_m,
            probe_velocity_m_per_s: probe_velocity,
            proxy_m: out.proxy_m,
            rendered_force_n: rendered_n,
            sent_force_n: device_out.sent_force_n,
            primitive_slots,
            primitive_count: slot as u8,
            error_bound_m: out.error_bound_m,
            status: out.status,
            sweeps: out.sweeps,
            stiffness_n_per_m: bundle.scene.stiffness_n_per_m(),
            damping_n_s_per_m: damping,
            connected: device_out.connected,
            engaged: self.device.engaged(),
            output_state: device_out.output_state,
            active_faults: device_out.active_faults,
            flags,
            scene_generation: bundle.generation,
            hand_target_m: None,
            truth,
        };
        self.io.snapshot.write(Some(snapshot));
        if tick_index.is_multiple_of(self.scene_frame_every_ticks) {
            // Before the tick's sample, so the recorder finds it when that sample arrives.
            let _ = self.io.scene_frames.push(snapshot);
        }
        if std::mem::take(&mut self.samples_dropped_pending) {
            flags |= FLAG_SAMPLES_DROPPED;
        }
        if !device_out.connected {
            flags |= FLAG_DEVICE_DISCONNECTED;
        }
        let sample = TraceSample {
            device_sequence: self.last_state.and_then(|s| s.sequence).map(u64::from),
            device_time_us: self.last_state.and_then(|s| s.device_time_us),
            flags,
            ..TraceSample::published(&snapshot, &out)
        };
        if self.io.samples.push(sample).is_err() {
            stats.recorder_drops.fetch_add(1, Ordering::Relaxed);
            self.samples_dropped_pending = true;
        }

        self.publish_safety(&device_out, tick_index, period_s);

        self.last_tick = Some(tick_index);
        let advance = self.schedule.advance(waiter.now_ns());
        let stats = &*self.stats;
        if advance.overrun {
            stats.overruns.fetch_add(1, Ordering::Relaxed);
            stats
                .skipped_ticks
                .fetch_add(advance.skipped, Ordering::Relaxed);
            self.overrun_pending = true;
        }
        tick_index
    }

    /// The directed-force modes' share of the tick's force: intended work (crate::energy).
    fn directed_force_n(&self, out: &voxhap_core::haptics::tick::TickOutput) -> DVec3 {
        let modes = self.bundle.scene.modes().iter().zip(out.modes.forces_n());
        modes
            .filter(|(mode, _)| {
                matches!(mode, Mode::VectorForce { .. } | Mode::GradientForce { .. })
            })
            .map(|(_, force)| force)
            .sum()
    }

    /// Books the tick in the energy ledger (from the position the tick rendered from and the force the
    /// safety pipeline sent) and names why the force is off: the tick's truth.
    fn book_truth(
        &mut self,
        device_out: &voxhap_device::supervisor::SupervisorOutput,
        out: &voxhap_core::haptics::tick::TickOutput,
        input: TruthInput,
    ) -> TickTruth {
        // What the passivity controller dissipated so far is part of the ledger (crate::energy).
        self.ledger
            .book_passivity(self.passivity.totals().dissipated_j);
        let totals = if input.rendered_from_state {
            // The directed-force modes' share of the force and the external force are intended work (crate::energy).
            let active_n = input.external_force_n + input.directed_n;
            // The spring holds what the force actually sent can give back (crate::energy::SentShare).
            let coupling_j = self.sent_share.reaction_energy_j(
                input.k_n_per_m,
                input.stretch_m,
                input.directed_n,
            );
            self.ledger.record(
                input.t_s,
                input.dt_s,
                input.probe_m,
                device_out.sent_force_n,
                active_n,
                coupling_j,
            )
        } else {
            self.ledger.gap();
            self.ledger.totals()
        };
        self.stats.energy.store(&totals);
        TickTruth {
            energy: totals.tick_energy(),
            force_off_cause: self
                .force_off
                .cause(device_out, out.status, input.force_replaced),
            device_fault_bits: device_out.active_faults,
            sample_age_ticks: input.sample_age_ticks,
            // The device's own report comes with a state: none on ticks without one.
            device_force_n: device_out
                .state
                .and_then(|_| self.device.reported_force_n()),
            external_force_n: input.external_force_n,
            // What a capable device reported of its own loop with this tick's state (SPEC 10.4).
            device_local: device_out.local.map(|r| voxhap_api::DeviceLocal {
                proxy_m: r.proxy_m,
                proxy_bound_m: r.bound_m,
                model_sequence: r.model_sequence,
                model_age_s: f64::from(r.model_age_us) * 1e-6,
            }),
        }
    }

    /// Hands the tick's device events to the monitor and stores the safety counters; caps the coupling again
    /// when a (new) device connected.
    fn publish_safety(
        &mut self,
        device_out: &voxhap_device::supervisor::SupervisorOutput,
        tick_index: u64,
        period_s: f64,
    ) {
        let mut connected = false;
        for event in device_out.events.iter() {
            connected |= event == SupervisorEvent::Connected;
            let report = DeviceReport {
                tick: tick_index,
                t_s: tick_index as f64 * period_s,
                event,
            };
            if self.io.events.push(report).is_err() {
                self.stats
                    .safety
                    .events_dropped
                    .fetch_add(1, Ordering::Relaxed);
            }
        }
        self.link.follow(
            &*self.device,
            connected,
            &mut self.passivity,
            &self.stats.link_delay,
            tick_index,
        );
        if connected {
            self.caps =
                CouplingCaps::new(self.device.max_stiffness_n_per_m().unwrap_or(0.0), period_s)
                    .with_damping_limit(self.device.max_damping_n_s_per_m());
            self.ledger
                .set_device_damping(self.caps.device_damping_n_s_per_m);
            self.apply_caps();
        }
        let stats = &*self.stats;
        let counters = self.device.counters();
        let input = self.device.input_counters();
        let safety = &stats.safety;
        let store = |a: &AtomicU64, v: u64| a.store(v, Ordering::Relaxed);
        safety
            .output_state
            .store(device_out.output_state as u8, Ordering::Relaxed);
        safety
            .active_faults
            .store(u32::from(device_out.active_faults), Ordering::Relaxed);
        store(&safety.device_faults, counters.faults);
        store(
            &safety.device_watchdog_trips,
            counters.device_watchdog_trips,
        );
        store(&safety.device_rejections, counters.rejections);
        store(&safety.enables, counters.enables);
        store(&safety.not_enabled_ticks, counters.not_enabled_ticks);
        store(&safety.stale_ticks, counters.stale_ticks);
        store(&safety.device_surplus, counters.device_surplus);
        store(&safety.positions_rejected, input.positions_rejected);
        store(&safety.velocities_replaced, input.velocities_replaced);
        if device_out.flags.contains(SafetyFlags::SLEW_LIMITED) {
            safety.slew_limited_ticks.fetch_add(1, Ordering::Relaxed);
        }
        if device_out.flags.contains(SafetyFlags::CLAMPED) {
            safety.forces_clamped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Runs ticks until `stop` is set, then zeroes the force and closes the device.
    pub fn run(&mut self, waiter: &mut dyn Waiter, stop: &AtomicBool) {
        while !stop.load(Ordering::Acquire) {
            self.step(waiter);
        }
        self.shutdown();
    }

    /// Zero force, device disabled and closed.
    pub fn shutdown(&mut self) {
        self.device.stop();
    }
}

/// What [`ServoLoop::book_truth`] needs from the tick besides the exchange and the solve.
#[derive(Debug, Clone, Copy)]
struct TruthInput {
    t_s: f64,
    dt_s: f64,
    /// The probe position the tick rendered from.
    probe_m: DVec3,
    /// The coupling spring's stretch this tick (anchor less probe) and its stiffness.
    stretch_m: DVec3,
    /// The directed-force modes' share of the tick's force (intended work, crate::energy).
    directed_n: DVec3,
    k_n_per_m: f64,
    /// The tick had a device state to render from (else the ledger books a gap).
    rendered_from_state: bool,
    sample_age_ticks: u32,
    force_replaced: bool,
    /// The external force added to the rendered force this tick.
    external_force_n: DVec3,
}

/// The trace's flag bits for what the safety stages did this tick.
pub fn trace_flags(safety: SafetyFlags) -> u32 {
    let mut flags = 0;
    let map = [
        (SafetyFlags::CLAMPED, FLAG_FORCE_CLAMPED),
        (SafetyFlags::NON_FINITE, FLAG_NON_FINITE_REPLACED),
        (SafetyFlags::SLEW_LIMITED, FLAG_FORCE_SLEW_LIMITED),
        (SafetyFlags::DEVICE_NOT_ENABLED, FLAG_DEVICE_NOT_ENABLED),
        (SafetyFlags::STALE_STATE, FLAG_STALE_STATE),
        (SafetyFlags::POSITION_REJECTED, FLAG_POSITION_REJECTED),
        (SafetyFlags::VELOCITY_REPLACED, FLAG_VELOCITY_REPLACED),
        (SafetyFlags::DEVICE_FAULTED, FLAG_DEVICE_FAULTED),
        (SafetyFlags::VELOCITY_ESTIMATED, FLAG_VELOCITY_ESTIMATED),
    ];
    for (safety_flag, trace_flag) in map {
        if safety.contains(safety_flag) {
            flags |= trace_flag;
        }
    }
    if safety.limited() {
        flags |= FLAG_FORCE_LIMITED_BY_SAFETY;
    }
    flags
}
