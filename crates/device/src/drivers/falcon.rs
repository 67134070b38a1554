//! Novint Falcon through the FTDI serial port Linux's `ftdi_sio` driver exposes (`/dev/ttyUSBn`):
//! `--device falcon[:SERIAL|:PATH][,firmware=FILE]`.
//!
//! Where it sits: a [`HapticDevice`] on a [`FalconPort`] (a [`SerialTransport`] on real hardware, a
//! pseudo-terminal or an in-memory pipe in tests), under the supervisor's safety pipeline.
//!
//! Sources (libnifalcon/libnifalcon, BSD; cited as FILE:LINE):
//! - Frames, 16 bytes both ways (src/firmware/FalconFirmwareNovintSDK.cpp:40-97): `<`, 12 bytes carrying three
//!   16-bit values as four nibbles each, least significant first, every nibble plus 0x41, one control/status
//!   byte (plus 0x41), one unused byte (0x41), `>`. Host to device: the values are motor commands; the control
//!   byte holds the LED bits (green 0x2, blue 0x4, red 0x8; include/falcon/core/FalconFirmware.h:68-70) and the
//!   homing-mode request in bit 0 (FalconFirmwareNovintSDK.cpp:92-93). Device to host: the values are the three
//!   encoder counts (signed 16-bit), the status byte's bits 4-6 the homing state of motors 1-3, its low nibble
//!   the grip (FalconFirmwareNovintSDK.cpp:51-62); the device answers each frame with one frame.
//! - Homing (include/falcon/core/FalconFirmware.h:50-61): the homing-mode bit must be set in every frame for the
//!   Falcon to stay homed; the user pulls the grip all the way out and pushes it in, until the three homing bits
//!   are set; becoming homed resets the coordinate system, so no torque may be computed from positions before.
//!   voxhap sets the bit in every frame, sends zero torque and lights the red LED until homed, then green, and
//!   restarts its position estimate at the moment the Falcon becomes homed. States before homing have an
//!   unknown age, so the supervisor sends zero and enables, with its ramp-in, only once the Falcon is homed.
//! - Kinematics (R. E. Stamper's delta-robot analysis as libnifalcon implements it,
//!   src/kinematic/FalconKinematicStamper.cpp): leg angle from encoder counts
//!   θ = count · (π·0.01425 / (320·4)) / (π·0.110/360) + 35° (include/falcon/core/FalconKinematic.h:59-62,
//!   constants include/falcon/core/FalconGeometry.h:20-36); inverse kinematics per leg (IK, :28-94); the
//!   Jacobian of joint rates by handle velocity, inverted (:101-142); forward kinematics by Newton steps on that
//!   Jacobian from the previous position, step 0.5 halved on overshoot, stopping below 0.01 rad or after 15
//!   tries (:149-225); torques τ = (J⁻¹)ᵀ f, scaled together so none exceeds 30, times 10 000, negated
//!   (:227-281).
//! - Firmware upload (src/core/FalconFirmware.cpp:89-167 and the libusb port's mode switches,
//!   src/comm/FalconCommLibUSB.cpp:367-583), done here with termios on the `ftdi_sio` port: purge both
//!   queues; 9600 baud 8N1, no flow control, RTS low, DTR low then high; send `0a 43 0d` until the bootloader
//!   answers `0a 44 2c 0d` (up to 100 tries; libusb also sees FTDI's two status bytes, which `ftdi_sio`
//!   removes); DTR low; FTDI divisor 0x15 (3 MHz / 21 = 142 857 baud; libnifalcon calls it 140 000); send `A`,
//!   expect `A`; then the file in 62-byte pieces, each echoed back and compared; then normal mode: FTDI divisor
//!   2 (1 500 000 baud) and both queues purged. The FTDI latency timer is set as libnifalcon sets it (16 ms
//!   while loading, 1 ms after; FalconCommLibUSB.cpp:407-413, :560-564) through `ftdi_sio`'s sysfs attribute
//!   `latency_timer` where voxhap may write it ([`ftdi_latency`]; contrib/udev/70-voxhap.rules sets 1 ms at
//!   plug-in), and `open` refuses a timer above 1 ms with a message naming the value and the fix.
//!
//! Which pose converts force: the position the forward kinematics found for the newest frame is a candidate
//! until the host's input checks accept it ([`HapticDevice::input_checked`]); torques are computed only at the
//! newest accepted position. After a rejected frame (an encoder glitch, a jump) the driver keeps the last
//! accepted position, and restarts its forward-kinematics guess there; before any position was accepted, and
//! again after homing resets the coordinates, it sends zero torque.
//!
//! Late replies (libnifalcon waits for each reply before it sends the next frame,
//! src/firmware/FalconFirmwareNovintSDK.cpp:113-154; the reply comes 1-2 ms after its command,
//! [`crate::latency::FALCON`], later than the wait of a 1 kHz tick): voxhap sends a command every tick
//! anyway and counts the commands whose replies are still to come ([`super::in_flight::InFlight`]). The Falcon
//! answers each frame with one frame, in order ("16 bytes sent to the Falcon causes 16 bytes to be returned",
//! include/falcon/firmware/FalconFirmwareNovintSDK.h:29), so the frame read answers the oldest of them, and the
//! state it gives is as many ticks old as commands went out after it. Before each command the driver takes
//! every frame already waiting and holds the newest reply; if this tick's wait brings nothing newer, the held
//! reply is the tick's state (one tick old at 1-2 ms latency and 1 kHz) rather than a miss. Frames no command
//! asked for are dropped, counted and reported ([`DeviceEvent::Surplus`]), and the next state counts a tick
//! older.
//!
//! When the count cannot be trusted, the driver resynchronises instead of guessing: bytes that are not a
//! well-formed frame (a garbled reply and junk that answers nothing look alike), a reply still missing
//! [`LOST_REPLY_AFTER`] after its command, or ages above [`RESYNC_AGE_TICKS`] for that long (lost replies
//! inflate the count for as long as the stream runs). Then every state's age is unknown
//! ([`super::in_flight::UNKNOWN_AGE`], older than any staleness bound, so the supervisor sends zero), the
//! driver sends one zero-torque frame and then none, and hands out the newest frame it has (its age unknown)
//! until no byte has come for [`LOST_REPLY_AFTER`]; then nothing is owed and counting starts from zero. A
//! stream still corrupt after [`RESYNC_GIVE_UP`] is a protocol error every tick, so the supervisor drops the
//! link and reopens it. Open, too, waits for a quiet link after its first exchange before it counts.

