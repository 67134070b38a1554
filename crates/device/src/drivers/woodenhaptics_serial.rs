//! WoodenHaptics, Polhem and retrofitted PHANTOMs on the current Teensy firmware: text lines over USB serial
//! (`--device woodenhaptics:PATH`).
//!
//! Where it sits: a [`HapticDevice`] on a [`ByteTransport`] (a USB CDC-ACM port `/dev/ttyACMn`, or a
//! pseudo-terminal in tests), under the supervisor's safety pipeline.
//!
//! Sources (public):
//! - the firmware `firmware/woody_teensy_mini/woody_teensy_mini.ino` in forsslund/woodenhaptics (cited below as
//!   `ino:LINE`): device to PC `[model,enc0,...,enc5,error]\n` (ino:101-117), PC to device `[ma0,ma1,ma2]\n` in
//!   milliamperes (ino:119-131); one reply per message (ino:470-553); a malformed message is answered with the
//!   last values and an error code (256 no `[` before `]`, 512 not three values, 8 trailing characters, 128 line
//!   too long, 1024 parse error; ino:419-455, 486-488); a current outside ±6000 mA is replaced by 0 (ino:17,
//!   510); the amplifiers are enabled while messages flow and cut by a 100 ms message watchdog (ino:274-281,
//!   493-494, 504); model 1 is Polhem 2022, 2 a retrofitted ("vintage") PHANTOM, 3 WoodenHaptics (ino:98-100).
//! - the host library forsslund/hfabapi (cited as `FILE:LINE`): the model in each report selects the kinematic
//!   configuration and encoder home offsets (hfab_api.cpp:103-106, 159-179: model 1 `polhem_v3()` with home
//!   (8312, -10366, 19764), model 2 `vintage()` with (0, 7700, 0), model 3 `woodenhaptics_v2015()` with
//!   (0, 0, -6000)); the configurations (hfab_math.h:306-317, 347-358, 374-385); joint angles
//!   θ_i = dir_i 2π e_i / cpr_i · d_capstan_i / d_body_i with dir_i = -1 where the motor and body are aligned
//!   (hfab_kinematics.cpp:106-143); the serial-chain position of models 2 and 3
//!   (hfab_kinematics.cpp:228-232); joint torques τ = Jᵀ f (hfab_kinematics.cpp:265-270); motor torques
//!   τ_m = τ dir d_capstan / d_body and currents τ_m / k_t (hfab_kinematics.cpp:290-303), sent as `int(A·1000)`
//!   (hfab_api.cpp:243-247); Polhem's closed-chain position (hfab_polhem.h:84-89, 175-206) and its Jacobian by
//!   central differences with h = 1e-5 (hfab_polhem.h:227-256), a NaN torque replaced by zero (260-266).
//!
//! Not implemented: hfabapi's gravity compensation (0 for models 2 and 3 in their configurations; Polhem's
//! direct compensation, hfab_polhem.h:276-333, is left out, so a Polhem feels its own weight), and the gimbal
//! encoders 3-5 (reported by the firmware, not used: voxhap renders 3-DOF forces).
//!
//! Which pose converts force: the driver keeps the newest report's joint angles as a candidate and converts
//! force with them only once the host's input checks accepted that report ([`HapticDevice::input_checked`]);
//! after a rejected report (an encoder glitch, a jump) it keeps converting with the last accepted angles, and
//! before any report was accepted it sends zero currents. A glitched reading therefore never turns the next
//! force into currents that push another way at the arm's true pose.
//!
//! No backlog: the firmware answers each message once (ino:470-553). Before each command the driver reads
//! whatever lines are already waiting without blocking (a reply that came after its read timed out, a second
//! answer, a flood) and drops them; after the reply to the command it drops any further lines already waiting.
//! Lines nobody asked for are counted and reported ([`DeviceEvent::Surplus`]); a flood larger than
//! [`MAX_LINES_DRAINED`] lines per tick is discarded wholesale. The state handed out is the first reply after the
//! command (at most one tick old when a second answer of the previous command slipped in behind the drain), so
//! positions never queue up: the supervisor's staleness bound (`stale_state_ticks`) counts from there.
//!
//! Frame: hfabapi's device frame in metres with its workspace origin subtracted (for a WoodenHaptics: x forward
//! from the base axis, y to the side, z up). The supervisor's safety pipeline bounds the force; this driver also
//! scales the three currents together so none exceeds [`MAX_CURRENT_MA`] (keeping the force's direction, as
//! libnifalcon does for the Falcon), where the firmware would zero a single motor.

