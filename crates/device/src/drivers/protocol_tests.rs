//! The driver against the protocol crate's own device session, in process (no transport): what the handshake
//! negotiates with devices of each version (SPEC section 10.1).

use super::*;
use std::collections::VecDeque;
use std::time::Instant;
use voxhap_protocol::{DeviceSample, DeviceSession, Label, RateSet, Version};

/// A device session behind a [`MessageLink`]: every message the driver sends reaches it at once; its replies
/// come back in order. Its clock moves 100 µs per call.
struct InProcess {
    device: DeviceSession,
    now_us: u64,
    replies: VecDeque<DeviceToHost>,
}

impl InProcess {
    fn new(device: DeviceSession) -> Self {
        Self {
            device,
            now_us: 0,
            replies: VecDeque::new(),
        }
    }

    fn run(&mut self) {
        self.now_us += 100;
        let sample = DeviceSample {
            position_m: [0.0; 3],
            velocity_m_per_s: [0.0; 3],
            buttons: 0,
        };
        self.device.poll(self.now_us, &sample);
        while let Some(reply) = self.device.poll_transmit() {
            self.replies.push_back(reply);
        }
    }
}

impl MessageLink for InProcess {
    fn send(&mut self, message: &HostToDevice) -> Result<(), DeviceError> {
        self.device.on_message(message, self.now_us);
        self.run();
        Ok(())
    }

    fn receive(&mut self, _timeout: Duration) -> Result<Option<DeviceToHost>, DeviceError> {
        if self.replies.is_empty() {
            self.run();
        }
        Ok(self.replies.pop_front())
    }

    fn flush(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }

    fn stats(&self) -> DecoderStats {
        DecoderStats::default()
    }
}