//! The firmware file is Novint's (for example `test_firmware.bin` of their SDK); voxhap never ships it.

pub use super::falcon_frames::{
    decode_reply, encode_command, FalconReply, FrameAssembler, ALL_HOMED, FRAME_LEN, HOMING_MODE,
    LED_BLUE, LED_GREEN, LED_RED,
};
pub use super::falcon_kinematics::{
    forward_kinematics, inverse_kinematics, jacobian_inverse, leg_angle_rad, motor_commands,
    FalconGeometry, LegAngles,
};
use super::in_flight::{InFlight, NextCommand, UNKNOWN_AGE};
use super::reply_book::{reply_book_methods, ReplyBook};
use crate::transport::{ftdi_latency, ByteTransport, SerialTransport};
use crate::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;
use std::time::{Duration, Instant};

/// USB vendor id of the Falcon's FTDI chip.
pub const VENDOR_ID: u16 = 0x0403;
/// USB product id of the Falcon.
pub const PRODUCT_ID: u16 = 0xcb48;
/// Baud rate in normal mode (FTDI divisor 2).
pub const NORMAL_BAUD: u32 = 1_500_000;
/// Baud rate of the bootloader check (FalconCommLibUSB.cpp:423-424).
pub const BOOTLOADER_CHECK_BAUD: u32 = 9_600;
/// Baud rate of the firmware upload (FTDI divisor 0x15).
pub const UPLOAD_BAUD: u32 = 142_857;
/// How long after its command a reply that has not come may never come (25 times the link's worst latency,
/// [`crate::latency::FALCON`], 2 ms): a reply missing this long starts a resynchronisation (it is never written
/// off, which would make a late reply look younger than it is), and the link must be this long without a byte
/// before counting starts again. Meanwhile each missing reply makes the states look a tick older than they are
/// (the safe direction).
pub const LOST_REPLY_AFTER: Duration = Duration::from_millis(50);

