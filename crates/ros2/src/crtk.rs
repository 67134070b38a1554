//! One session snapshot as the CRTK messages, and the CRTK operating state of voxhap's output state.
//!
//! CRTK names (crtk-robotics.readthedocs.io, "Robot API"): `measured_cp` is the measured Cartesian
//! position, `measured_cv` the measured Cartesian velocity, `measured_cf` the measured Cartesian force,
//! `setpoint_cf` the force setpoint last sent with `servo_cf`. voxhap's device has no force sensor: its
//! `measured_cf` is the force the rendering computed for the probe this tick (coupling spring plus damping,
//! before the safety pipeline) and `setpoint_cf` the force actually sent to the device after it.
//! Everything is in the scene frame (`world`, metres, m/s, newtons); no orientation or torque is rendered,
//! so those are identity and zero.

use crate::messages::{
    Header, OperatingState, Pose, PoseStamped, Quaternion, Time, Twist, TwistStamped, Vector3,
    Wrench, WrenchStamped,
};
use glam::DVec3;
use voxhap_api::Snapshot;
use voxhap_core::status::OutputState;

/// The frame every message is stamped with (the scene frame, as in voxhap's recordings).
pub const FRAME_ID: &str = "world";

/// CRTK's standard operating states.
pub use voxhap_api::truth::crtk_state as state;

/// The CRTK state, `is_homed` and `is_busy` for `output` (`None`: the servo loop has not ticked yet), with
/// no force-off cause: [`voxhap_api::crtk_operating_state`], which the Foxglove view uses too.
///
/// FAULT is a fault that needs a person (`faulted`, `enable_refused`: the operator's `clear_fault`);
/// ENABLED is force reaching the hand or about to (`engaged`; `waiting_to_engage` and `ramping_in` are
/// ENABLED and busy); DISABLED is no force, busy while voxhap is bringing the device up on its own
/// (`starting`, `recovering`, `stale_state`). `is_homed` is true while a device is connected: voxhap's
/// devices report calibrated positions from connection on.
pub fn operating_state(output: Option<OutputState>) -> (&'static str, bool, bool) {
    voxhap_api::crtk_operating_state(output.map(|o| (o, voxhap_api::ForceOffCause::None)))
}

/// The five CRTK messages of one tick. A vector that is not finite leaves its message out (`None`): no NaN
/// or infinity is ever published.
#[derive(Debug, Clone, PartialEq)]
pub struct CrtkMessages {
    pub measured_cp: Option<PoseStamped>,
    pub measured_cv: Option<TwistStamped>,
    pub measured_cf: Option<WrenchStamped>,
    pub setpoint_cf: Option<WrenchStamped>,
    pub operating_state: OperatingState,
}

fn header(stamp: Time) -> Header {
    Header {
        stamp,
        frame_id: FRAME_ID.to_owned(),
    }
}

fn finite(v: DVec3) -> Option<Vector3> {
    v.is_finite().then(|| Vector3::from(v))
}

fn wrench(stamp: Time, force_n: DVec3) -> Option<WrenchStamped> {
    finite(force_n).map(|force| WrenchStamped {
        header: header(stamp),
        wrench: Wrench {
            force,
            torque: Vector3::default(),
        },
    })
}

/// The operating state message for `snapshot` (`None`: not ticked yet).
pub fn operating_state_message(snapshot: Option<&Snapshot>, stamp: Time) -> OperatingState {
    // FAULT whenever the safety pipeline is faulted: the output state or the tick's force-off cause.
    let (state, is_homed, is_busy) = voxhap_api::crtk_operating_state(
        snapshot.map(|s| (s.output_state, s.truth.force_off_cause)),
    );
    OperatingState {
        header: header(stamp),
        state: state.to_owned(),
        is_homed,
        is_busy,
    }
}

/// The CRTK messages of `snapshot`, stamped `stamp`.
pub fn messages(snapshot: &Snapshot, stamp: Time) -> CrtkMessages {
    CrtkMessages {
        measured_cp: finite(snapshot.probe_m).map(|position| PoseStamped {
            header: header(stamp),
            pose: Pose {
                position,
                orientation: Quaternion::IDENTITY,
            },
        }),
        measured_cv: finite(snapshot.probe_velocity_m_per_s).map(|linear| TwistStamped {
            header: header(stamp),
            twist: Twist {
                linear,
                angular: Vector3::default(),
            },
        }),
        measured_cf: wrench(stamp, snapshot.rendered_force_n),
        setpoint_cf: wrench(stamp, snapshot.sent_force_n),
        operating_state: operating_state_message(Some(snapshot), stamp),
    }
}

#[cfg(test)]
#[path = "crtk_tests.rs"]
mod tests;
