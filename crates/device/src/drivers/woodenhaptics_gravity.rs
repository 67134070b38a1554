//! Polhem's gravity compensation as hfabapi computes it (forsslund/hfabapi hfab_polhem.h; hfab_kinematics.cpp:9
//! compiles it in with `USE_DIRECT_COMPUTE_GRAVITY_COMPENSATION`): the centres of mass of the four moving bodies
//! in the arm's vertical plane from joint angles θ2, θ3 (`polhemGravcompkinematics`, hfab_polhem.h:91-127), their
//! heights differentiated by central differences with h = 0.001 (:283-301), and the joint torque that holds
//! their weight, τ_g = Σ Jᵢᵀ (0, 0, g mᵢ) = (0, Σ g mᵢ ∂zᵢ/∂θ2, Σ g mᵢ ∂zᵢ/∂θ3) (:303-325), added to Jᵀ f
//! (:328-329); a body whose term is NaN adds nothing (:315-322). Pure functions, no allocation.

use glam::DVec3;
use std::f64::consts::PI;

/// Gravity (m/s²), hfab_polhem.h:13.
pub const G_M_PER_S2: f64 = 9.81;
/// Masses of bodies 1, 2, 3 and 4-5 (kg), with covers (hfab_polhem.h:53-57).
pub const MASS_KG: [f64; 4] = [157.64e-3, 77.33e-3, 97.67e-3, 112.65e-3];
/// Centres of mass of bodies 1, 2, 3 and 4-5 in their own frames (m), hfab_polhem.h:58-65.
pub const CENTRE_OF_MASS_M: [[f64; 2]; 4] = [
    [30.123e-3, 0.484e-3],
    [-4.086e-3, 1.911e-3],
    [87.765e-3, 1.978e-3],
    [61.701e-3, 0.576e-3],
];
/// Link lengths (m), hfab_polhem.h:84-89.
const L0: f64 = 34e-3;
const L1: f64 = 165e-3;
const L2: f64 = 25e-3;
const L3: f64 = 190e-3;
const L4: f64 = 34e-3;
/// The step of the central differences (rad), hfab_polhem.h:283.
const H: f64 = 0.001;

type V2 = [f64; 2];

/// `R(t) · v` with `R` hfab_math.h's `rot_z` (rows (cos, -sin), (sin, cos)).
fn rot(t: f64, v: V2) -> V2 {
    let (s, c) = t.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1]]
}

fn add(a: V2, b: V2) -> V2 {
    [a[0] + b[0], a[1] + b[1]]
}

/// The centres of mass of bodies 1, 2, 3, 4-5 in the vertical plane (x out, y up) at joint angles θ2, θ3
/// (`polhemGravcompkinematics`, hfab_polhem.h:91-127).
pub fn centres_of_mass(t2: f64, t3: f64) -> [V2; 4] {
    let sq = |v: f64| v * v;
    let (c2, s2, c3, s3) = (t2.cos(), t2.sin(), t3.cos(), t3.sin());
    let q1 = 2.0
        * (sq(L0 + L1 * c2) + sq(L1) * sq(s2)).sqrt()
        * (sq(L0 + L1 * c2 - L2 * c3) + sq(L1 * s2 - L2 * s3)).sqrt();
    let q2 = (-sq(L2)
        + sq(L0 + L1 * c2)
        + sq(L0 + L1 * c2 - L2 * c3)
        + sq(L1) * sq(s2)
        + sq(L1 * s2 - L2 * s3))
        / q1;
    let q3 = 2.0 * L4 * (sq(L0 + L1 * c2 - L2 * c3) + sq(L1 * s2 - L2 * s3)).sqrt();
    let q4 = (-sq(L3) + sq(L4) + sq(L0 + L1 * c2 - L2 * c3) + sq(L1 * s2 - L2 * s3)) / q3;
    let q5 = 2.0 * L1 * (sq(L0 + L1 * c2) + sq(L1) * sq(s2)).sqrt();
    let q6 = (-sq(L0) + sq(L1) + sq(L0 + L1 * c2) + sq(L1) * sq(s2)) / q5;
    let lambda = t2 - q6.acos() - q4.acos() - q2.acos();
    let ob = [L1 * c2 + L0 / 2.0, L1 * s2];
    let oc = [ob[0] - L4 * lambda.cos(), ob[1] - L4 * lambda.sin()];
    let oa = [-L0 / 2.0, 0.0];
    let d9 = (sq(oc[0] - oa[0]) + sq(oc[1] - oa[1])).sqrt();
    let a3 = ((L2 * L2 + L3 * L3 - d9 * d9) / (2.0 * L2 * L3)).acos() - PI;
    let [cdg1, cdg2, cdg3, cdg45] = CENTRE_OF_MASS_M;
    [
        add(rot(t2, cdg1), [L0 / 2.0, 0.0]),
        add(rot(t3, cdg2), [-L0 / 2.0, 0.0]),
        add(rot(t3, add(rot(a3, cdg3), [L2, 0.0])), [-L0 / 2.0, 0.0]),
        add(
            rot(t2, add(rot(lambda - t2, cdg45), [L1, 0.0])),
            [L0 / 2.0, 0.0],
        ),
    ]
}

