//! Degrees of freedom: which components of position, velocity and force a device uses (protocol/SPEC.md
//! section 6.8), and the one function that drops the others.
//!
//! Where it sits: the supervisor applies it at the device's edge, in the device frame, for every driver. A
//! device with 2 position or force DOF uses x and y, one with 1 uses x alone; "unused components are reported
//! as 0 and are ignored by the host". So:
//!
//! - **in**: the unused components of every reported position and velocity are set to 0 before the input checks
//!   (workspace box, speed, velocity estimate) see them. A device that reports garbage there (against the SPEC)
//!   changes nothing: its probe stays on its line or plane.
//! - **out**: the unused components of the rendered force are set to 0 *before* the safety pipeline, so the clamp
//!   to `max_force_n`, the engage rule and the slew limit act on the force the device actually receives, and
//!   once more after it, so they go out as exactly `+0.0`.
//!
//! What the hand feels: the device's line or plane, mapped into the scene by the workspace mapping
//! (`device::mapping`: `x_scene = s R x_device + t`; a 2-DOF device moves in the scene plane through `t` spanned
//! by `R e_x` and `R e_y`), is where the probe lives; the scene is rendered in 3-D at that probe, and the device
//! receives the components of the 3-D coupling force along its axes (the in-plane part, for a planar device).
//! Where the surface under the probe is perpendicular to the plane (a ball sliced through its centre, any shape
//! extruded across the plane) that is the whole force; elsewhere it is its projection (docs/devices/README.md,
//! "Planar and one-axis devices").
//!
//! Any other DOF count (0, 3 to 6) uses all three components: protocol v1 carries positions and forces only
//! (no orientation, no torque), so a 6-DOF device is a 3-DOF one here. Nothing here allocates.

use glam::DVec3;

/// The components of a device-frame vector a device uses: x; x and y; or x, y and z.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UsedAxes {
    count: u8,
}

impl UsedAxes {
    /// x, y and z.
    pub const ALL: UsedAxes = UsedAxes { count: 3 };

    /// The axes a device with `dof` degrees of freedom uses (SPEC 6.8): 1 → x, 2 → x and y, anything else → all
    /// three.
    pub fn from_dof(dof: u8) -> UsedAxes {
        UsedAxes {
            count: match dof {
                1 | 2 => dof,
                _ => 3,
            },
        }
    }

    /// `v` with the unused components set to exactly `+0.0` (whatever they held: a NaN there is dropped too).
    pub fn keep(self, v: DVec3) -> DVec3 {
        DVec3::new(
            v.x,
            if self.count >= 2 { v.y } else { 0.0 },
            if self.count >= 3 { v.z } else { 0.0 },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_and_two_dof_keep_x_and_xy_everything_else_keeps_all() {
        let v = DVec3::new(1.0, -2.0, 3.0);
        assert_eq!(UsedAxes::from_dof(1).keep(v), DVec3::new(1.0, 0.0, 0.0));
        assert_eq!(UsedAxes::from_dof(2).keep(v), DVec3::new(1.0, -2.0, 0.0));
        for dof in [0, 3, 4, 5, 6, 7, 255] {
            assert_eq!(UsedAxes::from_dof(dof).keep(v), v, "dof {dof}");
        }
    }

    #[test]
    fn dropped_components_are_plus_zero_even_from_nan_or_negative_zero() {
        let v = DVec3::new(-0.0, f64::NAN, -0.0);
        let kept = UsedAxes::from_dof(1).keep(v);
        assert_eq!(kept.y.to_bits(), 0);
        assert_eq!(kept.z.to_bits(), 0);
        let kept = UsedAxes::from_dof(2).keep(DVec3::new(1.0, 1.0, f64::INFINITY));
        assert_eq!(kept.z.to_bits(), 0);
    }
}
