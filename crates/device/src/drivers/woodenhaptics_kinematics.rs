//! WoodenHaptics kinematics, once for every WoodenHaptics driver: encoder counts to joint angles through the
//! capstan drive, the serial chain's position and Jacobian (WoodenHaptics and retrofitted PHANTOMs), Polhem's
//! closed chain, gravity compensation, and joint torques to motor currents. Both drivers use [`WoodyKinematics`]:
//! the Teensy serial driver ([`super::woodenhaptics_serial`]) with the model's published constants, the legacy
//! HID driver ([`super::woodenhaptics`]) with `woodenhaptics_v2015()` and its firmware's counts put in hfabapi's
//! convention.
//!
//! Sources: hfabapi (hfab_kinematics.cpp, hfab_polhem.h, hfab_math.h, hfab_api.cpp) and chai3d's
//! CWoodenDevice.cpp, which write the same serial chain; the line numbers cited are hfabapi's (see
//! [`super::woodenhaptics_serial`] for the full list). Pure functions, no I/O; safe on the servo path (no
//! allocation).

use glam::{DMat3, DVec3};
use std::f64::consts::PI;

/// The firmware's current limit: a larger |current| is replaced by zero (ino:17, 510).
pub const FIRMWARE_MAX_CURRENT_MA: i32 = 6000;

/// A joint's angle (rad) from motor encoder counts through the capstan drive: 2π counts / cpr · d_capstan /
/// d_body (hfab_kinematics.cpp:106-143; CWoodenDevice.cpp divides by the gear ratio d_body / d_capstan).
pub fn drum_angle_rad(counts: f64, counts_per_revolution: f64, capstan_m: f64, body_m: f64) -> f64 {
    2.0 * PI * counts / counts_per_revolution * capstan_m / body_m
}

/// A motor's torque for a joint torque, through the capstan drive: τ d_capstan / d_body
/// (hfab_kinematics.cpp:290-303; CWoodenDevice.cpp). The direction sign is the caller's.
pub fn motor_torque_n_m(joint_torque: f64, capstan_m: f64, body_m: f64) -> f64 {
    joint_torque * capstan_m / body_m
}

/// The serial chain's point before the origin shift (m), links A (height of the first axis), B and C at joint
/// angles θ (hfab_kinematics.cpp:228-232; CWoodenDevice.cpp, USB branch):
/// `x = cos θA (Lb sin θB + Lc sin θC)`, `y = sin θA (...)`, `z = La + Lb cos θB - Lc cos θC`.
pub fn serial_chain_point(link_length_m: [f64; 3], theta: [f64; 3]) -> [f64; 3] {
    let [la, lb, lc] = link_length_m;
    let [ta, tb, tc] = theta;
    let reach = lb * tb.sin() + lc * tc.sin();
    [
        ta.cos() * reach,
        ta.sin() * reach,
        la + lb * tb.cos() - lc * tc.cos(),
    ]
}

/// The Jacobian of [`serial_chain_point`], d(position)/d(θ) with one column per joint
/// (hfab_kinematics.cpp:267-269 and CWoodenDevice.cpp give its transpose).
pub fn serial_chain_jacobian(link_length_m: [f64; 3], theta: [f64; 3]) -> DMat3 {
    let [_, lb, lc] = link_length_m;
    let [ta, tb, tc] = theta;
    let reach = lb * tb.sin() + lc * tc.sin();
    DMat3::from_cols(
        DVec3::new(-ta.sin() * reach, ta.cos() * reach, 0.0),
        DVec3::new(
            lb * ta.cos() * tb.cos(),
            lb * ta.sin() * tb.cos(),
            -lb * tb.sin(),
        ),
        DVec3::new(
            lc * ta.cos() * tc.cos(),
            lc * ta.sin() * tc.cos(),
            lc * tc.sin(),
        ),
    )
}

/// `point` minus the workspace `origin` (m).
pub fn relative_to(point: [f64; 3], origin: [f64; 3]) -> DVec3 {
    DVec3::new(
        point[0] - origin[0],
        point[1] - origin[1],
        point[2] - origin[2],
    )
}

/// Which position equations a configuration uses (hfab_kinematics.cpp:210-232).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chain {
    /// The serial chain of WoodenHaptics and the PHANTOM (hfab_kinematics.cpp:229-231).
    Serial,
    /// Polhem's closed chain (hfab_polhem.h:129-207).
    Polhem,
}

