//! The supervisor's input checks time each reading from the exchange that brought it: a reading may have been
//! taken from when the force it answers was sent (its age in ticks back) until the driver handed it over
//! (after this tick's clock was read). The handle below moves at 0.5 m/s; the speed limit is 5 m/s with 0.5 mm
//! of noise, so a step is refused when it is longer than 5 m/s × Δt + 0.5 mm.

use super::*;
use crate::DeviceInfo;
use std::collections::VecDeque;
use std::time::Duration;

/// The handle's speed (m/s).
const SPEED_M_PER_S: f64 = 0.5;

/// One read of the script: where the handle is, the age the driver reports, and how long the read takes (the
/// servo thread kept off the CPU inside the exchange).
#[derive(Debug, Clone, Copy)]
struct Read {
    x_m: f64,
    age_ticks: u32,
    takes: Duration,
}

fn fresh(at_us: u64) -> Read {
    Read {
        x_m: SPEED_M_PER_S * at_us as f64 * 1e-6,
        age_ticks: 0,
        takes: Duration::ZERO,
    }
}

struct Scripted {
    info: DeviceInfo,
    reads: VecDeque<Read>,
    age_ticks: u32,
}

impl HapticDevice for Scripted {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn write_force(&mut self, _force_n: DVec3) -> Result<(), DeviceError> {
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        let read = self.reads.pop_front().expect("a scripted read");
        std::thread::sleep(read.takes);
        self.age_ticks = read.age_ticks;
        Ok(DeviceState::at_rest(DVec3::new(read.x_m, 0.0, 0.0)))
    }

    fn state_age_ticks(&self) -> u32 {
        self.age_ticks
    }
}

/// Ticks the script at the host's monotonic servo clock's `times_us` (connected at the first): the ticks whose
/// reading was refused, by index.
fn refused(reads: Vec<Read>, times_us: &[u64]) -> Vec<usize> {
    refused_on(reads, times_us, TickClock::Monotonic, None)
}

/// [`refused`] on `clock`, the clock restarting before tick `restart` ([`Supervisor::restart_clock`]) when given.
fn refused_on(
    reads: Vec<Read>,
    times_us: &[u64],
    clock: TickClock,
    restart: Option<usize>,
) -> Vec<usize> {
    let mut device = Some(Scripted {
        info: DeviceInfo::basic("scripted", DVec3::splat(-0.1), DVec3::splat(0.1)),
        reads: reads.into(),
        age_ticks: 0,
    });
    let opener = move || {
        device
            .take()
            .ok_or(DeviceError::Protocol { what: "reopened" })
    };
    let mut supervisor = Supervisor::new(SupervisorConfig::default(), opener).unwrap();
    supervisor.connect(times_us[0]).unwrap();
    times_us
        .iter()
        .enumerate()
        .filter(|&(tick, &now_us)| {
            if restart == Some(tick) {
                supervisor.restart_clock(now_us);
            }
            let out = supervisor.tick(TickInput {
                clock,
                ..TickInput::at(DVec3::ZERO, now_us)
            });
            assert!(out.connected, "{out:?}");
            out.flags.contains(SafetyFlags::POSITION_REJECTED)
        })
        .map(|(tick, _)| tick)
        .collect()
}

/// The ticks of [`late_in_its_tick`]: at 0 and 1 ms, then at 1.5 ms (catching up) and 17 ms.
const LATE_TICKS_US: [u64; 4] = [0, 1_000, 1_500, 17_000];

/// Fresh readings, but the one at the 1.5 ms tick takes 15 ms of real time to read: it was taken at 16.5 ms.
fn late_in_its_tick() -> Vec<Read> {
    let late = Read {
        takes: Duration::from_millis(15),
        ..fresh(16_500)
    };
    vec![fresh(0), fresh(1_000), late, fresh(17_000)]
}

