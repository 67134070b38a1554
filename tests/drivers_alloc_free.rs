//! The servo-path rule for every driver of issue 13: after warm-up, a tick's `write_force` + `read_state`
//! allocates nothing (the counting allocator counts this thread only; the device doubles answer from their own
//! threads). WoodenHaptics (Teensy), Haply 2DIY and Falcon run over in-memory pipes, the Inverse3 over a loopback
//! WebSocket, the legacy WoodenHaptics HID driver over a fixed report source.

use crate::util::alloc::count_allocations;
use crate::util::falcon_firmware::Bootloader;
use crate::util::inverse_service::InverseService;
use glam::DVec3;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use voxhap::device::drivers::falcon::{Falcon, FalconConfig};
use voxhap::device::drivers::haply::{Haply2Diy, Haply2DiyConfig};
use voxhap::device::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use voxhap::device::drivers::woodenhaptics::{WoodenHaptics, WoodenHapticsConfig};
use voxhap::device::drivers::woodenhaptics_serial::{WoodenHapticsSerial, WoodyConfig};
use voxhap::device::transport::inverse_service::ServiceConfig;
use voxhap::device::transport::{ByteTransport, MemoryPipe, ReportTransport};
use voxhap::device::{DeviceError, HapticDevice};

/// Runs `ticks` ticks after `warm_up` ticks and returns the allocation events of the counted ones.
fn ticks_allocate<D: HapticDevice>(device: &mut D, warm_up: usize, ticks: usize) -> u64 {
    let mut tick = |i: usize| {
        let force = DVec3::new(0.1 * (i as f64 * 0.01).sin(), 0.0, 0.2);
        device.write_force(force).unwrap();
        std::hint::black_box(device.read_state().unwrap());
    };
    for i in 0..warm_up {
        tick(i);
    }
    let ((), events) = count_allocations(|| {
        for i in 0..ticks {
            tick(warm_up + i);
        }
    });
    events
}

/// A device thread on the far end of a pipe: `answer` turns the bytes of one command into the reply.
fn responder(
    mut pipe: MemoryPipe,
    command_len: impl Fn(&[u8]) -> Option<usize> + Send + 'static,
    answer: impl Fn(&[u8]) -> Vec<u8> + Send + 'static,
) -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    std::thread::spawn(move || {
        let mut pending = Vec::new();
        let mut buf = [0u8; 256];
        while !flag.load(Ordering::Acquire) {
            match pipe.read(&mut buf, Duration::from_millis(5)) {
                Ok(n) => pending.extend_from_slice(&buf[..n]),
                Err(_) => return,
            }
            while let Some(len) = command_len(&pending) {
                let command: Vec<u8> = pending.drain(..len).collect();
                if pipe.write_all(&answer(&command)).is_err() {
                    return;
                }
            }
        }
    });
    stop
}

#[test]
fn woodenhaptics_serial_ticks_allocate_nothing() {
    let (host, device) = MemoryPipe::pair();
    let stop = responder(
        device,
        |p| p.iter().position(|&b| b == b'\n').map(|i| i + 1),
        |_| b"[3,120,-40,300,0,0,0,0]\n".to_vec(),
    );
    let mut driver = WoodenHapticsSerial::new(host, WoodyConfig::default());
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
    stop.store(true, Ordering::Release);
}

#[test]
fn haply_2diy_ticks_allocate_nothing() {
    let (host, device) = MemoryPipe::pair();
    let stop = responder(
        device,
        |p| match p.first() {
            Some(0) if p.len() >= 2 => Some(2),
            Some(1) if p.len() >= 26 => Some(26),
            Some(2) if p.len() >= 10 => Some(10),
            _ => None,
        },
        |c| {
            if c[0] == 2 {
                let mut r = vec![5u8];
                r.extend_from_slice(&45f32.to_le_bytes());
                r.extend_from_slice(&135f32.to_le_bytes());
                r
            } else {
                Vec::new()
            }
        },
    );
    let mut driver = Haply2Diy::new(host, Haply2DiyConfig::default());
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
    stop.store(true, Ordering::Release);
}

#[test]
fn falcon_ticks_allocate_nothing() {
    // The bootloader double runs its firmware once it has 1 byte of "firmware"; upload it, then tick.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("fw.bin");
    std::fs::write(&file, [0x5a]).unwrap();
    let (bootloader, pipe) = Bootloader::start(1);
    *bootloader.shared.homing.lock().unwrap() = 0x7;
    *bootloader.shared.encoders.lock().unwrap() = [-300, 200, 100];
    let mut driver = Falcon::new(
        pipe,
        FalconConfig {
            firmware: Some(file),
            ..FalconConfig::default()
        },
    );
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
}

#[test]
fn haply_inverse_ticks_allocate_nothing() {
    let service = InverseService::start();
    let mut driver = HaplyInverse::new(HaplyInverseConfig {
        service: ServiceConfig {
            url: service.url(),
            ..ServiceConfig::default()
        },
        reply_wait: Duration::from_millis(20),
        ..HaplyInverseConfig::default()
    });
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
    driver.close().unwrap();
}

/// A HID source that always has the same two reports queued (so every read drains one stale report).
struct FixedReports {
    queued: u8,
}

impl ReportTransport for FixedReports {
    fn write_report(&mut self, _report: &[u8]) -> Result<(), DeviceError> {
        self.queued = 2;
        Ok(())
    }
    fn read_report(&mut self, buf: &mut [u8], _timeout: Duration) -> Result<usize, DeviceError> {
        if self.queued == 0 {
            return Ok(0);
        }
        self.queued -= 1;
        buf[..8].copy_from_slice(&[10, 0, 20, 0, 30, 0, self.queued, 0]);
        Ok(8)
    }
}

#[test]
fn woodenhaptics_hid_ticks_allocate_nothing_and_keep_the_newest_report() {
    let mut driver =
        WoodenHaptics::new(FixedReports { queued: 0 }, WoodenHapticsConfig::default()).unwrap();
    assert_eq!(ticks_allocate(&mut driver, 10, 1000), 0);
    // Two reports were queued per tick; the newest (counter 0) was kept, the older one skipped.
    assert_eq!(driver.last_counter(), Some(0));
    assert_eq!(driver.drained_reports(), 1010);
}
