//! Test doubles of the Novint Falcon, written from libnifalcon's description of the link (libnifalcon/libnifalcon:
//! src/firmware/FalconFirmwareNovintSDK.cpp for the 16-byte frames, include/falcon/core/FalconFirmware.h for
//! the LED and homing bits and the homing procedure, src/core/FalconFirmware.cpp and
//! src/comm/FalconCommLibUSB.cpp for the bootloader exchange), not from voxhap's driver.
//!
//! [`FalconDevice`] is the Falcon with its firmware running, on a pseudo-terminal: it answers each well-formed
//! host frame with one frame of encoder counts and status, and logs every motor command with its LED and
//! homing bits. [`Bootloader`] is the Falcon before its firmware is loaded, on an in-memory line that carries
//! the baud rate, DTR, RTS, purges and the FTDI latency timer ([`FalconLine`]; a pseudo-terminal has no baud rate
//! or DTR line to switch): as FalconComm.h:45-66 describes, it answers the `0a 43 0d` check only at 9600 baud
//! with RTS low after DTR went low then high, echoes `A` only at 142 857 baud (FTDI divisor 0x15) with DTR low,
//! echoes the firmware at that rate, then runs like [`FalconDevice`] only at 1 500 000 baud (divisor 2). At any
//! other setting the bytes are garbled on a real line: the double drops them and answers nothing.
//!
//! Misbehaviour a test can ask for: frames whose encoder counts are not the true ones (glitches, jumps) while
//! every command is logged with the true counts ([`Applied`]), and more than one answer per frame.
//!
//! Timing a test can ask for ([`FalconDevice::start_late`], [`FalconDevice::start_late_at_pose`]): each answer
//! reaches the host as late as on a real Falcon ([`libnifalcon_arrival`]), or later by a test's extra delay;
//! numbered, each carries the number of the command it answers as its encoder counts.
//!
//! What the double has been sent, settled ([`FalconDevice::commands_settled`]): the double writes a mark frame on
//! the host's side of the line and waits until it reads it back; the line is one queue, so by then it has read
//! every frame the host wrote before. No guess at how long a busy machine takes to deliver them.
//!
//! Damage on the line a test can ask for, per answer ([`Junk`]): junk bytes before it (no answer of their own),
//! an answer garbled in transit, bytes inserted inside an answer, an answer lost. A frame is 16 bytes from `<`
//! to `>` whose other bytes run from 0x41 to 0x50 except the status byte
//! (include/falcon/firmware/FalconFirmwareNovintSDK.h:29-34, :63-80); the junk here never makes one. The double
//! logs, for every command, the newest answer that had reached the host whole before the command arrived
//! ([`Applied::newest_delivered`]): no state the host had could be newer.
//!
//! What the double could not decode, counted ([`FalconShared::undecodable`]): the host's frames are framed as
//! libnifalcon frames them (`formatInput`, src/firmware/FalconFirmwareNovintSDK.cpp:88-112 at libnifalcon commit
//! 28347c2: `<`, bytes 1-14 each a nibble plus 0x41, `>`), and parsed as libnifalcon parses the Falcon's
//! (`formatOutput`, :39-86: bytes up to a `<` are skipped, the 16 bytes from it are a frame only if the 16th is
//! `>`, else "Clearing malformed packet!", :79-83), with the byte range of
//! include/falcon/firmware/FalconFirmwareNovintSDK.h:33-34 (0x41 to 0x50) checked too. Each run of bytes skipped
//! before a `<` and each 16 bytes from a `<` that are not a frame count once. The driver must never send one.

use super::pty::PtyDevice;
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use voxhap::device::drivers::falcon::FalconPort;
use voxhap::device::transport::{ByteTransport, MemoryPipe};
use voxhap::device::DeviceError;

