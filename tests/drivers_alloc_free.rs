//! The servo-path rule for every driver: after warm-up, a tick allocates nothing (the counting allocator counts
//! this thread only; the device doubles answer from their own threads). WoodenHaptics (Teensy), Haply 2DIY, Falcon
//! and the voxhap protocol over serial run over in-memory pipes, the voxhap protocol over HID over an in-memory
//! report pipe, the Inverse3 over a loopback WebSocket, the legacy WoodenHaptics HID driver over a fixed report
//! source; both HID links through the real HID transport over doubles that wait in whole milliseconds, as hidapi;
//! the 2DIY (with its resync) and WoodenHaptics drivers also through the real serial transport on a
//! pseudo-terminal.
//!
//! Each driver is checked twice: bare (`write_force` + `read_state`), and the way the servo thread holds it, inside
//! the reconnecting wrapper (`servo::device::Reconnecting`: connector thread, supervisor with its lifecycle, link
//! health and safety pipeline), connected, enabled and engaged, one `ServoDevice::exchange` per tick.

use crate::util::alloc::count_allocations;
use crate::util::falcon_firmware::{Bootloader, FalconLine, Junk};
use crate::util::haply_board::{Fault, HaplyBoard};
use crate::util::inverse_service::InverseService;
use crate::util::woody_firmware::WoodyFirmware;
use glam::DVec3;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use voxhap::device::drivers::falcon::{Falcon, FalconConfig};
use voxhap::device::drivers::haply::{Haply2Diy, Haply2DiyConfig};
use voxhap::device::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use voxhap::device::drivers::protocol::{HidLink, ProtocolConfig, ProtocolDevice, SerialLink};
use voxhap::device::drivers::woodenhaptics::{WoodenHaptics, KINEMATICS as WOODENHAPTICS_HID};
use voxhap::device::drivers::woodenhaptics_serial::{WoodenHapticsSerial, WoodyConfig};
use voxhap::device::supervisor::{SupervisorConfig, TickInput};
use voxhap::device::transport::inverse_service::ServiceConfig;
use voxhap::device::transport::{
    ByteTransport, HidTransport, MemoryPipe, MillisecondHid, SerialTransport,
};
use voxhap::device::{DeviceError, HapticDevice};
use voxhap::servo::device::{Reconnecting, ServoDevice};
use voxhap::servo::monitor::StopSlot;
use voxhap_protocol::hid::REPORT_LEN;
use voxhap_protocol::{DeviceSample, DeviceSession, FrameDecoder, HostToDevice};