/// States the count says are older than this many ticks for [`LOST_REPLY_AFTER`] start a resynchronisation:
/// the supervisor's default staleness bound (3 periods, docs/safety.md), above which they drive no force anyway.
pub const RESYNC_AGE_TICKS: u32 = 3;

/// A resynchronisation not done after this long (bytes kept coming that are not frames) is a protocol error on
/// every read, so the supervisor drops the link and reopens it.
pub const RESYNC_GIVE_UP: Duration = Duration::from_millis(200);

/// Bytes per firmware piece (FalconFirmware.cpp:115).
pub const UPLOAD_CHUNK: usize = 62;

/// A byte stream that can also change its line settings (baud rate, modem lines, queues, the FTDI latency
/// timer), as the firmware upload needs. A serial port does it through termios and sysfs; a test double must
/// model what a wrong setting does (the bootloader does not answer at another baud rate).
pub trait FalconPort: ByteTransport {
    /// Sets the baud rate.
    fn set_baud(&mut self, baud: u32) -> Result<(), DeviceError>;
    /// Sets DTR and RTS.
    fn set_modem(&mut self, dtr: bool, rts: bool) -> Result<(), DeviceError>;
    /// Throws away both queues: bytes the host has not sent yet and bytes the device sent (libnifalcon purges
    /// RX and TX before the firmware load and after it, src/comm/FalconCommLibUSB.cpp:393-402 and :571-580).
    fn purge(&mut self) -> Result<(), DeviceError>;
    /// Sets the FTDI latency timer (ms); false when the port has none or it may not be set here
    /// ([`ftdi_latency`]).
    fn set_latency_timer(&mut self, ms: u8) -> Result<bool, DeviceError>;
    /// Checks the FTDI latency timer is at most 1 ms: an error naming the value and the fix otherwise. A port
    /// without one passes.
    fn check_latency_timer(&self) -> Result<(), DeviceError>;
}

impl FalconPort for SerialTransport {
    fn set_baud(&mut self, baud: u32) -> Result<(), DeviceError> {
        self.set_baud_rate(baud)
    }
    fn set_modem(&mut self, dtr: bool, rts: bool) -> Result<(), DeviceError> {
        self.set_modem_lines(dtr, rts)
    }
    fn purge(&mut self) -> Result<(), DeviceError> {
        self.purge_both()
    }
    fn set_latency_timer(&mut self, ms: u8) -> Result<bool, DeviceError> {
        match self
            .name()
            .and_then(|name| ftdi_latency::attribute_for(&name))
        {
            Some(attribute) => ftdi_latency::try_set_ms(&attribute, ms),
            None => Ok(false),
        }
    }
    fn check_latency_timer(&self) -> Result<(), DeviceError> {
        match self
            .name()
            .and_then(|name| ftdi_latency::attribute_for(&name))
        {
            Some(attribute) => ftdi_latency::check_normal(&attribute),
            None => Ok(()),
        }
    }
}

fn read_exact_within<T: ByteTransport + ?Sized>(
    port: &mut T,
    buf: &mut [u8],
    timeout: Duration,
) -> Result<usize, DeviceError> {
    let deadline = Instant::now() + timeout;
    let mut filled = 0;
    while filled < buf.len() {
        let remaining = deadline.saturating_duration_since(Instant::now());
        if remaining.is_zero() {
            break;
        }
        let n = port.read(&mut buf[filled..], remaining)?;
        if n == 0 {
            break;
        }
        filled += n;
    }
    Ok(filled)
}

/// A [`DeviceError::Protocol`]: the Falcon (or its bootloader) did not answer as its protocol says.
fn protocol_error(what: &'static str) -> DeviceError {
    DeviceError::Protocol { what }
}