/// The line settings the host made, as the Falcon's end of the cable sees them.
#[derive(Debug, Default)]
pub struct LineState {
    pub baud: AtomicU32,
    pub dtr: AtomicBool,
    pub rts: AtomicBool,
    /// DTR went low and then high since the last check answer (the bootloader's reset, FalconComm.h:53-54).
    pub dtr_pulsed: AtomicBool,
    /// Every latency timer the host set (ms), in order.
    pub latency_ms: Mutex<Vec<u8>>,
    /// Purges of both queues.
    pub purges: AtomicU32,
}

/// The host's end of the Falcon's line: a byte pipe plus the settings the double reads.
pub struct FalconLine {
    pipe: MemoryPipe,
    pub state: Arc<LineState>,
}

impl ByteTransport for FalconLine {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        self.pipe.write_all(bytes)
    }
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        self.pipe.read(buf, timeout)
    }
}

impl FalconPort for FalconLine {
    fn set_baud(&mut self, baud: u32) -> Result<(), DeviceError> {
        self.state.baud.store(baud, Ordering::Release);
        Ok(())
    }
    fn set_modem(&mut self, dtr: bool, rts: bool) -> Result<(), DeviceError> {
        let was = self.state.dtr.swap(dtr, Ordering::AcqRel);
        if dtr && !was {
            self.state.dtr_pulsed.store(true, Ordering::Release);
        }
        self.state.rts.store(rts, Ordering::Release);
        Ok(())
    }
    fn purge(&mut self) -> Result<(), DeviceError> {
        self.state.purges.fetch_add(1, Ordering::AcqRel);
        self.pipe.discard_input()
    }
    fn set_latency_timer(&mut self, ms: u8) -> Result<bool, DeviceError> {
        self.state.latency_ms.lock().unwrap().push(ms);
        Ok(true)
    }
    fn check_latency_timer(&self) -> Result<(), DeviceError> {
        Ok(())
    }
}

/// One host frame, as the Falcon decoded it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FalconCommand {
    pub motor: [i16; 3],
    pub leds: u8,
    pub homing_requested: bool,
}

/// One motor command with the true encoder counts when it arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Applied {
    pub motor: [i16; 3],
    pub true_encoders: [i16; 3],
    /// This command's number (from 0, in the order the Falcon received commands).
    pub number: i64,
    /// The number of the newest command whose answer had reached the host whole when this one arrived (-1:
    /// none yet).
    pub newest_delivered: i64,
    /// The homing bits the double reported when this command arrived.
    pub homing: u8,
}

/// Damage to one answer on its way to the host.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Junk {
    /// These bytes reach the host just before the answer, which arrives whole: they answer nothing.
    Before(Vec<u8>),
    /// The answer arrives with its end byte damaged: it answered, but cannot be read.
    Garbled,
    /// These bytes are inserted after the answer's seventh byte: the answer cannot be read.
    Inside(Vec<u8>),
    /// The answer never arrives.
    Lost,
}

#[derive(Debug, Default)]
pub struct FalconShared {
    pub commands: Mutex<Vec<FalconCommand>>,
    /// Every command with the true counts.
    pub applied: Mutex<Vec<Applied>>,
    /// Counts for the next answers instead of the true ones, in order.
    pub glitches: Mutex<VecDeque<[i16; 3]>>,
    /// Answers per frame beyond the first.
    pub extra_answers: AtomicU32,
    /// Frames answered (all answers written).
    pub answered: AtomicU64,
    pub encoders: Mutex<[i16; 3]>,
    /// Homing bits reported (bit n = motor n+1).
    pub homing: Mutex<u8>,
    pub grip: Mutex<u8>,
    /// Firmware bytes received by the bootloader.
    pub firmware: Mutex<Vec<u8>>,
    /// Each answer's encoder counts are `[n, -n, 2n]` for the n-th command answered (from 0), instead of the
    /// true counts: the host can tell which command a state answers.
    pub numbered: AtomicBool,
    /// The latest a late answer reached the host after its planned arrival, or the longest the double's thread
    /// was away from the line between two rounds of its loop (µs), since a test last took it (`swap(0)`): how far
    /// the double's own thread fell behind its model on a busy machine. A command the thread reads late gets
    /// its answer late too, which the planned arrival (counted from the read) does not show; the gap does.
    /// Recorded before the round writes anything, so a host that has read a late answer sees its lateness.
    pub max_late_us: AtomicU64,
    /// Damage to the answer to command n (by number).
    pub junk: Mutex<BTreeMap<i64, Junk>>,
    /// Delay added to each late answer's arrival (µs), as from now.
    pub extra_delay_us: AtomicU64,
    /// The newest command whose answer reached the host whole (-1: none yet).
    pub newest_delivered: AtomicI64,
    /// Host frames the double could not decode (module docs): runs of bytes outside any frame, and 16 bytes
    /// from a `<` with no `>` at the end or a byte outside 0x41-0x50.
    pub undecodable: AtomicU64,
    /// Marks asked for ([`FalconDevice::commands_settled`]) and marks read back.
    marks_asked: AtomicU64,
    marks_read: AtomicU64,
    stop: AtomicBool,
}