/// The joint torques (N m; θ1, θ2, θ3) that hold Polhem's bodies up at joint angles `theta`, as hfabapi adds them
/// to Jᵀ f (module docs).
pub fn polhem_gravity_torque(theta: [f64; 3]) -> DVec3 {
    let [_, t2, t3] = theta;
    let (p2, m2) = (
        centres_of_mass(t2 + H / 2.0, t3),
        centres_of_mass(t2 - H / 2.0, t3),
    );
    let (p3, m3) = (
        centres_of_mass(t2, t3 + H / 2.0),
        centres_of_mass(t2, t3 - H / 2.0),
    );
    let mut torque = DVec3::ZERO;
    for i in 0..4 {
        let weight = G_M_PER_S2 * MASS_KG[i];
        let term = DVec3::new(
            0.0,
            (p2[i][1] - m2[i][1]) / H * weight,
            (p3[i][1] - m3[i][1]) / H * weight,
        );
        if !term.is_nan() {
            torque += term;
        }
    }
    torque
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Body 1 turns with θ2 about (L0/2, 0): its centre is (L0/2, 0) + R(θ2)·(30.123, 0.484) mm, so its height
    /// is 30.123 mm·sin θ2 + 0.484 mm·cos θ2 and the torque holding it is g m1 (30.123 mm cos θ2 - 0.484 mm
    /// sin θ2): worked by hand from hfab_polhem.h:107, :120.
    #[test]
    fn body_one_is_a_pendulum_about_its_axis() {
        for t2 in [0.0, 0.4, 1.0] {
            let c = centres_of_mass(t2, 2.0)[0];
            let height = 30.123e-3 * f64::sin(t2) + 0.484e-3 * f64::cos(t2);
            assert!((c[1] - height).abs() < 1e-12, "{t2}: {c:?}");
        }
    }

    /// At a pose where the chain closes, the torque is finite, needs no θ1 term (gravity is along the base
    /// axis), and is the sum over the bodies of g m ∂z/∂θ (checked for θ2 with a finer step than hfabapi's).
    #[test]
    fn the_torque_holds_the_bodies_weight() {
        let theta = [0.0, 0.9, 2.2];
        let tau = polhem_gravity_torque(theta);
        assert!(tau.is_finite(), "{tau}");
        assert_eq!(tau.x, 0.0);
        let h = 1e-6;
        let (p, m) = (centres_of_mass(0.9 + h, 2.2), centres_of_mass(0.9 - h, 2.2));
        let expected: f64 = (0..4)
            .map(|i| G_M_PER_S2 * MASS_KG[i] * (p[i][1] - m[i][1]) / (2.0 * h))
            .sum();
        assert!((tau.y - expected).abs() < 1e-6, "{} vs {expected}", tau.y);
        assert!(tau.y.abs() > 0.05, "{tau}");
    }
}
