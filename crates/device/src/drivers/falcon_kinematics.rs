//! Novint Falcon kinematics, as libnifalcon implements R. E. Stamper's delta-robot analysis
//! (src/kinematic/FalconKinematicStamper.cpp; sources and line numbers in [`super::falcon`]): leg angles from
//! encoder counts, inverse kinematics per leg, the inverted Jacobian, forward kinematics by Newton steps, and
//! torques to motor commands. Pure functions, no I/O; the driver ([`super::falcon`]) calls them every tick.

use glam::{DMat3, DVec3};
use std::f64::consts::PI;

/// The Falcon's kinematic constants as libnifalcon's kinematics use them (include/falcon/core/FalconGeometry.h
/// lines 20-36; names as there, lengths in metres). A device profile may replace any of them
/// (`[kinematics]` with `device = "falcon"`); [`FalconGeometry::LIBNIFALCON`] is the published set.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FalconGeometry {
    /// Thigh length `a` (m).
    pub a_m: f64,
    /// Shin length `b` (m).
    pub b_m: f64,
    /// Knee offset `c` (m).
    pub c_m: f64,
    /// Shin spacing `d` (m).
    pub d_m: f64,
    /// Shin spacing `e` (m; libnifalcon sets e = d).
    pub e_m: f64,
    /// Ankle offset `f` (m; negative in libnifalcon).
    pub f_m: f64,
    /// Leg base radius `r` (m).
    pub r_m: f64,
    /// Leg base offset `s` (m; negative in libnifalcon).
    pub s_m: f64,
    /// Encoder wheel slots per revolution (`wheel_slots_number`; four counts per slot).
    pub wheel_slots: f64,
    /// Motor shaft diameter (`shaft_diameter`, m).
    pub shaft_diameter_m: f64,
    /// Diameter of the arm's drum the shaft drives (`small_arm_diameter`, m).
    pub small_arm_diameter_m: f64,
    /// Leg angle at encoder count 0 (`theta_offset_angle`, degrees).
    pub theta_offset_deg: f64,
}

impl Default for FalconGeometry {
    fn default() -> Self {
        FalconGeometry::LIBNIFALCON
    }
}

impl FalconGeometry {
    /// libnifalcon's values (FalconGeometry.h:20-36).
    pub const LIBNIFALCON: FalconGeometry = FalconGeometry {
        a_m: 0.060,
        b_m: 0.1025,
        c_m: 0.01443,
        d_m: 0.01125,
        e_m: 0.01125,
        f_m: -0.025,
        r_m: 0.0400,
        s_m: -0.02309,
        wheel_slots: 320.0,
        shaft_diameter_m: 0.01425,
        small_arm_diameter_m: 0.110,
        theta_offset_deg: 35.0,
    };
}

const OFFSET_ANGLE: f64 = PI / 12.0;
/// Each leg's angle about z (FalconKinematicStamper.cpp, the `phy` array).
const PHY: [f64; 3] = [
    PI / 2.0 + OFFSET_ANGLE,
    -PI / 6.0 + OFFSET_ANGLE,
    -5.0 * PI / 6.0 + OFFSET_ANGLE,
];
/// libnifalcon's torque limit before the ×10 000 (FalconKinematicStamper.cpp:253).
const MAX_TORQUE: f64 = 30.0;
/// libnifalcon's torque-to-command factor (FalconKinematicStamper.cpp:276).
const TORQUE_TO_COMMAND: f64 = 10_000.0;

/// Leg angle (rad) of an encoder count (FalconKinematic.h:59-62), with libnifalcon's constants.
pub fn leg_angle_rad(count: i16) -> f64 {
    FalconGeometry::LIBNIFALCON.leg_angle_rad(count)
}

/// Inverse kinematics with libnifalcon's constants ([`FalconGeometry::inverse_kinematics`]).
pub fn inverse_kinematics(p: DVec3) -> LegAngles {
    FalconGeometry::LIBNIFALCON.inverse_kinematics(p)
}

/// [`FalconGeometry::jacobian_inverse`] with libnifalcon's constants.
pub fn jacobian_inverse(angles: &LegAngles) -> Option<DMat3> {
    FalconGeometry::LIBNIFALCON.jacobian_inverse(angles)
}

/// [`FalconGeometry::forward_kinematics`] with libnifalcon's constants.
pub fn forward_kinematics(theta1: [f64; 3], guess: DVec3) -> (DVec3, bool) {
    FalconGeometry::LIBNIFALCON.forward_kinematics(theta1, guess)
}