/// Runs `ticks` ticks after `warm_up` ticks and returns the allocation events of the counted ones.
fn ticks_allocate<D: HapticDevice>(device: &mut D, warm_up: usize, ticks: usize) -> u64 {
    let mut tick = |i: usize| {
        let force = DVec3::new(0.1 * (i as f64 * 0.01).sin(), 0.0, 0.2);
        device.write_force(force).unwrap();
        // A double's thread descheduled past the driver's read timeout (a loaded machine) gives a Timeout, which
        // allocates nothing either; read again for the late answer.
        let mut attempts = 0;
        loop {
            match device.read_state() {
                Ok(state) => {
                    // As the supervisor does: the pose is accepted, so the next force is converted with it.
                    device.input_checked(true);
                    break std::hint::black_box(state);
                }
                Err(error)
                    if voxhap::device::Error::kind(&error)
                        == voxhap::device::ErrorKind::Timeout
                        && attempts < 100 =>
                {
                    attempts += 1;
                }
                Err(error) => panic!("read_state failed after {attempts} timeouts: {error}"),
            };
        }
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

/// A WoodenHaptics (Teensy) driver on a pipe whose far end answers every command with a report.
fn woody() -> (WoodenHapticsSerial<MemoryPipe>, Arc<AtomicBool>) {
    let (host, device) = MemoryPipe::pair();
    let stop = responder(
        device,
        |p| p.iter().position(|&b| b == b'\n').map(|i| i + 1),
        |_| b"[3,120,-40,300,0,0,0,0]\n".to_vec(),
    );
    (WoodenHapticsSerial::new(host, WoodyConfig::default()), stop)
}

#[test]
fn woodenhaptics_serial_ticks_allocate_nothing() {
    let (mut driver, stop) = woody();
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
    stop.store(true, Ordering::Release);
    let (driver, stop) = woody();
    assert_eq!(
        supervised_ticks_allocate(driver, SUPERVISED_WARM_UP, 1000),
        0
    );
    stop.store(true, Ordering::Release);
}

/// A Haply 2DIY driver on a pipe whose far end answers as the board's firmware does.
fn haply() -> (Haply2Diy<MemoryPipe>, Arc<AtomicBool>) {
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
    (Haply2Diy::new(host, Haply2DiyConfig::default()), stop)
}

#[test]
fn haply_2diy_ticks_allocate_nothing() {
    let (mut driver, stop) = haply();
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
    stop.store(true, Ordering::Release);
    let (driver, stop) = haply();
    assert_eq!(
        supervised_ticks_allocate(driver, SUPERVISED_WARM_UP, 1000),
        0
    );
    stop.store(true, Ordering::Release);
}

/// A Falcon driver on the bootloader double, which runs its firmware once it has 1 byte of "firmware" (uploaded
/// at open). The bootloader handle and the firmware file must live as long as the driver.
fn falcon() -> (Falcon<FalconLine>, Bootloader, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("fw.bin");
    std::fs::write(&file, [0x5a]).unwrap();
    let (bootloader, pipe) = Bootloader::start(1);
    *bootloader.shared.homing.lock().unwrap() = 0x7;
    *bootloader.shared.encoders.lock().unwrap() = [-300, 200, 100];
    let driver = Falcon::new(
        pipe,
        FalconConfig {
            firmware: Some(file),
            ..FalconConfig::default()
        },
    );
    (driver, bootloader, dir)
}

#[test]
fn falcon_ticks_allocate_nothing() {
    let (mut driver, bootloader, _dir) = falcon();
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
    // The resynchronisation paths: junk before an answer, an answer garbled, one cut by inserted bytes (the
    // count becomes unknown, the newest frame is handed out again), then a quiet line (counting starts again).
    let next = bootloader.shared.commands.lock().unwrap().len() as i64;
    bootloader.shared.junk.lock().unwrap().extend([
        (next + 3, Junk::Before(vec![0x00, 0x13])),
        (next + 10, Junk::Garbled),
        (next + 20, Junk::Inside(vec![0x7f])),
    ]);
    assert_eq!(ticks_allocate(&mut driver, 5, 300), 0);
    std::thread::sleep(std::time::Duration::from_millis(120));
    assert_eq!(ticks_allocate(&mut driver, 0, 300), 0);
    assert!(driver.resyncs() >= 1, "no resynchronisation was exercised");
    let (driver, _bootloader, _dir) = falcon();
    assert_eq!(
        supervised_ticks_allocate(driver, SUPERVISED_WARM_UP, 1000),
        0
    );
}

fn inverse(service: &InverseService) -> HaplyInverse {
    HaplyInverse::new(HaplyInverseConfig {
        service: ServiceConfig {
            url: service.url(),
            ..ServiceConfig::default()
        },
        reply_wait: Duration::from_millis(20),
        ..HaplyInverseConfig::default()
    })
}

#[test]
fn haply_inverse_ticks_allocate_nothing() {
    let service = InverseService::start();
    let mut driver = inverse(&service);
    driver.open().unwrap();
    assert_eq!(ticks_allocate(&mut driver, 50, 1000), 0);
    driver.close().unwrap();
    assert_eq!(
        supervised_ticks_allocate(inverse(&service), SUPERVISED_WARM_UP, 1000),
        0
    );
}

/// The Inverse3 link's protocol core through every path the I/O thread drives (a send, its reply, an extra
/// message, an unusable one, a lost reply, a keepalive, the servo thread's verdict and a safety event's fault
/// code) allocates nothing: only the decoding before it does (messages are decoded once, outside the count).
#[test]
fn the_inverse_link_core_allocates_nothing() {
    use voxhap::device::drivers::haply_inverse::link::{self, Incoming, LinkCore};
    use voxhap::device::transport::inverse_service::events::SafetyEvent;
    use voxhap::device::transport::inverse_service::{
        parse_frame_text, ForceCommand, ServiceSnapshot,
    };
    let state = parse_frame_text(
        r#"{"inverse3":[{"device_id":"049D","state":{"cursor_position":{"x":0.0,"y":-0.12,"z":0.15}}}]}"#,
    )
    .unwrap();
    let drift =
        parse_frame_text(r#"{"inverse3":[{"device_id":"049D","state":{"cursor_position":"x"}}]}"#)
            .unwrap_err();
    let t0 = std::time::Instant::now();
    let mut core = LinkCore::new(
        ServiceSnapshot {
            answers_sequence: 0,
            position_m: DVec3::ZERO,
            velocity_m_per_s: DVec3::ZERO,
            arm_force_n: None,
        },
        t0,
    );
    let mut used = 0u64;
    let ((), allocations) = count_allocations(|| {
        for n in 1..=1000u64 {
            let at = t0 + Duration::from_millis(n);
            core.socket_empty();
            let command = ForceCommand {
                sequence: n,
                force_n: DVec3::new(0.0, 0.0, 1.0),
            };
            let out = core.next_command(Some(command), n % 2, at).unwrap();
            core.command_sent(out.sequence, at);
            if n % 7 != 0 {
                // Every 7th reply is lost; the next one answers the oldest force.
                core.socket_empty();
                let _ = core.message(Incoming::Frame(&state), "049D");
            }
            if n % 5 == 0 {
                let _ = core.message(Incoming::Frame(&state), "049D");
                let _ = core.message(Incoming::Undecodable(&drift), "049D");
                let _ = core.message(Incoming::Binary, "049D");
            }
            let _ = core.next_command(None, 0, at + Duration::from_millis(150));
            let label = core.snapshot().answers_sequence;
            if let link::Verdict::Use { .. } = link::judge(label, n, n % 3 == 0, 3) {
                used += 1;
            }
            let _ = link::fault_code(SafetyEvent::StallDetected);
        }
    });
    assert_eq!(allocations, 0);
    assert!(used > 0 && core.counters().extra > 0 && core.counters().drifted > 0);
}

/// A HID source that always has the same two reports queued (so every read drains one stale report); it reads
/// like hidapi (waits in whole milliseconds) and runs under the real HID transport.
struct FixedReports {
    queued: u8,
    /// The three encoder counts (little-endian i16 each) every report carries.
    counts: [u8; 6],
}

impl MillisecondHid for FixedReports {
    fn write(&mut self, report: &[u8]) -> Result<usize, DeviceError> {
        self.queued = 2;
        Ok(report.len())
    }
    fn read_timeout(&mut self, buf: &mut [u8], _timeout_ms: i32) -> Result<usize, DeviceError> {
        if self.queued == 0 {
            return Ok(0);
        }
        self.queued -= 1;
        buf[..6].copy_from_slice(&self.counts);
        buf[6..8].copy_from_slice(&[self.queued, 0]);
        Ok(8)
    }
}

#[test]
fn woodenhaptics_hid_ticks_allocate_nothing_and_keep_the_newest_report() {
    let reports = HidTransport::on(FixedReports {
        queued: 0,
        counts: [10, 0, 20, 0, 30, 0],
    });
    let mut driver = WoodenHaptics::new(reports, WOODENHAPTICS_HID).unwrap();
    assert_eq!(ticks_allocate(&mut driver, 10, 1000), 0);
    // Two reports were queued per tick; the newest (counter 0) was kept, the older one skipped.
    assert_eq!(driver.last_counter(), Some(0));
    assert_eq!(driver.drained_reports(), 1010);
    // Supervised: the handle at the arm's power-up pose (all encoder counts zero; chai3d's CWoodenDevice.cpp
    // zeroes the encoders there), (0.025, 0, 0.205) m, which the workspace the driver declares must contain, or
    // the input checks would drop the link after a run of such reports.
    let reports = HidTransport::on(FixedReports {
        queued: 0,
        counts: [0; 6],
    });
    let driver = WoodenHaptics::new(reports, WOODENHAPTICS_HID).unwrap();
    assert_eq!(
        supervised_ticks_allocate(driver, SUPERVISED_WARM_UP, 1000),
        0
    );
}

// ---------------------------------------------------------------------------------------------------------------
// The drivers inside the reconnecting wrapper, through the supervisor and the safety pipeline.

/// Wraps `driver` (not yet opened) in the reconnecting wrapper with a link patient with timeouts, connects it,
/// runs at least `warm_up` exchanges and on until it is engaged (enable after the steady ticks, engagement,
/// ramp-in), and returns the allocation events of the next exchanges, until `ticks` of them found it engaged.
/// Panics if it was never engaged within [`ENGAGE_WITHIN`] or the counted exchanges did not reach `ticks`
/// engaged ones.
fn supervised_ticks_allocate<D: HapticDevice + Send + 'static>(
    driver: D,
    warm_up: u64,
    ticks: u64,
) -> u64 {
    supervised_ticks_allocate_then(driver, warm_up, ticks, |_| {})
}

/// [`supervised_ticks_allocate`], handing the device to `then` after the counted exchanges (before it stops).
fn supervised_ticks_allocate_then<D: HapticDevice + Send + 'static>(
    driver: D,
    warm_up: u64,
    ticks: u64,
    then: impl FnOnce(&Reconnecting<D>),
) -> u64 {
    let mut slot = Some(driver);
    // A patient link: a double's thread descheduled on a busy machine gives timeouts (which allocate nothing
    // either), and they must not drop the link, which cannot come back here (the driver sits on its one
    // in-memory line and is opened once).
    let config = SupervisorConfig {
        max_consecutive_errors: 1_000_000,
        link_timeout_us: 3_600_000_000,
        ..SupervisorConfig::default()
    };
    let mut device = Reconnecting::new(
        config,
        Box::new(move || {
            slot.take().ok_or(DeviceError::Config {
                what: "the in-memory device was already opened".to_owned(),
            })
        }),
    )
    .unwrap();
    device.set_stop_slot(StopSlot::new());
    device.connect(0).unwrap();
    // A small force (under the engage threshold) that varies, so every stage of the pipeline works.
    let exchange = |device: &mut Reconnecting<D>, tick: u64| {
        let force = DVec3::new(0.3 * (tick as f64 * 0.01).sin(), 0.1, 0.2);
        device.exchange(TickInput::at(force, tick * 1_000))
    };
    // On a busy machine the double may stall, and stale states hold the engagement back or end it (zero force
    // until fresh ones come, then the ramp-in again): the warm-up runs until the device is engaged, however long
    // the load makes that, within ENGAGE_WITHIN.
    let mut warm_up_events = Vec::new();
    let started = Instant::now();
    let mut tick = 0;
    while tick < warm_up || !device.engaged() {
        if started.elapsed() > ENGAGE_WITHIN {
            panic!(
                "not engaged after {tick} ticks ({} s): {:?}; events {:?}",
                ENGAGE_WITHIN.as_secs(),
                device.counters(),
                &warm_up_events[warm_up_events.len().saturating_sub(20)..]
            );
        }
        tick += 1;
        let output = exchange(&mut device, tick);
        warm_up_events.extend(output.events.iter().map(|e| (tick, e)));
    }
    assert!(
        device.counters().enables >= 1,
        "never enabled: {:?}; events {warm_up_events:?}",
        device.counters()
    );
    // The steady state must not allocate, whatever happens in it: a fault and its recovery included (the device
    // doubles' threads may fall behind on a loaded machine). util::alloc prints where the first allocation was.
    // Should stale states end the engagement, the count runs until `ticks` exchanges found the device engaged
    // (bounded at 20 times as many), so the engaged path is always what was measured, whatever the load.
    let (mut engaged, mut total) = (0u64, 0u64);
    let ((), allocations) = count_allocations(|| {
        while engaged < ticks && total < 20 * ticks {
            tick += 1;
            total += 1;
            exchange(&mut device, tick);
            if device.engaged() {
                engaged += 1;
            }
        }
    });
    assert_eq!(
        engaged, ticks,
        "only {engaged} of {total} exchanges found the device engaged"
    );
    then(&device);
    device.stop();
    allocations
}

/// The longest the supervised warm-up waits for the device to be engaged.
const ENGAGE_WITHIN: Duration = Duration::from_secs(60);

/// Ticks enough for Enable (50 steady ticks), engagement (10 small ticks) and the 0.5 s ramp-in on a link that
/// stays up: the least the warm-up runs.
const SUPERVISED_WARM_UP: u64 = 700;

/// The voxhap protocol device side (the reference crate's `DeviceSession`, as `voxhap mock-device` runs it), fed one
/// message at a time; answers go out through `send`.
struct ProtocolResponder {
    session: DeviceSession,
    start: std::time::Instant,
}

impl ProtocolResponder {
    fn new() -> Self {
        ProtocolResponder {
            session: DeviceSession::new(voxhap::device::mock::mock_device_info()),
            start: std::time::Instant::now(),
        }
    }

    fn on_message(
        &mut self,
        message: &HostToDevice,
        mut send: impl FnMut(&voxhap_protocol::DeviceToHost),
    ) {
        let now_us = self.start.elapsed().as_micros() as u64;
        self.session.on_message(message, now_us);
        let sample = DeviceSample {
            position_m: [0.01, 0.0, 0.0],
            velocity_m_per_s: [0.0; 3],
            buttons: 0,
        };
        self.session.poll(now_us, &sample);
        while let Some(reply) = self.session.poll_transmit() {
            send(&reply);
        }
    }
}

/// The in-memory pipe the serial drivers run over here must not allocate either, even when the device double's
/// thread falls behind and bytes pile up: a growing buffer did, once in a CI run (2 events in 1 000 supervised
/// exchanges, found by the backtrace util::alloc prints). 60 KiB pending, written in 20-byte frames.
#[test]
fn the_memory_pipe_allocates_nothing_while_its_reader_falls_behind() {
    let (mut host, device) = MemoryPipe::pair();
    let frame = [0x5au8; 20];
    let ((), events) = count_allocations(|| {
        for _ in 0..(60 * 1024 / frame.len()) {
            host.write_all(&frame).unwrap();
        }
    });
    assert_eq!(events, 0);
    drop(device);
}

#[test]
fn supervised_protocol_serial_exchanges_allocate_nothing() {
    let (host, mut device) = MemoryPipe::pair();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    std::thread::spawn(move || {
        let mut responder = ProtocolResponder::new();
        let mut decoder = FrameDecoder::<HostToDevice>::new();
        let mut buf = [0u8; 256];
        while !flag.load(Ordering::Acquire) {
            let Ok(n) = device.read(&mut buf, Duration::from_millis(5)) else {
                return;
            };
            for &byte in &buf[..n] {
                if let Some(Ok(message)) = decoder.push(byte) {
                    responder.on_message(&message, |reply| {
                        let mut frame = [0u8; voxhap_protocol::MAX_WIRE_FRAME_LEN];
                        if let Ok(len) = voxhap_protocol::encode_frame(reply, &mut frame) {
                            let _ = device.write_all(&frame[..len]);
                        }
                    });
                }
            }
        }
    });
    let driver = ProtocolDevice::new(SerialLink::new(host), ProtocolConfig::default());
    // The per-tick round-trip timing ran in the counted exchanges: the driver timed more round trips than the
    // warm-up sent forces (a reconnect starts again from 0, so only that some were timed if one came).
    let timed = |device: &Reconnecting<_>| {
        let seen = device.link_delay_seen().expect("round trips timed");
        assert!(
            seen.round_trips > 0 && seen.worst >= seen.typical,
            "{seen:?}"
        );
        if device.counters().disconnects == 0 {
            assert!(seen.round_trips > SUPERVISED_WARM_UP, "{seen:?}");
        }
    };
    assert_eq!(
        supervised_ticks_allocate_then(driver, SUPERVISED_WARM_UP, 1000, timed),
        0
    );
    stop.store(true, Ordering::Release);
}

/// One direction of an in-memory HID link: whole reports, in order (capacity reserved up front, so passing a
/// report never allocates).
#[derive(Clone)]
struct ReportQueue(
    Arc<(
        std::sync::Mutex<std::collections::VecDeque<[u8; REPORT_LEN]>>,
        std::sync::Condvar,
    )>,
);

impl ReportQueue {
    fn new() -> Self {
        ReportQueue(Arc::new((
            std::sync::Mutex::new(std::collections::VecDeque::with_capacity(64)),
            std::sync::Condvar::new(),
        )))
    }

    fn push(&self, report: &[u8]) {
        let mut fixed = [0u8; REPORT_LEN];
        let n = report.len().min(REPORT_LEN);
        fixed[..n].copy_from_slice(&report[..n]);
        let (queue, ready) = &*self.0;
        let mut queue = queue.lock().unwrap();
        if queue.len() < queue.capacity() {
            queue.push_back(fixed);
        }
        ready.notify_one();
    }

    fn pop(&self, timeout: Duration) -> Option<[u8; REPORT_LEN]> {
        let (queue, ready) = &*self.0;
        let queue = queue.lock().unwrap();
        let (mut queue, _) = ready
            .wait_timeout_while(queue, timeout, |q| q.is_empty())
            .unwrap();
        queue.pop_front()
    }
}

/// The host's end of an in-memory HID link, read like hidapi (waits in whole milliseconds only) and used under
/// the real HID transport, which must wait out the driver's sub-millisecond waits itself.
struct ReportPipe {
    to_device: ReportQueue,
    to_host: ReportQueue,
}

impl MillisecondHid for ReportPipe {
    fn write(&mut self, report: &[u8]) -> Result<usize, DeviceError> {
        self.to_device.push(report);
        Ok(report.len())
    }

    fn read_timeout(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, DeviceError> {
        let timeout = Duration::from_millis(u64::try_from(timeout_ms).unwrap_or(0));
        match self.to_host.pop(timeout) {
            Some(report) => {
                let n = buf.len().min(REPORT_LEN);
                buf[..n].copy_from_slice(&report[..n]);
                Ok(n)
            }
            None => Ok(0),
        }
    }
}

#[test]
fn supervised_protocol_hid_exchanges_allocate_nothing() {
    let (to_device, to_host) = (ReportQueue::new(), ReportQueue::new());
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let (from_host, replies) = (to_device.clone(), to_host.clone());
    std::thread::spawn(move || {
        let mut responder = ProtocolResponder::new();
        while !flag.load(Ordering::Acquire) {
            let Some(report) = from_host.pop(Duration::from_millis(5)) else {
                continue;
            };
            if let Ok(message) = voxhap_protocol::decode_report::<HostToDevice>(&report) {
                responder.on_message(&message, |reply| {
                    let mut out = [0u8; REPORT_LEN];
                    if let Ok(len) = voxhap_protocol::encode_report(reply, &mut out) {
                        replies.push(&out[..len]);
                    }
                });
            }
        }
    });
    let driver = ProtocolDevice::new(
        HidLink::new(HidTransport::on(ReportPipe { to_device, to_host })),
        ProtocolConfig::default(),
    );
    assert_eq!(
        supervised_ticks_allocate(driver, SUPERVISED_WARM_UP, 1000),
        0
    );
    stop.store(true, Ordering::Release);
}

/// One tick as the supervisor makes it, whatever the link does (timeouts and shifted replies are errors that
/// allocate nothing either).
fn tolerant_tick<D: HapticDevice>(device: &mut D) {
    let _ = device.write_force(DVec3::new(0.1, 0.0, 0.2));
    if device.read_state().is_ok() {
        device.input_checked(true);
    }
}

/// The 2DIY over a real pseudo-terminal (SerialTransport's ppoll wait and its input discard), through the resync
/// a reply cut short and a reply shifted by a stray byte take: nothing allocates.
#[test]
fn haply_2diy_over_a_pty_resyncs_without_allocating() {
    let board = HaplyBoard::start(&[]);
    let transport = SerialTransport::open(board.path(), 0).unwrap();
    let mut driver = Haply2Diy::new(transport, Haply2DiyConfig::default());
    driver.open().unwrap();
    for _ in 0..50 {
        tolerant_tick(&mut driver);
    }
    let resyncs = driver.resync_count();
    board
        .shared
        .faults
        .lock()
        .unwrap()
        .extend([Fault::Partial, Fault::ExtraByte]);
    let ((), allocations) = count_allocations(|| {
        for _ in 0..300 {
            tolerant_tick(&mut driver);
        }
    });
    assert_eq!(allocations, 0);
    assert!(driver.resync_count() > resyncs, "no resync happened");
}

/// The WoodenHaptics Teensy driver over a real pseudo-terminal: nothing allocates.
#[test]
fn woodenhaptics_serial_over_a_pty_allocates_nothing() {
    let firmware = WoodyFirmware::start(3);
    let transport = SerialTransport::open(firmware.path(), 115_200).unwrap();
    let mut driver = WoodenHapticsSerial::new(transport, WoodyConfig::default());
    driver.open().unwrap();
    for _ in 0..50 {
        tolerant_tick(&mut driver);
    }
    let ((), allocations) = count_allocations(|| {
        for _ in 0..300 {
            tolerant_tick(&mut driver);
        }
    });
    assert_eq!(allocations, 0);
}
