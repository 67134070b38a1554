//! Which State rate a local-model session needs on a link (protocol/SPEC.md section 10.4): a State and the
//! LocalState after it take 108 bytes on a serial wire (two HID reports), more than a 1 000 000-baud UART or one
//! full-speed HID interrupt endpoint carries at 1 kHz in lockstep. On such a link the host streams State at a
//! rate of 500 Hz or less that the link carries; if the device offers none, or the link cannot carry a LocalModel
//! every servo period, the host does not use the capability (SetForce, lockstep).

use std::time::Duration;
use voxhap_protocol::RateSet;

/// What a link carries each second in one direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkBudget {
    /// No limit that matters at servo rates (an in-process link, a test double).
    Unlimited,
    /// A serial line at this many bits per second, 8N1: 10 bits on the line per byte (SPEC section 4.1). The host
    /// cannot tell a USB CDC-ACM port (which ignores the rate) from a UART, so every serial port counts as a UART
    /// at its configured rate.
    SerialBaud(u32),
    /// USB full-speed HID: one 64-byte report per 1 ms frame in each direction (SPEC section 5).
    HidFullSpeed,
}

/// On the serial wire (SPEC section 4.2, "Sizes"): a State, a LocalState, a LocalModel, bytes with the delimiter.
const STATE_WIRE_BYTES: u64 = 51;
const LOCAL_STATE_WIRE_BYTES: u64 = 57;
const LOCAL_MODEL_WIRE_BYTES: u64 = 67;

/// The highest State rate SPEC section 10.4 allows on a link that cannot carry lockstep, Hz.
pub const MAX_LOCAL_STREAM_HZ: u16 = 500;

/// The State rate of a local-model session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LocalStateRate {
    /// The link carries a State and a LocalState every servo period: lockstep.
    Lockstep,
    /// Stream State at this rate (SetStateRate), one of the device's rates.
    Stream(u16),
    /// The link cannot carry the capability at this servo rate: SetForce instead.
    Unusable,
}

impl LinkBudget {
    /// True if `per_period` messages each period of `period` fit, each of `wire_bytes` on a serial wire.
    fn carries(self, messages_per_s: f64, wire_bytes: u64) -> bool {
        match self {
            LinkBudget::Unlimited => true,
            LinkBudget::SerialBaud(baud) => {
                messages_per_s * (wire_bytes * 10) as f64 <= f64::from(baud)
            }
            LinkBudget::HidFullSpeed => messages_per_s <= 1000.0,
        }
    }

    /// The State rate a session with a capable device needs at servo `period` (SPEC section 10.4).
    pub fn local_state_rate(self, period: Duration, device_rates: RateSet) -> LocalStateRate {
        let servo_hz = 1.0 / period.as_secs_f64().max(1e-6);
        // Host to device: one LocalModel a period (one report on HID).
        if !self.carries(servo_hz, LOCAL_MODEL_WIRE_BYTES) {
            return LocalStateRate::Unusable;
        }
        // Device to host: a State and a LocalState (two reports on HID) per State.
        let fits = |states_per_s: f64| match self {
            LinkBudget::HidFullSpeed => self.carries(2.0 * states_per_s, 0),
            _ => self.carries(states_per_s, STATE_WIRE_BYTES + LOCAL_STATE_WIRE_BYTES),
        };
        if fits(servo_hz) {
            return LocalStateRate::Lockstep;
        }
        device_rates
            .iter_hz()
            .filter(|&hz| hz <= MAX_LOCAL_STREAM_HZ && f64::from(hz) <= servo_hz)
            .filter(|&hz| fits(f64::from(hz)))
            .max()
            .map_or(LocalStateRate::Unusable, LocalStateRate::Stream)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn rates(hz: &[u16]) -> RateSet {
        RateSet::from_rates_hz(hz).unwrap()
    }

    // Expected values: SPEC section 10.4's figures (108 bytes a State and LocalState, 1 080 000 baud at 1 kHz;
    // two HID reports per frame) and section 4.2's sizes (a LocalModel 67 bytes: 670 000 baud at 1 kHz).
    #[test]
    fn a_1_mbaud_uart_at_1_khz_streams_at_500_hz() {
        let all = rates(&[100, 200, 250, 500, 1000]);
        let uart = LinkBudget::SerialBaud(1_000_000);
        assert_eq!(uart.local_state_rate(MS, all), LocalStateRate::Stream(500));
        // 108 bytes at 1 kHz need 1 080 000 baud: 1 100 000 carries lockstep, 1 070 000 does not.
        assert_eq!(
            LinkBudget::SerialBaud(1_100_000).local_state_rate(MS, all),
            LocalStateRate::Lockstep
        );
        assert_eq!(
            LinkBudget::SerialBaud(1_070_000).local_state_rate(MS, all),
            LocalStateRate::Stream(500)
        );
    }

    #[test]
    fn the_highest_device_rate_that_fits_is_taken() {
        let uart = LinkBudget::SerialBaud(1_000_000);
        assert_eq!(
            uart.local_state_rate(MS, rates(&[100, 250, 1000])),
            LocalStateRate::Stream(250)
        );
        // Only 1 kHz (too fast for this link) or nothing at all: no local models on this link.
        assert_eq!(
            uart.local_state_rate(MS, rates(&[1000])),
            LocalStateRate::Unusable
        );
        assert_eq!(
            uart.local_state_rate(MS, RateSet(0)),
            LocalStateRate::Unusable
        );
        // 700 000 baud: 500 Hz needs 540 000, fits; 460 800 baud cannot carry a LocalModel a period (670 000).
        assert_eq!(
            LinkBudget::SerialBaud(700_000).local_state_rate(MS, rates(&[500])),
            LocalStateRate::Stream(500)
        );
        assert_eq!(
            LinkBudget::SerialBaud(460_800).local_state_rate(MS, rates(&[250, 500])),
            LocalStateRate::Unusable
        );
    }

    #[test]
    fn hid_streams_at_500_hz_and_a_slow_servo_keeps_lockstep() {
        let all = rates(&[250, 500, 1000]);
        assert_eq!(
            LinkBudget::HidFullSpeed.local_state_rate(MS, all),
            LocalStateRate::Stream(500)
        );
        // At a 500 Hz servo two reports a period are 1000 a second: lockstep fits HID and a 1 Mbaud UART.
        let period = Duration::from_millis(2);
        assert_eq!(
            LinkBudget::HidFullSpeed.local_state_rate(period, all),
            LocalStateRate::Lockstep
        );
        assert_eq!(
            LinkBudget::SerialBaud(1_000_000).local_state_rate(period, all),
            LocalStateRate::Lockstep
        );
        assert_eq!(
            LinkBudget::Unlimited.local_state_rate(MS, RateSet(0)),
            LocalStateRate::Lockstep
        );
    }
}
