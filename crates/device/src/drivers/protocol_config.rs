//! The protocol driver's settings ([`ProtocolConfig`]) and the Hello schedule they give.

use std::time::Duration;

/// Settings of the protocol driver (defaults: protocol/SPEC.md, "Host behaviour a firmware can rely on").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProtocolConfig {
    /// How long open waits for DeviceInfo after the first Hello before sending another; each later wait is
    /// twice the one before, up to 1 s (or this, if longer).
    pub hello_timeout: Duration,
    /// How long open waits in all for a DeviceInfo answering one of its Hellos, and then again for the State
    /// answering its first zero force (`serve --connect-timeout`).
    pub connect_timeout: Duration,
    /// How long `read_state` waits for the State answering the last SetForce; at most a servo period, so
    /// device I/O never holds up the servo thread for longer (`open_device` sets half a period).
    pub state_timeout: Duration,
    /// The device's own force watchdog, sent with Enable (µs, 1 000 ..= 1 000 000).
    pub device_watchdog_us: u32,
    /// The servo period: with what the link carries, it sets the State rate of a local-model session
    /// (`drivers::protocol_rate`).
    pub period: Duration,
    /// Zero-force round trips open times after the first State to measure the link's latency
    /// (`drivers::protocol`, "Link latency"), at most [`MAX_LATENCY_PROBES`]. 0 (the default for a bare
    /// driver, whose every byte a scripted test spells): the latency is the first State's round trip alone;
    /// a servo loop ([`ProtocolConfig::for_period`]) measures [`DEFAULT_LATENCY_PROBES`].
    pub latency_probes: u32,
}

/// The round trips a servo loop's open measures after the first State (`ProtocolConfig::for_period`): 64
/// zero forces, about 64 ms on a link with 1 ms of latency.
pub const DEFAULT_LATENCY_PROBES: u32 = 64;

/// The most round trips open measures after the first State.
pub const MAX_LATENCY_PROBES: u32 = 255;

/// The handshake's default patience for a device's answer (`serve --connect-timeout`).
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(3);

/// The longest wait between two Hellos (unless `hello_timeout` is longer).
const MAX_HELLO_INTERVAL: Duration = Duration::from_secs(1);

impl Default for ProtocolConfig {
    fn default() -> Self {
        ProtocolConfig {
            hello_timeout: Duration::from_millis(100),
            connect_timeout: DEFAULT_CONNECT_TIMEOUT,
            state_timeout: Duration::from_micros(500),
            device_watchdog_us: 50_000,
            period: Duration::from_millis(1),
            latency_probes: 0,
        }
    }
}

impl ProtocolConfig {
    /// The defaults for a servo loop of `period`: States are waited for at most half a period, and open
    /// measures the link's latency from [`DEFAULT_LATENCY_PROBES`] round trips.
    pub fn for_period(period: Duration) -> ProtocolConfig {
        ProtocolConfig {
            state_timeout: (period / 2).max(Duration::from_micros(50)),
            period,
            latency_probes: DEFAULT_LATENCY_PROBES,
            ..ProtocolConfig::default()
        }
    }

    /// How long open waits after each Hello: `hello_timeout`, then twice the last wait up to 1 s, until the
    /// waits add up to `connect_timeout` (the last one cut short). At least one Hello is always sent.
    pub fn hello_waits(&self) -> impl Iterator<Item = Duration> {
        let first = self.hello_timeout.max(Duration::from_millis(1));
        let cap = MAX_HELLO_INTERVAL.max(first);
        let total = self.connect_timeout.max(first);
        let mut spent = Duration::ZERO;
        let mut next = first;
        std::iter::from_fn(move || {
            if spent >= total {
                return None;
            }
            let wait = next.min(total - spent);
            spent += wait;
            next = (next * 2).min(cap);
            Some(wait)
        })
    }
}
