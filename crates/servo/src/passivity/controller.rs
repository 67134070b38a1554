//! The passivity observer and controller of the coupling (time-domain passivity approach).
//!
//! **Method.** Hannaford and Ryu's time-domain passivity approach (B. Hannaford, J.-H. Ryu, "Time-domain
//! passivity control of haptic interfaces", IEEE Trans. Robotics and Automation 18(1):1-10, 2002): a
//! *passivity observer* sums, from the measured motion and the force sent, the energy the virtual environment
//! gave the hand, and a *passivity controller*, a variable damper `F = -alpha v` on the measured velocity,
//! dissipates the excess it observes. Its known fault is the force jump: the observer of the original method
//! compares the energy output with zero, so a stiff contact stores energy in the virtual spring during the
//! press, the observer sees a large reserve, and the controller acts only when the reserve has run out, late
//! in the release and in one large dose. We use the refinement of J.-H. Ryu, C. Preusche, B. Hannaford and
//! G. Hirzinger, "Time domain passivity control with reference energy following", IEEE Trans. Control Systems
//! Technology 13(5):737-742, 2005: the observed energy is made to follow a *reference energy*, the energy a
//! passive (continuous) version of the virtual environment would hold, so the controller acts every tick in
//! small amounts, during the press as well as the release. For the coupling spring the reference is exact and
//! cheap: the spring's stored energy `k/2 |proxy - probe|^2` (a continuous spring gives back exactly what it
//! stored, and the proxy's moves only ever lower it). Page numbers and the abstracts' claims were not
//! re-checked against the full papers here.
//!
//! Why not energy bounding (Kim and Ryu 2004) or energy tanks: energy bounding limits each tick's generated
//! energy to what the device's own damping `b` can take, so it needs `b` for each device, and no damping figure
//! is published for the devices voxhap drives (docs/sim-arm.md); the observer needs no device model, only the
//! device's latency in ticks to pair each motion with the force that acted over it.
//!
//! **Books** (per tick `n`, reported probe `x_n`, force sent `F_n` after the safety pipeline, held until the
//! next, acting `d` ticks after it was sent):
//!
//! - the step from `x_{n-1}` to `x_n` was moved under `F_{n-1-d}`: the work on the probe is
//!   `F_{n-1-d} . (x_n - x_{n-1})` (exact under a zero-order hold with a latency of whole ticks);
//! - generated this step: that work plus the rise of the reference `E_ref = k/2 |anchor - x|^2` (the anchor is
//!   the point the spring pulls towards: the proxy, or [`super::transition`]'s virtual proxy);
//! - the *excess* `e_n = max(0, e_{n-1} + generated)`: energy out beyond the reference. Clamping at zero is the
//!   reference-energy following: energy the coupling absorbed (friction, a softened spring) is not banked as a
//!   reserve that would later let the coupling generate unchecked.
//!
//! **Control** (mode `control`): with the damping of the forces already sent but not yet observed (the
//! `d` latest ticks) counted as pending, the controller adds `F = -alpha v_n` with
//! `alpha = min(max_damping, (e_n - pending) / (|v_n|^2 T))` when `e_n - pending` exceeds the threshold:
//! it dissipates the observed excess over the next step, never more damping than `max_damping` (a damper acting
//! a latency late is itself active above roughly `m / (T/2 + tau)`).
//!
//! **Latency.** Over a delayed channel the time-domain passivity approach measures the energy at each end
//! of the channel and books what one port sent against what reaches the other port after the delay (J.-H.
//! Ryu, J. Artigas, C. Preusche, "A passive bilateral control scheme for a teleoperator with time-varying
//! communication delay", Mechatronics 20(7):812-823, 2010; J. Artigas, J.-H. Ryu, C. Preusche, G. Hirzinger,
//! "Network representation and passivity of delayed teleoperation systems", IEEE/RSJ IROS 2011, whose
//! abstract states the approach is used to render the communication channel passive; the full texts were not
//! re-checked here). Here the channel is the device link: the force sent at tick `j` meets the arm only `d`
//! ticks later, so its work is booked against the step it meets, `F_{n-1-d} . (x_n - x_{n-1})`, and not
//! against the step that follows it on the host. The same pairing holds when the state is what comes late
//! (the position reported at tick `n` is the arm's at `n - d`): a delay in sensing and one in actuation
//! shift the reported motion and the sent force against each other by the same `d`. Over a cycle of a slow
//! oscillation `A sin(w t)` on a sampled spring `k`, the sum `-k sum x_{n-1-d} (x_n - x_{n-1})` is
//! `k pi A^2 sin(w (d + 1/2) T)` (the held force lags the step's middle by `(d + 1/2) T`; the reference
//! energy returns to its value). Paired without the delay the observer books `k pi A^2 sin(w T / 2)`, about
//! `1 / (2d + 1)` of what the delayed loop generates, and the controller lets it oscillate.
//!
//! `d` is the device's latency in whole ticks ([`super::latency::ObserverLatency`]: `[passivity] latency_s`,
//! else the simulated arm's `[arm] latency_s`, else the driver's worst-case link latency, which voxhap's
//! protocol driver measures on the link at open, else 0). A fraction of a tick is rounded up: for oscillations slower than a quarter
//! period per delay (`w (d + 1/2) T < pi/2`) the booked generation `sin(w (d + 1/2) T)` rises with `d`, so
//! an observer that assumes the force acts later than it does books more than was generated, and dissipates
//! more, never less.
//!
//! Real-time: fixed arrays, no allocation, a few multiplications per tick.