/// Uploads `firmware` (FalconFirmware.cpp:89-167, FalconCommLibUSB.cpp:367-583), leaving the port in normal
/// mode.
pub fn upload_firmware<P: FalconPort + ?Sized>(
    port: &mut P,
    firmware: &[u8],
) -> Result<(), DeviceError> {
    if firmware.is_empty() {
        return Err(DeviceError::Config {
            what: "the Falcon firmware file is empty".to_owned(),
        });
    }
    // FalconComm.h:47-55: purge, latency timer 16 ms ("otherwise firmware checks tend to always fail",
    // FalconCommLibUSB.cpp:407), 9600 8N1, RTS low, DTR low then high. Without permission to set the timer
    // (no root, the udev rule sets 1 ms) the load is tried anyway.
    port.purge()?;
    port.set_latency_timer(ftdi_latency::FIRMWARE_LOAD_MS)?;
    port.set_baud(BOOTLOADER_CHECK_BAUD)?;
    port.set_modem(false, false)?;
    port.set_modem(true, false)?;
    let expected = [0x0a, 0x44, 0x2c, 0x0d];
    let mut answered = false;
    for _ in 0..100 {
        port.write_all(&[0x0a, 0x43, 0x0d])?;
        let mut reply = [0u8; 8];
        let n = read_exact_within(port, &mut reply[..5], Duration::from_millis(100))?;
        if reply[..n].windows(4).any(|w| w == expected) {
            answered = true;
            break;
        }
    }
    if !answered {
        return Err(protocol_error(
            "the Falcon's bootloader did not answer the check (0a 43 0d -> 0a 44 2c 0d); \
             unplug the Falcon's USB and power, plug them in again, and retry",
        ));
    }
    port.set_modem(false, false)?;
    port.set_baud(UPLOAD_BAUD)?;
    port.write_all(b"A")?;
    let mut echo = [0u8; 1];
    if read_exact_within(port, &mut echo, Duration::from_millis(1000))? != 1 || echo[0] != b'A' {
        return Err(protocol_error(
            "the Falcon's bootloader did not echo 'A' at 142857 baud",
        ));
    }
    let mut back = [0u8; UPLOAD_CHUNK];
    for chunk in firmware.chunks(UPLOAD_CHUNK) {
        port.write_all(chunk)?;
        let got = read_exact_within(port, &mut back[..chunk.len()], Duration::from_millis(1000))?;
        if got != chunk.len() {
            return Err(protocol_error(
                "the Falcon stopped echoing the firmware during the upload",
            ));
        }
        if back[..got] != *chunk {
            return Err(protocol_error(
                "the Falcon echoed different firmware bytes (checksum mismatch)",
            ));
        }
    }
    // Normal mode (FalconComm.h:71-74): latency timer 1 ms, baud divisor 2, both queues purged.
    port.set_latency_timer(ftdi_latency::NORMAL_MS)?;
    port.set_baud(NORMAL_BAUD)?;
    port.purge()
}

/// Settings of the driver.
#[derive(Debug, Clone, PartialEq)]
pub struct FalconConfig {
    /// Firmware to upload when none is running (Novint's file; never shipped with voxhap).
    pub firmware: Option<std::path::PathBuf>,
    /// Longest wait for the frame answering a command (derived from the servo period:
    /// [`reply_wait`](super::reply_age::reply_wait)).
    pub reply_timeout: Duration,
    /// Largest force for the capability record (N); voxhap's choice.
    pub max_force_n: f64,
    /// Kinematic constants (libnifalcon's unless a device profile replaces some).
    pub geometry: FalconGeometry,
}

impl Default for FalconConfig {
    fn default() -> Self {
        FalconConfig {
            firmware: None,
            reply_timeout: super::reply_age::DEFAULT_REPLY_WAIT,
            max_force_n: 5.0,
            geometry: FalconGeometry::LIBNIFALCON,
        }
    }
}

impl FalconConfig {
    /// The defaults for a servo loop of `period`: a frame is waited for at most
    /// [`reply_wait`](super::reply_age::reply_wait)`(period)`, so a lost frame costs at most one tick.
    pub fn for_period(period: Duration) -> FalconConfig {
        FalconConfig {
            reply_timeout: super::reply_age::reply_wait(period),
            ..FalconConfig::default()
        }
    }
}

