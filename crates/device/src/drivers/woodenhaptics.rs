//! WoodenHaptics 1.5 over USB HID (an mbed LPC1768 running the WoodenHapticsHID firmware): **legacy**, selected
//! with `--device woodenhaptics-hid`. The WoodenHaptics project retired this firmware in 2019; current devices run
//! the Teensy serial firmware, driven by [`super::woodenhaptics_serial`] (`--device woodenhaptics:PATH`).
//!
//! Latency: the firmware streams reports faster than a host may read them, and the kernel queues them; reading
//! one per tick would fall behind by up to the whole queue (~64 reports, ~64 ms). `read_state` therefore drains
//! the queue and keeps the newest report, as chai3d's USB branch does on every read. Its age
//! ([`HapticDevice::state_age_ticks`]) counts the ticks in a row before it that brought no report: a report
//! read in the tick after a command is 0 ticks old, but one read after `k` ticks whose waits ended empty may
//! have been sent just after the last report read, `k` ticks ago (the stream stalled, then its reports came
//! late; reports carry only a counter, no time), so it is reported `k` ticks old. A stalled stream is a
//! timeout, never an old report handed out again.
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
//! Maths: one implementation for both WoodenHaptics drivers ([`WoodyKinematics`], hfabapi's equations). chai3d's
//! USB branch (CWoodenDevice.cpp) writes the same chain with encoder A negated and θC = π/2 - θ: with the
//! counts in hfabapi's convention ([`hfab_counts`]) and `woodenhaptics_v2015()`'s home offset (0, 0, -6000)
//! both give the same angles, positions and motor currents (τ = Jᵀ f, through the capstans, I = τ_motor / k_t).
//! Currents are scaled together so none exceeds 3 A (chai3d clamps each motor alone, which changes the force's
//! direction) and sent as whole milliamperes, truncated toward zero as C's `short(...)` does.

use super::reply_book::{reply_book_methods, ReplyBook};
use super::report_stream::NewestReport;
use super::woodenhaptics_kinematics::WoodyKinematics;
use crate::transport::ReportTransport;
use crate::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;
use std::time::Duration;

/// USB vendor id of the WoodenHapticsHID firmware (mbed USBHID default).
pub const VENDOR_ID: u16 = 0x1234;
/// USB product id of the WoodenHapticsHID firmware.
pub const PRODUCT_ID: u16 = 0x0006;
/// Report length both ways (no report id in the data).
pub const REPORT_LEN: usize = 8;
/// Largest motor current the host sends (A); the firmware maps 3 A to 90 % PWM.
pub const MAX_CURRENT_A: f64 = 3.0;

/// Room kept around the power-up pose in the declared workspace (m).
pub const POWER_UP_MARGIN_M: f64 = 0.02;

/// The largest current this driver sends (mA): [`MAX_CURRENT_A`].
pub const MAX_CURRENT_MA: i32 = 3000;

/// The kinematics of a WoodenHaptics 1.5 on this firmware: chai3d's `default_woody()` (CWoodenDevice.cpp), whose
/// constants and chain are hfabapi's `woodenhaptics_v2015()` (hfab_math.h:306-317) once the firmware's counts are
/// put in hfabapi's convention ([`hfab_counts`]): the home offset (0, 0, -6000) is chai3d's θC = π/2 - θ.
pub const KINEMATICS: WoodyKinematics = WoodyKinematics::WOODENHAPTICS_V2015;

/// The firmware's encoder counts in hfabapi's convention: chai3d's USB branch negates encoder A (and turns B
/// through a negative gear ratio, which hfabapi's `motor_and_body_aligned_b` does), so A is negated here.
pub fn hfab_counts(counts: [i16; 3]) -> [i32; 3] {
    [
        -i32::from(counts[0]),
        i32::from(counts[1]),
        i32::from(counts[2]),
    ]
}

