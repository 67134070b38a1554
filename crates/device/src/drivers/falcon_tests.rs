//! Every way a Falcon link can be let go of ends on a zero-torque frame: a stop (the lifecycle wrapper's
//! `close`) or a lost link (its `disable`) arriving while a torque frame is unanswered, while the reply count
//! resynchronises (its zero sent or not yet), after the count overflowed, after a reply went missing, and when
//! the wrapper's own zero cannot go out (a refused write, a failed read before it). Deterministic: the line is
//! an in-memory double that answers at once or not at all, and the frames the host wrote are decoded here as
//! libnifalcon's `formatInput` lays them out (src/firmware/FalconFirmwareNovintSDK.cpp: `<`, three 16-bit
//! motor values as four nibbles each, least significant first, control byte, spare byte, `>`, bytes 1-14 plus
//! 0x41), not by the driver's codec.

use super::*;
use crate::Lifecycle;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

/// The Falcon's end of the line, as the test sets it.
#[derive(Debug, Default)]
struct Line {
    /// Every byte the host wrote.
    written: Vec<u8>,
    /// Bytes on their way to the host.
    to_host: VecDeque<u8>,
    /// Answer each frame at once with a homed frame (a Falcon on time); otherwise answer nothing.
    answer: bool,
    /// Writes to refuse (an error, nothing written) before the next goes through.
    refuse_writes: u32,
    /// Reads to fail before the next succeeds.
    fail_reads: u32,
}

#[derive(Debug, Clone)]
struct Port(Arc<Mutex<Line>>);

fn line_gone(during: &'static str) -> DeviceError {
    DeviceError::Disconnected {
        during,
        kind: std::io::ErrorKind::BrokenPipe,
    }
}

/// A homed Falcon's frame (libnifalcon's `formatOutput` read backwards): encoder counts 0 (every leg at
/// libnifalcon's 35° offset), status byte homing bits 0x7 << 4.
fn homed_reply() -> [u8; 16] {
    let mut frame = [0x41u8; 16];
    frame[0] = b'<';
    frame[13] = 0x41 + (0x7 << 4);
    frame[15] = b'>';
    frame
}

impl ByteTransport for Port {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        let mut line = self.0.lock().unwrap();
        if line.refuse_writes > 0 {
            line.refuse_writes -= 1;
            return Err(line_gone("writing to the test line"));
        }
        line.written.extend_from_slice(bytes);
        if line.answer {
            for _ in bytes.chunks(16) {
                line.to_host.extend(homed_reply());
            }
        }
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], _timeout: Duration) -> Result<usize, DeviceError> {
        let mut line = self.0.lock().unwrap();
        if line.fail_reads > 0 {
            line.fail_reads -= 1;
            return Err(line_gone("reading from the test line"));
        }
        let n = buf.len().min(line.to_host.len());
        for (slot, byte) in buf.iter_mut().zip(line.to_host.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }
}

impl FalconPort for Port {
    fn set_baud(&mut self, _: u32) -> Result<(), DeviceError> {
        Ok(())
    }
    fn set_modem(&mut self, _: bool, _: bool) -> Result<(), DeviceError> {
        Ok(())
    }
    fn purge(&mut self) -> Result<(), DeviceError> {
        self.0.lock().unwrap().to_host.clear();
        Ok(())
    }
    fn set_latency_timer(&mut self, _: u8) -> Result<bool, DeviceError> {
        Ok(false)
    }
    fn check_latency_timer(&self) -> Result<(), DeviceError> {
        Ok(())
    }
}

/// The motor commands of every frame the host wrote, decoded as libnifalcon lays them out (module docs).
fn motor_frames(line: &Arc<Mutex<Line>>) -> Vec<[i16; 3]> {
    let written = line.lock().unwrap().written.clone();
    assert_eq!(written.len() % 16, 0, "a frame was cut: {written:?}");
    written
        .chunks(16)
        .map(|frame| {
            assert!(frame[0] == b'<' && frame[15] == b'>', "{frame:?}");
            let nibble = |i: usize| u16::from(frame[i] - 0x41);
            [0, 1, 2].map(|k| {
                let base = 1 + 4 * k;
                (nibble(base)
                    | nibble(base + 1) << 4
                    | nibble(base + 2) << 8
                    | nibble(base + 3) << 12) as i16
            })
        })
        .collect()
}

/// An open, enabled, homed Falcon whose position the host accepted, that has just written a torque frame
/// (answered or not, as `answered` says); the line's handle.
fn pushing(answered: bool) -> (Lifecycle<Falcon<Port>>, Arc<Mutex<Line>>) {
    let line = Arc::new(Mutex::new(Line {
        answer: true,
        ..Line::default()
    }));
    let mut falcon = Lifecycle::new(Falcon::new(Port(line.clone()), FalconConfig::default()));
    falcon.open().unwrap();
    falcon.enable().unwrap();
    // Two exchanges: the first state makes the Falcon homed (its position is not yet one force may use), the
    // second's position is accepted.
    for _ in 0..2 {
        falcon.write_force(DVec3::ZERO).unwrap();
        falcon.read_state().unwrap();
        falcon.input_checked(true);
    }
    line.lock().unwrap().answer = answered;
    falcon.write_force(DVec3::new(0.0, 0.0, 2.0)).unwrap();
    let frames = motor_frames(&line);
    assert_ne!(
        *frames.last().unwrap(),
        [0; 3],
        "the set-up wrote no torque: {frames:?}"
    );
    (falcon, line)
}