fn info(minor: u8) -> voxhap_protocol::DeviceInfo {
    voxhap_protocol::DeviceInfo {
        version: Version { major: 1, minor },
        model: Label::new("in-process").unwrap_or_default(),
        serial_number: Label::new("1").unwrap_or_default(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        supported_rates: RateSet::from_rates_hz(&[500, 1000]).unwrap_or_default(),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 2000.0,
    }
}

fn opened(device: DeviceSession) -> ProtocolDevice<InProcess> {
    let mut driver = ProtocolDevice::new(InProcess::new(device), ProtocolConfig::default());
    driver.open().expect("the in-process device answers");
    driver
}

#[test]
fn a_1_1_device_with_the_capability_gets_local_models() {
    let driver = opened(DeviceSession::with_local_model(info(1)));
    assert!(driver.local_model_capable());
}

#[test]
fn a_1_0_device_keeps_set_force_even_if_it_sets_bit_6() {
    // Bit 6 is reserved in 1.0 (sent as zero, ignored on receipt): a 1.0 device that sets it anyway is not
    // capable (SPEC sections 2 and 10.1).
    let device = DeviceSession::with_local_model(info(0));
    assert!(device.status().contains(StatusFlags::LOCAL_MODEL));
    let driver = opened(device);
    assert!(!driver.local_model_capable());
}

#[test]
fn a_1_1_device_without_the_capability_keeps_set_force() {
    let driver = opened(DeviceSession::new(info(1)));
    assert!(!driver.local_model_capable());
}

#[test]
fn a_1_0_device_without_the_bit_opens_and_keeps_set_force() {
    let driver = opened(DeviceSession::new(info(0)));
    assert!(!driver.local_model_capable());
    assert_eq!(driver.info().model, "in-process");
}

/// A device session whose replies reach the host `delay` after it answered (a slow link), on the wall clock;
/// with `drop_states_after`, every State after that many is lost.
struct Delayed {
    device: DeviceSession,
    started: Instant,
    delay: Duration,
    replies: VecDeque<(Instant, DeviceToHost)>,
    states: usize,
    drop_states_after: Option<usize>,
}

impl Delayed {
    fn new(device: DeviceSession, delay: Duration) -> Self {
        Delayed {
            device,
            started: Instant::now(),
            delay,
            replies: VecDeque::new(),
            states: 0,
            drop_states_after: None,
        }
    }

    fn now_us(&self) -> u64 {
        self.started.elapsed().as_micros() as u64
    }
}

impl MessageLink for Delayed {
    fn send(&mut self, message: &HostToDevice) -> Result<(), DeviceError> {
        let now_us = self.now_us();
        self.device.on_message(message, now_us);
        let sample = DeviceSample {
            position_m: [0.0; 3],
            velocity_m_per_s: [0.0; 3],
            buttons: 0,
        };
        self.device.poll(now_us, &sample);
        let release = Instant::now() + self.delay;
        while let Some(reply) = self.device.poll_transmit() {
            if matches!(reply, DeviceToHost::State(_)) {
                self.states += 1;
                if self
                    .drop_states_after
                    .is_some_and(|kept| self.states > kept)
                {
                    continue;
                }
            }
            self.replies.push_back((release, reply));
        }
        Ok(())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<DeviceToHost>, DeviceError> {
        let deadline = Instant::now() + timeout;
        let Some(&(release, _)) = self.replies.front() else {
            std::thread::sleep(timeout);
            return Ok(None);
        };
        if release > deadline {
            std::thread::sleep(timeout);
            return Ok(None);
        }
        std::thread::sleep(release.saturating_duration_since(Instant::now()));
        Ok(self.replies.pop_front().map(|(_, reply)| reply))
    }

    fn flush(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }

    fn stats(&self) -> DecoderStats {
        DecoderStats::default()
    }
}

fn open_delayed(link: Delayed, probes: u32) -> ProtocolDevice<Delayed> {
    let config = ProtocolConfig {
        latency_probes: probes,
        ..ProtocolConfig::default()
    };
    let mut driver = ProtocolDevice::new(link, config);
    driver.open().expect("the delayed device answers");
    driver
}

/// Replies 2 ms late: every round trip open times is at least the link's 2 ms (whatever the machine's load,
/// a reply cannot come before it was released), one for the first State and one per probe, and the declared
/// worst case is at least 2 ms, a multiple of 0.1 ms, and says it was measured. Before open nothing is
/// declared.
#[test]
fn open_measures_the_links_round_trips_and_declares_their_95th_percentile() {
    let delay = Duration::from_millis(2);
    let link = Delayed::new(DeviceSession::new(info(1)), delay);
    assert_eq!(
        ProtocolDevice::new(link, ProtocolConfig::default()).link_latency(),
        None
    );
    let driver = open_delayed(Delayed::new(DeviceSession::new(info(1)), delay), 16);
    assert_eq!(driver.round_trips().len(), 17);
    assert!(
        driver.round_trips().iter().all(|trip| *trip >= delay),
        "{:?}",
        driver.round_trips()
    );
    let latency = driver.link_latency().expect("measured");
    assert_eq!(latency.round_trips, 17);
    assert_eq!(latency.source, latency::MEASURED);
    assert!(
        latency.worst >= delay && latency.typical >= delay,
        "{latency:?}"
    );
    assert_eq!(latency.worst.as_micros() % 100, 0, "{latency:?}");
    assert!(latency.worst >= latency.typical);
}

/// The bare driver's default measures the first State's round trip alone; a device that stops answering
/// after it costs three unanswered probes and still opens, its latency from what did come.
#[test]
fn no_probes_by_default_and_lost_answers_do_not_fail_open() {
    let delay = Duration::from_micros(500);
    let driver = open_delayed(Delayed::new(DeviceSession::new(info(1)), delay), 0);
    assert_eq!(driver.round_trips().len(), 1);
    let mut link = Delayed::new(DeviceSession::new(info(1)), delay);
    link.drop_states_after = Some(1);
    let driver = open_delayed(link, 64);
    assert_eq!(driver.round_trips().len(), 1);
    assert_eq!(driver.link().states, 4, "the first State and three probes");
    assert_eq!(driver.link_latency().unwrap().round_trips, 1);
}

/// Every force the servo sends after open is timed to the State echoing it: ten ticks over a link that
/// holds each reply 2 ms give ten round trips, none shorter than the 2 ms (a reply cannot come before the
/// link released it, whatever the machine's load), the longest at least 2 ms, 2 ticks or more at 1 kHz. A
/// new open forgets them (the next connection's delay is its own).
#[test]
fn every_tick_times_the_round_trip_of_its_force() {
    let delay = Duration::from_millis(2);
    let mut driver = open_delayed(Delayed::new(DeviceSession::new(info(1)), delay), 0);
    assert_eq!(driver.link_delay_seen(), None, "open's probes are not live");
    for tick in 0..10 {
        driver
            .write_force(glam::DVec3::new(0.0, 0.0, 0.1 * f64::from(tick)))
            .unwrap();
        let _ = driver.read_state();
    }
    // The last answers come after the ticks: drain them.
    while driver
        .poll_event(Duration::from_millis(20))
        .unwrap()
        .is_some()
    {}
    let seen = driver.link_delay_seen().expect("timed");
    assert_eq!(seen.round_trips, 10, "{seen:?}");
    assert!(
        seen.typical >= delay && seen.worst >= seen.typical,
        "{seen:?}"
    );
    assert!(seen.worst_ticks(Duration::from_millis(1)) >= 2);
    driver.open().unwrap();
    assert_eq!(driver.link_delay_seen(), None);
}
