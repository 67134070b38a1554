//! Haply 2DIY over USB serial: a planar pantograph on an Arduino-based board.
//!
//! Sources (public): HaplyHaptics/Haply-API-cpp `src/Haply/Board.cpp` (V2.1.0: every command is
//! `[communication type][device id][bytes...][f32 little-endian...]`; reset is type 0 with device id 0 and no
//! data; a reply is `[device id][f32 little-endian...]`) and `src/Haply/Device.cpp` (setup = type 1 with motor,
//! encoder, sensor and PWM parameter bytes then (offset, resolution) floats per encoder in port order; torques =
//! type 2 with one float per actuator in port order, answered by one angle in degrees per encoder in port order);
//! the 2DIY mounting used by the Haply examples and the HaplyHAPI Python package (PyPI, `HaplyHAPI.py`, whose
//! README defines CW = 0, CCW = 1): actuator 1 CCW on port 2, actuator 2 CW on port 1, encoder 1 CCW offset 241°
//! resolution 10752 on port 2, encoder 2 CW offset -61° resolution 10752 on port 1, device id 5; pantograph link
//! lengths l = 0.07 m, L = 0.09 m, base distance d = 0 (hardware version 2; 0.038 m on version 3).
//!
//! Kinematics (HaplyHAPI.py `Pantograph.forwardKinematics`): with motor angles θ1, θ2, the elbows are
//! A = l(cos θ1, sin θ1) and B = (d + l cos θ2, l sin θ2); the handle P is the intersection of the circles of radius
//! L about A and B on the far side, found from h = B - A, cos β = (|h|² + L² - L²)/(2 L |h|), h1 = L cos β h/|h| and
//! the perpendicular L sin β (-h1y, h1x)/|h1|. The Jacobian J follows from the same construction (η, ν there), and
//! torques are τ1 = J11 fx + J12 fy, τ2 = J21 fx + J22 fy (gain 1), scaled together so neither exceeds the
//! firmware's 0.123 N m per motor ([`FIRMWARE_MAX_TORQUE_N_M`]), which keeps the force's direction. The device is planar: z is reported as 0 and
//! the z force is dropped.
//!
//! Framing: a reply has no start marker or checksum, so a reply cut short (a timeout) or a late one would shift
//! every later reply by a few bytes. The driver therefore discards the port's input when it opens (stale bytes
//! from an earlier program) and again before the next command after any timeout or reply with a wrong device id,
//! so each exchange starts on a reply boundary. Bytes already waiting before a command when no reply is overdue
//! were not asked for (a board that answers twice, or streams): they are dropped (so replies never queue up and
//! the state is the reply to this tick's command, at most one tick old), counted in whole replies and reported
//! ([`DeviceEvent::Surplus`]).
//!
//! Which pose converts force: the Jacobian of the newest reply is a candidate until the host's input checks
//! accept that reply ([`HapticDevice::input_checked`]); force is turned into torques only with the Jacobian of
//! the newest accepted reply (after a rejected one, the last accepted), and before any reply was accepted the
//! torques are zero. Velocity is not measured: `read_state` reports zero and the
//! host's safety pipeline estimates it from positions.

use super::assemble::FixedAssembler;
use super::reply_age::ReplyAge;
use super::reply_book::{reply_book_methods, ReplyBook};
use crate::transport::ByteTransport;
use crate::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;
use std::time::Duration;

/// The firmware's limit per motor (N m). Haply's board firmware (`create_torque` in Haply_Arduino_Control.h,
/// V0.1.0, S. Ding and C. Gallacher, and the same function in the M0 board firmware) takes |τ|, clamps it at
/// 0.123 and sets the PWM duty 4095·|τ|/0.123, each motor on its own: a pair with one motor over the limit would
/// come out in another ratio, so the force would change direction. [`saturate_torques`] scales the pair first.
pub const FIRMWARE_MAX_TORQUE_N_M: f64 = 0.123;

/// Scales the motor torque pair `tau` together so that neither exceeds `limit_n_m` (N m), keeping their ratio
/// and so the direction of the force they render; a pair within the limit is returned unchanged.
pub fn saturate_torques(tau: [f64; 2], limit_n_m: f64) -> [f64; 2] {
    let largest = tau[0].abs().max(tau[1].abs());
    if largest > limit_n_m {
        let scale = limit_n_m / largest;
        [tau[0] * scale, tau[1] * scale]
    } else {
        tau
    }
}

/// Communication type of the reset command.
pub const RESET: u8 = 0;
/// Communication type of the setup command.
pub const SETUP: u8 = 1;
/// Communication type of the torque command (answered with angles).
pub const TORQUES: u8 = 2;
/// Direction code for clockwise.
pub const CW: u8 = 0;
/// Direction code for counter-clockwise.
pub const CCW: u8 = 1;

