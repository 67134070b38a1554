//! The passivity observer and controller of the local loop's coupling (protocol/SPEC.md section 10.5, step
//! 4b): the host's method (`voxhap-servo`'s `passivity::controller`), run by the device on its own cycle.
//!
//! **Method.** Hannaford and Ryu's time-domain passivity approach (IEEE Trans. Robotics and Automation
//! 18(1), 2002) with reference energy following (Ryu, Preusche, Hannaford, Hirzinger, IEEE Trans. Control
//! Systems Technology 13(5), 2005), as the host runs it: an observer sums the energy the coupling gave the
//! hand beyond what a continuous spring would hold, and a variable damper `F = -alpha v` dissipates the excess.
//!
//! **Books** (cycle `n`, sensed handle `p_n`, applied force `F_n` held until the next cycle: a zero-order
//! hold, acting in the cycle it is applied, so the host's latency `d` is 0 here):
//!
//! - the step from `p_{n-1}` to `p_n` was moved under `F_{n-1}`; its coupling work is
//!   `(F_{n-1} - sigma_{n-1} d_{n-1}) . (p_n - p_{n-1})`, where `d` is the model's directed slot and `sigma` the
//!   share of the asked force the clamp, ramp and slew limit let out (each scales the whole vector, so the
//!   directed part of the applied force is exactly `sigma d`). The directed force is left out: it is meant to
//!   do work (the host's energy ledger books it as active work, apart from the coupling).
//! - the reference is the energy the applied spring can give back,
//!   `E_ref = sigma_{n-1}^2 k/2 |x_n - d/k - p_n|^2`: the solve minimises `k/2 |x - p - d/k|^2 + ...`
//!   (SPEC 10.5 step 2), so `k (x - d/k - p)` is the coupling spring without the directed force, and
//!   `k/2 |x - d/k - p|^2` the energy it stores. The share is last cycle's, the latest known before the
//!   pipeline runs, as on the host.
//! - generated `g_n` = work + `E_ref,n - E_ref,n-1`; excess `e_n = max(0, e_{n-1} + g_n)`.
//!
//! **Control** (mode `control`): when `e_n` exceeds [`PASSIVITY_THRESHOLD_J`] and the handle moves,
//! `F_pc = -alpha v_n` with `alpha = min(max_damping, e_n / (|v_n|^2 T))`: the excess dissipated over the next
//! cycle, never more damping than the model's. Added to the coupling force before the clamp, ramp and slew
//! limit, which stay the last word on the force; whatever they cut is booked, since the observer books the
//! force applied. Not added while last cycle's share is zero (before the engage ramp starts), so that it cannot
//! hold the force above the engage threshold.
//!
//! Fixed size, no allocation, a few multiplications a cycle.

use glam::DVec3;
use voxhap_protocol::local::PASSIVITY_THRESHOLD_J;
use voxhap_protocol::{LocalPassivity, LocalPassivityMode};

/// The observer's and controller's totals since the loop started, joules.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PassivityTotals {
    /// Energy the coupling generated beyond its reference, summed without clamping (J).
    pub generated_j: f64,
    /// The observer's excess now (J).
    pub excess_j: f64,
    /// Work the controller's force took from the handle (J): positive when it dissipated.
    pub dissipated_j: f64,
    /// Cycles in which the controller added a force.
    pub active_cycles: u64,
}

/// What the previous cycle applied, as the observer books it.
#[derive(Debug, Clone, Copy)]
struct Applied {
    probe_m: DVec3,
    /// The applied force less its directed part (the coupling's), N.
    coupling_n: DVec3,
    /// The controller's part of the applied force, N.
    control_n: DVec3,
    reference_j: f64,
}

/// The device loop's observer and controller.
#[derive(Debug, Clone, Copy, Default)]
pub struct DevicePassivity {
    last: Option<Applied>,
    /// Last cycle's share, kept across a gap (the ramp's state is).
    share: f64,
    probe_m: DVec3,
    reference_j: f64,
    control_n: DVec3,
    totals: PassivityTotals,
}

impl DevicePassivity {
    /// The totals so far.
    pub fn totals(&self) -> PassivityTotals {
        self.totals
    }

    /// The next cycle starts a new step (the loop left local mode: the motion since was not under its force).
    pub fn gap(&mut self) {
        self.last = None;
    }

    /// The drive left Enabled (the engage ramp resets with it): the next Enable starts from an empty excess
    /// and a zero share, as at power-up, so nothing the coupling generated before the Disable is dissipated
    /// after the Enable, and the controller waits for the new engage ramp (SPEC 10.5 step 4b). The totals'
    /// sums are kept.
    pub fn reset(&mut self) {
        self.last = None;
        self.share = 0.0;
        self.totals.excess_j = 0.0;
    }

    /// Books the step to `probe_m` and this cycle's reference (`stretch_m` is `x - d/k - p`), then returns the
    /// controller's force (zero unless the mode is `control`).
    pub fn observe_and_control(
        &mut self,
        request: LocalPassivity,
        stiffness_n_per_m: f64,
        probe_m: DVec3,
        velocity_m_per_s: DVec3,
        stretch_m: DVec3,
        dt_s: f64,
    ) -> DVec3 {
        self.control_n = DVec3::ZERO;
        if request.mode == LocalPassivityMode::Off {
            self.last = None;
            return DVec3::ZERO;
        }
        let reference_j =
            self.share * self.share * 0.5 * stiffness_n_per_m * stretch_m.length_squared();
        if let Some(last) = self.last {
            let dx = probe_m - last.probe_m;
            let generated = last.coupling_n.dot(dx) + reference_j - last.reference_j;
            let t = &mut self.totals;
            if generated.is_finite() {
                t.generated_j += generated;
                t.excess_j = (t.excess_j + generated).max(0.0);
            }
            let control_work = last.control_n.dot(dx);
            if control_work.is_finite() {
                t.dissipated_j -= control_work;
            }
        }
        self.probe_m = probe_m;
        self.reference_j = reference_j;
        let need_j = self.totals.excess_j;
        let speed2 = velocity_m_per_s.length_squared();
        let engaged = self.share > 0.0;
        if request.mode != LocalPassivityMode::Control
            || need_j <= PASSIVITY_THRESHOLD_J
            || !(speed2 > 0.0 && dt_s > 0.0)
            || !engaged
        {
            return DVec3::ZERO;
        }
        let alpha = (need_j / (speed2 * dt_s)).min(request.max_damping_n_s_per_m());
        let force = -alpha * velocity_m_per_s;
        if !force.is_finite() {
            return DVec3::ZERO;
        }
        self.control_n = force;
        self.totals.active_cycles += 1;
        force
    }

    /// Books what the cycle applied: `asked_n` the force handed to the clamp (coupling and controller),
    /// `applied_n` the force applied, `directed_n` the model's directed force. Ends the cycle.
    pub fn applied(
        &mut self,
        request: LocalPassivity,
        asked_n: DVec3,
        applied_n: DVec3,
        directed_n: DVec3,
    ) {
        let asked = asked_n.length();
        let share = if asked > 0.0 {
            (applied_n.length() / asked).min(1.0)
        } else {
            1.0
        };
        self.share = if share.is_finite() { share } else { 0.0 };
        if request.mode == LocalPassivityMode::Off {
            return;
        }
        let control_share = if asked > 0.0 { self.share } else { 0.0 };
        self.last = Some(Applied {
            probe_m: self.probe_m,
            coupling_n: applied_n - self.share * directed_n,
            control_n: self.control_n * control_share,
            reference_j: self.reference_j,
        });
    }
}