use super::woodenhaptics_constants::{set, WoodenHapticsConstants};
use crate::transport::ByteTransport;
use crate::{DeviceError, DeviceEvent, DeviceInfo, DeviceState, HapticDevice, SurplusCount};
use glam::{DMat3, DVec3};
use std::f64::consts::PI;
use std::io::Write as _;
use std::time::{Duration, Instant};

/// The firmware's current limit: a larger |current| is replaced by zero (ino:17, 510).
pub const FIRMWARE_MAX_CURRENT_MA: i32 = 6000;
/// The largest current this driver sends (mA); currents are scaled together to stay within it.
pub const MAX_CURRENT_MA: i32 = 6000;
/// The firmware's message watchdog (ino:494): the amplifiers are cut after this long without a message.
pub const WATCHDOG_MS: u64 = 100;
/// Longest line the firmware accepts (ino:413: 127 characters).
pub const MAX_LINE_LEN: usize = 127;
/// Error bits the firmware sets when it could not parse our message (ino:433-454, 487).
pub const MESSAGE_ERROR_BITS: i32 = 8 | 128 | 256 | 512 | 1024;
/// Most lines read and dropped in one tick before the rest of the input is discarded at once (a flood).
pub const MAX_LINES_DRAINED: usize = 64;

/// Which device the firmware says it is (the first number of every report).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WoodyModel {
    /// Model 1: Polhem (2022).
    Polhem,
    /// Model 2: a retrofitted ("vintage") PHANTOM.
    VintagePhantom,
    /// Model 3: WoodenHaptics.
    WoodenHaptics,
}

impl WoodyModel {
    /// The model for a report's model number (ino:98-100).
    pub fn from_number(number: i32) -> Option<WoodyModel> {
        match number {
            1 => Some(WoodyModel::Polhem),
            2 => Some(WoodyModel::VintagePhantom),
            3 => Some(WoodyModel::WoodenHaptics),
            _ => None,
        }
    }

    /// A name for people.
    pub fn name(self) -> &'static str {
        match self {
            WoodyModel::Polhem => "Polhem (Teensy firmware)",
            WoodyModel::VintagePhantom => "retrofitted PHANTOM (Teensy firmware)",
            WoodyModel::WoodenHaptics => "WoodenHaptics (Teensy firmware)",
        }
    }

    /// Index of this model in per-model tables (model number - 1).
    pub fn index(self) -> usize {
        match self {
            WoodyModel::Polhem => 0,
            WoodyModel::VintagePhantom => 1,
            WoodyModel::WoodenHaptics => 2,
        }
    }

    /// The published kinematic configuration for this model (hfab_api.cpp:159-179).
    pub fn config(self) -> WoodyKinematics {
        match self {
            WoodyModel::Polhem => WoodyKinematics::POLHEM_V3,
            WoodyModel::VintagePhantom => WoodyKinematics::VINTAGE,
            WoodyModel::WoodenHaptics => WoodyKinematics::WOODENHAPTICS_V2015,
        }
    }
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
}