/// A Novint Falcon on a [`FalconPort`].
#[derive(Debug)]
pub struct Falcon<P> {
    port: P,
    config: FalconConfig,
    info: DeviceInfo,
    /// The forward kinematics' newest estimate (its next guess).
    position_m: DVec3,
    /// The positions (the newest frame's until the host's verdict, the newest accepted: the only one force is
    /// converted at), surplus frames, and the age (ticks) of the state handed out last ([`InFlight`]: the
    /// commands sent after the one its frame answers, one more after a frame nobody asked for).
    book: ReplyBook<DVec3, u32>,
    last_reply: Option<FalconReply>,
    /// The receive side's protocol state: bytes in, frames out (no I/O).
    frames: FrameAssembler,
    /// The newest reply the drain before a command found (it answers an earlier command): the state handed
    /// out when this tick's own reply has not come.
    held: Option<FalconReply>,
    /// The commands whose replies are still to come (the replies' ages).
    in_flight: InFlight,
    /// Malformed frames the assembler had dropped when last looked at.
    malformed_seen: u64,
    /// Bytes the assembler had taken when last looked at.
    received_seen: u64,
    /// The last frame written (or begun) carried a torque: [`HapticDevice::disable`] sends a zero one then,
    /// whatever the reply count's state, so the Falcon never keeps a torque once voxhap lets go of it.
    torque_on: bool,
}

impl<P: FalconPort> Falcon<P> {
    /// A driver on `port`.
    pub fn new(port: P, config: FalconConfig) -> Self {
        let info = DeviceInfo {
            model: "Novint Falcon".to_owned(),
            serial_number: String::new(),
            position_dof: 3,
            force_dof: 3,
            button_count: 4,
            workspace_min_m: DVec3::new(-0.06, -0.06, 0.075),
            workspace_max_m: DVec3::new(0.06, 0.06, 0.175),
            max_force_n: config.max_force_n,
            max_stiffness_n_per_m: 1000.0,
            max_speed_m_per_s: crate::info::DEFAULT_MAX_SPEED_M_PER_S,
            reports_velocity: false,
            state_rates_hz: Vec::new(),
        };
        Falcon {
            port,
            config,
            info,
            // libnifalcon's first guess (FalconKinematicStamper.cpp:20).
            position_m: DVec3::new(0.0, 0.0, 0.08),
            book: ReplyBook::new(),
            last_reply: None,
            frames: FrameAssembler::new(),
            held: None,
            in_flight: InFlight::new(LOST_REPLY_AFTER, RESYNC_AGE_TICKS),
            malformed_seen: 0,
            received_seen: 0,
            torque_on: false,
        }
    }

    /// Frames the Falcon sent that no command asked for, dropped.
    pub fn surplus_frames(&self) -> u64 {
        self.book.surplus_total()
    }

    /// The position torques are computed at: the newest the host accepted (`None` before the first).
    pub fn conversion_position(&self) -> Option<DVec3> {
        self.book.accepted()
    }

    /// Takes every frame already waiting before a command (bounded, so a flood cannot hold the tick): a
    /// reply to an earlier command is held as the newest state (its age counted by [`InFlight`]); a frame no
    /// command asked for is dropped, counted and reported.
    fn drain_waiting(&mut self) -> Result<(), DeviceError> {
        let mut surplus = 0;
        let mut emptied = false;
        for _ in 0..64 {
            let polled_at = Instant::now();
            let Some(frame) = self.read_frame(Duration::ZERO)? else {
                self.nothing_waiting(polled_at);
                emptied = true;
                break;
            };
            if self.in_flight.reply_read() {
                self.held = Some(frame);
            } else {
                surplus += 1;
            }
        }
        if !emptied && self.read_frame(Duration::ZERO)?.is_some() {
            // Still more: a flood. Throw the rest away; what was thrown away is not counted, so resynchronise.
            self.port.discard_input()?;
            self.frames.clear();
            self.in_flight.malformed(Instant::now());
            surplus += 1;
        }
        self.book.count_surplus(surplus);
        Ok(())
    }

