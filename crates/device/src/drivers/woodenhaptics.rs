//! WoodenHaptics 1.5 over USB HID (an mbed LPC1768 running the WoodenHapticsHID firmware): **legacy**, selected
//! with `--device woodenhaptics-hid`. The WoodenHaptics project retired this firmware in 2019; current devices run
//! the Teensy serial firmware, driven by [`super::woodenhaptics_serial`] (`--device woodenhaptics:PATH`).
//!
//! Latency: the firmware streams reports faster than a host may read them, and the kernel queues them; reading
//! one per tick would fall behind by up to the whole queue (~64 reports, ~64 ms). `read_state` therefore drains
//! the queue and keeps the newest report, as chai3d's USB branch does on every read. Its age
//! ([`HapticDevice::state_age_ticks`]) is 0: the report handed out is the newest the device has sent, read this
//! tick (a stalled stream is a timeout, never an old report handed out again), and reports carry no command
//! they answer, so there is no older command it could stand for.
//!
//! Sources (public): the firmware `mbed-code/main.cpp` in WoodenHaptics/woody-experimental (8-byte reports both
//! ways: `pc_to_hid_message` = three `short` motor currents in mA then a debug word; `hid_to_pc_message` = three
//! `short` encoder counts then an `unsigned short` counter; a 0.5 s message watchdog that disables the amplifiers),
//! and the host driver `src/devices/CWoodenDevice.cpp` in forsslund/chai3d (USB branch: VID 0x1234, PID 0x0006,
//! a leading report id 0 on writes, the kinematics, the Jacobian-transpose torques, the 3 A current limit and the
//! default configuration used here).
//!
//! Which pose converts force: the newest report's joint angles are a candidate until the host's input checks
//! accept that report ([`HapticDevice::input_checked`]); currents are computed only with the newest accepted
//! angles (after a rejected report, the last accepted), and before any report was accepted the currents are
//! zero. The firmware streams reports, so more reports than commands are expected here, not surplus.
//!
//! Maths (all from CWoodenDevice.cpp, USB branch). Encoder counts e = (-e_a, e_b, e_c); gear ratios
//! g = (d_bodyA/d_capA, -d_bodyB/d_capB, d_bodyC/d_capC); joint angles θ_i = 2π e_i / (cpr_i g_i), then
//! θ_C ← π/2 - θ_C. Forward kinematics with link lengths L_a, L_b, L_c and workspace origin o:
//!
//! ```text
//! x = cos θA (Lb sin θB + Lc sin θC) - o_x
//! y = sin θA (Lb sin θB + Lc sin θC) - o_y
//! z = La + Lb cos θB - Lc cos θC     - o_z
//! ```
//!
//! Torques τ = Jᵀ f with J the Jacobian of that map, plus gravity compensation
//! -g (0, m_B l_B sin θB + m_C (l_B + l_C) sin θC, m_C l_C sin θC); motor torques through the capstans
//! (τ_A d_capA/d_bodyA, -τ_B d_capB/d_bodyB, -τ_C d_capC/d_bodyC); currents I = τ_motor / k_t clamped to ±3 A,
//! sent as whole milliamperes (truncated toward zero, as C's `short(...)` does).

use super::woodenhaptics_kinematics::{
    drum_angle_rad, motor_torque_n_m, relative_to, serial_chain_jacobian, serial_chain_point,
};
use crate::transport::ReportTransport;
use crate::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;
use std::f64::consts::PI;
use std::time::Duration;

/// USB vendor id of the WoodenHapticsHID firmware (mbed USBHID default).
pub const VENDOR_ID: u16 = 0x1234;
/// USB product id of the WoodenHapticsHID firmware.
pub const PRODUCT_ID: u16 = 0x0006;
/// Report length both ways (no report id in the data).
pub const REPORT_LEN: usize = 8;
/// Largest motor current the host sends (A); the firmware maps 3 A to 90 % PWM.
pub const MAX_CURRENT_A: f64 = 3.0;

/// Mechanical configuration (chai3d's `cWoodenDevice::configuration`, the subset the USB path uses).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WoodenHapticsConfig {
    /// Capstan diameters of motors A, B, C (m).
    pub capstan_diameter_m: [f64; 3],
    /// Body (drum) diameters A, B, C (m).
    pub body_diameter_m: [f64; 3],
    /// Link lengths A (height of the first axis), B, C (m).
    pub link_length_m: [f64; 3],
    /// Workspace origin subtracted from the position (m).
    pub workspace_origin_m: [f64; 3],
    /// Workspace radius, for the capability record (m).
    pub workspace_radius_m: f64,
    /// Motor torque constants (N m / A).
    pub torque_constant_n_m_per_a: [f64; 3],
    /// Encoder counts per revolution (quadrature counted).
    pub counts_per_revolution: [f64; 3],
    /// Largest force (N).
    pub max_force_n: f64,
    /// Largest stable stiffness (N/m).
    pub max_stiffness_n_per_m: f64,
    /// Masses of bodies B and C (kg), for gravity compensation.
    pub body_mass_kg: [f64; 2],
    /// Distances to the centres of mass of bodies B and C (m).
    pub center_of_mass_m: [f64; 2],
    /// Gravity for compensation (m/s²); 0 disables it.
    pub gravity_m_per_s2: f64,
}