/// The workspace the driver declares (m): the cube of `workspace_radius_m` about the workspace origin, grown to
/// hold the power-up pose (where the incremental encoders read zero: (0.025, 0, 0.205) m with
/// `default_woody()`) with [`POWER_UP_MARGIN_M`] around it, so the arm where it starts is never taken for an
/// implausible reading.
pub fn workspace_box_m(kinematics: &WoodyKinematics) -> (DVec3, DVec3) {
    let radius = DVec3::splat(kinematics.workspace_radius_m);
    let margin = DVec3::splat(POWER_UP_MARGIN_M);
    match kinematics.position_m(kinematics.joint_angles_rad(hfab_counts([0; 3]))) {
        Some(power_up) => (
            (-radius).min(power_up - margin),
            radius.max(power_up + margin),
        ),
        None => (-radius, radius),
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
    kinematics: WoodyKinematics,
    info: DeviceInfo,
    /// The joint angles force is converted with and the host's verdict on the newest report's; the age is kept
    /// by the receive core (`book.age`): the newest report of each tick's read, and its age.
    book: ReplyBook<[f64; 3], NewestReport>,
    read_timeout: Duration,
    last_counter: Option<u16>,
}

impl<T: ReportTransport> WoodenHaptics<T> {
    /// A driver with `kinematics` ([`KINEMATICS`] unless a device profile replaced some constants) on
    /// `transport`.
    pub fn new(transport: T, kinematics: WoodyKinematics) -> Result<Self, DeviceError> {
        kinematics.validate()?;
        let (workspace_min_m, workspace_max_m) = workspace_box_m(&kinematics);
        let info = DeviceInfo {
            max_force_n: kinematics.max_force_n,
            max_stiffness_n_per_m: kinematics.max_stiffness_n_per_m,
            ..DeviceInfo::basic(
                "WoodenHaptics 1.5 (legacy HID firmware)",
                workspace_min_m,
                workspace_max_m,
            )
        };
        Ok(WoodenHaptics {
            transport,
            kinematics,
            info,
            book: ReplyBook::new(),
            read_timeout: super::reply_age::DEFAULT_REPLY_WAIT,
            last_counter: None,
        })
    }

    /// How long `read_state` waits for a report: [`reply_wait`](super::reply_age::reply_wait) of the servo
    /// period, so a stalled stream costs at most one tick (the 1 kHz value unless set here).
    pub fn with_reply_wait(mut self, wait: Duration) -> Self {
        self.read_timeout = wait;
        self
    }

    /// The transport (to check a scripted double with `done()`).
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// How many older queued reports `read_state` skipped to reach the newest one.
    pub fn drained_reports(&self) -> u64 {
        self.book.age.skipped()
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
        let currents = match self.book.accepted() {
            // |current| <= MAX_CURRENT_MA, so it fits the firmware's `short`.
            Some(theta) => self
                .kinematics
                .currents_ma(theta, force_n, MAX_CURRENT_MA)
                .map(|ma| ma as i16),
            None => [0; 3],
        };
        self.transport.write_report(&encode_output(currents, 0))?;
        self.book.age.command_sent();
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        self.book.reading_begins();
        // The queue drained, the newest report kept (the shared runner over the report core).
        super::exchange::newest_report_within(
            &mut self.transport,
            &mut self.book.age,
            self.read_timeout,
        )?;
        let Some((report, _age)) = self.book.age.take() else {
            return Err(DeviceError::Timeout {
                waited_us: u64::try_from(self.read_timeout.as_micros()).unwrap_or(u64::MAX),
                waiting_for: "a WoodenHaptics input report",
            });
        };
        let (counts, counter) = decode_input(report)?;
        self.last_counter = Some(counter);
        let theta = self.kinematics.joint_angles_rad(hfab_counts(counts));
        let Some(position_m) = self.kinematics.position_m(theta) else {
            return Err(DeviceError::InvalidData {
                what: "WoodenHaptics encoder counts put the arm where its links cannot reach",
            });
        };
        self.book.propose(theta);
        Ok(DeviceState::at_rest(position_m))
    }

    // The age: ticks in a row before the report handed out that brought none (module docs). No surplus is
    // counted (a streaming firmware sends more reports than commands), so there is never an event.
    reply_book_methods!(crate::latency::WOODENHAPTICS_HID);

    fn disable(&mut self) -> Result<(), DeviceError> {
        // The wrapper has written a zero force; the firmware's own 0.5 s watchdog disables the amplifiers.
        Ok(())
    }
}