use super::settings::{PassivityMode, PassivitySettings};
use glam::DVec3;

pub use super::settings::MAX_LATENCY_TICKS;
const HISTORY: usize = MAX_LATENCY_TICKS + 1;

/// The observer's and controller's totals (J).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PassivityTotals {
    /// Energy the coupling generated beyond its reference, summed without clamping (J).
    pub generated_j: f64,
    /// The observer's excess now (J).
    pub excess_j: f64,
    /// Work the controller's force took from the probe (J): positive when it dissipated.
    pub dissipated_j: f64,
    /// Ticks in which the controller added a force.
    pub active_ticks: u64,
    /// The largest controller force magnitude (N).
    pub max_force_n: f64,
}

/// The passivity observer and controller of one session (module docs).
#[derive(Debug, Clone)]
pub struct PassivityController {
    mode: PassivityMode,
    max_damping_n_s_per_m: f64,
    threshold_j: f64,
    latency_ticks: usize,
    sent_n: [DVec3; HISTORY],
    control_n: [DVec3; HISTORY],
    expected_j: [f64; HISTORY],
    pending_j: f64,
    tick: u64,
    last_probe_m: Option<DVec3>,
    last_reference_j: f64,
    control_now_n: DVec3,
    totals: PassivityTotals,
}

impl PassivityController {
    /// A controller in `mode` with `settings`' parameters, for a device whose force acts `latency_ticks`
    /// after it was sent (at most [`MAX_LATENCY_TICKS`]).
    pub fn new(mode: PassivityMode, settings: &PassivitySettings, latency_ticks: usize) -> Self {
        PassivityController {
            mode,
            max_damping_n_s_per_m: settings.max_damping_n_s_per_m,
            threshold_j: settings.threshold_j,
            latency_ticks: latency_ticks.min(MAX_LATENCY_TICKS),
            sent_n: [DVec3::ZERO; HISTORY],
            control_n: [DVec3::ZERO; HISTORY],
            expected_j: [0.0; HISTORY],
            pending_j: 0.0,
            tick: 0,
            last_probe_m: None,
            last_reference_j: 0.0,
            control_now_n: DVec3::ZERO,
            totals: PassivityTotals::default(),
        }
    }

    /// The mode it runs in.
    pub fn mode(&self) -> PassivityMode {
        self.mode
    }

    /// The latency it pairs with now (ticks).
    pub fn latency_ticks_now(&self) -> usize {
        self.latency_ticks
    }

    /// Pairs with `latency_ticks` from the next tick on (at most [`MAX_LATENCY_TICKS`]; the forces of the last
    /// [`MAX_LATENCY_TICKS`] ticks are kept, so any pairing finds its force): the link's delay changed
    /// ([`super::link_delay`]). Widened from `d` to `d'`, the steps of the next `d' - d` ticks are paired with
    /// forces already paired once (the delay grew: those forces acted longer); narrowed, the forces of
    /// `d - d'` ticks are paired with no step (a new connection: they acted on the old one).
    pub fn set_latency_ticks(&mut self, latency_ticks: usize) {
        self.latency_ticks = latency_ticks.min(MAX_LATENCY_TICKS);
    }

