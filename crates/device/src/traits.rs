//! The driver traits: [`HapticDevice`] (what every driver implements) and [`EmergencyStop`] (a stop any
//! thread may trigger).

use super::local_offer::{LocalOffer, LocalReport};
use super::{DeviceError, DeviceEvent, DeviceInfo, DeviceState, Error};
use glam::DVec3;

/// A haptic device driver: what it is, where its handle is, and which force to render.
///
/// Drivers implement the lifecycle hooks; the order (open, enable, forces, disable, close) is enforced by
/// [`Lifecycle`](super::Lifecycle), so a driver may assume it. `write_force` receives a force that the safety pipeline has already
/// made finite and clamped; drivers still refuse a non-finite one.
pub trait HapticDevice {
    /// The driver's error type.
    type Error: Error;

    /// Capabilities. Valid after a successful [`HapticDevice::open`]; drivers that know them up front return them
    /// at any time.
    fn info(&self) -> &DeviceInfo;

    /// Connects: handshake, setup commands. Forces stay zero.
    fn open(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Lets the device apply forces.
    fn enable(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Stops applying forces (the wrapper has already sent an explicit zero force).
    fn disable(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Releases the device.
    fn close(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Sends the force to render now (N, device frame).
    fn write_force(&mut self, force_n: DVec3) -> Result<(), Self::Error>;

    /// Reads the newest state of the handle.
    fn read_state(&mut self) -> Result<DeviceState, Self::Error>;

    /// True when the open device renders local models itself (protocol/SPEC.md section 10: it set
    /// `LOCAL_MODEL` in the handshake). The default: no driver but voxhap's protocol has the capability.
    fn local_model_capable(&self) -> bool {
        false
    }

    /// Sends the tick's local model (device frame) with the host's force limit instead of a set-force; only
    /// called when [`HapticDevice::local_model_capable`]. A model the wire cannot carry goes out as the
    /// set-force `fallback_force_n` (the safety pipeline's force). The default sends the fallback.
    /// Allocation-free.
    fn write_local_model(
        &mut self,
        model: &LocalOffer,
        force_limit_n: f64,
        fallback_force_n: DVec3,
    ) -> Result<(), Self::Error> {
        let _ = (model, force_limit_n);
        self.write_force(fallback_force_n)
    }

    /// What the device last reported of its local loop (LocalState), if it sent one since the last local model
    /// or set-force was written. Allocation-free.
    fn local_report(&self) -> Option<LocalReport> {
        None
    }

    /// How many servo ticks old the state the last `read_state` returned may be: 0 when it answers this tick's
    /// force, `n` when it may answer the force of `n` ticks ago: the Haply Inverse3 labels each state with the
    /// command it answers; drivers whose replies carry no sequence number report the oldest it may be
    /// (`drivers::reply_age`: after missed replies, or from a device that sends more than asked). The
    /// supervisor counts it towards its staleness bound, so a state older than `stale_state_ticks` never
    /// computes force. Allocation-free.
    fn state_age_ticks(&self) -> u32 {
        0
    }

    /// The force the device itself reports reached the arm with the state the last `read_state` returned
    /// (N, device frame): the Haply Inverse3's `current_cursor_force`. `None` (the default) for devices that
    /// report none. Recorded beside the force voxhap sent; allocation-free.
    fn reported_force_n(&self) -> Option<DVec3> {
        None
    }

    /// The host's verdict on the state the last `read_state` returned: `accepted` is false when the input checks
    /// (`plausibility`) rejected its position (held at the last accepted one, or unusable). The supervisor calls
    /// it every tick on which `read_state` returned a state, after checking it and before the next
    /// `write_force`. A driver that turns force into motor commands from a pose it read itself (joint angles,
    /// a Jacobian) must convert only with a pose the host accepted: it keeps the newest reading as a
    /// candidate, adopts it here when accepted, and keeps the last accepted pose when not; until a first pose
    /// is accepted it sends zero. Allocation-free. The default does nothing (drivers whose device converts
    /// force itself).
    fn input_checked(&mut self, accepted: bool) {
        let _ = accepted;
    }

    /// The next thing the device said outside its states (a fault, a refused command), if any. Drivers
    /// queue these while reading states; the supervisor drains them every tick. Allocation-free.
    fn take_event(&mut self) -> Option<DeviceEvent> {
        None
    }

    /// Clears the device's latched faults, on an operator's explicit request only (never automatically).
    fn clear_fault(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Keeps an idle link alive (voxhap protocol: a Heartbeat) while the host is connected but not sending a
    /// force every period; called off the servo thread, at most every 100 ms.
    fn keep_alive(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// How late this device's state is on its link ([`crate::latency`]), from its vendor's documents or, for
    /// voxhap's own protocol, measured on the link at open; `None` when the driver does not know (simulations,
    /// replays).
    fn link_latency(&self) -> Option<crate::latency::LinkLatency> {
        None
    }

    /// The round trips this driver timed on every tick since it was last opened ([`crate::latency`]): what
    /// the link's delay was during the run. `None` when the driver times none (only voxhap's protocol driver
    /// does) or before the first. Allocation-free.
    fn link_delay_seen(&self) -> Option<crate::latency::LinkDelaySeen> {
        None
    }

    /// A handle that brings the device to zero force from another thread, used by the stall monitor when
    /// the servo thread stops ticking (see `servo::monitor`). `None` when the driver has no such path; the
    /// device's own watchdog is then the only stop while the servo thread is stalled. Called off the servo
    /// thread, after open.
    fn emergency_stop(&self) -> Option<Box<dyn EmergencyStop>> {
        None
    }
}

/// A minimal stop channel to a device, usable from another thread while the servo thread owns the device.
///
/// It writes only a self-contained "zero force, then disable" sequence (for the voxhap protocol over serial:
/// a delimiter that ends any frame the stalled servo thread left half-written, a zero SetForce and a Disable,
/// on a second handle of the same port), so it is safe to call while the servo thread is stalled anywhere,
/// even inside a write.
pub trait EmergencyStop: Send {
    /// Commands zero force and, where the device has it, disables. Must return within a few milliseconds.
    fn stop(&mut self) -> Result<(), DeviceError>;
}
