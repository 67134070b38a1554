//! A test double of the Haply 2DIY board (Haply-API-cpp V2.1.0 `src/Haply/Board.cpp`, `src/Haply/Device.cpp`):
//! commands are `[type][device id][bytes…]` (type 0 reset: 2 bytes; type 1 setup: 26 bytes for two ports; type 2
//! torques: id then two little-endian f32 in port order), and a torque command is answered by
//! `[device id][f32 angle port 1][f32 angle port 2]` (degrees). Served on a pseudo-terminal. It logs every torque
//! pair, and can misbehave the way a USB serial link does: stale bytes before the host opens, a reply cut short
//! whose rest arrives late, and a stray extra byte. It can also report readings that are not the pantograph's
//! true angles (glitches, NaN) while logging every torque pair with the true angles ([`Applied`]), and answer
//! every command more than once.

use super::pty::PtyDevice;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// How the next reply goes wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Only the first 4 bytes now, the other 5 after 30 ms.
    Partial,
    /// One stray byte before the reply.
    ExtraByte,
}

/// One torque command with the true angles when it arrived (both in port order).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Applied {
    pub torques: [f32; 2],
    pub true_angles_deg: [f32; 2],
}

#[derive(Debug, Default)]
pub struct BoardShared {
    /// The pantograph's true angles (degrees, port order); `None` means [`ANGLES_DEG`].
    pub true_angles_deg: Mutex<Option<[f32; 2]>>,
    /// Readings for the next replies instead of the true angles (port order; NaN allowed), in order.
    pub readings: Mutex<VecDeque<[f32; 2]>>,
    /// Every torque command with the true angles.
    pub applied: Mutex<Vec<Applied>>,
    /// Replies per torque command beyond the first.
    pub extra_answers: AtomicU32,
    /// Torque commands answered (all answers written).
    pub answered: AtomicU64,
    /// Torque pairs received (port order), in order.
    pub torques: Mutex<Vec<[f32; 2]>>,
    /// Resets and setups received.
    pub setups: Mutex<u32>,
    /// Faults to apply to the next replies, in order.
    pub faults: Mutex<Vec<Fault>>,
    stop: AtomicBool,
}

pub struct HaplyBoard {
    pub shared: Arc<BoardShared>,
    path: String,
    thread: Option<JoinHandle<()>>,
}

pub const DEVICE_ID: u8 = 5;
/// Angles reported (degrees, port 1 then port 2): a symmetric pose.
pub const ANGLES_DEG: [f32; 2] = [45.0, 135.0];

impl HaplyBoard {
    /// Starts the board; `stale` bytes are queued for the host before it opens the port.
    pub fn start(stale: &[u8]) -> HaplyBoard {
        let mut pty = PtyDevice::new();
        pty.write(stale).unwrap();
        let path = pty.path().to_string();
        let shared = Arc::new(BoardShared::default());
        let thread = {
            let shared = shared.clone();
            std::thread::spawn(move || run(&mut pty, &shared))
        };
        HaplyBoard {
            shared,
            path,
            thread: Some(thread),
        }
    }

    pub fn path(&self) -> &str {
        &self.path
    }

    pub fn torques(&self) -> Vec<[f32; 2]> {
        self.shared.torques.lock().unwrap().clone()
    }
}

impl Drop for HaplyBoard {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn reply(angles: [f32; 2]) -> [u8; 9] {
    let mut out = [0u8; 9];
    out[0] = DEVICE_ID;
    out[1..5].copy_from_slice(&angles[0].to_le_bytes());
    out[5..9].copy_from_slice(&angles[1].to_le_bytes());
    out
}

fn run(pty: &mut PtyDevice, shared: &BoardShared) {
    let mut pending: Vec<u8> = Vec::new();
    let mut chunk = [0u8; 256];
    let mut late: Option<(std::time::Instant, Vec<u8>)> = None;
    while !shared.stop.load(Ordering::Acquire) {
        if let Some((at, bytes)) = &late {
            if at.elapsed() >= Duration::from_millis(30) {
                let _ = pty.write(bytes);
                late = None;
            }
        }
        match pty.read(&mut chunk) {
            Ok(n) => pending.extend_from_slice(&chunk[..n]),
            Err(_) => {
                std::thread::sleep(Duration::from_millis(1));
                continue;
            }
        }
        while let Some(&kind) = pending.first() {
            let len = match kind {
                0 => 2,
                1 => 26,
                2 => 10,
                _ => {
                    // Not a command start: the board's parser would be lost too; drop the byte.
                    pending.remove(0);
                    continue;
                }
            };
            if pending.len() < len {
                break;
            }
            let command: Vec<u8> = pending.drain(..len).collect();
            match kind {
                0 | 1 => *shared.setups.lock().unwrap() += 1,
                _ => {
                    let f = |i: usize| {
                        f32::from_le_bytes([
                            command[i],
                            command[i + 1],
                            command[i + 2],
                            command[i + 3],
                        ])
                    };
                    shared.torques.lock().unwrap().push([f(2), f(6)]);
                    let truth = shared.true_angles_deg.lock().unwrap().unwrap_or(ANGLES_DEG);
                    shared.applied.lock().unwrap().push(Applied {
                        torques: [f(2), f(6)],
                        true_angles_deg: truth,
                    });
                    let fault = {
                        let mut faults = shared.faults.lock().unwrap();
                        (!faults.is_empty()).then(|| faults.remove(0))
                    };
                    let reading = shared.readings.lock().unwrap().pop_front().unwrap_or(truth);
                    let answer = reply(reading);
                    let extra = shared.extra_answers.load(Ordering::Acquire) as usize;
                    let _ = match fault {
                        None => pty.write(&answer.repeat(1 + extra)),
                        Some(Fault::ExtraByte) => pty.write(&[0x77]).and(pty.write(&answer)),
                        Some(Fault::Partial) => {
                            late = Some((std::time::Instant::now(), answer[4..].to_vec()));
                            pty.write(&answer[..4])
                        }
                    };
                    shared.answered.fetch_add(1, Ordering::AcqRel);
                }
            }
        }
    }
}