    /// Sets the serial number shown in the capability record (from the USB descriptor).
    pub fn set_serial_number(&mut self, serial: &str) {
        self.info.serial_number = serial.to_owned();
    }

    /// True once all three motors are homed.
    pub fn is_homed(&self) -> bool {
        self.last_reply.is_some_and(|r| r.homing == ALL_HOMED)
    }

    /// The newest device frame.
    pub fn last_reply(&self) -> Option<FalconReply> {
        self.last_reply
    }

    /// Frames dropped as malformed.
    pub fn malformed_frames(&self) -> u64 {
        self.frames.malformed()
    }

    /// The port.
    pub fn port(&self) -> &P {
        &self.port
    }

    fn send(&mut self, motor: [i16; 3]) -> Result<(), DeviceError> {
        let leds = if self.is_homed() { LED_GREEN } else { LED_RED };
        // A torque counts as on from the moment its frame is begun; off only once a zero frame went out whole.
        let zero = motor == [0; 3];
        self.torque_on |= !zero;
        // Homing mode in every frame, or the Falcon does not stay homed (FalconFirmware.h:50).
        self.port.write_all(&encode_command(motor, leds, true))?;
        if zero {
            self.torque_on = false;
        }
        Ok(())
    }

    /// Reads the next well-formed frame within `timeout`, skipping bytes until a `<` whose frame ends in `>`
    /// (the shared runner, [`super::exchange::receive_within`], over the frame assembler). With a zero timeout
    /// the port is still polled (without waiting).
    fn read_frame(&mut self, timeout: Duration) -> Result<Option<FalconReply>, DeviceError> {
        let frame =
            super::exchange::receive_within(&mut self.port, &mut self.frames, timeout, |frames| {
                Ok(frames.next_frame())
            })?;
        let now = Instant::now();
        let received = self.frames.received();
        if received != self.received_seen {
            self.received_seen = received;
            self.in_flight.bytes_came(now);
        }
        // Bytes that were not a frame: a garbled reply or junk, which cannot be told apart. The count of
        // replies owed is lost (never written down, which could make a later state look younger than it is).
        let malformed = self.frames.malformed();
        if malformed != self.malformed_seen {
            self.malformed_seen = malformed;
            self.in_flight.malformed(now);
        }
        Ok(frame)
    }

    /// The port held nothing when polled at `at`: an overdue reply starts a resynchronisation; a quiet link
    /// ends one, and any partial frame held then is junk (no byte came for [`LOST_REPLY_AFTER`]).
    fn nothing_waiting(&mut self, at: Instant) {
        if self.in_flight.nothing_waiting(at) {
            self.frames.clear();
        }
    }

    /// Resynchronisations of the reply count since the last open (module docs).
    pub fn resyncs(&self) -> u64 {
        self.in_flight.resyncs()
    }

    /// Waits until no byte has come for [`LOST_REPLY_AFTER`] (every reply owed has come or never will), at
    /// most [`RESYNC_GIVE_UP`] and a little more; then nothing is owed.
    fn settle(&mut self) -> Result<(), DeviceError> {
        let give_up = Instant::now() + RESYNC_GIVE_UP + LOST_REPLY_AFTER;
        let mut quiet_since = Instant::now();
        loop {
            let now = Instant::now();
            let quiet_for = now.saturating_duration_since(quiet_since);
            if quiet_for > LOST_REPLY_AFTER {
                break;
            }
            if now > give_up {
                return Err(protocol_error(
                    "the Falcon kept sending after its first frame (a port that is not a Falcon, or a \
                     Falcon running other firmware)",
                ));
            }
            let seen = (self.frames.received(), self.frames.malformed());
            if let Some(reply) =
                self.read_frame(LOST_REPLY_AFTER - quiet_for + Duration::from_millis(1))?
            {
                self.last_reply = Some(reply);
            }
            if (self.frames.received(), self.frames.malformed()) != seen {
                quiet_since = Instant::now();
            }
        }
        self.frames.clear();
        self.in_flight.clear();
        Ok(())
    }