impl FalconShared {
    fn new() -> FalconShared {
        FalconShared {
            newest_delivered: AtomicI64::new(-1),
            ..FalconShared::default()
        }
    }
}

/// When the answer to a frame the Falcon received at `received` reaches the host, on the link libnifalcon sets
/// up: the 16-byte answer is shorter than an FTDI packet, so the chip sends it when its latency timer runs out
/// (1 ms in normal mode, set by the vendor request 0x09 with value 1 in src/comm/FalconCommLibUSB.cpp:560),
/// and the host collects it at the next 1 ms full-speed USB frame (the frames counted from `bus_start`): 1 to
/// 2 ms after the command. libnifalcon's loop waits for that answer before it sends the next frame
/// (src/firmware/FalconFirmwareNovintSDK.cpp:113-154: no write while `m_hasWritten` and no bytes available).
pub fn libnifalcon_arrival(bus_start: Instant, received: Instant) -> Instant {
    const USB_FRAME_US: u128 = 1_000;
    let timer_out = received + Duration::from_millis(1);
    let since_us = timer_out.saturating_duration_since(bus_start).as_micros();
    let frame = since_us.div_ceil(USB_FRAME_US);
    bus_start + Duration::from_micros(u64::try_from(frame * USB_FRAME_US).unwrap_or(u64::MAX))
}

/// The mark [`FalconDevice::commands_settled`] writes on the host's side: a well-formed frame whose spare byte
/// is 0x50, which no host frame carries (libnifalcon's `formatInput`, src/firmware/FalconFirmwareNovintSDK.cpp,
/// clears bytes 1-14, never sets byte 14 and adds 0x41 to each: the spare byte is always 0x41); it is neither
/// logged nor answered.
const MARK: [u8; 16] = *b"<AAAAAAAAAAAAAP>";

/// Host frame → command: `<`, 3 × 4 nibbles + 0x41 (least significant first), control byte + 0x41, spare, `>`.
fn decode_host_frame(frame: &[u8]) -> Option<FalconCommand> {
    if frame.len() != 16 || frame[0] != b'<' || frame[15] != b'>' {
        return None;
    }
    if frame[1..15].iter().any(|&b| !(0x41..=0x50).contains(&b)) {
        return None;
    }
    let nibble = |i: usize| u16::from(frame[i] - 0x41);
    let mut motor = [0i16; 3];
    for (k, m) in motor.iter_mut().enumerate() {
        let base = 1 + 4 * k;
        *m = (nibble(base) | nibble(base + 1) << 4 | nibble(base + 2) << 8 | nibble(base + 3) << 12)
            as i16;
    }
    let control = frame[13] - 0x41;
    Some(FalconCommand {
        motor,
        leds: control & 0xe,
        homing_requested: control & 1 == 1,
    })
}