/// The last frame's motor commands, with the frames before it for a failure's message.
fn last_frames(line: &Arc<Mutex<Line>>) -> ([i16; 3], Vec<[i16; 3]>) {
    let frames = motor_frames(line);
    let tail = frames[frames.len().saturating_sub(4)..].to_vec();
    (*frames.last().unwrap(), tail)
}

fn assert_ends_on_zero(line: &Arc<Mutex<Line>>, how: &str) {
    let (last, tail) = last_frames(line);
    assert_eq!(last, [0; 3], "{how}: the last frames {tail:?}");
}

#[test]
fn a_stop_or_a_lost_link_while_a_torque_frame_is_unanswered_ends_on_zero() {
    let (mut falcon, line) = pushing(false);
    falcon.close().unwrap();
    assert_ends_on_zero(&line, "close");
    let (mut falcon, line) = pushing(false);
    falcon.disable().unwrap();
    assert_ends_on_zero(&line, "disable (a lost link)");
    let (mut falcon, line) = pushing(true);
    falcon.close().unwrap();
    assert_ends_on_zero(&line, "close after an answered torque");
}

/// Sixteen bytes that are not a frame (a garbled reply or junk) start a resynchronisation; found before a command, that command is the resync's zero
/// and the stop sends nothing more; found in the state read after a torque frame, the stop's zero is the
/// resync's zero.
#[test]
fn a_stop_while_the_count_resynchronises_ends_on_zero() {
    let (mut falcon, line) = pushing(true);
    falcon.read_state().unwrap();
    line.lock().unwrap().to_host.extend(*b"<AAAAAAAAAAAAAA!");
    falcon.write_force(DVec3::new(0.0, 0.0, 2.0)).unwrap();
    assert!(falcon.device().in_flight.resyncing());
    let before = motor_frames(&line).len();
    falcon.write_force(DVec3::new(0.0, 0.0, 2.0)).unwrap();
    assert_eq!(
        motor_frames(&line).len(),
        before,
        "a frame while resynchronising"
    );
    falcon.close().unwrap();
    assert_ends_on_zero(&line, "close after the resync's zero");

    let (mut falcon, line) = pushing(false);
    line.lock().unwrap().to_host.extend(*b"<AAAAAAAAAAAAAA!");
    // The state read finds the junk: the count is in doubt with a torque frame the last one out.
    let _ = falcon.read_state();
    assert!(falcon.device().in_flight.resyncing());
    falcon.close().unwrap();
    assert_ends_on_zero(&line, "close with the resync's zero not yet sent");
}

/// A Falcon that never answers: after [`super::super::in_flight::IN_FLIGHT_CAPACITY`] unanswered commands the
/// count is past belief (the last frame out carried a torque), and a stop then still ends on zero; so does a
/// stop after a reply has been missing longer than [`LOST_REPLY_AFTER`].
#[test]
fn a_stop_after_the_count_overflowed_or_a_reply_went_missing_ends_on_zero() {
    let (mut falcon, line) = pushing(false);
    for _ in 0..super::super::in_flight::IN_FLIGHT_CAPACITY {
        falcon.write_force(DVec3::new(0.0, 0.0, 2.0)).unwrap();
    }
    assert!(falcon.device().in_flight.resyncing());
    falcon.close().unwrap();
    assert_ends_on_zero(&line, "close after the count overflowed");

    let (mut falcon, line) = pushing(false);
    std::thread::sleep(LOST_REPLY_AFTER + Duration::from_millis(10));
    falcon.close().unwrap();
    assert_ends_on_zero(&line, "close after a reply went missing");
}

/// The wrapper's zero cannot go out: its write is refused, or the read before it (the drain) fails. The
/// driver's own disable still sends one (the last frame out carried a torque). Without that, the Falcon keeps
/// the torque: both fail with `disable`'s zero removed.
#[test]
fn a_stop_whose_zero_cannot_go_out_is_zeroed_by_disable() {
    let (mut falcon, refused) = pushing(false);
    refused.lock().unwrap().refuse_writes = 1;
    assert!(falcon.close().is_err());
    let (mut falcon, unread) = pushing(false);
    unread.lock().unwrap().fail_reads = 1;
    assert!(falcon.close().is_err());
    // Both cases checked before either fails, so a broken driver shows both.
    let ends = [
        ("the wrapper's zero refused", last_frames(&refused)),
        ("the read before the zero failed", last_frames(&unread)),
    ];
    assert!(
        ends.iter().all(|(_, (last, _))| *last == [0; 3]),
        "the last frames after a close with {ends:?}"
    );
}