/// One model's kinematic and motor constants, as hfabapi publishes them (hfab_math.h `configuration`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WoodyKinematics {
    /// Position equations.
    pub chain: Chain,
    /// Capstan diameters A, B, C (m).
    pub capstan_diameter_m: [f64; 3],
    /// Link lengths A, B, C (m) (`length_body_*`).
    pub link_length_m: [f64; 3],
    /// Body (drum) diameters A, B, C (m).
    pub body_diameter_m: [f64; 3],
    /// Workspace origin subtracted from the position (m).
    pub workspace_origin_m: [f64; 3],
    /// Workspace radius (m), for the capability record.
    pub workspace_radius_m: f64,
    /// Motor torque constants (N m / A).
    pub torque_constant_n_m_per_a: [f64; 3],
    /// Encoder counts per revolution (quadrature counted).
    pub counts_per_revolution: [f64; 3],
    /// Largest force (N).
    pub max_force_n: f64,
    /// Largest stiffness (N/m).
    pub max_stiffness_n_per_m: f64,
    /// Motor and body turn the same way (`motor_and_body_aligned_*`; then the direction factor is -1).
    pub motor_and_body_aligned: [bool; 3],
    /// Encoder counts at the home pose, added to every reading (hfab_api.cpp:103-106).
    pub encoder_home: [i32; 3],
    /// Masses of bodies B and C (kg), for the serial chain's gravity compensation (`mass_body_b/c`).
    pub body_mass_kg: [f64; 2],
    /// Distances to the centres of mass of bodies B and C (m) (`length_cm_body_b/c`).
    pub center_of_mass_m: [f64; 2],
    /// Gravity for compensation (m/s²; `g_constant`, 0 in every published serial-chain configuration, which
    /// turns it off). Polhem's compensation uses its own body table ([`super::woodenhaptics_gravity`]) and
    /// this value.
    pub gravity_m_per_s2: f64,
}

impl WoodyKinematics {
    /// hfab_math.h:306-317 (`woodenhaptics_v2015()`), home from hfab_api.cpp:106.
    pub const WOODENHAPTICS_V2015: WoodyKinematics = WoodyKinematics {
        chain: Chain::Serial,
        capstan_diameter_m: [0.010, 0.010, 0.010],
        link_length_m: [0.080, 0.205, 0.245],
        body_diameter_m: [0.160, 0.120, 0.120],
        workspace_origin_m: [0.220, 0.000, 0.080],
        workspace_radius_m: 0.100,
        torque_constant_n_m_per_a: [0.0259, 0.0259, 0.0259],
        counts_per_revolution: [2000.0, 2000.0, 2000.0],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 1000.0,
        motor_and_body_aligned: [false, true, true],
        encoder_home: [0, 0, -6000],
        body_mass_kg: [0.170, 0.110],
        center_of_mass_m: [0.051, 0.091],
        gravity_m_per_s2: 0.0,
    };

    /// hfab_math.h:347-358 (`polhem_v3()`), home from hfab_api.cpp:105.
    pub const POLHEM_V3: WoodyKinematics = WoodyKinematics {
        chain: Chain::Polhem,
        capstan_diameter_m: [0.0288534, 0.0136981, 0.0137281],
        link_length_m: [0.1, 0.165, 0.1308],
        body_diameter_m: [0.175, 0.100, 0.100],
        workspace_origin_m: [0.2045, 0.0, 0.0325],
        workspace_radius_m: 0.150,
        torque_constant_n_m_per_a: [0.0603, 0.0538, 0.0538],
        counts_per_revolution: [4096.0, 4096.0, 4096.0],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 2000.0,
        motor_and_body_aligned: [false, true, false],
        encoder_home: [8312, -10366, 19764],
        body_mass_kg: [0.0, 0.0],
        center_of_mass_m: [0.0, 0.0],
        // hfab_polhem.h:13: Polhem's direct compensation is always on in hfabapi (hfab_kinematics.cpp:9).
        gravity_m_per_s2: super::woodenhaptics_gravity::G_M_PER_S2,
    };

