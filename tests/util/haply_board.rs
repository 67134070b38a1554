//! A test double of the Haply 2DIY board, parsing commands the way the board's firmware does
//! (Haply_Arduino_Firmware.h V1.5.0, S. Ding and C. Gallacher; the host side is Haply-API-cpp V2.1.0
//! `src/Haply/Board.cpp`, `src/Haply/Device.cpp`): a command starts with its type (`command_instructions`);
//! reset (0) is followed by the device address (`reset_haply`); setup (1) by the address, the motor mask and one
//! direction byte per motor set in it (`mtr_parameters`), the encoder mask and one direction byte per encoder
//! (`enc_parameters`), a sensor count and that many sensor ports, a PWM count and that many pins, then offset and
//! resolution (two little-endian f32) per encoder (`setup_device`); torques (2) by the address, one pulse byte per
//! PWM pin set up, and one f32 per motor (`write_states`), answered by the address then one f32 per analogue
//! sensor and per encoder (`read_states`). So the lengths come from the setup the host sent, never from voxhap's
//! driver. Each motor's torque is clamped at `MAX_TORQUE` = 0.123 N m on its own (`create_torque`); the double
//! records what the motors then exert ([`BoardShared::exerted`]). Served on a pseudo-terminal. It logs every torque
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
    /// The torque pairs the motors exert after the firmware's per-motor clamp (port order), in order.
    pub exerted: Mutex<Vec<[f32; 2]>>,
    /// The setup the host sent, as the firmware parsed it (`None` before one).
    pub setup: Mutex<Option<Setup>>,
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

/// The firmware's per-motor torque limit (N m), Haply_Arduino_Firmware.h `MAX_TORQUE`.
pub const MAX_TORQUE: f32 = 0.123;

/// A setup command as `setup_device` parses it.
#[derive(Debug, Clone, PartialEq)]
pub struct Setup {
    pub address: u8,
    pub motor_directions: Vec<u8>,
    pub encoder_directions: Vec<u8>,
    pub sensor_ports: Vec<u8>,
    pub pwm_pins: Vec<u8>,
    /// (offset degrees, resolution) per encoder.
    pub encoder_parameters: Vec<(f32, f32)>,
}

/// Parses a setup command (type byte first) the way `setup_device` reads it; `None` until all of it is there.
/// Returns the setup and its length.
pub fn parse_setup(bytes: &[u8]) -> Option<(Setup, usize)> {
    let mut at = 1;
    let mut next = |n: usize| {
        let slice = bytes.get(at..at + n)?;
        at += n;
        Some(slice.to_vec())
    };
    let address = next(1)?[0];
    let motor_mask = next(1)?[0];
    let motor_directions = next((motor_mask & 0xf).count_ones() as usize)?;
    let encoder_mask = next(1)?[0];
    let encoder_directions = next((encoder_mask & 0xf).count_ones() as usize)?;
    let sensors = next(1)?[0] as usize;
    let sensor_ports = next(sensors)?;
    let pwms = next(1)?[0] as usize;
    let pwm_pins = next(pwms)?;
    let raw = next(encoder_directions.len() * 8)?;
    let float = |i: usize| f32::from_le_bytes([raw[i], raw[i + 1], raw[i + 2], raw[i + 3]]);
    let encoder_parameters = (0..encoder_directions.len())
        .map(|e| (float(8 * e), float(8 * e + 4)))
        .collect();
    Some((
        Setup {
            address,
            motor_directions,
            encoder_directions,
            sensor_ports,
            pwm_pins,
            encoder_parameters,
        },
        at,
    ))
}
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

/// `read_states`: the address the torques came with, then one f32 per encoder (no analogue sensors here).
fn reply(address: u8, angles: [f32; 2]) -> [u8; 9] {
    let mut out = [0u8; 9];
    out[0] = address;
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
            let setup = shared.setup.lock().unwrap().clone();
            let len = match (kind, &setup) {
                (0, _) => 2,
                (1, _) => match parse_setup(&pending) {
                    Some((setup, len)) => {
                        *shared.setup.lock().unwrap() = Some(setup);
                        len
                    }
                    None => break,
                },
                (2, Some(setup)) => 2 + setup.pwm_pins.len() + 4 * setup.motor_directions.len(),
                _ => {
                    // Not a command start (or torques before any setup): the board's parser would be lost
                    // too; drop the byte.
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
                    let setup = setup.expect("torques parsed only after a setup");
                    let first = 2 + setup.pwm_pins.len();
                    let f = |i: usize| {
                        f32::from_le_bytes([
                            command[i],
                            command[i + 1],
                            command[i + 2],
                            command[i + 3],
                        ])
                    };
                    // A 2DIY: two motors, two encoders; other setups are recorded but not served.
                    assert_eq!(setup.motor_directions.len(), 2, "{setup:?}");
                    assert_eq!(setup.encoder_directions.len(), 2, "{setup:?}");
                    let torques = [f(first), f(first + 4)];
                    shared.torques.lock().unwrap().push(torques);
                    shared
                        .exerted
                        .lock()
                        .unwrap()
                        .push(torques.map(|t| t.clamp(-MAX_TORQUE, MAX_TORQUE)));
                    let truth = shared.true_angles_deg.lock().unwrap().unwrap_or(ANGLES_DEG);
                    shared.applied.lock().unwrap().push(Applied {
                        torques,
                        true_angles_deg: truth,
                    });
                    let fault = {
                        let mut faults = shared.faults.lock().unwrap();
                        (!faults.is_empty()).then(|| faults.remove(0))
                    };
                    let reading = shared.readings.lock().unwrap().pop_front().unwrap_or(truth);
                    let answer = reply(command[1], reading);
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
