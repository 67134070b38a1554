//! The driver against the protocol crate's own device session, in process (no transport): what the handshake
//! negotiates with devices of each version (SPEC section 10.1).

use super::*;
use std::collections::VecDeque;
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