    /// hfab_math.h:374-385 (`vintage()`), home from hfab_api.cpp:103.
    pub const VINTAGE: WoodyKinematics = WoodyKinematics {
        chain: Chain::Serial,
        capstan_diameter_m: [0.013, 0.010, 0.010],
        link_length_m: [0.000, 0.138, 0.112],
        body_diameter_m: [0.117, 0.077, 0.077],
        workspace_origin_m: [0.138, 0.000, -0.097],
        workspace_radius_m: 0.100,
        torque_constant_n_m_per_a: [0.0234, 0.0234, 0.0234],
        counts_per_revolution: [4000.0, 4000.0, 4000.0],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 800.0,
        motor_and_body_aligned: [true, false, true],
        encoder_home: [0, 7700, 0],
        body_mass_kg: [0.170, 0.110],
        center_of_mass_m: [0.051, 0.091],
        gravity_m_per_s2: 0.0,
    };

    fn direction(&self, i: usize) -> f64 {
        if self.motor_and_body_aligned[i] {
            -1.0
        } else {
            1.0
        }
    }

    /// Joint angles (θA, θB, θC) from raw encoder counts (the home offset is added here;
    /// hfab_api.cpp:178-179, hfab_kinematics.cpp:109-139).
    pub fn joint_angles_rad(&self, raw_counts: [i32; 3]) -> [f64; 3] {
        let mut theta = [0.0; 3];
        for (i, angle) in theta.iter_mut().enumerate() {
            let counts = f64::from(raw_counts[i]) + f64::from(self.encoder_home[i]);
            *angle = self.direction(i)
                * drum_angle_rad(
                    counts,
                    self.counts_per_revolution[i],
                    self.capstan_diameter_m[i],
                    self.body_diameter_m[i],
                );
        }
        theta
    }

    /// The mechanism's point before the origin shift (m); NaN where Polhem's chain cannot close.
    fn chain_point(&self, theta: [f64; 3]) -> [f64; 3] {
        let [ta, tb, tc] = theta;
        match self.chain {
            Chain::Serial => serial_chain_point(self.link_length_m, theta),
            Chain::Polhem => polhem_point(ta, tb, tc),
        }
    }

    /// Handle position (m) at joint angles `theta`; `None` where the chain cannot close.
    pub fn position_m(&self, theta: [f64; 3]) -> Option<DVec3> {
        let position = relative_to(self.chain_point(theta), self.workspace_origin_m);
        position.is_finite().then_some(position)
    }

    /// The Jacobian d(position)/d(θ) (columns per joint): analytic for the serial chain
    /// (hfab_kinematics.cpp:267-269 gives its transpose), central differences with h = 1e-5 for Polhem
    /// (hfab_polhem.h:227-245).
    pub fn jacobian(&self, theta: [f64; 3]) -> DMat3 {
        match self.chain {
            Chain::Serial => serial_chain_jacobian(self.link_length_m, theta),
            Chain::Polhem => {
                const H: f64 = 0.00001;
                let column = |i: usize| {
                    let mut plus = theta;
                    let mut minus = theta;
                    plus[i] += H / 2.0;
                    minus[i] -= H / 2.0;
                    let (p, m) = (polhem_point(plus[0], plus[1], plus[2]), {
                        polhem_point(minus[0], minus[1], minus[2])
                    });
                    DVec3::new((p[0] - m[0]) / H, (p[1] - m[1]) / H, (p[2] - m[2]) / H)
                };
                DMat3::from_cols(column(0), column(1), column(2))
            }
        }
    }

    /// The joint torques that hold the arm's own weight at `theta`, as hfabapi adds them to Jᵀ f: for the
    /// serial chain g (0, m_B l_B sin θB + m_C (l_B + l_C) sin θC, m_C l_C sin θC) (hfab_kinematics.cpp:271-280),
    /// for Polhem its four-body compensation ([`super::woodenhaptics_gravity`]) scaled by
    /// `gravity_m_per_s2` / 9.81.
    pub fn gravity_torque(&self, theta: [f64; 3]) -> DVec3 {
        let g = self.gravity_m_per_s2;
        if g == 0.0 {
            return DVec3::ZERO;
        }
        let [_, tb, tc] = theta;
        match self.chain {
            Chain::Serial => {
                let [mb, mc] = self.body_mass_kg;
                let [lb_cm, lc_cm] = self.center_of_mass_m;
                g * DVec3::new(
                    0.0,
                    mb * lb_cm * tb.sin() + mc * (lb_cm + lc_cm) * tc.sin(),
                    mc * lc_cm * tc.sin(),
                )
            }
            Chain::Polhem => {
                super::woodenhaptics_gravity::polhem_gravity_torque(theta) * g
                    / super::woodenhaptics_gravity::G_M_PER_S2
            }
        }
    }

