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
//! Gravity compensation as hfabapi does it: off for models 2 and 3 (`g_constant` 0 in their configurations,
//! hfab_math.h), Polhem's direct four-body compensation always on (hfab_polhem.h:276-333,
//! [`super::woodenhaptics_gravity`]), added to Jᵀ f, so a released Polhem holds its pose instead of dropping:
//! while the host asks for zero force the motors still carry the arm's weight (the firmware's 100 ms watchdog
//! cuts the amplifiers when messages stop).
//!
//! Not implemented: the gimbal encoders 3-5 (reported by the firmware, not used: voxhap renders 3-DOF forces).
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
//! command, so positions never queue up; its age ([`HapticDevice::state_age_ticks`], see
//! [`super::reply_age`]) is the oldest it may be: 0 in lockstep, more after missed replies or lines nobody asked
//! for (a second answer may have slipped in behind the drain), and the supervisor's staleness bound
//! (`stale_state_ticks`) counts from there.
//!
//! Frame: hfabapi's device frame in metres with its workspace origin subtracted (for a WoodenHaptics: x forward
//! from the base axis, y to the side, z up). The supervisor's safety pipeline bounds the force; this driver also
//! scales the three currents together so none exceeds [`MAX_CURRENT_MA`] (keeping the force's direction, as
//! libnifalcon does for the Falcon), where the firmware would zero a single motor.

use super::assemble::{Line, LineAssembler};
use super::reply_age::ReplyAge;
use super::reply_book::{reply_book_methods, ReplyBook};
use super::woodenhaptics_constants::WoodenHapticsConstants;
use crate::transport::ByteTransport;
use crate::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;
use std::io::Write as _;
use std::time::Duration;

pub use super::woodenhaptics_kinematics::{Chain, WoodyKinematics, FIRMWARE_MAX_CURRENT_MA};
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
    /// How long `read_state` waits for the reply line: [`reply_wait`](super::reply_age::reply_wait) of the
    /// servo period, so a lost reply costs at most one tick.
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
            reply_timeout: super::reply_age::DEFAULT_REPLY_WAIT,
            hello_timeout: Duration::from_millis(100),
            hello_attempts: 5,
            max_current_ma: MAX_CURRENT_MA,
            kinematics_override: None,
            model_constants: [WoodenHapticsConstants::default(); 3],
        }
    }
}

impl WoodyConfig {
    /// The defaults for a servo loop of `period` (the reply wait derived from it).
    pub fn for_period(period: Duration) -> WoodyConfig {
        WoodyConfig {
            reply_timeout: super::reply_age::reply_wait(period),
            ..WoodyConfig::default()
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
    /// The joint angles (the newest report's until the host's verdict, the newest accepted: the only pose
    /// force is converted with), surplus lines, and how old the reply handed out may be ([`ReplyAge`]: more
    /// than 0 after missed replies or lines nobody asked for).
    book: ReplyBook<[f64; 3], ReplyAge>,
    /// The receive core: bytes in, report lines out (no I/O).
    lines: LineAssembler<256>,
    last_report: Option<WoodyReport>,
    awaiting_reply: bool,
    late_replies: u64,
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
            book: ReplyBook::new(),
            lines: LineAssembler::new(),
            last_report: None,
            awaiting_reply: false,
            late_replies: 0,
        }
    }

    /// Lines the device sent that no command asked for (second answers, floods), dropped.
    pub fn surplus_replies(&self) -> u64 {
        self.book.surplus_total()
    }

    /// Replies that came after their read had timed out, dropped before the next command.
    pub fn late_replies(&self) -> u64 {
        self.late_replies
    }

    /// Joint angles force is converted with: the newest report the host accepted (`None` before the first).
    pub fn conversion_angles(&self) -> Option<[f64; 3]> {
        self.book.accepted()
    }

    fn count_surplus(&mut self, n: u64) {
        if n > 0 {
            self.book.age.surplus_dropped();
        }
        self.book.count_surplus(n);
    }

    /// Drops every complete line already waiting, without blocking: a reply whose read timed out (late), or
    /// lines nobody asked for (surplus). More than [`MAX_LINES_DRAINED`] lines: the rest is discarded at once.
    fn drain_waiting(&mut self) -> Result<(), DeviceError> {
        let mut surplus = 0;
        let mut lines = 0;
        loop {
            if lines == MAX_LINES_DRAINED {
                self.transport.discard_input()?;
                self.lines.clear();
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
                self.book.age.late_reply_dropped();
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

    /// Reads one line (up to `\n`) within `timeout` (the shared runner, [`super::exchange::receive_within`], over
    /// the receive core [`LineAssembler`]). `Ok(None)` on timeout (a partial line is kept for the next call). A
    /// line longer than the buffer is dropped and reported.
    fn read_line(&mut self, timeout: Duration) -> Result<Option<WoodyReport>, DeviceError> {
        super::exchange::receive_within(&mut self.transport, &mut self.lines, timeout, |lines| {
            match lines.next_line() {
                None => Ok(None),
                Some(Line::Whole(line)) => parse_report(line).map(Some),
                Some(Line::TooLong) => Err(DeviceError::Protocol {
                    what: "WoodenHaptics sent a line longer than 256 bytes",
                }),
            }
        })
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
        self.book.propose(theta);
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
        max_force_n: kinematics.max_force_n,
        max_stiffness_n_per_m: kinematics.max_stiffness_n_per_m,
        // The box the handle can physically reach (the host rejects positions outside it): the links' full
        // reach around the workspace origin, not the usable sphere of `radius`, which only sizes fitting.
        ..DeviceInfo::basic(
            model
                .map(WoodyModel::name)
                .unwrap_or("WoodenHaptics family (Teensy firmware)"),
            DVec3::splat(-(radius + REACH_M)),
            DVec3::splat(radius + REACH_M),
        )
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
        self.lines.clear();
        self.model = None;
        self.book.opened();
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
        DeviceError::check_finite_force(force_n.to_array())?;
        self.drain_waiting()?;
        // Only a pose the host accepted converts force; none yet means zero.
        let currents = match self.book.accepted() {
            Some(theta) => self
                .kinematics
                .currents_ma(theta, force_n, self.config.max_current_ma),
            None => [0; 3],
        };
        self.send_currents(currents)?;
        self.awaiting_reply = true;
        self.book.age.command_sent();
        Ok(())
    }

    /// The reply to the last command, or the newest good line already waiting behind it (those extra lines are
    /// counted as surplus).
    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.book.reading_begins();
        let Some(report) = self.read_line(self.config.reply_timeout)? else {
            return Err(DeviceError::Timeout {
                waited_us: u64::try_from(self.config.reply_timeout.as_micros()).unwrap_or(u64::MAX),
                waiting_for: "a WoodenHaptics report line",
            });
        };
        self.awaiting_reply = false;
        self.book.age.reply_read();
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

    reply_book_methods!(crate::latency::WOODENHAPTICS_SERIAL);

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
}
