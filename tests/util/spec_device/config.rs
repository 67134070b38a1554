//! What a test asks of the device: when a misbehaviour starts ([`Trigger`]), the scripted handle, and every
//! misbehaviour switch ([`SpecDeviceConfig`]).

use std::sync::Arc;
use std::time::Duration;

// ---------------------------------------------------------------------------------------------------------------
// Configuration.

/// When an injected misbehaviour starts. The device checks each trigger at every control cycle and latches it the
/// first time it holds (logged as a [`TriggerRecord`]); two settings with equal triggers fire at the same cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Trigger {
    /// This long after the first accepted Enable.
    AfterFirstEnable(Duration),
    /// At the first control cycle at which the drive is Enabled and the last SetForce received since the latest
    /// Enable was applied and longer than this many newtons: force is flowing at that moment, however long the
    /// host took to get there.
    ForceAbove(f32),
}

/// The time a scripted handle sees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandleTime {
    /// Seconds since the device was spawned.
    pub since_spawn_s: f64,
    /// Seconds since the first accepted Enable, if there was one.
    pub since_first_enable_s: Option<f64>,
}

/// Handle position (device frame, metres) as a function of time.
pub type HandleFn = Arc<dyn Fn(HandleTime) -> [f32; 3] + Send + Sync>;

/// What the device is and how it misbehaves. `SpecDeviceConfig::default()` is a well-behaved 3-DOF arm, 8 N,
/// stiffness 2000 N/m, workspace ±8 × ±6 × ±5 cm, handle still at (0.02, 0, 0.04) m (the built-in scene's start).
#[derive(Clone)]
pub struct SpecDeviceConfig {
    /// Protocol version sent in DeviceInfo, `(major, minor)`.
    pub version: (u8, u8),
    pub model: String,
    pub serial_number: String,
    pub position_dof: u8,
    pub force_dof: u8,
    pub workspace_min_m: [f32; 3],
    pub workspace_max_m: [f32; 3],
    pub max_force_n: f32,
    pub max_stiffness_n_per_m: f32,
    /// Rate-table bit set (SPEC section 3.2), default {250, 500, 1000} Hz.
    pub supported_rates: u8,
    /// The handle position.
    pub handle: HandleFn,
    /// Reject every Enable with this reason (e.g. [`reject::INVALID_ARGUMENT`]), changing nothing.
    pub refuse_enable: Option<u8>,
    /// Start Faulted with this latched code (Enable is then rejected with FAULTED until ClearFault).
    pub start_faulted: Option<u8>,
    /// Raise `Fault(code)` at the trigger (once). Code 0 drops to Idle; codes ≥ 1 latch.
    pub fault: Option<(Trigger, u8)>,
    /// The first N DeviceInfo replies go out with a bad CRC.
    pub corrupt_device_infos: u32,
    /// Write nothing at all for this long from the trigger (the device still receives, logs and runs its watchdog).
    pub silence: Option<(Trigger, Duration)>,
    /// Every frame is written this long after it was produced.
    pub reply_delay: Duration,
    /// Each DeviceInfo (with its leading 0x00) is written this long after the Hello it answers arrived (on top
    /// of `reply_delay`), and, since the device writes in order, so is everything it produced after it: a device
    /// slow to answer Hello (a bootloader, a USB-serial adapter's latency timer, a long round trip). The session
    /// itself opens when the Hello arrives (SPEC section 6).
    pub device_info_delay: Duration,
    /// `device_info_delay` acts only from this trigger on (`None`: from the start).
    pub device_info_delay_from: Option<Trigger>,
    /// Each written byte is replaced by a random one with this probability (seeded by `seed`).
    pub corrupt_fraction: f64,
    /// Every Nth frame written is cut to its first half, without the delimiter.
    pub partial_frame_every: Option<u32>,
    /// From the trigger on, the reported position is offset by this many metres (an encoder jump).
    pub position_glitch: Option<(Trigger, [f32; 3])>,
    /// From the trigger on, the reported velocity is this constant (m/s) instead of the handle's own.
    pub velocity_override: Option<(Trigger, [f32; 3])>,
    /// Against SPEC 6.8: a 1- or 2-DOF device reports these (position m, velocity m/s) in the components its
    /// `position_dof` leaves unused, instead of 0. (`None`: 0, as the SPEC says.)
    pub unused_components: Option<([f32; 3], [f32; 3])>,
    /// RNG seed for `corrupt_fraction`.
    pub seed: u64,
    /// `corrupt_fraction` and `partial_frame_every` act only from this trigger on (`None`: from the start).
    pub noise_from: Option<Trigger>,
    /// At the trigger the device resets (a brown-out): session closed, Idle, counters and settings back to
    /// power-up, pending replies lost, a lone 0x00 sent as at start-up (SPEC sections 4.3 and 6).
    pub reset: Option<Trigger>,
    /// From the trigger on, the handle stays where it was when the trigger fired (the hand stops moving).
    pub handle_hold: Option<Trigger>,
    /// Called once, on the device thread, at the control cycle the trigger fires: lets a test act on the host at
    /// that exact moment (freeze it, signal it to stop) rather than some scheduling delay later.
    pub call_at: Option<(Trigger, Callback)>,
}

/// A test's action run by the device thread ([`SpecDeviceConfig::call_at`]).
pub type Callback = Arc<dyn Fn() + Send + Sync>;

impl Default for SpecDeviceConfig {
    fn default() -> Self {
        Self {
            version: (1, 0),
            model: "spec-device".to_owned(),
            serial_number: "SPEC-1".to_owned(),
            position_dof: 3,
            force_dof: 3,
            workspace_min_m: [-0.08, -0.06, -0.05],
            workspace_max_m: [0.08, 0.06, 0.05],
            max_force_n: 8.0,
            max_stiffness_n_per_m: 2000.0,
            supported_rates: 0b0001_1100,
            handle: Arc::new(|_| [0.02, 0.0, 0.04]),
            refuse_enable: None,
            start_faulted: None,
            fault: None,
            corrupt_device_infos: 0,
            silence: None,
            reply_delay: Duration::ZERO,
            device_info_delay: Duration::ZERO,
            device_info_delay_from: None,
            corrupt_fraction: 0.0,
            partial_frame_every: None,
            position_glitch: None,
            velocity_override: None,
            unused_components: None,
            seed: 1,
            noise_from: None,
            reset: None,
            handle_hold: None,
            call_at: None,
        }
    }
}