    /// Checks the constants a driver computes with: diameters, torque constants and counts finite and > 0,
    /// every other number finite.
    pub fn validate(&self) -> Result<(), crate::DeviceError> {
        let positive = self
            .capstan_diameter_m
            .iter()
            .chain(&self.body_diameter_m)
            .chain(&self.torque_constant_n_m_per_a)
            .chain(&self.counts_per_revolution)
            .all(|v| v.is_finite() && *v > 0.0);
        let finite = self
            .link_length_m
            .iter()
            .chain(&self.workspace_origin_m)
            .chain(&self.body_mass_kg)
            .chain(&self.center_of_mass_m)
            .chain([
                &self.workspace_radius_m,
                &self.max_force_n,
                &self.max_stiffness_n_per_m,
                &self.gravity_m_per_s2,
            ])
            .all(|v| v.is_finite());
        if positive && finite {
            Ok(())
        } else {
            Err(crate::DeviceError::Config {
                what: "WoodenHaptics configuration: diameters, torque constants and counts must be finite and > 0, \
                       every other value finite"
                    .to_string(),
            })
        }
    }

    /// Motor currents (mA, as sent) that render `force_n` at joint angles `theta`: τ = Jᵀ f plus the
    /// [`gravity_torque`](Self::gravity_torque), through the capstans and torque constants, truncated toward
    /// zero as `int(A·1000)`; scaled together so none exceeds `max_current_ma`. A non-finite Jᵀ f (a singular
    /// pose) gives zero currents, without gravity compensation (hfab_polhem.h:260-266).
    pub fn currents_ma(&self, theta: [f64; 3], force_n: DVec3, max_current_ma: i32) -> [i32; 3] {
        let torque = self.jacobian(theta).transpose() * force_n;
        if !torque.is_finite() {
            return [0; 3];
        }
        let torque = torque + self.gravity_torque(theta);
        if !torque.is_finite() {
            return [0; 3];
        }
        let joint = torque.to_array();
        let mut milliamps = [0.0f64; 3];
        for (i, ma) in milliamps.iter_mut().enumerate() {
            let motor_torque = motor_torque_n_m(
                joint[i] * self.direction(i),
                self.capstan_diameter_m[i],
                self.body_diameter_m[i],
            );
            *ma = motor_torque / self.torque_constant_n_m_per_a[i] * 1000.0;
        }
        let largest = milliamps.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let limit = f64::from(max_current_ma.clamp(0, FIRMWARE_MAX_CURRENT_MA));
        let scale = if largest > limit {
            limit / largest
        } else {
            1.0
        };
        // `as` truncates toward zero, as C's int(); |value| <= limit fits.
        milliamps.map(|ma| (ma * scale) as i32)
    }
}

// Polhem's link lengths (hfab_polhem.h:84-89).
const POLHEM_L0: f64 = 34e-3;
const POLHEM_L1: f64 = 165e-3;
const POLHEM_L2: f64 = 25e-3;
const POLHEM_L3: f64 = 190e-3;
const POLHEM_L4: f64 = 34e-3;
const POLHEM_L5: f64 = 130.8e-3;