impl Default for WoodenHapticsConfig {
    /// `default_woody()` of forsslund/chai3d src/devices/CWoodenDevice.cpp.
    fn default() -> Self {
        WoodenHapticsConfig {
            capstan_diameter_m: [0.010, 0.010, 0.010],
            body_diameter_m: [0.160, 0.120, 0.120],
            link_length_m: [0.080, 0.205, 0.245],
            workspace_origin_m: [0.220, 0.000, 0.080],
            workspace_radius_m: 0.100,
            torque_constant_n_m_per_a: [0.0259, 0.0259, 0.0259],
            counts_per_revolution: [2000.0, 2000.0, 2000.0],
            max_force_n: 5.0,
            max_stiffness_n_per_m: 1000.0,
            body_mass_kg: [0.170, 0.110],
            center_of_mass_m: [0.051, 0.091],
            gravity_m_per_s2: 0.0,
        }
    }
}

impl WoodenHapticsConfig {
    fn validate(&self) -> Result<(), DeviceError> {
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
            Err(DeviceError::Config {
                what: "WoodenHaptics configuration: diameters, torque constants and counts must be finite and > 0, \
                       every other value finite"
                    .to_string(),
            })
        }
    }

    /// Joint angles (θA, θB, θC after the π/2 shift) from the three encoder counts of a report.
    pub fn joint_angles_rad(&self, counts: [i16; 3]) -> [f64; 3] {
        // CWoodenDevice.cpp: counts (-e_a, e_b, e_c) over gear ratios (+, -, +) d_body / d_capstan; the sign of
        // B's ratio is folded into its count here.
        let encoder = [
            -f64::from(counts[0]),
            -f64::from(counts[1]),
            f64::from(counts[2]),
        ];
        let angle = |i: usize| {
            drum_angle_rad(
                encoder[i],
                self.counts_per_revolution[i],
                self.capstan_diameter_m[i],
                self.body_diameter_m[i],
            )
        };
        [angle(0), angle(1), PI / 2.0 - angle(2)]
    }

    /// Handle position (m) at joint angles `theta`.
    pub fn position_m(&self, theta: [f64; 3]) -> DVec3 {
        relative_to(
            serial_chain_point(self.link_length_m, theta),
            self.workspace_origin_m,
        )
    }

    /// Motor currents (mA, as sent) that render `force_n` at joint angles `theta`.
    pub fn currents_ma(&self, theta: [f64; 3], force_n: DVec3) -> [i16; 3] {
        let [_, tb, tc] = theta;
        let jacobian = serial_chain_jacobian(self.link_length_m, theta);
        let [mb, mc] = self.body_mass_kg;
        let [lb_cm, lc_cm] = self.center_of_mass_m;
        let gravity = -self.gravity_m_per_s2
            * DVec3::new(
                0.0,
                mb * lb_cm * tb.sin() + mc * (lb_cm + lc_cm) * tc.sin(),
                mc * lc_cm * tc.sin(),
            );
        let joint_torque = jacobian.transpose() * force_n + gravity;
        let direction = [1.0, -1.0, -1.0];
        let mut currents = [0i16; 3];
        for (i, current) in currents.iter_mut().enumerate() {
            let motor_torque = motor_torque_n_m(
                direction[i] * joint_torque[i],
                self.capstan_diameter_m[i],
                self.body_diameter_m[i],
            );
            let amperes = (motor_torque / self.torque_constant_n_m_per_a[i])
                .clamp(-MAX_CURRENT_A, MAX_CURRENT_A);
            // Truncation toward zero, as `short(motorAmpere*1000)`; |value| <= 3000 fits.
            *current = (amperes * 1000.0) as i16;
        }
        currents
    }
}

/// Encodes the 9-byte output write: report id 0, three little-endian i16 currents (mA), the debug word.
pub fn encode_output(currents_ma: [i16; 3], debug: u16) -> [u8; REPORT_LEN + 1] {
    let mut out = [0u8; REPORT_LEN + 1];
    for (i, current) in currents_ma.iter().enumerate() {
        out[1 + 2 * i..3 + 2 * i].copy_from_slice(&current.to_le_bytes());
    }
    out[7..9].copy_from_slice(&debug.to_le_bytes());
    out
}