#[test]
fn a_reading_handed_over_late_in_its_tick_is_checked_against_when_it_came() {
    // Ticks at 0 and 1 ms; the next, catching up, at 1.5 ms, but the servo thread is kept off the CPU for
    // 15 ms inside its exchange: the reading it gets was taken at 16.5 ms, 8.25 mm along, 7.75 mm on from the
    // reading at 1 ms. Against the tick's clock (0.5 ms) that is 15.5 m/s, over 3.0 mm; against when it came
    // (15.5 ms or more after the 1 ms tick's force), 78 mm would be allowed.
    assert_eq!(
        refused(late_in_its_tick(), &LATE_TICKS_US),
        Vec::<usize>::new()
    );
}

#[test]
fn an_earlier_reading_handed_out_again_is_timed_from_the_force_it_answers() {
    // Fresh readings at 0..=5 ms; the servo thread stalls 15 ms, and the tick at 20 ms gets no new reading in
    // time: the driver hands out the 5 ms one again (age 1). The tick at 21 ms gets a fresh one, 8 mm on from
    // it. Against the 20 ms tick that is 1 ms (5.5 mm allowed); from the force the held reading answers (5 ms),
    // 16 ms (80.5 mm allowed).
    let mut reads: Vec<Read> = (0..=5).map(|ms| fresh(ms * 1_000)).collect();
    reads.push(Read {
        age_ticks: 1,
        ..fresh(5_000)
    });
    reads.push(fresh(21_000));
    let times_us = [0, 1_000, 2_000, 3_000, 4_000, 5_000, 20_000, 21_000];
    assert_eq!(refused(reads, &times_us), Vec::<usize>::new());
}

#[test]
fn a_jump_beyond_the_speed_limit_is_still_refused() {
    // 5 cm in 1 ms (50 m/s): over the 5.5 mm allowed, whichever way the time is counted.
    let jump = Read {
        x_m: fresh(2_000).x_m + 0.05,
        ..fresh(2_000)
    };
    let reads = vec![fresh(0), fresh(1_000), jump, fresh(3_000)];
    assert_eq!(refused(reads, &[0, 1_000, 2_000, 3_000]), vec![2]);
}

#[test]
fn on_a_virtual_clock_real_time_inside_the_exchange_does_not_widen_the_window() {
    // The reads of the late-reading test above, on a clock that stands still during a tick (a test's
    // `tick × period`): the 15 ms the read takes in real time are not time on that clock. The reading at the
    // 1.5 ms tick is 7.75 mm on from the one at 1 ms, and only 0.5 ms passed on this clock: 3.0 mm allowed.
    assert_eq!(
        refused_on(late_in_its_tick(), &LATE_TICKS_US, TickClock::Virtual, None),
        vec![2]
    );
}

/// The handle at 0.5 m/s, read once at connect (0 ms); the servo clock then restarts at 0 after a set-up of
/// 50 ms it did not see, so the reading at its first tick is 25 mm on. Ticks 1 ms apart follow (0.5 mm each,
/// 5.5 mm allowed), one of them 5 cm off the path.
fn reads_across_a_restart() -> Vec<Read> {
    vec![
        fresh(0),
        fresh(50_000),
        fresh(51_000),
        Read {
            // 5 cm beyond the handle's path in 1 ms: a jump whichever way time is counted.
            x_m: fresh(52_000).x_m + 0.05,
            ..fresh(52_000)
        },
        fresh(53_000),
    ]
}

#[test]
fn a_clock_that_starts_over_after_a_set_up_does_not_refuse_a_handle_moved_meanwhile() {
    // Without the restart every reading after the connect's is judged against it as if the set-up took no time:
    // 25 mm in 0 ms (0.5 mm allowed), 25.5 mm in 1 ms (5.5 mm), the jump, 26.5 mm in 3 ms (15.5 mm): all refused.
    // After the restart the first reading starts the history afresh and the checks hold again from the next
    // one: only the 5 cm jump is refused (the last reading is 1 mm on from tick 2's in 2 ms: 10.5 mm allowed).
    let times_us = [0, 0, 1_000, 2_000, 3_000];
    assert_eq!(
        refused_on(
            reads_across_a_restart(),
            &times_us,
            TickClock::Virtual,
            None
        ),
        vec![1, 2, 3, 4]
    );
    assert_eq!(
        refused_on(
            reads_across_a_restart(),
            &times_us,
            TickClock::Virtual,
            Some(1)
        ),
        vec![3]
    );
}
