//! A test double of the WoodenHaptics Teensy firmware, written from its source
//! (forsslund/woodenhaptics `firmware/woody_teensy_mini/woody_teensy_mini.ino`, cited as `ino:LINE`), served on a
//! pseudo-terminal. It logs every current command it accepts and every watchdog cut, so tests check safety from
//! the device's side.
//!
//! Behaviour reproduced: the message scanner `await_message` (ino:419-455: a `]` before any `[` is error 256,
//! not exactly two commas is 512, trailing characters other than `\n`, `\r`, `\0` are 8, 127 characters without
//! `]` are 128), the `sscanf("[%d,%d,%d]")` parse (ino:486-488, error 1024), one reply per message with
//! `[model,enc0..enc5,error]\n` (ino:108, 457-466, 543-553), currents outside ±6000 mA replaced by 0
//! (ino:17, 510), and the 100 ms message watchdog that cuts the amplifiers (ino:274-281, 493-494).
//!
//! Misbehaviour a test can ask for: glitched replies (encoder counts that are not the arm's true ones, or a
//! line that is not numbers at all) while the true counts stay in `encoders` and are logged with every command
//! ([`Applied`]), so a test computes the force the arm really exerts; answering every message more than once,
//! or flooding lines after it; and stamping each reply with the number of the message it answers (in the
//! unused gimbal encoder 3), so a test measures how old the reply a driver uses is.

use super::pty::PtyDevice;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// What the firmware double saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FirmwareEvent {
    /// A valid message set these motor currents (mA, after the ±6000 check).
    Currents([i32; 3]),
    /// A message was refused with this error code.
    Refused(i32),
    /// The watchdog expired and cut the amplifiers.
    WatchdogCut,
}

/// A reply that does not tell the truth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Glitch {
    /// Report these counts for encoders 0-2 instead of the true ones.
    Counts([i32; 3]),
    /// A line that is not numbers (a corrupted reading): `[3,nan,nan,nan,0,0,0,0]`.
    Garbage,
}

/// One accepted command with the arm's true encoder counts when it arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Applied {
    /// Motor currents applied (mA).
    pub currents_ma: [i32; 3],
    /// The true counts of encoders 0-2 (what a truthful reply would have said).
    pub true_counts: [i32; 3],
}

/// Shared state of a running double.
#[derive(Debug)]
pub struct FirmwareShared {
    /// Glitches for the next replies, in order (each reply takes one).
    pub glitches: Mutex<VecDeque<Glitch>>,
    /// Every accepted command with the true counts.
    pub applied: Mutex<Vec<Applied>>,
    /// Motor currents the firmware's range check zeroed (outside ±6000 mA, ino:17, :510).
    pub zeroed_by_check: AtomicU32,
    /// Replies per valid message (1 for the real firmware).
    pub answers: AtomicU32,
    /// Extra unsolicited lines sent after each reply (a flood).
    pub flood: AtomicU32,
    /// Write the number of the message answered into encoder 3 of every reply.
    pub stamp: AtomicBool,
    /// Valid messages answered so far (all answers written).
    pub answered: AtomicU64,
    /// Every event, in order.
    pub log: Mutex<Vec<FirmwareEvent>>,
    /// The six encoder counters the firmware reports.
    pub encoders: Mutex<[i32; 6]>,
    /// True while the amplifiers are enabled.
    pub amplifiers_enabled: AtomicBool,
    /// Set by a test to stop answering (the device hangs).
    pub mute: AtomicBool,
    stop: AtomicBool,
}

/// The double, running on its own thread until dropped.
pub struct WoodyFirmware {
    pub shared: Arc<FirmwareShared>,
    path: String,
    thread: Option<JoinHandle<()>>,
}

const BUF_LEN: usize = 127; // ino:413
const ESCON_MAX_MILLIAMPS: i32 = 6000; // ino:17

impl WoodyFirmware {
    /// Starts a double that reports `model` (1 Polhem, 2 vintage PHANTOM, 3 WoodenHaptics).
    pub fn start(model: i32) -> WoodyFirmware {
        let mut pty = PtyDevice::new();
        let path = pty.path().to_string();
        let shared = Arc::new(FirmwareShared {
            glitches: Mutex::new(VecDeque::new()),
            applied: Mutex::new(Vec::new()),
            zeroed_by_check: AtomicU32::new(0),
            answers: AtomicU32::new(1),
            flood: AtomicU32::new(0),
            stamp: AtomicBool::new(false),
            answered: AtomicU64::new(0),
            log: Mutex::new(Vec::new()),
            encoders: Mutex::new([0; 6]),
            amplifiers_enabled: AtomicBool::new(false),
            mute: AtomicBool::new(false),
            stop: AtomicBool::new(false),
        });
        let thread = {
            let shared = shared.clone();
            std::thread::spawn(move || run(&mut pty, model, &shared))
        };
        WoodyFirmware {
            shared,
            path,
            thread: Some(thread),
        }
    }

    /// The pseudo-terminal path to open.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// A copy of the event log.
    pub fn events(&self) -> Vec<FirmwareEvent> {
        self.shared.log.lock().unwrap().clone()
    }

    /// The currents of every accepted command.
    pub fn currents(&self) -> Vec<[i32; 3]> {
        self.events()
            .into_iter()
            .filter_map(|e| match e {
                FirmwareEvent::Currents(c) => Some(c),
                _ => None,
            })
            .collect()
    }

    /// Sets the encoder counters.
    pub fn set_encoders(&self, encoders: [i32; 6]) {
        *self.shared.encoders.lock().unwrap() = encoders;
    }
}