/// The 2DIY's setup and mechanism.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Haply2DiyConfig {
    /// Device id sent in every command and echoed in replies.
    pub device_id: u8,
    /// Rotation direction of the actuators on ports 1 and 2.
    pub actuator_direction: [u8; 2],
    /// Rotation direction of the encoders on ports 1 and 2.
    pub encoder_direction: [u8; 2],
    /// Encoder offsets on ports 1 and 2 (degrees).
    pub encoder_offset_deg: [f32; 2],
    /// Encoder resolutions on ports 1 and 2 (steps per revolution).
    pub encoder_resolution: [f32; 2],
    /// Proximal link length l (m).
    pub proximal_link_m: f64,
    /// Distal link length L (m).
    pub distal_link_m: f64,
    /// Distance between the motor axes d (m).
    pub base_distance_m: f64,
    /// Largest force (N), for the capability record.
    pub max_force_n: f64,
}

impl Default for Haply2DiyConfig {
    /// Hardware version 2 (metal plate), as in the Haply examples.
    fn default() -> Self {
        Haply2DiyConfig {
            device_id: 5,
            // Port 1 holds actuator/encoder 2 (CW), port 2 holds actuator/encoder 1 (CCW).
            actuator_direction: [CW, CCW],
            encoder_direction: [CW, CCW],
            encoder_offset_deg: [-61.0, 241.0],
            encoder_resolution: [10752.0, 10752.0],
            proximal_link_m: 0.07,
            distal_link_m: 0.09,
            base_distance_m: 0.0,
            max_force_n: 2.0,
        }
    }
}

impl Haply2DiyConfig {
    /// The reset command.
    pub fn reset_command() -> [u8; 2] {
        [RESET, 0]
    }

    /// The setup command: `[1, id, motor params, encoder params, sensor params, pwm params, floats]` with both
    /// ports used (control mask 0b0011), no analogue sensors, no PWM pins.
    pub fn setup_command(&self) -> [u8; 26] {
        let mut out = [0u8; 26];
        out[..10].copy_from_slice(&[
            SETUP,
            self.device_id,
            0b0011,
            self.actuator_direction[0],
            self.actuator_direction[1],
            0b0011,
            self.encoder_direction[0],
            self.encoder_direction[1],
            0,
            0,
        ]);
        let floats = [
            self.encoder_offset_deg[0],
            self.encoder_resolution[0],
            self.encoder_offset_deg[1],
            self.encoder_resolution[1],
        ];
        for (i, value) in floats.iter().enumerate() {
            out[10 + 4 * i..14 + 4 * i].copy_from_slice(&value.to_le_bytes());
        }
        out
    }

    /// The torque command for motor torques `tau` (actuators 1 and 2): port order puts actuator 2 first.
    pub fn torque_command(&self, tau: [f32; 2]) -> [u8; 10] {
        let mut out = [0u8; 10];
        out[0] = TORQUES;
        out[1] = self.device_id;
        out[2..6].copy_from_slice(&tau[1].to_le_bytes());
        out[6..10].copy_from_slice(&tau[0].to_le_bytes());
        out
    }

    /// Parses a 9-byte reply into motor angles (θ1, θ2) in degrees (port order puts encoder 2 first).
    pub fn parse_reply(&self, reply: &[u8; 9]) -> Result<[f32; 2], DeviceError> {
        if reply[0] != self.device_id {
            return Err(DeviceError::Protocol {
                what: "Haply reply carries another device id",
            });
        }
        let port1 = f32::from_le_bytes([reply[1], reply[2], reply[3], reply[4]]);
        let port2 = f32::from_le_bytes([reply[5], reply[6], reply[7], reply[8]]);
        if !port1.is_finite() || !port2.is_finite() {
            return Err(DeviceError::InvalidData {
                what: "Haply reply holds a non-finite angle",
            });
        }
        Ok([port2, port1])
    }