/// Polhem's closed-chain forward kinematics (hfab_polhem.h:175-205), before the origin shift.
fn polhem_point(t1: f64, t2: f64, t3: f64) -> [f64; 3] {
    let sq = |v: f64| v * v;
    let l1_cos_t2 = POLHEM_L1 * t2.cos();
    let l1_sin_t2 = POLHEM_L1 * t2.sin();
    let a = POLHEM_L0 + l1_cos_t2;
    let sq1 = sq(a - POLHEM_L2 * t3.cos());
    let sq2 = sq(l1_sin_t2 - POLHEM_L2 * t3.sin());
    let sq3 = a * a;
    let sq4 = l1_sin_t2 * l1_sin_t2;
    let sqrt1 = (sq1 + sq2).sqrt();
    let sqrt2 = (sq3 + sq4).sqrt();
    let x1 = 2.0 * sqrt2 * sqrt1;
    let x2 = -sq(POLHEM_L3) + sq(POLHEM_L4) + sq1 + sq2;
    let x3 = 2.0 * POLHEM_L1 * sqrt2;
    let x4 = 2.0 * POLHEM_L4 * sqrt1;
    let x5 = -sq(POLHEM_L0) + sq(POLHEM_L1) + sq3 + sq4;
    let x6 = -sq(POLHEM_L2) + sq1 + sq2 + sq3 + sq4;
    let y1 = t2 - (x5 / x3).acos() - (x2 / x4).acos() - (x6 / x1).acos();
    let x7 = POLHEM_L0 / 2.0 + l1_cos_t2 + POLHEM_L5 * y1.cos();
    [
        x7 * t1.cos(),
        x7 * t1.sin(),
        l1_sin_t2 + POLHEM_L5 * y1.sin(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The serial driver's limit, as tests/woodenhaptics_serial.rs uses it.
    const MAX_CURRENT_MA: i32 = 6000;

    #[test]
    fn woody_home_pose_puts_body_c_at_a_right_angle() {
        // hfab_api.cpp:106 home (0, 0, -6000); hfab_math.h:306-317: cpr 2000, capstan 0.010, body 0.120, body C
        // aligned (dir -1): θC = -1 · 2π(-6000)/2000 · 0.010/0.120 = π/2.
        let k = WoodyKinematics::WOODENHAPTICS_V2015;
        let theta = k.joint_angles_rad([0, 0, 0]);
        assert!(theta[0].abs() < 1e-12 && theta[1].abs() < 1e-12);
        assert!((theta[2] - PI / 2.0).abs() < 1e-12, "{theta:?}");
        // hfab_kinematics.cpp:229-231 at (0, 0, π/2): x = Lc - ox, y = 0, z = Ln + Lb - oz.
        let p = k.position_m(theta).unwrap();
        assert!((p.x - (0.245 - 0.220)).abs() < 1e-12, "{p}");
        assert!(p.y.abs() < 1e-12);
        assert!((p.z - (0.080 + 0.205 - 0.080)).abs() < 1e-12, "{p}");
    }

    #[test]
    fn serial_chain_jacobian_matches_finite_differences_of_the_position() {
        for k in [
            WoodyKinematics::WOODENHAPTICS_V2015,
            WoodyKinematics::VINTAGE,
        ] {
            let theta = [0.3, 0.4, 1.2];
            let j = k.jacobian(theta);
            for i in 0..3 {
                let h = 1e-6;
                let mut plus = theta;
                let mut minus = theta;
                plus[i] += h;
                minus[i] -= h;
                let numeric =
                    (k.position_m(plus).unwrap() - k.position_m(minus).unwrap()) / (2.0 * h);
                assert!(
                    (j.col(i) - numeric).length() < 1e-6,
                    "{i}: {} vs {numeric}",
                    j.col(i)
                );
            }
        }
    }

    #[test]
    fn currents_follow_jacobian_transpose_capstans_and_torque_constants() {
        // Woody at home (θ = 0, 0, π/2), force +x 1 N: τ = Jᵀ f = (0, Lb cos0, Lc cos(π/2))·1 = (0, 0.205, ~0)
        // (hfab_kinematics.cpp:267-269). Motor B: τ_m = 0.205 · (-1) · 0.010/0.120 (hfab_kinematics.cpp:296),
        // I = τ_m / 0.0259 A = -0.6596 A → int(-659.6) = -659 mA (hfab_api.cpp:245).
        let k = WoodyKinematics::WOODENHAPTICS_V2015;
        let theta = k.joint_angles_rad([0, 0, 0]);
        let currents = k.currents_ma(theta, DVec3::X, MAX_CURRENT_MA);
        assert_eq!(currents, [0, -659, 0]);
        // Scaling keeps the ratio: 100 N asks for -65 962 mA on motor B; all currents scale to fit 6000 mA.
        let big = k.currents_ma(theta, DVec3::new(100.0, 0.0, 0.0), MAX_CURRENT_MA);
        assert_eq!(big[1], -6000);
        assert_eq!(k.currents_ma(theta, DVec3::ZERO, MAX_CURRENT_MA), [0, 0, 0]);
    }

    #[test]
    fn polhem_home_pose_closes_and_its_numeric_jacobian_is_consistent() {
        let k = WoodyKinematics::POLHEM_V3;
        let theta = k.joint_angles_rad([0, 0, 0]);
        let p = k.position_m(theta).expect("Polhem closes at its home pose");
        assert!(p.length() < 0.3, "{p}");
        let j = k.jacobian(theta);
        assert!(j.is_finite());
        // The force +z pushes up: the resulting joint torques are finite and not all zero.
        let currents = k.currents_ma(theta, DVec3::Z, MAX_CURRENT_MA);
        assert!(currents.iter().any(|&c| c != 0), "{currents:?}");
    }
}