/// Decodes an input report: three little-endian i16 encoder counts and the firmware's report counter. A report
/// of another length is refused (the chai3d host also keeps only 8-byte reports).
pub fn decode_input(report: &[u8]) -> Result<([i16; 3], u16), DeviceError> {
    let Ok(bytes) = <[u8; REPORT_LEN]>::try_from(report) else {
        return Err(DeviceError::Protocol {
            what: "WoodenHaptics input report is not 8 bytes long",
        });
    };
    let word = |i: usize| [bytes[2 * i], bytes[2 * i + 1]];
    Ok((
        [
            i16::from_le_bytes(word(0)),
            i16::from_le_bytes(word(1)),
            i16::from_le_bytes(word(2)),
        ],
        u16::from_le_bytes(word(3)),
    ))
}

/// A WoodenHaptics 1.5 on a report transport.
#[derive(Debug)]
pub struct WoodenHaptics<T> {
    transport: T,
    config: WoodenHapticsConfig,
    info: DeviceInfo,
    /// Joint angles of the newest report the host accepted: the only pose force is converted with.
    theta: Option<[f64; 3]>,
    /// Joint angles of the newest report, until the host's verdict on it.
    candidate: Option<[f64; 3]>,
    read_timeout: Duration,
    last_counter: Option<u16>,
    drained_reports: u64,
}

impl<T: ReportTransport> WoodenHaptics<T> {
    /// A driver with `config` on `transport`.
    pub fn new(transport: T, config: WoodenHapticsConfig) -> Result<Self, DeviceError> {
        config.validate()?;
        let radius = config.workspace_radius_m;
        let info = DeviceInfo {
            model: String::from("WoodenHaptics 1.5 (legacy HID firmware)"),
            serial_number: String::new(),
            position_dof: 3,
            force_dof: 3,
            button_count: 0,
            workspace_min_m: DVec3::splat(-radius),
            workspace_max_m: DVec3::splat(radius),
            max_force_n: config.max_force_n,
            max_stiffness_n_per_m: config.max_stiffness_n_per_m,
            max_speed_m_per_s: crate::info::DEFAULT_MAX_SPEED_M_PER_S,
            reports_velocity: false,
            state_rates_hz: Vec::new(),
        };
        Ok(WoodenHaptics {
            transport,
            config,
            info,
            theta: None,
            candidate: None,
            read_timeout: Duration::from_millis(5),
            last_counter: None,
            drained_reports: 0,
        })
    }

    /// The transport (to check a scripted double with `done()`).
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// How many older queued reports `read_state` skipped to reach the newest one.
    pub fn drained_reports(&self) -> u64 {
        self.drained_reports
    }

    /// The firmware's report counter from the last input report.
    pub fn last_counter(&self) -> Option<u16> {
        self.last_counter
    }
}

impl<T: ReportTransport> HapticDevice for WoodenHaptics<T> {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        DeviceError::check_finite_force(force_n.to_array())?;
        // Only a pose the host accepted converts force; none yet means zero.
        let currents = match self.theta {
            Some(theta) => self.config.currents_ma(theta, force_n),
            None => [0; 3],
        };
        self.transport.write_report(&encode_output(currents, 0))
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.candidate = None;
        let mut report = [0u8; 64];
        let n = self.transport.read_report(&mut report, self.read_timeout)?;
        if n == 0 {
            return Err(DeviceError::Timeout {
                waited_us: u64::try_from(self.read_timeout.as_micros()).unwrap_or(u64::MAX),
                waiting_for: "a WoodenHaptics input report",
            });
        }
        // Drain the queue: keep the newest report (bounded, so a device flooding reports cannot hold the tick).
        let mut newest = n;
        let mut next = [0u8; 64];
        for _ in 0..128 {
            let m = self.transport.read_report(&mut next, Duration::ZERO)?;
            if m == 0 {
                break;
            }
            report = next;
            newest = m;
            self.drained_reports += 1;
        }
        let (counts, counter) = decode_input(&report[..newest])?;
        self.last_counter = Some(counter);
        let theta = self.config.joint_angles_rad(counts);
        self.candidate = Some(theta);
        let position_m = self.config.position_m(theta);
        Ok(DeviceState::at_rest(position_m))
    }

    fn disable(&mut self) -> Result<(), DeviceError> {
        // The wrapper has written a zero force; the firmware's own 0.5 s watchdog disables the amplifiers.
        Ok(())
    }

    fn input_checked(&mut self, accepted: bool) {
        match self.candidate.take() {
            Some(theta) if accepted => self.theta = Some(theta),
            _ => {}
        }
    }
}
