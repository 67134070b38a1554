//! How late a device's state is on its link: [`LinkLatency`], for the passivity controller (a transport delay
//! of one tick halves the stable stiffness, Hulin et al. 2014). A driver reports it through
//! [`crate::HapticDevice::link_latency`]; [`crate::supervisor::Supervisor::link_latency`] reads the connected
//! one.
//!
//! The figure is the time from the host writing a command to the state answering it being readable on the
//! host. The vendor drivers declare it from the path their vendor documents (the constants below, each saying
//! where its numbers come from; not measured here, no hardware). voxhap's own protocol driver measures it on
//! the link at open instead, from the round trips of its zero forces
//! (`crate::drivers::protocol`, "Link latency"), and says how many it measured in
//! [`LinkLatency::round_trips`].

use std::time::Duration;

/// A device link's latency (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkLatency {
    /// The usual delay from a command to the state answering it being readable.
    pub typical: Duration,
    /// The longest delay the documented path allows (after it, the reply counts as missed).
    pub worst: Duration,
    /// Where the figures come from.
    pub source: &'static str,
    /// How many round trips the figures were measured from; 0 when they come from documents.
    pub round_trips: u32,
}

impl LinkLatency {
    /// A reply that leaves the device at once and is collected at the next 1 ms full-speed USB frame:
    /// typically 1 ms, at worst 2 ms (a reply that just missed a frame).
    pub const fn one_usb_frame(source: &'static str) -> LinkLatency {
        LinkLatency {
            typical: Duration::from_millis(1),
            worst: Duration::from_millis(2),
            source,
            round_trips: 0,
        }
    }

    /// The worst delay in whole servo ticks of `period` (rounded up; 0 for a zero period).
    pub fn worst_ticks(&self, period: Duration) -> u32 {
        whole_ticks(self.worst, period)
    }
}

/// The round trips a driver timed on every servo tick since it was last opened (voxhap's protocol driver:
/// `crate::drivers::protocol`, "Link latency"): what the link's delay really was during the run, where
/// [`LinkLatency`] is what was declared at open.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkDelaySeen {
    /// The median round trip, rounded up to 0.1 ms (at most the longest; the longest when the median is
    /// beyond what the driver's histogram resolves).
    pub typical: Duration,
    /// The longest round trip.
    pub worst: Duration,
    /// How many round trips were timed.
    pub round_trips: u64,
}

impl LinkDelaySeen {
    /// The longest round trip in whole servo ticks of `period`, rounded up (0 for a zero period).
    pub fn worst_ticks(&self, period: Duration) -> u32 {
        whole_ticks(self.worst, period)
    }

    /// The median round trip in whole servo ticks of `period`, rounded up (0 for a zero period).
    #[cfg(any(test, feature = "test-support"))]
    pub fn typical_ticks(&self, period: Duration) -> u32 {
        whole_ticks(self.typical, period)
    }
}

/// `delay` in whole ticks of `period`, rounded up ([`ticks_rounded_up`]).
fn whole_ticks(delay: Duration, period: Duration) -> u32 {
    ticks_rounded_up(delay.as_secs_f64(), period.as_secs_f64())
}

/// A delay of `delay_s` in whole ticks of `period_s` (both in seconds): the one rule for a delay in servo
/// ticks, here (a link's figures) and in crate `voxhap-servo` (the passivity observer's pairing). A fraction
/// of a tick is rounded up, the safe side for the observer; a part per million of a tick is taken as rounding
/// error (of seconds in floating point, or of a period that is no whole number of nanoseconds), so 1 ms at
/// 4 kHz is 4 ticks and 1 ms at 3 kHz is 3. 0 for a delay or period that is not a positive finite number; at
/// most `u32::MAX`.
pub fn ticks_rounded_up(delay_s: f64, period_s: f64) -> u32 {
    if delay_s.is_finite() && delay_s > 0.0 && period_s > 0.0 {
        // A float-to-integer cast saturates: a delay of more than u32::MAX ticks is u32::MAX.
        (delay_s / period_s - 1e-6).ceil().max(0.0) as u32
    } else {
        0
    }
}

/// Novint Falcon on `ftdi_sio`: the 16-byte reply is shorter than the FTDI chip's 62-byte packet payload, so
/// the chip sends it when its latency timer runs out (FTDI AN232B-04 "Data Throughput, Latency and
/// Handshaking", section 3), set to 1 ms in normal mode (libnifalcon src/comm/FalconCommLibUSB.cpp:560, voxhap
/// sets and checks the same), and the host collects it at the next 1 ms full-speed USB frame: typically 1 ms,
/// at worst 2 ms. libnifalcon does not wait for a reply with a deadline: it sends the next frame only once the
/// reply has come (src/firmware/FalconFirmwareNovintSDK.cpp:113-154).
pub const FALCON: LinkLatency = LinkLatency::one_usb_frame(
    "FTDI latency timer 1 ms (libnifalcon FalconCommLibUSB.cpp:560) + one 1 ms full-speed USB frame",
);