/// [`FalconGeometry::motor_commands`] with libnifalcon's constants.
pub fn motor_commands(p: DVec3, force_n: DVec3) -> [i16; 3] {
    FalconGeometry::LIBNIFALCON.motor_commands(p, force_n)
}

/// The three angles of each leg.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LegAngles {
    /// Thigh angles (the motor angles).
    pub theta1: [f64; 3],
    /// Knee angles.
    pub theta2: [f64; 3],
    /// Shin angles.
    pub theta3: [f64; 3],
}

impl FalconGeometry {
    /// Leg angle (rad) of an encoder count (FalconKinematic.h:59-62): count · (π·shaft / (slots·4)) /
    /// (π·small_arm / 360) + offset, in degrees.
    pub fn leg_angle_rad(&self, count: i16) -> f64 {
        let degrees = ((self.shaft_diameter_m * PI) / (self.wheel_slots * 4.0)) * f64::from(count)
            / ((PI * self.small_arm_diameter_m) / 360.0)
            + self.theta_offset_deg;
        degrees.to_radians()
    }

    /// Inverse kinematics: leg angles at handle position `p` (m) (FalconKinematicStamper.cpp:28-94).
    pub fn inverse_kinematics(&self, p: DVec3) -> LegAngles {
        let mut angles = LegAngles {
            theta1: [0.0; 3],
            theta2: [0.0; 3],
            theta3: [0.0; 3],
        };
        let (a, b, c, d, e, f, r, s_offset) = (
            self.a_m, self.b_m, self.c_m, self.d_m, self.e_m, self.f_m, self.r_m, self.s_m,
        );
        for (leg, phy) in PHY.iter().enumerate() {
            let (sin, cos) = phy.sin_cos();
            // Rot * p + offset, Rot = [[cos, sin, 0], [-sin, cos, 0], [0, 0, 1]], offset (-r, -s, 0).
            let pu = cos * p.x + sin * p.y - r;
            let pv = -sin * p.x + cos * p.y - s_offset;
            let pw = p.z;
            let t3 = ((pv + f) / b).acos();
            let sin3 = t3.sin();
            let common = pw * pw + pu * pu + 2.0 * c * pu + a * a + c * c
                - d * d
                - e * e
                - b * b * sin3 * sin3
                - 2.0 * b * e * sin3
                - 2.0 * b * d * sin3
                - 2.0 * d * e;
            let l0 = common - 2.0 * a * pu - 2.0 * a * c;
            let l1 = -4.0 * a * pw;
            let l2 = common + 2.0 * a * pu + 2.0 * a * c;
            let t = (-l1 - (l1 * l1 - 4.0 * l0 * l2).sqrt()) / (2.0 * l2);
            let t1 = t.atan() * 2.0;
            let t2 = ((-pu + a * t1.cos() - c) / (-d - e - b * sin3)).acos();
            angles.theta1[leg] = t1;
            angles.theta2[leg] = t2;
            angles.theta3[leg] = t3;
        }
        angles
    }

    /// The Jacobian mapping joint rates to handle velocity (the inverse of libnifalcon's rows of joint rate per
    /// handle velocity; FalconKinematicStamper.cpp:101-142). `None` where it is singular.
    pub fn jacobian_inverse(&self, angles: &LegAngles) -> Option<DMat3> {
        let mut rows = [DVec3::ZERO; 3];
        for (leg, row) in rows.iter_mut().enumerate() {
            let (t1, t2, t3) = (angles.theta1[leg], angles.theta2[leg], angles.theta3[leg]);
            let den = -self.a_m * t3.sin() * (t1.sin() * t2.cos() - t2.sin() * t1.cos());
            let (sp, cp) = PHY[leg].sin_cos();
            *row = DVec3::new(
                cp * t2.cos() * t3.sin() / den - sp * t3.cos() / den,
                sp * t2.cos() * t3.sin() / den + cp * t3.cos() / den,
                (t2.sin() * t2.sin()) / den,
            );
        }
        let j = DMat3::from_cols(rows[0], rows[1], rows[2]).transpose();
        let det = j.determinant();
        if !det.is_finite() || det.abs() < 1e-12 {
            return None;
        }
        let inverse = j.inverse();
        inverse.is_finite().then_some(inverse)
    }