impl Drop for WoodyFirmware {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// `sscanf(c, "[%d,%d,%d]")` == 3 (ino:129): leading whitespace before each number allowed, as %d does.
fn scan_three(text: &[u8]) -> Option<[i32; 3]> {
    let text = std::str::from_utf8(text).ok()?;
    let inner = text.strip_prefix('[')?;
    let mut out = [0i32; 3];
    let mut rest = inner;
    for (i, slot) in out.iter_mut().enumerate() {
        let trimmed = rest.trim_start();
        let end = trimmed
            .char_indices()
            .find(|&(j, c)| !(c.is_ascii_digit() || (j == 0 && (c == '-' || c == '+'))))
            .map(|(j, _)| j)
            .unwrap_or(trimmed.len());
        *slot = trimmed[..end].parse().ok()?;
        rest = &trimmed[end..];
        let sep = if i < 2 { ',' } else { ']' };
        rest = rest.strip_prefix(sep)?;
    }
    Some(out)
}

fn reply(pty: &mut PtyDevice, model: i32, shared: &FirmwareShared, error_code: i32) {
    if shared.mute.load(Ordering::Acquire) {
        return;
    }
    let mut e = *shared.encoders.lock().unwrap();
    if shared.stamp.load(Ordering::Acquire) {
        e[3] = (shared.answered.load(Ordering::Acquire) + 1) as i32;
    }
    let glitch = shared.glitches.lock().unwrap().pop_front();
    let line = match glitch {
        Some(Glitch::Garbage) => format!("[{model},nan,nan,nan,0,0,0,{error_code}]\n"),
        Some(Glitch::Counts(counts)) => format!(
            "[{},{},{},{},{},{},{},{}]\n",
            model, counts[0], counts[1], counts[2], e[3], e[4], e[5], error_code
        ),
        None => format!(
            "[{},{},{},{},{},{},{},{}]\n",
            model, e[0], e[1], e[2], e[3], e[4], e[5], error_code
        ),
    };
    // Every answer (and any flood) in one write, so they reach the host together.
    let answers = shared.answers.load(Ordering::Acquire).max(1) as usize;
    let flood = shared.flood.load(Ordering::Acquire) as usize;
    let out = line.repeat(answers + flood);
    let _ = pty.write(out.as_bytes());
}

fn run(pty: &mut PtyDevice, model: i32, shared: &FirmwareShared) {
    let mut pending: Vec<u8> = Vec::new();
    let mut last_message: Option<Instant> = None;
    let mut chunk = [0u8; 256];
    while !shared.stop.load(Ordering::Acquire) {
        // Watchdog (ino:274-281): 100 ms after the last valid message the amplifiers are cut.
        if let Some(at) = last_message {
            if at.elapsed() > Duration::from_millis(100) {
                last_message = None;
                shared.amplifiers_enabled.store(false, Ordering::Release);
                shared.log.lock().unwrap().push(FirmwareEvent::WatchdogCut);
            }
        }
        match pty.read(&mut chunk) {
            Ok(n) => pending.extend_from_slice(&chunk[..n]),
            Err(_) => {
                // The host closed its end; wait for it to open again.
                std::thread::sleep(Duration::from_millis(2));
                continue;
            }
        }
        // await_message (ino:419-455) over the bytes received so far.
        loop {
            let mut start: Option<usize> = None;
            let mut commas = 0;
            let mut outcome: Option<(usize, i32)> = None; // (bytes consumed, error or 0)
            for (pos, &c) in pending.iter().enumerate() {
                if pos >= BUF_LEN {
                    outcome = Some((BUF_LEN, 128));
                    break;
                }
                if c == b']' {
                    let mut consumed = pos + 1;
                    let mut error = if start.is_none() {
                        256
                    } else if commas != 2 {
                        512
                    } else {
                        0
                    };
                    if error == 0 {
                        // Everything still available is read; anything but line ends is error 8.
                        let trailing = &pending[consumed..];
                        if trailing.iter().any(|&b| b != b'\n' && b != b'\r' && b != 0) {
                            error = 8;
                        }
                        consumed = pending.len();
                    }
                    outcome = Some((consumed, error));
                    break;
                }
                if c == b'[' {
                    start = Some(pos);
                }
                if c == b',' {
                    commas += 1;
                }
            }
            let Some((consumed, error)) = outcome else {
                break;
            };
            let message: Vec<u8> = pending.drain(..consumed).collect();
            if error != 0 {
                shared
                    .log
                    .lock()
                    .unwrap()
                    .push(FirmwareEvent::Refused(error));
                reply(pty, model, shared, error);
                continue;
            }
            let start = start.unwrap_or(0);
            let Some(ma) = scan_three(&message[start..]) else {
                shared
                    .log
                    .lock()
                    .unwrap()
                    .push(FirmwareEvent::Refused(1024));
                reply(pty, model, shared, 1024);
                continue;
            };
            last_message = Some(Instant::now());
            shared.amplifiers_enabled.store(true, Ordering::Release);
            let checked = ma.map(|m| {
                if (-ESCON_MAX_MILLIAMPS..=ESCON_MAX_MILLIAMPS).contains(&m) {
                    m
                } else {
                    shared.zeroed_by_check.fetch_add(1, Ordering::AcqRel);
                    0
                }
            });
            shared
                .log
                .lock()
                .unwrap()
                .push(FirmwareEvent::Currents(checked));
            let e = *shared.encoders.lock().unwrap();
            shared.applied.lock().unwrap().push(Applied {
                currents_ma: checked,
                true_counts: [e[0], e[1], e[2]],
            });
            reply(pty, model, shared, 0);
            shared.answered.fetch_add(1, Ordering::AcqRel);
        }
    }
}