/// Device frame: encoders as nibbles, status byte = homing bits << 4 | grip, each + 0x41.
fn device_frame(encoders: [i16; 3], homing: u8, grip: u8) -> [u8; 16] {
    let mut out = [0x41u8; 16];
    out[0] = b'<';
    out[15] = b'>';
    for (k, e) in encoders.iter().enumerate() {
        let v = *e as u16;
        for n in 0..4 {
            out[1 + 4 * k + n] = 0x41 + ((v >> (4 * n)) & 0xf) as u8;
        }
    }
    out[13] = 0x41 + ((homing & 7) << 4 | (grip & 0xf));
    out
}

/// Handles the host frames in `pending`, answering each (with the damage a test asked for); returns what to
/// send and the number of the newest command it answers whole.
fn serve_frames(pending: &mut Vec<u8>, shared: &FalconShared) -> (Vec<u8>, Option<i64>) {
    let mut out = Vec::new();
    let mut newest_whole = None;
    loop {
        let Some(start) = pending.iter().position(|&b| b == b'<') else {
            if !pending.is_empty() {
                shared.undecodable.fetch_add(1, Ordering::AcqRel);
            }
            pending.clear();
            break;
        };
        if start > 0 {
            shared.undecodable.fetch_add(1, Ordering::AcqRel);
        }
        pending.drain(..start);
        if pending.len() < 16 {
            break;
        }
        let frame: Vec<u8> = pending.drain(..16).collect();
        if frame == MARK {
            shared.marks_read.fetch_add(1, Ordering::AcqRel);
            continue;
        }
        let Some(command) = decode_host_frame(&frame) else {
            shared.undecodable.fetch_add(1, Ordering::AcqRel);
            continue;
        };
        let number = {
            let mut commands = shared.commands.lock().unwrap();
            commands.push(command);
            commands.len() as i64 - 1
        };
        let truth = *shared.encoders.lock().unwrap();
        let homing = *shared.homing.lock().unwrap();
        shared.applied.lock().unwrap().push(Applied {
            motor: command.motor,
            true_encoders: truth,
            number,
            newest_delivered: shared.newest_delivered.load(Ordering::Acquire),
            homing,
        });
        let reported = if shared.numbered.load(Ordering::Acquire) {
            let n = number as i16;
            [n, -n, 2 * n]
        } else {
            shared.glitches.lock().unwrap().pop_front().unwrap_or(truth)
        };
        let answer = device_frame(reported, homing, *shared.grip.lock().unwrap());
        let junk = shared.junk.lock().unwrap().remove(&number);
        for _ in 0..=shared.extra_answers.load(Ordering::Acquire) {
            match &junk {
                None => out.extend_from_slice(&answer),
                Some(Junk::Before(bytes)) => {
                    out.extend_from_slice(bytes);
                    out.extend_from_slice(&answer);
                }
                Some(Junk::Garbled) => {
                    out.extend_from_slice(&answer[..15]);
                    out.push(0x00);
                }
                Some(Junk::Inside(bytes)) => {
                    out.extend_from_slice(&answer[..7]);
                    out.extend_from_slice(bytes);
                    out.extend_from_slice(&answer[7..]);
                }
                Some(Junk::Lost) => {}
            }
        }
        if matches!(junk, None | Some(Junk::Before(_))) {
            newest_whole = Some(number);
        }
    }
    (out, newest_whole)
}

/// A Falcon with its firmware running, on a pseudo-terminal.
pub struct FalconDevice {
    pub shared: Arc<FalconShared>,
    path: String,
    thread: Option<JoinHandle<()>>,
}

impl FalconDevice {
    /// A Falcon whose answers reach the host at once.
    pub fn start() -> FalconDevice {
        FalconDevice::start_with(false, false)
    }

    /// A Falcon whose answers reach the host as late as libnifalcon's link delivers them
    /// ([`libnifalcon_arrival`]), numbered by the command they answer ([`FalconShared::numbered`]).
    /// `answered` counts answers that have reached the host.
    pub fn start_late() -> FalconDevice {
        FalconDevice::start_with(true, true)
    }

    /// The same late Falcon reporting its true encoder counts (a handle at a pose).
    pub fn start_late_at_pose() -> FalconDevice {
        FalconDevice::start_with(true, false)
    }