    /// Books this tick's reported probe and the coupling's reference energy now (the spring's stored energy,
    /// J), then returns the controller's force for this tick (zero unless the mode is `control`).
    pub fn observe_and_control(
        &mut self,
        probe_m: DVec3,
        probe_velocity_m_per_s: DVec3,
        reference_j: f64,
        dt_s: f64,
    ) -> DVec3 {
        self.control_now_n = DVec3::ZERO;
        if self.mode == PassivityMode::Off {
            return DVec3::ZERO;
        }
        let n = self.tick as usize;
        if let Some(previous_m) = self.last_probe_m {
            let dx = probe_m - previous_m;
            let acted = n.checked_sub(1 + self.latency_ticks).map(|j| j % HISTORY);
            let (work_j, control_work_j) = acted.map_or((0.0, 0.0), |j| {
                (self.sent_n[j].dot(dx), self.control_n[j].dot(dx))
            });
            if let Some(j) = acted {
                // Taken once: a widened pairing meets this force again (set_latency_ticks).
                self.pending_j =
                    (self.pending_j - std::mem::take(&mut self.expected_j[j])).max(0.0);
            }
            let generated = work_j + reference_j - self.last_reference_j;
            let t = &mut self.totals;
            t.generated_j += generated;
            t.excess_j = (t.excess_j + generated).max(0.0);
            t.dissipated_j -= control_work_j;
        }
        self.last_probe_m = Some(probe_m);
        self.last_reference_j = reference_j;
        let slot = n % HISTORY;
        self.expected_j[slot] = 0.0;
        if self.mode != PassivityMode::Control {
            return DVec3::ZERO;
        }
        let need_j = self.totals.excess_j - self.pending_j;
        let speed2 = probe_velocity_m_per_s.length_squared();
        let moving = speed2 > 0.0 && dt_s > 0.0;
        if need_j <= self.threshold_j || !moving {
            return DVec3::ZERO;
        }
        let alpha = (need_j / (speed2 * dt_s)).min(self.max_damping_n_s_per_m);
        let force = -alpha * probe_velocity_m_per_s;
        if !force.is_finite() {
            return DVec3::ZERO;
        }
        self.expected_j[slot] = alpha * speed2 * dt_s;
        self.pending_j += self.expected_j[slot];
        self.control_now_n = force;
        self.totals.active_ticks += 1;
        self.totals.max_force_n = self.totals.max_force_n.max(force.length());
        force
    }

    /// [`PassivityController::sent_with_active`] with no intended work (the tests' coupling alone).
    #[cfg(test)]
    pub fn sent(&mut self, rendered_n: DVec3, sent_n: DVec3) {
        self.sent_with_active(rendered_n, sent_n, DVec3::ZERO);
    }

    /// Books the force the device was sent this tick (after the safety pipeline), given the force that was
    /// asked for (`rendered_n`, the controller's force included): the controller's part is scaled as the
    /// pipeline scaled the whole. Ends the tick. `active_n` of the rendered force is intended work (the
    /// directed-force modes and an external force; zero when there is none): the observer books only the
    /// coupling's part of what was sent, `sent - s active` with `s` the share of the rendered force the
    /// safety pipeline let through (its stages scale the whole vector), so the controller never damps work
    /// the scene asks for; the energy ledger splits the same work out as active (crate::energy).
    pub fn sent_with_active(&mut self, rendered_n: DVec3, sent_n: DVec3, active_n: DVec3) {
        if self.mode == PassivityMode::Off {
            return;
        }
        let slot = (self.tick as usize) % HISTORY;
        let asked = rendered_n.length();
        let scale = if asked > 0.0 {
            (sent_n.length() / asked).min(1.0)
        } else {
            0.0
        };
        let coupling_n = sent_n - scale * active_n;
        self.sent_n[slot] = if coupling_n.is_finite() {
            coupling_n
        } else {
            DVec3::ZERO
        };
        self.control_n[slot] = self.control_now_n * scale;
        self.tick += 1;
    }

    /// The totals so far.
    pub fn totals(&self) -> PassivityTotals {
        self.totals
    }
}

#[cfg(test)]
#[path = "controller_tests.rs"]
mod tests;