/// Haply 2DIY: the board answers each torque command at once (hAPI Board.receive reads the reply right after
/// the command) over native full-speed USB CDC, collected at the next 1 ms frame: typically 1 ms, at worst
/// 2 ms (a command that just missed a frame).
pub const HAPLY_2DIY: LinkLatency = LinkLatency::one_usb_frame(
    "hAPI Board.receive (one reply per command) over full-speed USB CDC, 1 ms frames",
);

/// WoodenHaptics and Polhem on the Teensy firmware: each reply is pushed with `Serial.send_now()`
/// (firmware/woody_teensy_mini/woody_teensy_mini.ino:552-553), so it leaves at the next USB frame (1 ms at full
/// speed; a Teensy 4 at high speed is faster): typically 1 ms, at worst 2 ms.
pub const WOODENHAPTICS_SERIAL: LinkLatency = LinkLatency::one_usb_frame(
    "woody_teensy_mini.ino:552-553 (Serial.send_now per reply), full-speed USB 1 ms frames",
);

/// WoodenHaptics 1.5 over USB HID: input reports go out on an interrupt endpoint polled at most once per 1 ms
/// full-speed frame (USB 2.0 section 5.7.4); the endpoint interval of the legacy firmware was not re-checked.
pub const WOODENHAPTICS_HID: LinkLatency = LinkLatency::one_usb_frame(
    "full-speed HID interrupt endpoint, 1 ms polling (USB 2.0 5.7.4); firmware interval not re-checked",
);

/// Haply Inverse3 through the Inverse Service: the service answers each force message with one state
/// (docs.haply.co "WebSocket Protocol"); Haply publishes no figure for its own device loop, so these are the
/// driver's bounds: a state answering this tick's force is waited for 0.4 ms, and one answering one of the last
/// three commands is still used (three ticks at 1 kHz).
pub const HAPLY_INVERSE: LinkLatency = LinkLatency {
    typical: Duration::from_micros(400),
    worst: Duration::from_millis(3),
    source: "voxhap's reply wait and staleness bound; Haply publishes no device-loop latency",
    round_trips: 0,
};

#[cfg(test)]
mod tests {
    use super::*;

    /// By hand: 2 ms is 2 ticks at 1 kHz, 1 tick at 500 Hz, 8 at 4 kHz; 0.4 ms is one tick at 1 kHz.
    #[test]
    fn worst_ticks_round_up() {
        assert_eq!(FALCON.worst_ticks(Duration::from_millis(1)), 2);
        assert_eq!(FALCON.worst_ticks(Duration::from_millis(2)), 1);
        assert_eq!(FALCON.worst_ticks(Duration::from_micros(250)), 8);
        let short = LinkLatency {
            worst: Duration::from_micros(400),
            ..HAPLY_INVERSE
        };
        assert_eq!(short.worst_ticks(Duration::from_millis(1)), 1);
        assert_eq!(FALCON.worst_ticks(Duration::ZERO), 0);
    }

    /// Where the exact rule on nanoseconds (`delay_ns.div_ceil(period_ns)`, this module's until the
    /// passivity observer and the link's figures shared [`ticks_rounded_up`]) and the observer's rule
    /// disagreed, worked by hand: a longest round trip of 2 ms + 1 ns at 500 Hz is 1.0000005 ticks, within
    /// a part per million of one tick, so 1 tick (div_ceil said 2, while the observer, widening to the same
    /// round trip, paired 1). 2 ms + 10 ns is 1.000005 ticks: 2. 1 ms at 3 kHz is exactly 3 periods of
    /// 1/3 ms: 3 (in whole nanoseconds the period is 333 333 ns and div_ceil gives 4).
    #[test]
    fn a_part_per_million_of_a_tick_is_rounding_error() {
        let seen = |worst_ns: u64| LinkDelaySeen {
            typical: Duration::from_millis(1),
            worst: Duration::from_nanos(worst_ns),
            round_trips: 1,
        };
        let period = Duration::from_millis(2);
        assert_eq!(seen(2_000_001).worst_ticks(period), 1);
        assert_eq!(seen(2_000_010).worst_ticks(period), 2);
        assert_eq!(ticks_rounded_up(1e-3, 1.0 / 3000.0), 3);
        assert_eq!(ticks_rounded_up(1e-3, 2.5e-4), 4);
        assert_eq!(ticks_rounded_up(f64::NAN, 1e-3), 0);
        assert_eq!(ticks_rounded_up(1e-3, 0.0), 0);
    }
}