    fn start_with(late: bool, numbered: bool) -> FalconDevice {
        let mut pty = PtyDevice::new();
        if late {
            pty.set_read_timeout(Duration::from_micros(100));
        }
        let path = pty.path().to_string();
        let shared = Arc::new(FalconShared::new());
        shared.numbered.store(numbered, Ordering::Release);
        let thread = {
            let shared = shared.clone();
            std::thread::spawn(move || {
                let bus_start = Instant::now();
                let mut pending = Vec::new();
                // Answers on their way: when each reaches the host, its bytes, how many commands it answers, the
                // newest it answers whole.
                let mut on_the_way: VecDeque<(Instant, Vec<u8>, usize, Option<i64>)> =
                    VecDeque::new();
                let mut chunk = [0u8; 256];
                let mut marks_written = 0;
                let mut round = Instant::now();
                while !shared.stop.load(Ordering::Acquire) {
                    let away = round.elapsed().as_micros();
                    shared.max_late_us.fetch_max(away as u64, Ordering::AcqRel);
                    round = Instant::now();
                    let asked = shared.marks_asked.load(Ordering::Acquire);
                    if asked > marks_written {
                        marks_written = asked;
                        pty.write_as_host(&MARK)
                            .expect("write a mark on the host's side");
                    }
                    while on_the_way
                        .front()
                        .is_some_and(|(at, _, _, _)| *at <= Instant::now())
                    {
                        let (at, out, served, whole) = on_the_way.pop_front().unwrap();
                        let late = Instant::now().saturating_duration_since(at).as_micros();
                        shared.max_late_us.fetch_max(late as u64, Ordering::AcqRel);
                        let _ = pty.write(&out);
                        if let Some(whole) = whole {
                            shared.newest_delivered.fetch_max(whole, Ordering::AcqRel);
                        }
                        shared.answered.fetch_add(served as u64, Ordering::AcqRel);
                    }
                    match pty.read(&mut chunk) {
                        Ok(n) => pending.extend_from_slice(&chunk[..n]),
                        Err(_) => {
                            std::thread::sleep(Duration::from_millis(1));
                            continue;
                        }
                    }
                    let received = Instant::now();
                    let before = shared.commands.lock().unwrap().len();
                    let (out, whole) = serve_frames(&mut pending, &shared);
                    let served = shared.commands.lock().unwrap().len() - before;
                    if late {
                        if served > 0 {
                            let extra = shared.extra_delay_us.load(Ordering::Acquire);
                            let at = libnifalcon_arrival(bus_start, received)
                                .max(received + Duration::from_micros(extra));
                            // The link delivers in order: never before the answer ahead.
                            let at = on_the_way.back().map_or(at, |ahead| at.max(ahead.0));
                            on_the_way.push_back((at, out, served, whole));
                        }
                        continue;
                    }
                    if !out.is_empty() {
                        let _ = pty.write(&out);
                    }
                    if let Some(whole) = whole {
                        shared.newest_delivered.fetch_max(whole, Ordering::AcqRel);
                    }
                    shared.answered.fetch_add(served as u64, Ordering::AcqRel);
                }
            })
        };
        FalconDevice {
            shared,
            path,
            thread: Some(thread),
        }
    }

    pub fn path(&self) -> &str {
        &self.path
    }

    pub fn commands(&self) -> Vec<FalconCommand> {
        self.shared.commands.lock().unwrap().clone()
    }

    /// Host frames the double could not decode so far ([`FalconShared::undecodable`]); read it after
    /// [`FalconDevice::commands_settled`], when the double has read every frame the host wrote.
    pub fn undecodable_frames(&self) -> u64 {
        self.shared.undecodable.load(Ordering::Acquire)
    }

