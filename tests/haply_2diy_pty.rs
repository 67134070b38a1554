//! The Haply 2DIY driver against a double of the board (tests/util/haply_board.rs, from Haply-API-cpp's
//! Board.cpp/Device.cpp) over a real pseudo-terminal: stale input is discarded on open, and after a reply cut
//! short (its rest arriving late) or a stray byte the driver gets back onto reply boundaries within a few ticks.

use crate::util::haply_board::{Fault, HaplyBoard, ANGLES_DEG};
use glam::DVec3;
use voxhap::device::drivers::haply::{Haply2Diy, Haply2DiyConfig};
use voxhap::device::transport::SerialTransport;
use voxhap::device::Lifecycle;

fn expected_position() -> DVec3 {
    let config = Haply2DiyConfig::default();
    // Port order puts encoder 2 first (Haply2DiyConfig::parse_reply).
    let (p, _) = config.kinematics([ANGLES_DEG[1], ANGLES_DEG[0]]).unwrap();
    DVec3::new(p[0], p[1], 0.0)
}

fn open(board: &HaplyBoard) -> Lifecycle<Haply2Diy<SerialTransport>> {
    let transport = SerialTransport::open(board.path(), 0).unwrap();
    let mut device = Lifecycle::new(Haply2Diy::new(transport, Haply2DiyConfig::default()));
    device.open().unwrap();
    device.enable().unwrap();
    device
}

#[test]
fn stale_bytes_from_an_earlier_program_are_discarded_on_open() {
    // Half a reply and some noise, as a killed program leaves behind.
    let board = HaplyBoard::start(&[5, 0, 0, 0x34, 0x42, 9, 9]);
    std::thread::sleep(std::time::Duration::from_millis(20));
    let mut device = open(&board);
    for _ in 0..20 {
        device.write_force(DVec3::ZERO).unwrap();
        let state = device.read_state().unwrap();
        assert!(
            (state.position_m - expected_position()).length() < 1e-9,
            "{state:?}"
        );
    }
    assert_eq!(device.device().resync_count(), 0);
}

#[test]
fn a_partial_or_shifted_reply_costs_a_few_ticks_then_replies_are_aligned_again() {
    for fault in [Fault::Partial, Fault::ExtraByte] {
        let board = HaplyBoard::start(&[]);
        let mut device = open(&board);
        let mut errors = 0;
        let mut good_after_fault = 0;
        for tick in 0..200 {
            if tick == 20 {
                board.shared.faults.lock().unwrap().push(fault);
            }
            if device.write_force(DVec3::new(0.5, 0.0, 0.0)).is_err() {
                errors += 1;
                continue;
            }
            match device.read_state() {
                Ok(state) => {
                    // A wrong state must never be reported as a good one.
                    assert!(
                        (state.position_m - expected_position()).length() < 1e-9,
                        "{fault:?} tick {tick}: {state:?}"
                    );
                    if tick > 20 {
                        good_after_fault += 1;
                    }
                }
                Err(_) => errors += 1,
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert!((1..=4).contains(&errors), "{fault:?}: {errors} errors");
        assert!(good_after_fault >= 170, "{fault:?}: {good_after_fault}");
        assert!(device.device().resync_count() >= 1);
        // The board saw a torque command for every tick, all finite.
        let torques = board.torques();
        assert!(torques.len() >= 190 && torques.iter().flatten().all(|t| t.is_finite()));
    }
}
