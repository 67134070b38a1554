//! libnifalcon's kinematics, reimplemented for the Falcon tests from its source (libnifalcon/libnifalcon), not
//! from voxhap's driver: geometry include/falcon/core/FalconGeometry.h:20-36, inverse kinematics and Jacobian
//! src/kinematic/FalconKinematicStamper.cpp, encoder angle include/falcon/core/FalconKinematic.h:59-62.

use glam::{DMat3, DVec3};
use std::f64::consts::PI;

const A: f64 = 0.060;
const B: f64 = 0.1025;
const C: f64 = 0.01443;
const D: f64 = 0.01125;
const E: f64 = D;
const F: f64 = -0.025;
const R: f64 = 0.0400;
const S: f64 = -0.02309;
const OFFSET_ANGLE: f64 = PI / 12.0;
const PHY: [f64; 3] = [
    PI / 2.0 + OFFSET_ANGLE,
    -PI / 6.0 + OFFSET_ANGLE,
    -5.0 * PI / 6.0 + OFFSET_ANGLE,
];

/// (θ1, θ2, θ3) of each leg at handle position `p`: FalconKinematicStamper.cpp:28-94 (`IK`), written term by
/// term in the source's order: `P = R(phy) p + offset` with `offset = (-r, -s, 0)` (lines 32-51), `theta3`
/// (line 56), `l0`, `l1`, `l2` (lines 64-66), the `-` root `T1b` (line 81), `theta1 = 2 atan(T1b)` (line 85),
/// `theta2` (line 91).
pub fn ik(p: DVec3) -> [[f64; 3]; 3] {
    let mut legs = [[0.0; 3]; 3];
    for (leg, phy) in PHY.iter().enumerate() {
        let rot = DMat3::from_cols(
            DVec3::new(phy.cos(), -phy.sin(), 0.0),
            DVec3::new(phy.sin(), phy.cos(), 0.0),
            DVec3::Z,
        );
        let pp = rot * p + DVec3::new(-R, -S, 0.0);
        let theta3 = ((pp.y + F) / B).acos();
        let s3 = theta3.sin();
        let l0 = pp.z * pp.z + pp.x * pp.x + 2.0 * C * pp.x - 2.0 * A * pp.x + A * A + C * C
            - D * D
            - E * E
            - B * B * s3 * s3
            - 2.0 * B * E * s3
            - 2.0 * B * D * s3
            - 2.0 * D * E
            - 2.0 * A * C;
        let l1 = -4.0 * A * pp.z;
        let l2 = pp.z * pp.z + pp.x * pp.x + 2.0 * C * pp.x + 2.0 * A * pp.x + A * A + C * C
            - D * D
            - E * E
            - B * B * s3 * s3
            - 2.0 * B * E * s3
            - 2.0 * B * D * s3
            - 2.0 * D * E
            + 2.0 * A * C;
        let t1b = (-l1 - (l1 * l1 - 4.0 * l0 * l2).sqrt()) / (2.0 * l2);
        let theta1 = t1b.atan() * 2.0;
        let theta2 = ((-pp.x + A * theta1.cos() - C) / (-D - E - B * s3)).acos();
        legs[leg] = [theta1, theta2, theta3];
    }
    legs
}

/// The rows of joint rate per handle velocity before libnifalcon inverts them
/// (FalconKinematicStamper.cpp:101-133, `jacobian`; it returns their inverse, line 135).
pub fn joint_rate_rows(legs: [[f64; 3]; 3]) -> DMat3 {
    let mut rows = [DVec3::ZERO; 3];
    for (leg, [t1, t2, t3]) in legs.into_iter().enumerate() {
        let den = -A * t3.sin() * (t1.sin() * t2.cos() - t2.sin() * t1.cos());
        let (sp, cp) = PHY[leg].sin_cos();
        rows[leg] = DVec3::new(
            cp * t2.cos() * t3.sin() / den - sp * t3.cos() / den,
            sp * t2.cos() * t3.sin() / den + cp * t3.cos() / den,
            t2.sin() * t2.sin() / den,
        );
    }
    DMat3::from_cols(rows[0], rows[1], rows[2]).transpose()
}

/// Encoder count of leg angle θ1 (inverse of FalconKinematic.h:59-62, `getTheta`).
pub fn count(theta1: f64) -> i16 {
    let per_count_deg = (0.01425 * PI / (320.0 * 4.0)) / (PI * 0.110 / 360.0);
    ((theta1.to_degrees() - 35.0) / per_count_deg).round() as i16
}

/// The force the Falcon exerts at true handle position `p` for motor commands `motor`: libnifalcon sends
/// -(J⁻¹)ᵀ f · 10 000 with J the joint-rate rows (FalconKinematicStamper.cpp:244-279), so the torque is
/// τ = -motor / 10 000 and the force f = Jᵀ τ.
pub fn nifalcon_exerted_force(p: DVec3, motor: [i16; 3]) -> DVec3 {
    let tau = DVec3::new(
        -f64::from(motor[0]),
        -f64::from(motor[1]),
        -f64::from(motor[2]),
    ) / 10_000.0;
    let rows: DMat3 = joint_rate_rows(ik(p));
    rows.transpose() * tau
}