    /// Every command, once the double has read every frame the host wrote before this call (module docs):
    /// call it after the host has stopped writing. Panics if the mark is not back within 60 s.
    pub fn commands_settled(&self) -> Vec<FalconCommand> {
        let before = self.shared.marks_read.load(Ordering::Acquire);
        self.shared.marks_asked.fetch_add(1, Ordering::AcqRel);
        let deadline = Instant::now() + Duration::from_secs(60);
        while self.shared.marks_read.load(Ordering::Acquire) == before {
            assert!(
                Instant::now() < deadline,
                "the double did not read back its mark within 60 s"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
        self.commands()
    }
}

impl Drop for FalconDevice {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// A Falcon without firmware, on an in-memory pipe; it expects a firmware file of `firmware_len` bytes.
pub struct Bootloader {
    pub shared: Arc<FalconShared>,
    thread: Option<JoinHandle<()>>,
}

impl Bootloader {
    /// Starts the double; returns it and the host's end of the line.
    pub fn start(firmware_len: usize) -> (Bootloader, FalconLine) {
        let (host, mut device) = MemoryPipe::pair();
        let shared = Arc::new(FalconShared::new());
        let line = Arc::new(LineState::default());
        let host = FalconLine {
            pipe: host,
            state: line.clone(),
        };
        let thread = {
            let shared = shared.clone();
            std::thread::spawn(move || {
                #[derive(PartialEq)]
                enum Stage {
                    Check,
                    WaitA,
                    Firmware,
                    Running,
                }
                let mut stage = Stage::Check;
                let mut pending = Vec::new();
                let mut chunk = [0u8; 256];
                while !shared.stop.load(Ordering::Acquire) {
                    let n = match device.read(&mut chunk, Duration::from_millis(2)) {
                        Ok(n) => n,
                        Err(_) => return,
                    };
                    let baud = line.baud.load(Ordering::Acquire);
                    let dtr = line.dtr.load(Ordering::Acquire);
                    // The rate each stage listens at (FalconComm.h:50, :56, :73); at any other rate the bytes
                    // arrive garbled and are dropped.
                    let expected_baud = match stage {
                        Stage::Check => 9_600,
                        Stage::WaitA | Stage::Firmware => 142_857,
                        Stage::Running => 1_500_000,
                    };
                    if baud != expected_baud {
                        pending.clear();
                        continue;
                    }
                    pending.extend_from_slice(&chunk[..n]);
                    let reply: Vec<u8> = match stage {
                        Stage::Check => {
                            // Until firmware runs, normal frames get no answer; the check gets the bootloader's,
                            // after DTR went low then high with RTS low (FalconComm.h:52-54).
                            let reset = dtr
                                && !line.rts.load(Ordering::Acquire)
                                && line.dtr_pulsed.load(Ordering::Acquire);
                            match pending.windows(3).position(|w| w == [0x0a, 0x43, 0x0d]) {
                                Some(at) if reset => {
                                    pending.drain(..at + 3);
                                    stage = Stage::WaitA;
                                    vec![0x0a, 0x44, 0x2c, 0x0d]
                                }
                                _ => Vec::new(),
                            }
                        }
                        // DTR low before the rate change (FalconComm.h:57).
                        Stage::WaitA => match pending.iter().position(|&b| b == b'A') {
                            Some(at) if !dtr => {
                                pending.drain(..=at);
                                stage = Stage::Firmware;
                                vec![b'A']
                            }
                            _ => Vec::new(),
                        },
                        Stage::Firmware => {
                            let mut firmware = shared.firmware.lock().unwrap();
                            let take = pending.len().min(firmware_len - firmware.len());
                            let echoed: Vec<u8> = pending.drain(..take).collect();
                            firmware.extend_from_slice(&echoed);
                            if firmware.len() == firmware_len {
                                stage = Stage::Running;
                            }
                            echoed
                        }
                        Stage::Running => serve_frames(&mut pending, &shared).0,
                    };
                    if !reply.is_empty() && device.write_all(&reply).is_err() {
                        return;
                    }
                }
            })
        };
        (
            Bootloader {
                shared,
                thread: Some(thread),
            },
            host,
        )
    }
}

impl Drop for Bootloader {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
