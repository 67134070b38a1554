//! The I/O shell's waits, recorded by a double of the service's socket while the whole driver runs (servo
//! thread: `write_force`/`read_state`; I/O thread: this shell, the link core, the shared runner).

use super::*;
use crate::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use crate::transport::inverse_service::{Configuration, ServiceDevice};
use crate::HapticDevice;
use std::collections::VecDeque;
use std::sync::Mutex;

/// Which wait the shell asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Asked {
    /// `wait_readable`: for the reply to the message just sent.
    Reply(Duration),
    /// `idle`: nothing to send.
    Idle(Duration),
}

/// A service socket that answers each message with one state update, as Haply documents ("exactly one State
/// Update message for each message received"), except every third, whose reply never comes (so the shell
/// waits its whole reply wait for it), and records every wait the shell asks of it. Each wait lasts as long
/// as asked, as a socket's would.
struct RecordingChannel {
    waiting: VecDeque<Message>,
    received: u64,
    asked: Arc<Mutex<Vec<Asked>>>,
}

const DEVICE_ID: &str = "049D";

impl MessageTransport for RecordingChannel {
    type Message = Message;

    fn try_read_message(&mut self) -> Result<Option<Message>, DeviceError> {
        Ok(self.waiting.pop_front())
    }

    fn wait_readable(&mut self, wait: Duration) -> Result<(), DeviceError> {
        self.asked.lock().unwrap().push(Asked::Reply(wait));
        if self.waiting.is_empty() {
            std::thread::sleep(wait);
        }
        Ok(())
    }
}

impl ServiceChannel for RecordingChannel {
    fn send_text(&mut self, _text: String) -> Result<(), DeviceError> {
        self.received += 1;
        if !self.received.is_multiple_of(3) {
            // Haply's example state (docs.haply.co tutorial "01. Print Inverse3").
            self.waiting.push_back(Message::text(format!(
                r#"{{"inverse3":[{{"device_id":"{DEVICE_ID}","state":{{"cursor_position":{{"x":0.0,"y":-0.12,"z":0.15}}}}}}]}}"#
            )));
        }
        Ok(())
    }

    fn close(&mut self) {}

    fn idle(&mut self, wait: Duration) {
        self.asked.lock().unwrap().push(Asked::Idle(wait));
        std::thread::park_timeout(wait);
    }
}

/// Runs the driver for `ticks` servo ticks of `period` on the recording double with `config`; returns every
/// wait the I/O thread asked for and the servo thread's own wait.
fn run_driver(config: HaplyInverseConfig, period: Duration, ticks: u32) -> (Vec<Asked>, Duration) {
    let asked = Arc::new(Mutex::new(Vec::new()));
    let channel = RecordingChannel {
        waiting: VecDeque::new(),
        received: 0,
        asked: asked.clone(),
    };
    let device = ServiceDevice {
        device_id: DEVICE_ID.to_owned(),
        device_type: "inverse3".to_owned(),
        firmware: None,
        handedness: None,
        session_id: None,
        configuration: Configuration::Confirmed,
        filters: None,
    };
    let snapshot = ServiceSnapshot {
        answers_sequence: 0,
        position_m: DVec3::new(0.0, -0.12, 0.15),
        velocity_m_per_s: DVec3::ZERO,
        arm_force_n: None,
    };
    let mut service = config.service.clone();
    // A port nothing listens on (refused at once): the events thread says so and retries, off this test's path.
    service.events_url = Some("ws://127.0.0.1:1".to_owned());
    let link = start_on(channel, device, snapshot, &service).unwrap();
    let mut driver = HaplyInverse::on_link(config, link);
    let servo_wait = driver.config().reply_wait;
    let start = Instant::now();
    for tick in 0..ticks {
        if let Some(wait) = (start + period * tick).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        // A lost reply is a late state or a timeout (and an I/O thread that waits too long lets the force
        // queue fill): the waits are what is checked here.
        let _ = driver.write_force(DVec3::new(0.0, 0.0, 1.0));
        let _ = driver.read_state();
    }
    driver.close().unwrap();
    let asked = asked.lock().unwrap().clone();
    (asked, servo_wait)
}

/// At a 4 kHz servo period every wait the driver asks for, on the servo thread and on the I/O thread (for a
/// reply, including replies that never come, and with nothing to send), is at most the period, so nothing the
/// service does (or does not) send holds a force back past one tick. Counted, not timed: the double records
/// the waits asked of it. With the period's caps removed from `for_period`, the I/O thread asks for 1 ms
/// slices of its 20 ms reply wait and 0.5 ms idle sleeps, and this fails.
#[test]
fn at_4_khz_no_wait_the_driver_asks_for_is_longer_than_the_period() {
    let period = Duration::from_micros(250);
    let config = HaplyInverseConfig::default().for_period(period);
    let (asked, servo_wait) = run_driver(config, period, 400);
    let replies = asked
        .iter()
        .filter(|a| matches!(a, Asked::Reply(_)))
        .count();
    let idles = asked.len() - replies;
    // Both kinds of wait happened, so the check below is not vacuous.
    assert!(
        replies > 0 && idles > 0,
        "{replies} reply waits, {idles} idle waits"
    );
    let too_long: Vec<&Asked> = asked
        .iter()
        .filter(|a| match a {
            Asked::Reply(wait) | Asked::Idle(wait) => *wait > period,
        })
        .collect();
    assert!(
        too_long.is_empty() && servo_wait <= period,
        "{} of {} I/O-thread waits longer than the {period:?} period, e.g. {:?}; the servo thread waits {servo_wait:?}",
        too_long.len(),
        asked.len(),
        &too_long[..too_long.len().min(5)]
    );
}