    /// Handle position (m, in the device plane) and the Jacobian rows [[J11, J12], [J21, J22]] at motor angles
    /// (degrees). `None` where the links cannot meet (a reading outside the mechanism's reach).
    pub fn kinematics(&self, angles_deg: [f32; 2]) -> Option<([f64; 2], [[f64; 2]; 2])> {
        let (l, big_l, d) = (
            self.proximal_link_m,
            self.distal_link_m,
            self.base_distance_m,
        );
        let th1 = f64::from(angles_deg[0]).to_radians();
        let th2 = f64::from(angles_deg[1]).to_radians();
        let (s1, c1) = th1.sin_cos();
        let (s2, c2) = th2.sin_cos();
        let (xa, ya) = (l * c1, l * s1);
        let (xb, yb) = (d + l * c2, l * s2);
        let (hx, hy) = (xb - xa, yb - ya);
        let hm = (hx * hx + hy * hy).sqrt();
        if hm.is_nan() || hm <= 0.0 || hm > 2.0 * big_l {
            return None;
        }
        // Equal distal links: cos β = |h| / (2 L).
        let cos_b = hm / (2.0 * big_l);
        let (h1x, h1y) = (big_l * cos_b * hx / hm, big_l * cos_b * hy / hm);
        let h1m = (h1x * h1x + h1y * h1y).sqrt();
        let sin_b = (1.0 - cos_b * cos_b).max(0.0).sqrt();
        let (lx, ly) = if h1m > 0.0 {
            (-big_l * sin_b * h1y / h1m, big_l * sin_b * h1x / h1m)
        } else {
            (0.0, 0.0)
        };
        let (xp, yp) = (xa + h1x + lx, ya + h1y + ly);
        let phi1 = ((xp - l * c1) / big_l).clamp(-1.0, 1.0).acos();
        let phi2 = ((xp - d - l * c2) / big_l).clamp(-1.0, 1.0).acos();
        let (s11, c11) = phi1.sin_cos();
        let (s22, c22) = phi2.sin_cos();
        let dn = big_l * (c11 * s22 - c22 * s11);
        let (eta, nu) = if dn == 0.0 {
            (0.0, 0.0)
        } else {
            (
                (-big_l * c11 * s22 + big_l * c22 * s11 - c1 * l * s22 + c22 * l * s1) / dn,
                l * (c2 * s22 - c22 * s2) / dn,
            )
        };
        let jacobian = [
            [
                -big_l * eta * s11 - big_l * s11 - l * s1,
                big_l * c11 * eta + big_l * c11 + c1 * l,
            ],
            [-big_l * s11 * nu, big_l * c11 * nu],
        ];
        let position = [xp, yp];
        let finite = position
            .iter()
            .chain(jacobian.iter().flatten())
            .all(|v| v.is_finite());
        finite.then_some((position, jacobian))
    }
}

/// A Haply 2DIY on a byte transport.
#[derive(Debug)]
pub struct Haply2Diy<T> {
    transport: T,
    config: Haply2DiyConfig,
    info: DeviceInfo,
    /// The Jacobians (the newest reply's until the host's verdict, the newest accepted: the only one force is
    /// converted with), surplus replies, and how old the reply handed out may be ([`ReplyAge`]: more than 0
    /// after missed replies or bytes nobody asked for).
    book: ReplyBook<[[f64; 2]; 2], ReplyAge>,
    reply_timeout: Duration,
    /// Set after a timeout or a shifted reply: the input holds (or may soon hold) the rest of an old reply.
    resync_needed: bool,
    resyncs: u64,
    /// The receive core: bytes in, 9-byte replies out (no I/O).
    replies: FixedAssembler<9>,
}

impl<T: ByteTransport> Haply2Diy<T> {
    /// A driver on `transport` (open it at 0 baud for USB CDC, as the Haply examples do; the rate is ignored).
    pub fn new(transport: T, config: Haply2DiyConfig) -> Self {
        let reach = config.proximal_link_m + config.distal_link_m;
        let info = DeviceInfo {
            position_dof: 2,
            force_dof: 2,
            max_force_n: config.max_force_n,
            ..DeviceInfo::basic(
                "Haply 2DIY",
                DVec3::new(-reach, 0.0, 0.0),
                DVec3::new(reach + config.base_distance_m, reach, 0.0),
            )
        };
        Haply2Diy {
            transport,
            config,
            info,
            book: ReplyBook::new(),
            reply_timeout: super::reply_age::DEFAULT_REPLY_WAIT,
            resync_needed: false,
            resyncs: 0,
            replies: FixedAssembler::new(),
        }
    }

    /// How long `read_state` waits for the board's reply: [`reply_wait`](super::reply_age::reply_wait) of the
    /// servo period, so a lost reply costs at most one tick (the 1 kHz value,
    /// [`DEFAULT_REPLY_WAIT`](super::reply_age::DEFAULT_REPLY_WAIT), unless set here).
    pub fn with_reply_timeout(mut self, reply_timeout: Duration) -> Self {
        self.reply_timeout = reply_timeout;
        self
    }

    /// Replies the board sent that no command asked for (counted in whole replies), dropped.
    pub fn surplus_replies(&self) -> u64 {
        self.book.surplus_total()
    }

    /// Drops whatever is waiting before a command. Without an overdue reply, those bytes were not asked for.
    fn drain_waiting(&mut self) -> Result<(), DeviceError> {
        if self.resync_needed {
            // The timed-out or shifted reply is thrown away with whatever came with it (or comes later, and is
            // then taken for the next: either way the next reply may be a tick old).
            self.transport.discard_input()?;
            self.replies.clear();
            self.resync_needed = false;
            self.resyncs += 1;
            self.book.age.late_reply_dropped();
            return Ok(());
        }
        let mut scratch = [0u8; 64];
        let mut bytes = 0u64;
        // Bounded (64 KiB), so a board that never stops talking cannot hold the tick.
        while bytes < 65_536 {
            let n = self.transport.read(&mut scratch, Duration::ZERO)?;
            if n == 0 {
                break;
            }
            bytes += n as u64;
        }
        if bytes > 0 {
            self.book.age.surplus_dropped();
            self.book.count_surplus(bytes.div_ceil(9));
        }
        Ok(())
    }