// Defined here rather than beside the type so that the constants module does not depend on this driver.
impl WoodenHapticsConstants {
    /// A serial-firmware model's `kinematics` with the constants given here replaced.
    pub fn applied_to(&self, mut kinematics: WoodyKinematics) -> WoodyKinematics {
        set(&mut kinematics.capstan_diameter_m, self.capstan_diameter_m);
        set(&mut kinematics.body_diameter_m, self.body_diameter_m);
        set(&mut kinematics.link_length_m, self.link_length_m);
        set(&mut kinematics.workspace_origin_m, self.workspace_origin_m);
        set(
            &mut kinematics.torque_constant_n_m_per_a,
            self.torque_constant_n_m_per_a,
        );
        set(
            &mut kinematics.counts_per_revolution,
            self.counts_per_revolution,
        );
        set(&mut kinematics.encoder_home, self.encoder_home_counts);
        kinematics
    }
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
            let motor_angle = 2.0 * PI * counts / self.counts_per_revolution[i];
            *angle = self.direction(i) * motor_angle * self.capstan_diameter_m[i]
                / self.body_diameter_m[i];
        }
        theta
    }

    /// The mechanism's point before the origin shift (m); NaN where Polhem's chain cannot close.
    fn chain_point(&self, theta: [f64; 3]) -> [f64; 3] {
        let [ta, tb, tc] = theta;
        match self.chain {
            Chain::Serial => {
                let [ln, lb, lc] = self.link_length_m;
                let reach = lb * tb.sin() + lc * tc.sin();
                [
                    ta.cos() * reach,
                    ta.sin() * reach,
                    ln + lb * tb.cos() - lc * tc.cos(),
                ]
            }
            Chain::Polhem => polhem_point(ta, tb, tc),
        }
    }

    /// Handle position (m) at joint angles `theta`; `None` where the chain cannot close.
    pub fn position_m(&self, theta: [f64; 3]) -> Option<DVec3> {
        let p = self.chain_point(theta);
        let position = DVec3::new(
            p[0] - self.workspace_origin_m[0],
            p[1] - self.workspace_origin_m[1],
            p[2] - self.workspace_origin_m[2],
        );
        position.is_finite().then_some(position)
    }

    /// The Jacobian d(position)/d(θ) (columns per joint): analytic for the serial chain
    /// (hfab_kinematics.cpp:267-269 gives its transpose), central differences with h = 1e-5 for Polhem
    /// (hfab_polhem.h:227-245).
    pub fn jacobian(&self, theta: [f64; 3]) -> DMat3 {
        let [ta, tb, tc] = theta;
        match self.chain {
            Chain::Serial => {
                let [_, lb, lc] = self.link_length_m;
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

    /// Motor currents (mA, as sent) that render `force_n` at joint angles `theta`: τ = Jᵀ f, through the
    /// capstans and torque constants, truncated toward zero as `int(A·1000)`; scaled together so none exceeds
    /// `max_current_ma`. A non-finite torque (a singular pose) gives zero currents.
    pub fn currents_ma(&self, theta: [f64; 3], force_n: DVec3, max_current_ma: i32) -> [i32; 3] {
        let torque = self.jacobian(theta).transpose() * force_n;
        if !torque.is_finite() {
            return [0; 3];
        }
        let joint = torque.to_array();
        let mut milliamps = [0.0f64; 3];
        for (i, ma) in milliamps.iter_mut().enumerate() {
            let motor_torque =
                joint[i] * self.direction(i) * self.capstan_diameter_m[i] / self.body_diameter_m[i];
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

/// One report of the firmware.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WoodyReport {
    /// Model number (1, 2 or 3).
    pub model: i32,
    /// Encoder counts: three motors, then three gimbal sensors.
    pub encoders: [i32; 6],
    /// Error bits (see [`MESSAGE_ERROR_BITS`]; 1, 2, 4 are gimbal sensor read errors).
    pub error_code: i32,
}

/// Parses one report line `[model,e0,e1,e2,e3,e4,e5,error]` (without the newline; surrounding whitespace
/// allowed). Anything else is refused: eight base-10 integers, nothing more.
pub fn parse_report(line: &[u8]) -> Result<WoodyReport, DeviceError> {
    let bad = |what: &'static str| DeviceError::Protocol { what };
    let text = std::str::from_utf8(line).map_err(|_| bad("WoodenHaptics report is not text"))?;
    let inner = text
        .trim()
        .strip_prefix('[')
        .and_then(|t| t.strip_suffix(']'))
        .ok_or_else(|| bad("WoodenHaptics report is not a bracketed list"))?;
    let mut values = [0i32; 8];
    let mut count = 0;
    for field in inner.split(',') {
        if count == values.len() {
            return Err(bad("WoodenHaptics report has more than 8 values"));
        }
        values[count] = field
            .trim()
            .parse()
            .map_err(|_| bad("WoodenHaptics report holds a value that is not an integer"))?;
        count += 1;
    }
    if count != values.len() {
        return Err(bad("WoodenHaptics report has fewer than 8 values"));
    }
    let mut encoders = [0i32; 6];
    encoders.copy_from_slice(&values[1..7]);
    Ok(WoodyReport {
        model: values[0],
        encoders,
        error_code: values[7],
    })
}

/// Formats the command `[ma0,ma1,ma2]\n` into `out`, returning its length (at most 37 bytes).
pub fn format_command(currents_ma: [i32; 3], out: &mut [u8; 40]) -> usize {
    let mut cursor = std::io::Cursor::new(&mut out[..]);
    // Three i32 in decimal fit in 40 bytes, so the write cannot fail.
    let _ = writeln!(
        cursor,
        "[{},{},{}]",
        currents_ma[0], currents_ma[1], currents_ma[2]
    );
    cursor.position() as usize
}

/// Settings of the driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WoodyConfig {
    /// How long `read_state` waits for the reply line (the firmware answers within about 1 ms).
    pub reply_timeout: Duration,
    /// How long `open` waits for the first report, per attempt.
    pub hello_timeout: Duration,
    /// Attempts at the first report.
    pub hello_attempts: u32,
    /// Largest current sent (mA), at most [`FIRMWARE_MAX_CURRENT_MA`].
    pub max_current_ma: i32,
    /// Kinematics to use instead of the model's published one (a calibrated profile).
    pub kinematics_override: Option<WoodyKinematics>,
    /// Per model (indexed by [`WoodyModel::index`]): constants replacing the published ones for the model the
    /// device reports (a device profile's `[kinematics.MODEL]`).
    pub model_constants: [WoodenHapticsConstants; 3],
}

impl Default for WoodyConfig {
    fn default() -> Self {
        WoodyConfig {
            reply_timeout: Duration::from_millis(5),
            hello_timeout: Duration::from_millis(100),
            hello_attempts: 5,
            max_current_ma: MAX_CURRENT_MA,
            kinematics_override: None,
            model_constants: [WoodenHapticsConstants::default(); 3],
        }
    }
}

/// A WoodenHaptics / Polhem / retrofitted PHANTOM on the Teensy firmware, on a byte transport.
#[derive(Debug)]
pub struct WoodenHapticsSerial<T> {
    transport: T,
    config: WoodyConfig,
    info: DeviceInfo,
    model: Option<WoodyModel>,
    kinematics: WoodyKinematics,
    /// Joint angles of the newest report the host accepted: the only pose force is converted with.
    theta: Option<[f64; 3]>,
    /// Joint angles of the newest report, until the host's verdict on it.
    candidate: Option<[f64; 3]>,
    line: [u8; 256],
    line_len: usize,
    last_report: Option<WoodyReport>,
    awaiting_reply: bool,
    late_replies: u64,
    surplus: SurplusCount,
    event: Option<DeviceEvent>,
}

impl<T: ByteTransport> WoodenHapticsSerial<T> {
    /// A driver on `transport`. The model (and so the kinematics) is read from the device in `open`.
    pub fn new(transport: T, config: WoodyConfig) -> Self {
        let kinematics = config
            .kinematics_override
            .unwrap_or(WoodyKinematics::WOODENHAPTICS_V2015);
        WoodenHapticsSerial {
            transport,
            config,
            info: info_for(None, &kinematics),
            model: None,
            kinematics,
            theta: None,
            candidate: None,
            line: [0; 256],
            line_len: 0,
            last_report: None,
            awaiting_reply: false,
            late_replies: 0,
            surplus: SurplusCount::default(),
            event: None,
        }
    }

    /// Lines the device sent that no command asked for (second answers, floods), dropped.
    pub fn surplus_replies(&self) -> u64 {
        self.surplus.total()
    }

    /// Replies that came after their read had timed out, dropped before the next command.
    pub fn late_replies(&self) -> u64 {
        self.late_replies
    }

    /// Joint angles force is converted with: the newest report the host accepted (`None` before the first).
    pub fn conversion_angles(&self) -> Option<[f64; 3]> {
        self.theta
    }

    fn count_surplus(&mut self, n: u64) {
        if let Some(event) = self.surplus.add(n) {
            self.event = Some(event);
        }
    }

    /// Drops every complete line already waiting, without blocking: a reply whose read timed out (late), or
    /// lines nobody asked for (surplus). More than [`MAX_LINES_DRAINED`] lines: the rest is discarded at once.
    fn drain_waiting(&mut self) -> Result<(), DeviceError> {
        let mut surplus = 0;
        let mut lines = 0;
        loop {
            if lines == MAX_LINES_DRAINED {
                self.transport.discard_input()?;
                self.line_len = 0;
                surplus += 1;
                break;
            }
            match self.read_line(Duration::ZERO) {
                Ok(Some(_)) | Err(DeviceError::Protocol { .. }) => {}
                Ok(None) => break,
                Err(error) => return Err(error),
            }
            lines += 1;
            if std::mem::take(&mut self.awaiting_reply) {
                self.late_replies += 1;
            } else {
                surplus += 1;
            }
        }
        // A reply still missing a whole tick later is lost (or so late that it counts as surplus when it comes).
        self.awaiting_reply = false;
        self.count_surplus(surplus);
        Ok(())
    }

    /// The model the device reported.
    pub fn model(&self) -> Option<WoodyModel> {
        self.model
    }

    /// The newest report.
    pub fn last_report(&self) -> Option<WoodyReport> {
        self.last_report
    }

    /// The kinematics in use.
    pub fn kinematics(&self) -> &WoodyKinematics {
        &self.kinematics
    }

    /// Reads one line (up to `\n`) within `timeout`. `Ok(None)` on timeout (a partial line is kept for the next
    /// call). A line longer than the buffer is dropped and reported.
    fn read_line(&mut self, timeout: Duration) -> Result<Option<WoodyReport>, DeviceError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(end) = self.line[..self.line_len].iter().position(|&b| b == b'\n') {
                let parsed = parse_report(&self.line[..end]);
                self.line.copy_within(end + 1..self.line_len, 0);
                self.line_len -= end + 1;
                return parsed.map(Some);
            }
            if self.line_len == self.line.len() {
                self.line_len = 0;
                return Err(DeviceError::Protocol {
                    what: "WoodenHaptics sent a line longer than 256 bytes",
                });
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            let n = self
                .transport
                .read(&mut self.line[self.line_len..], remaining)?;
            if n == 0 {
                return Ok(None);
            }
            self.line_len += n;
        }
    }

    fn accept(&mut self, report: WoodyReport) -> Result<DeviceState, DeviceError> {
        if report.error_code & MESSAGE_ERROR_BITS != 0 {
            return Err(DeviceError::Protocol {
                what: "WoodenHaptics firmware could not parse the current command",
            });
        }
        let Some(model) = WoodyModel::from_number(report.model) else {
            return Err(DeviceError::Protocol {
                what: "WoodenHaptics report names an unknown model (expected 1, 2 or 3)",
            });
        };
        if self.model != Some(model) {
            if self.model.is_some() {
                return Err(DeviceError::Protocol {
                    what: "WoodenHaptics report changed its model number mid-session",
                });
            }
            self.model = Some(model);
            self.kinematics = self.config.kinematics_override.unwrap_or_else(|| {
                self.config.model_constants[model.index()].applied_to(model.config())
            });
            self.info = info_for(Some(model), &self.kinematics);
        }
        let theta = self.kinematics.joint_angles_rad([
            report.encoders[0],
            report.encoders[1],
            report.encoders[2],
        ]);
        let Some(position_m) = self.kinematics.position_m(theta) else {
            return Err(DeviceError::InvalidData {
                what: "WoodenHaptics encoders put the linkage where it cannot close",
            });
        };
        self.candidate = Some(theta);
        self.last_report = Some(report);
        Ok(DeviceState::at_rest(position_m))
    }

    fn send_currents(&mut self, currents_ma: [i32; 3]) -> Result<(), DeviceError> {
        let mut buf = [0u8; 40];
        let len = format_command(currents_ma, &mut buf);
        self.transport.write_all(&buf[..len])
    }
}

fn info_for(model: Option<WoodyModel>, kinematics: &WoodyKinematics) -> DeviceInfo {
    let radius = kinematics.workspace_radius_m;
    // The longest arm of the family (links b + c of a WoodenHaptics, hfab_math.h) bounds how far the handle
    // can be from the workspace origin.
    const REACH_M: f64 = 0.45;
    DeviceInfo {
        model: model
            .map(WoodyModel::name)
            .unwrap_or("WoodenHaptics family (Teensy firmware)")
            .to_owned(),
        serial_number: String::new(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        // The box the handle can physically reach (the host rejects positions outside it): the links' full
        // reach around the workspace origin, not the usable sphere of `radius`, which only sizes fitting.
        workspace_min_m: DVec3::splat(-(radius + REACH_M)),
        workspace_max_m: DVec3::splat(radius + REACH_M),
        max_force_n: kinematics.max_force_n,
        max_stiffness_n_per_m: kinematics.max_stiffness_n_per_m,
        max_speed_m_per_s: crate::info::DEFAULT_MAX_SPEED_M_PER_S,
        reports_velocity: false,
        state_rates_hz: Vec::new(),
    }
}

impl<T: ByteTransport> HapticDevice for WoodenHapticsSerial<T> {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Discards stale input, then sends zero currents until a report arrives (the model is read from it).
    fn open(&mut self) -> Result<(), DeviceError> {
        self.transport.discard_input()?;
        self.line_len = 0;
        self.model = None;
        // Surplus counts from this open (the supervisor sums over links).
        self.surplus = SurplusCount::default();
        self.theta = None;
        self.candidate = None;
        self.awaiting_reply = false;
        let mut last_error = None;
        for _ in 0..self.config.hello_attempts.max(1) {
            self.send_currents([0; 3])?;
            match self.read_line(self.config.hello_timeout) {
                Ok(Some(report)) => match self.accept(report) {
                    Ok(_) => return Ok(()),
                    Err(error) => last_error = Some(error),
                },
                Ok(None) => {}
                Err(error) => last_error = Some(error),
            }
        }
        Err(last_error.unwrap_or(DeviceError::Timeout {
            waited_us: u64::try_from(self.config.hello_timeout.as_micros()).unwrap_or(u64::MAX)
                * u64::from(self.config.hello_attempts.max(1)),
            waiting_for: "a WoodenHaptics report (is the Teensy firmware running?)",
        }))
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        if !force_n.is_finite() {
            return Err(DeviceError::InvalidData {
                what: "force is not finite (the safety pipeline should have zeroed it)",
            });
        }
        self.drain_waiting()?;
        // Only a pose the host accepted converts force; none yet means zero.
        let currents = match self.theta {
            Some(theta) => self
                .kinematics
                .currents_ma(theta, force_n, self.config.max_current_ma),
            None => [0; 3],
        };
        self.send_currents(currents)?;
        self.awaiting_reply = true;
        Ok(())
    }

    /// The reply to the last command, or the newest good line already waiting behind it (those extra lines are
    /// counted as surplus).
    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.candidate = None;
        let Some(report) = self.read_line(self.config.reply_timeout)? else {
            return Err(DeviceError::Timeout {
                waited_us: u64::try_from(self.config.reply_timeout.as_micros()).unwrap_or(u64::MAX),
                waiting_for: "a WoodenHaptics report line",
            });
        };
        self.awaiting_reply = false;
        let mut state = self.accept(report)?;
        // Lines already waiting behind the reply were not asked for; the newest good one is the freshest pose.
        let mut surplus = 0;
        for _ in 0..MAX_LINES_DRAINED {
            match self.read_line(Duration::ZERO) {
                Ok(Some(extra)) => {
                    surplus += 1;
                    if let Ok(newer) = self.accept(extra) {
                        state = newer;
                    }
                }
                Err(DeviceError::Protocol { .. }) => surplus += 1,
                Ok(None) => break,
                Err(error) => return Err(error),
            }
        }
        self.count_surplus(surplus);
        Ok(state)
    }

    fn input_checked(&mut self, accepted: bool) {
        match self.candidate.take() {
            Some(theta) if accepted => self.theta = Some(theta),
            _ => {}
        }
    }

    fn take_event(&mut self) -> Option<DeviceEvent> {
        self.event.take()
    }

    fn disable(&mut self) -> Result<(), DeviceError> {
        // The wrapper's zero current went out; read its reply so the next session starts clean. The firmware's
        // 100 ms watchdog cuts the amplifiers once messages stop.
        if self.awaiting_reply {
            let _ = self.read_line(self.config.reply_timeout);
            self.awaiting_reply = false;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_parse_like_the_firmware_prints_them() {
        // ino:108: "[%d,%d,%d,%d,%d,%d,%d,%d]\n"
        let report = parse_report(b"[3,100,-200,300,0,30,0,0]").unwrap();
        assert_eq!(report.model, 3);
        assert_eq!(report.encoders, [100, -200, 300, 0, 30, 0]);
        assert_eq!(report.error_code, 0);
        for bad in [
            &b"[3,1,2,3,4,5,6]"[..],
            b"[3,1,2,3,4,5,6,7,8]",
            b"3,1,2,3,4,5,6,7",
            b"[3,1,2,x,4,5,6,7]",
            b"[3,1,2,3,4,5,6,99999999999]",
            b"\xff",
        ] {
            assert!(parse_report(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn commands_format_like_the_firmware_expects() {
        // ino:124: "[%d,%d,%d]\n"
        let mut buf = [0u8; 40];
        let len = format_command([-6000, 0, 123], &mut buf);
        assert_eq!(&buf[..len], b"[-6000,0,123]\n");
        let len = format_command([i32::MIN, i32::MIN, i32::MIN], &mut buf);
        assert_eq!(len, 38);
    }

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