    /// Forward kinematics: the handle position for motor angles `theta1`, by Newton steps from `guess`
    /// (FalconKinematicStamper.cpp:149-225). Returns the guess unchanged when it does not converge.
    pub fn forward_kinematics(&self, theta1: [f64; 3], guess: DVec3) -> (DVec3, bool) {
        let mut previous = guess;
        let mut previous_error = 10_000.0;
        let mut step = 0.5;
        for _ in 0..15 {
            let angles = self.inverse_kinematics(previous);
            let Some(j) = self.jacobian_inverse(&angles) else {
                return (guess, false);
            };
            let delta = DVec3::new(
                theta1[0] - angles.theta1[0],
                theta1[1] - angles.theta1[1],
                theta1[2] - angles.theta1[2],
            );
            let current = previous + j * delta * step;
            let error = delta.length();
            if !current.is_finite() {
                return (guess, false);
            }
            previous = current;
            if error < 0.01 {
                return (previous, true);
            }
            if error > previous_error {
                step /= 2.0;
            }
            previous_error = error;
        }
        (guess, false)
    }

    /// Motor commands for `force_n` at handle position `p` (FalconKinematicStamper.cpp:227-281), also scaled
    /// together to fit 16 bits (libnifalcon masks to 16 bits, which would wrap). Zero where the pose is singular.
    pub fn motor_commands(&self, p: DVec3, force_n: DVec3) -> [i16; 3] {
        let angles = self.inverse_kinematics(p);
        let Some(j) = self.jacobian_inverse(&angles) else {
            return [0; 3];
        };
        let torque = j.transpose() * force_n;
        if !torque.is_finite() {
            return [0; 3];
        }
        let largest = torque.abs().max_element();
        let mut torque = if largest > MAX_TORQUE {
            torque / (largest / MAX_TORQUE)
        } else {
            torque
        };
        torque *= TORQUE_TO_COMMAND;
        let largest = torque.abs().max_element();
        if largest > f64::from(i16::MAX) {
            torque *= f64::from(i16::MAX) / largest;
        }
        // C's int() truncates toward zero, as `as` does.
        [-torque.x as i16, -torque.y as i16, -torque.z as i16]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leg_angle_of_count_zero_is_the_35_degree_offset() {
        assert!((leg_angle_rad(0) - 35f64.to_radians()).abs() < 1e-12);
        // One count: π·0.01425/1280 m of shaft travel over π·0.110/360 m per degree.
        let per_count_deg = (0.01425 / 1280.0) / (0.110 / 360.0);
        assert!((leg_angle_rad(1).to_degrees() - 35.0 - per_count_deg).abs() < 1e-9);
    }

    #[test]
    fn forward_kinematics_inverts_inverse_kinematics_near_the_centre() {
        for p in [
            DVec3::new(0.0, 0.0, 0.11),
            DVec3::new(0.02, -0.01, 0.12),
            DVec3::new(-0.03, 0.02, 0.10),
        ] {
            let theta = inverse_kinematics(p).theta1;
            assert!(theta.iter().all(|t| t.is_finite()), "{p}: {theta:?}");
            let (found, converged) = forward_kinematics(theta, DVec3::new(0.0, 0.0, 0.11));
            assert!(converged, "{p}");
            // libnifalcon stops at a joint error below 0.01 rad: a few millimetres.
            assert!((found - p).length() < 5e-3, "{p} -> {found}");
        }
    }

    #[test]
    fn torques_are_the_jacobian_transpose_negated_and_fit_sixteen_bits() {
        let p = DVec3::new(0.0, 0.0, 0.11);
        assert_eq!(motor_commands(p, DVec3::ZERO), [0, 0, 0]);
        let up = motor_commands(p, DVec3::new(0.0, 0.0, 1.0));
        assert!(up.iter().all(|&m| m != 0), "{up:?}");
        // Symmetric legs at the centre: pushing along z loads the three motors alike.
        assert!((i32::from(up[0]) - i32::from(up[1])).abs() <= 2, "{up:?}");
        let opposite = motor_commands(p, DVec3::new(0.0, 0.0, -1.0));
        assert_eq!(opposite, up.map(|m| -m));
        let huge = motor_commands(p, DVec3::new(0.0, 0.0, 1e6));
        assert!(huge.iter().all(|m| m.unsigned_abs() <= i16::MAX as u16));
    }
}