    /// How many times the driver discarded input to get back onto a reply boundary.
    pub fn resync_count(&self) -> u64 {
        self.resyncs
    }

    /// The transport (to check a scripted double with `done()`).
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// The next 9-byte reply within the reply wait (the shared runner, [`super::exchange::receive_within`], over
    /// the receive core [`FixedAssembler`]).
    fn read_reply(&mut self) -> Result<[u8; 9], DeviceError> {
        let reply = super::exchange::receive_within(
            &mut self.transport,
            &mut self.replies,
            self.reply_timeout,
            |replies| Ok(replies.next_reply()),
        )?;
        reply.ok_or_else(|| {
            // The rest of this reply (or all of it) may still arrive: drop it before the next command.
            self.resync_needed = true;
            DeviceError::Timeout {
                waited_us: u64::try_from(self.reply_timeout.as_micros()).unwrap_or(u64::MAX),
                waiting_for: "the Haply board's angle reply",
            }
        })
    }
}

impl<T: ByteTransport> HapticDevice for Haply2Diy<T> {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn open(&mut self) -> Result<(), DeviceError> {
        // Stale angle replies from an earlier program would shift every reply of this session.
        self.transport.discard_input()?;
        self.replies.clear();
        self.resync_needed = false;
        self.book.opened();
        self.transport
            .write_all(&Haply2DiyConfig::reset_command())?;
        self.transport.write_all(&self.config.setup_command())
    }

    /// Sends the torques for `force_n` (z dropped). The board answers with the angles, read by `read_state`.
    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        DeviceError::check_finite_force(force_n.to_array())?;
        self.drain_waiting()?;
        // Only a pose the host accepted converts force; none yet means zero torque.
        self.book.age.command_sent();
        let Some([[j11, j12], [j21, j22]]) = self.book.accepted() else {
            return self
                .transport
                .write_all(&self.config.torque_command([0.0, 0.0]));
        };
        let [tau1, tau2] = saturate_torques(
            [
                j11 * force_n.x + j12 * force_n.y,
                j21 * force_n.x + j22 * force_n.y,
            ],
            FIRMWARE_MAX_TORQUE_N_M,
        );
        // `+ 0.0` turns a -0.0 (a zero force through a negative Jacobian entry) into the plain zero the board expects.
        let command = self
            .config
            .torque_command([tau1 as f32 + 0.0, tau2 as f32 + 0.0]);
        self.transport.write_all(&command)
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.book.reading_begins();
        let reply = self.read_reply()?;
        self.book.age.reply_read();
        let angles = self.config.parse_reply(&reply).inspect_err(|_| {
            // A wrong id or a non-finite angle: most likely a reply shifted by lost or extra bytes.
            self.resync_needed = true;
        })?;
        let Some((position, jacobian)) = self.config.kinematics(angles) else {
            return Err(DeviceError::InvalidData {
                what: "Haply angles put the pantograph links out of reach",
            });
        };
        self.book.propose(jacobian);
        Ok(DeviceState::at_rest(DVec3::new(
            position[0],
            position[1],
            0.0,
        )))
    }

    reply_book_methods!(crate::latency::HAPLY_2DIY);

    fn disable(&mut self) -> Result<(), DeviceError> {
        // The board keeps its last torque: the wrapper's zero force went out; drain its angle reply.
        self.read_reply().map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::{saturate_torques, FIRMWARE_MAX_TORQUE_N_M};

    /// Worked by hand: a pair twice over the limit on motor 1 is halved (its ratio, -4, kept); a pair within the
    /// limit passes unchanged. Clamping each motor on its own, as the firmware does, would give (0.123, -0.0615):
    /// ratio -2, another direction.
    #[test]
    fn the_pair_is_scaled_together() {
        let [a, b] = saturate_torques([0.246, -0.0615], FIRMWARE_MAX_TORQUE_N_M);
        assert!(
            (a - 0.123).abs() < 1e-12 && (b + 0.030_75).abs() < 1e-12,
            "{a} {b}"
        );
        assert_eq!(saturate_torques([0.1, -0.05], 0.123), [0.1, -0.05]);
        let [a, b] = saturate_torques([-0.01, 0.5], 0.123);
        assert!(
            (b - 0.123).abs() < 1e-12 && (a + 0.00246).abs() < 1e-12,
            "{a} {b}"
        );
    }
}