    /// The frame this tick's state comes from, and whether its age is unknown: the frame `read` this tick,
    /// else the one held from before this tick's command, else (resynchronising, or just done) the newest frame
    /// again, so the link stays up while it is quiet; else a timeout.
    fn tick_reply(
        &mut self,
        read: Option<FalconReply>,
        polled_at: Instant,
    ) -> Result<(FalconReply, bool), DeviceError> {
        // A frame read, or held, while the count was in doubt has no known age, even if the doubt ends now.
        let unknown_age = self.in_flight.resyncing();
        if let Some(reply) = read {
            self.in_flight.reply_read();
            self.held = None;
            return Ok((reply, unknown_age));
        }
        self.nothing_waiting(polled_at);
        let unknown_age = unknown_age || self.in_flight.resyncing();
        if let Some(reply) = self.held.take() {
            return Ok((reply, unknown_age));
        }
        match self.last_reply {
            Some(reply) if unknown_age => Ok((reply, unknown_age)),
            _ => Err(DeviceError::Timeout {
                waited_us: u64::try_from(self.config.reply_timeout.as_micros()).unwrap_or(u64::MAX),
                waiting_for: "a Falcon frame",
            }),
        }
    }

    /// Up to ten zero-torque exchanges, each waiting 20 ms for its frame: true once one is answered. The
    /// replies' bookkeeping starts from there.
    fn first_exchanges(&mut self) -> Result<bool, DeviceError> {
        for _ in 0..10 {
            self.send([0; 3])?;
            if let Some(reply) = self.read_frame(Duration::from_millis(20))? {
                self.last_reply = Some(reply);
                // An earlier exchange's reply may still come: count from a quiet link.
                self.settle()?;
                self.held = None;
                self.book.age = 0;
                return Ok(true);
            }
        }
        Ok(false)
    }
}

impl<P: FalconPort> HapticDevice for Falcon<P> {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Normal mode; if no firmware answers, uploads the configured file (or says that one is needed).
    fn open(&mut self) -> Result<(), DeviceError> {
        // Normal mode as libnifalcon sets it (FalconComm.h:71-74), then the latency timer checked: at ftdi_sio's
        // default 16 ms every frame would come up to 16 ms late.
        self.port.set_latency_timer(ftdi_latency::NORMAL_MS)?;
        self.port.set_baud(NORMAL_BAUD)?;
        self.port.purge()?;
        self.port.check_latency_timer()?;
        self.frames.clear();
        self.book.opened();
        // libnifalcon's isFirmwareLoaded tries many exchanges (FalconFirmware.cpp:169-190); a few suffice here.
        if self.first_exchanges()? {
            return Ok(());
        }
        let Some(path) = self.config.firmware.clone() else {
            return Err(DeviceError::Open {
                path: "Novint Falcon".to_owned(),
                message: "no firmware is running on the Falcon: give Novint's firmware file with \
                          falcon:...,firmware=FILE (voxhap does not ship it; see docs/devices/novint-falcon.md)"
                    .to_owned(),
            });
        };
        let firmware = std::fs::read(&path).map_err(|e| DeviceError::Open {
            path: path.display().to_string(),
            message: crate::transport::open_message(&e.to_string(), e.kind()),
        })?;
        if firmware.len() > 1 << 20 {
            return Err(DeviceError::Config {
                what: format!(
                    "{} is {} bytes; a Falcon firmware file is a few kilobytes",
                    path.display(),
                    firmware.len()
                ),
            });
        }
        upload_firmware(&mut self.port, &firmware)?;
        self.frames.clear();
        if self.first_exchanges()? {
            return Ok(());
        }
        Err(DeviceError::Timeout {
            waited_us: 200_000,
            waiting_for: "a Falcon frame after the firmware upload",
        })
    }

