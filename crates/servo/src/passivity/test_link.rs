//! A driver double for the latency tests: it declares a link latency (or none) and reports, as the round
//! trips it timed, the longest the test stores (µs; 0: none yet) and the median it stores (µs; 0: 1.1 ms),
//! over 100 round trips.

use glam::DVec3;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use voxhap_device::latency::{LinkDelaySeen, LinkLatency};
use voxhap_device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};

/// The double (module docs).
pub struct LinkDouble {
    pub info: DeviceInfo,
    pub latency: Option<LinkLatency>,
    pub worst_us: Arc<AtomicU64>,
    pub median_us: Arc<AtomicU64>,
}

impl HapticDevice for LinkDouble {
    type Error = DeviceError;
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
    fn write_force(&mut self, _force_n: DVec3) -> Result<(), DeviceError> {
        Ok(())
    }
    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        Ok(DeviceState::at_rest(DVec3::ZERO))
    }
    fn link_latency(&self) -> Option<LinkLatency> {
        self.latency
    }
    fn link_delay_seen(&self) -> Option<LinkDelaySeen> {
        match self.worst_us.load(Ordering::Relaxed) {
            0 => None,
            us => Some(LinkDelaySeen {
                typical: Duration::from_micros(match self.median_us.load(Ordering::Relaxed) {
                    0 => 1_100,
                    median => median,
                }),
                worst: Duration::from_micros(us),
                round_trips: 100,
            }),
        }
    }
}
