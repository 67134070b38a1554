//! A replay device (HAPI's PlaybackHapticsDevice): plays the probe positions of a recorded force trace, one
//! sample per `read_state`, and records the forces it is sent instead of rendering them.
//!
//! Where it sits: in place of a real arm, for regression runs of the servo loop against a recorded session.
//! Velocity is the finite difference of consecutive probe positions over their recorded times. At the end of the
//! trace it holds the last position (or starts over, if asked to loop).

use crate::device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use crate::record::Trace;
use glam::DVec3;

/// Plays a trace's probe positions.
#[derive(Debug, Clone)]
pub struct ReplayDevice {
    positions_m: Vec<DVec3>,
    times_s: Vec<f64>,
    next: usize,
    looped: bool,
    info: DeviceInfo,
    last_force_n: DVec3,
    forces_received: u64,
}

impl ReplayDevice {
    /// A replay of `trace`. Refuses an empty trace and non-finite positions or times.
    pub fn new(trace: &Trace, looped: bool) -> Result<ReplayDevice, DeviceError> {
        if trace.samples.is_empty() {
            return Err(DeviceError::Config {
                what: "cannot replay a trace with no samples".to_string(),
            });
        }
        let mut positions_m = Vec::with_capacity(trace.samples.len());
        let mut times_s = Vec::with_capacity(trace.samples.len());
        for (i, sample) in trace.samples.iter().enumerate() {
            if !sample.probe_m.is_finite() || !sample.t_s.is_finite() {
                return Err(DeviceError::Config {
                    what: format!("trace sample {i} has a non-finite probe position or time"),
                });
            }
            positions_m.push(sample.probe_m);
            times_s.push(sample.t_s);
        }
        let (min, max) = positions_m
            .iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        Ok(ReplayDevice {
            positions_m,
            times_s,
            next: 0,
            looped,
            info: DeviceInfo {
                model: String::from("trace replay"),
                serial_number: String::new(),
                position_dof: 3,
                force_dof: 0,
                button_count: 0,
                workspace_min_m: min,
                workspace_max_m: max,
                max_force_n: f64::INFINITY,
                max_stiffness_n_per_m: f64::INFINITY,
                state_rates_hz: Vec::new(),
            },
            last_force_n: DVec3::ZERO,
            forces_received: 0,
        })
    }

    /// The last force sent to the replay (N).
    pub fn last_force_n(&self) -> DVec3 {
        self.last_force_n
    }

    /// How many forces were sent.
    pub fn forces_received(&self) -> u64 {
        self.forces_received
    }

    /// True once every sample was played (never when looping).
    pub fn finished(&self) -> bool {
        !self.looped && self.next >= self.positions_m.len()
    }
}

impl HapticDevice for ReplayDevice {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        self.last_force_n = force_n;
        self.forces_received += 1;
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        let count = self.positions_m.len();
        if self.next >= count {
            if self.looped {
                self.next = 0;
            } else {
                return Ok(DeviceState::at_rest(self.positions_m[count - 1]));
            }
        }
        let i = self.next;
        self.next += 1;
        let velocity_m_per_s = if i > 0 {
            let dt_s = self.times_s[i] - self.times_s[i - 1];
            if dt_s > 0.0 {
                (self.positions_m[i] - self.positions_m[i - 1]) / dt_s
            } else {
                DVec3::ZERO
            }
        } else {
            DVec3::ZERO
        };
        Ok(DeviceState {
            position_m: self.positions_m[i],
            velocity_m_per_s,
            buttons: 0,
            device_time_us: Some((self.times_s[i].max(0.0) * 1e6) as u64),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::TraceSample;

    fn trace(points: &[(f64, f64)]) -> Trace {
        Trace {
            mode_names: Vec::new(),
            samples: points
                .iter()
                .enumerate()
                .map(|(i, &(t_s, x))| TraceSample {
                    tick: i as u64,
                    t_s,
                    probe_m: DVec3::new(x, 0.0, 0.0),
                    ..TraceSample::zeroed(0)
                })
                .collect(),
            sidecar: None,
            warnings: Vec::new(),
        }
    }

    #[test]
    fn plays_positions_in_order_with_finite_difference_velocity_then_holds() {
        let mut device =
            ReplayDevice::new(&trace(&[(0.0, 0.0), (0.001, 0.002), (0.002, 0.003)]), false)
                .unwrap();
        assert_eq!(device.read_state().unwrap().position_m.x, 0.0);
        let second = device.read_state().unwrap();
        assert_eq!(second.position_m.x, 0.002);
        assert!((second.velocity_m_per_s.x - 2.0).abs() < 1e-9);
        device.read_state().unwrap();
        assert!(device.finished());
        let held = device.read_state().unwrap();
        assert_eq!(held.position_m.x, 0.003);
        assert_eq!(held.velocity_m_per_s, DVec3::ZERO);
    }

    #[test]
    fn looping_starts_over() {
        let mut device = ReplayDevice::new(&trace(&[(0.0, 1.0), (0.1, 2.0)]), true).unwrap();
        let xs: Vec<f64> = (0..4)
            .map(|_| device.read_state().unwrap().position_m.x)
            .collect();
        assert_eq!(xs, [1.0, 2.0, 1.0, 2.0]);
    }

    #[test]
    fn refuses_empty_and_non_finite_traces() {
        assert!(ReplayDevice::new(&trace(&[]), false).is_err());
        assert!(ReplayDevice::new(&trace(&[(0.0, f64::NAN)]), false).is_err());
    }

    #[test]
    fn records_the_forces_it_is_sent() {
        let mut device = ReplayDevice::new(&trace(&[(0.0, 0.0)]), false).unwrap();
        device.write_force(DVec3::new(0.5, 0.0, 0.0)).unwrap();
        assert_eq!(device.last_force_n(), DVec3::new(0.5, 0.0, 0.0));
        assert_eq!(device.forces_received(), 1);
    }
}