    /// Zero torque until homed; then (J⁻¹)ᵀ f at the last position.
    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        DeviceError::check_finite_force(force_n.to_array())?;
        self.drain_waiting()?;
        let motor = match (self.in_flight.next_command(), self.book.accepted()) {
            // Resynchronising: one zero-torque frame, then a quiet link until the count is known again.
            (NextCommand::Nothing, _) => return Ok(()),
            (NextCommand::Force, Some(position)) if self.is_homed() => {
                self.config.geometry.motor_commands(position, force_n)
            }
            _ => [0; 3],
        };
        self.send(motor)?;
        self.in_flight.command_sent(Instant::now());
        Ok(())
    }

    fn input_checked(&mut self, accepted: bool) {
        if !self.book.input_checked(accepted) {
            // A rejected frame may have led the iteration astray: restart it from the accepted position.
            if let Some(position) = self.book.accepted() {
                self.position_m = position;
            }
        }
    }

    reply_book_methods!(crate::latency::FALCON, input_checked written by the driver);

    /// The wrapper's zero torque went out: read the frames still to come, up to the one that answers it (at
    /// most the link's worst latency), so the Falcon has taken it before the port closes.
    fn disable(&mut self) -> Result<(), DeviceError> {
        // The wrapper's zero is not sent while the count resynchronises (the link must stay quiet); a torque
        // still on then is zeroed here all the same: letting go matters more than the quiet.
        if self.torque_on {
            self.send([0; 3])?;
            self.in_flight.command_sent(Instant::now());
        }
        let deadline = Instant::now() + self.config.reply_timeout.max(crate::latency::FALCON.worst);
        while self.in_flight.unanswered() > 0 {
            let remaining = deadline.saturating_duration_since(Instant::now());
            match self.read_frame(remaining)? {
                Some(reply) => {
                    self.in_flight.reply_read();
                    self.last_reply = Some(reply);
                }
                None => break,
            }
        }
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.book.reading_begins();
        // With a reply held from before this tick's command, only what is already waiting is newer (this
        // command's own reply comes a latency timer and a USB frame later, 1-2 ms); without one, the reply to
        // the previous command may still come within the wait. Resynchronising, nothing was sent to wait for.
        let wait = if self.held.is_some() || self.in_flight.resyncing() {
            Duration::ZERO
        } else {
            self.config.reply_timeout
        };
        let polled_at = Instant::now();
        let read = self.read_frame(wait)?;
        let (reply, unknown_age) = self.tick_reply(read, polled_at)?;
        if self
            .in_flight
            .resync_began()
            .is_some_and(|began| polled_at.saturating_duration_since(began) > RESYNC_GIVE_UP)
        {
            return Err(protocol_error(
                "the Falcon's frames stayed corrupt (bytes that are not 16-byte <...> frames kept coming)",
            ));
        }
        let age = self.in_flight.state_age(polled_at);
        let was_homed = self.is_homed();
        self.last_reply = Some(reply);
        if !was_homed && self.is_homed() {
            // Homing resets the encoders' coordinate system: start the Newton iteration afresh, and convert no
            // force until a position in the new coordinates is accepted.
            self.position_m = DVec3::new(0.0, 0.0, 0.08);
            self.book.forget_accepted();
        }
        // Until homed, a position is in coordinates homing will reset, and no force may come from it
        // (FalconFirmware.h:52-55): its age is unknown, so the supervisor holds the force at zero, and enables
        // (from zero, through its ramp-in and slew limit) only on homed states. Otherwise the driver's own
        // zero would hide a force the supervisor had ramped up, sent as a step the moment the Falcon homes.
        self.book.age = if unknown_age || !self.is_homed() {
            UNKNOWN_AGE
        } else {
            age
        };
        let geometry = self.config.geometry;
        let theta = reply.encoders.map(|count| geometry.leg_angle_rad(count));
        let (position, converged) = geometry.forward_kinematics(theta, self.position_m);
        if converged {
            self.position_m = position;
            self.book.propose(position);
        }
        Ok(DeviceState {
            position_m: self.position_m,
            velocity_m_per_s: DVec3::ZERO,
            // Grip buttons, as the firmware reports them (low nibble of the status byte).
            buttons: u16::from(reply.grip),
            device_time_us: None,
            sequence: None,
            status: None,
        })
    }
}

#[cfg(test)]
#[path = "falcon_tests.rs"]
mod tests;
