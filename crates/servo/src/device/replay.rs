//! A replay device (HAPI's PlaybackHapticsDevice): plays the probe positions of a recorded force trace, one
//! recorded sample per `read_state` at speed 1, and records the forces it is sent instead of rendering them.
//!
//! Where it sits: in place of a real arm, for regression runs of the servo loop against a recorded session.
//! Controls ([`ReplayOptions`], written `replay:TRACE[,seek=S][,speed=X][,loop]`, see [`parse_replay_spec`]):
//! `seek` starts at the first sample at or after trace time S (s), also at run time with
//! [`ReplayDevice::seek`]; `speed` plays X recorded samples per read (0.5 holds each sample for two reads,
//! 2 skips every other one; velocities scale with it); the default plays the trace once and then holds
//! the last position, with [`ReplayDevice::end_message`] saying so; `loop` starts over instead.
//! [`ReplayDevice::report_end`] prints that message on stderr when the end is reached (`voxhap serve`
//! calls it): the servo thread only raises a flag, a small reporter thread prints.
//! Velocity is the finite difference of consecutive probe positions over their recorded times, times the
//! speed. Samples whose probe position or time is not finite (recorded with the `invalid_values` flag) are
//! left out and counted: a replay never hands a NaN to the servo loop.

use glam::DVec3;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use voxhap_device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use voxhap_record::Trace;

/// How a trace is played.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayOptions {
    /// Trace time to start at (s); default 0 (the first sample).
    pub seek_s: f64,
    /// Recorded samples per read, > 0 and at most [`MAX_REPLAY_SPEED`]; default 1.
    pub speed: f64,
    /// Start over at the end instead of holding the last position; default false (play once).
    pub looped: bool,
}

// Options are only made by `parse_replay_spec` and `Default`, which admit finite numbers only, so
// equality is reflexive (device specs compare with `Eq`).
impl Eq for ReplayOptions {}

/// The fastest replay speed.
pub const MAX_REPLAY_SPEED: f64 = 1000.0;

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            seek_s: 0.0,
            speed: 1.0,
            looped: false,
        }
    }
}

/// Why a replay spec or its options were refused: each names the option and the value given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplaySpecError {
    /// No trace file before the first comma.
    #[error("replay: needs a trace file: replay:TRACE[,seek=S][,speed=X][,loop]")]
    NoTrace,
    /// `seek=` or `speed=` is not a finite number.
    #[error("replay {name}={value:?}: not a finite number")]
    NotANumber {
        /// `seek` or `speed`.
        name: &'static str,
        /// The value given.
        value: String,
    },
    /// An option that is not `seek=S`, `speed=X` or `loop`.
    #[error("replay option {0:?}: expected seek=S, speed=X or loop")]
    UnknownOption(String),
    /// The speed is not in (0, [`MAX_REPLAY_SPEED`]].
    #[error("replay speed {0} must be > 0 and at most {max}", max = MAX_REPLAY_SPEED)]
    Speed(f64),
    /// The seek time is negative or not finite.
    #[error("replay seek {0} s must be >= 0")]
    Seek(f64),
}

/// Parses `TRACE[,seek=S][,speed=X][,loop]` (what follows `replay:` in `--device`).
pub fn parse_replay_spec(text: &str) -> Result<(PathBuf, ReplayOptions), ReplaySpecError> {
    let mut parts = text.split(',');
    let path = parts.next().unwrap_or("");
    if path.is_empty() {
        return Err(ReplaySpecError::NoTrace);
    }
    let mut options = ReplayOptions::default();
    for part in parts {
        let number = |value: &str, name: &'static str| {
            value
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| ReplaySpecError::NotANumber {
                    name,
                    value: value.to_owned(),
                })
        };
        match part.split_once('=') {
            Some(("seek", value)) => options.seek_s = number(value, "seek")?,
            Some(("speed", value)) => options.speed = number(value, "speed")?,
            None if part == "loop" => options.looped = true,
            _ => return Err(ReplaySpecError::UnknownOption(part.to_owned())),
        }
    }
    options.check()?;
    Ok((PathBuf::from(path), options))
}

impl ReplayOptions {
    fn check(&self) -> Result<(), ReplaySpecError> {
        if !(self.speed > 0.0 && self.speed <= MAX_REPLAY_SPEED) {
            return Err(ReplaySpecError::Speed(self.speed));
        }
        if !self.seek_s.is_finite() || self.seek_s < 0.0 {
            return Err(ReplaySpecError::Seek(self.seek_s));
        }
        Ok(())
    }
}

/// Plays a trace's probe positions.
#[derive(Debug, Clone)]
pub struct ReplayDevice {
    positions_m: Vec<DVec3>,
    times_s: Vec<f64>,
    /// Position in the samples (fractional at speeds other than 1).
    cursor: f64,
    options: ReplayOptions,
    skipped_samples: usize,
    info: DeviceInfo,
    last_force_n: DVec3,
    forces_received: u64,
    /// Raised (by `read_state`, on the servo thread) once a play-once replay has played its last sample,
    /// when [`ReplayDevice::report_end`] is watching.
    end_reached: Option<Arc<AtomicBool>>,
}

/// How often the end reporter thread looks at the flag.
const END_POLL_INTERVAL: Duration = Duration::from_millis(20);

impl ReplayDevice {
    /// A replay of `trace` from its start, looping or playing once.
    pub fn new(trace: &Trace, looped: bool) -> Result<ReplayDevice, DeviceError> {
        Self::with_options(
            trace,
            ReplayOptions {
                looped,
                ..ReplayOptions::default()
            },
        )
    }

    /// A replay of `trace` with `options`. Refuses a trace without a finite sample, and bad options.
    pub fn with_options(
        trace: &Trace,
        options: ReplayOptions,
    ) -> Result<ReplayDevice, DeviceError> {
        options.check().map_err(|problem| DeviceError::Config {
            what: problem.to_string(),
        })?;
        let mut positions_m = Vec::with_capacity(trace.samples.len());
        let mut times_s = Vec::with_capacity(trace.samples.len());
        let mut skipped_samples = 0;
        for sample in &trace.samples {
            if !sample.probe_m.is_finite() || !sample.t_s.is_finite() {
                skipped_samples += 1;
                continue;
            }
            positions_m.push(sample.probe_m);
            times_s.push(sample.t_s);
        }
        if positions_m.is_empty() {
            return Err(DeviceError::Config {
                what: format!(
                    "cannot replay a trace with no finite samples ({} samples, {skipped_samples} not finite)",
                    trace.samples.len()
                ),
            });
        }
        let (min, max) = positions_m
            .iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        let mut device = ReplayDevice {
            positions_m,
            times_s,
            cursor: 0.0,
            options,
            skipped_samples,
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
                max_speed_m_per_s: voxhap_device::info::DEFAULT_MAX_SPEED_M_PER_S,
                reports_velocity: false,
                state_rates_hz: Vec::new(),
            },
            last_force_n: DVec3::ZERO,
            forces_received: 0,
            end_reached: None,
        };
        device.seek(options.seek_s);
        Ok(device)
    }

    /// Continues from the first sample at or after trace time `t_s` (s); past the end, the replay is
    /// finished (or, looping, starts over).
    pub fn seek(&mut self, t_s: f64) {
        let index = self.times_s.partition_point(|&t| t < t_s);
        self.cursor = index as f64;
    }

    /// The last force sent to the replay (N).
    pub fn last_force_n(&self) -> DVec3 {
        self.last_force_n
    }

    /// How many forces were sent.
    pub fn forces_received(&self) -> u64 {
        self.forces_received
    }

    /// Samples left out because their position or time was not finite.
    pub fn skipped_samples(&self) -> usize {
        self.skipped_samples
    }

    /// True once every sample was played (never when looping).
    pub fn finished(&self) -> bool {
        !self.options.looped && self.cursor >= self.positions_m.len() as f64
    }

    /// What this replay will do, for the operator at start (allocates: call it off the servo thread):
    /// `replay run.csv: 3000 samples (trace time 0.000 s to 2.999 s) from 0.000 s at speed 1, once, then
    /// holding the last position (add ,loop to repeat)`.
    pub fn plan(&self, name: &str) -> String {
        let first = self.times_s[0];
        let last = self.times_s[self.times_s.len() - 1];
        format!(
            "replay {name}: {} samples (trace time {first:.3} s to {last:.3} s) from {:.3} s at speed {}, {}",
            self.positions_m.len(),
            self.times_s
                .get(self.cursor as usize)
                .copied()
                .unwrap_or(last),
            self.options.speed,
            if self.options.looped {
                "looping"
            } else {
                "once, then holding the last position (add ,loop to repeat)"
            }
        )
    }

    /// Once a play-once replay has finished: what the operator should be told (allocates: call it off the
    /// servo thread).
    pub fn end_message(&self, name: &str) -> Option<String> {
        self.finished().then(|| self.end_text(name))
    }

    /// `replay: end of run.csv after 3000 samples (2.999 s); holding the last position; use --device
    /// replay:run.csv,loop to repeat`: the samples and trace time played from the seek point.
    fn end_text(&self, name: &str) -> String {
        let first = self
            .times_s
            .partition_point(|&t| t < self.options.seek_s)
            .min(self.times_s.len() - 1);
        let played = self.times_s.len() - first;
        let span_s = self.times_s[self.times_s.len() - 1] - self.times_s[first];
        format!(
            "replay: end of {name} after {played} samples ({span_s:.3} s); holding the last position; use \
             --device replay:{name},loop to repeat"
        )
    }

    /// For a play-once replay: prints [`ReplayDevice::end_message`] on stderr once the last sample has
    /// been played. The message is made here; the servo thread only raises a flag, which a reporter thread
    /// (`voxhap-replay-end`) polls every 20 ms; it ends after printing, or when the device is dropped.
    pub fn report_end(&mut self, name: &str) -> std::io::Result<()> {
        if self.options.looped {
            return Ok(());
        }
        let reached = Arc::new(AtomicBool::new(false));
        self.end_reached = Some(reached.clone());
        let message = self.end_text(name);
        std::thread::Builder::new()
            .name("voxhap-replay-end".to_owned())
            .spawn(move || {
                // The device holds the other reference; once it is gone the end can no longer come.
                while Arc::strong_count(&reached) > 1 {
                    if reached.load(Ordering::Acquire) {
                        eprintln!("{message}");
                        return;
                    }
                    std::thread::sleep(END_POLL_INTERVAL);
                }
            })?;
        Ok(())
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
        if self.cursor >= count as f64 {
            if self.options.looped {
                self.cursor = 0.0;
            } else {
                if let Some(reached) = &self.end_reached {
                    reached.store(true, Ordering::Release);
                }
                return Ok(DeviceState::at_rest(self.positions_m[count - 1]));
            }
        }
        let i = self.cursor as usize;
        self.cursor += self.options.speed;
        let velocity_m_per_s = if i > 0 {
            let dt_s = self.times_s[i] - self.times_s[i - 1];
            if dt_s > 0.0 {
                (self.positions_m[i] - self.positions_m[i - 1]) / dt_s * self.options.speed
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
            sequence: None,
            status: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use voxhap_record::TraceSample;

    /// The x of the next `n` states `device` reads.
    fn next_xs(device: &mut ReplayDevice, n: usize) -> Vec<f64> {
        (0..n)
            .map(|_| device.read_state().unwrap().position_m.x)
            .collect()
    }

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
        let xs = next_xs(&mut device, 4);
        assert_eq!(xs, [1.0, 2.0, 1.0, 2.0]);
    }

    #[test]
    fn refuses_empty_traces_and_skips_non_finite_samples() {
        assert!(ReplayDevice::new(&trace(&[]), false).is_err());
        assert!(ReplayDevice::new(&trace(&[(0.0, f64::NAN)]), false).is_err());
        let mut device =
            ReplayDevice::new(&trace(&[(0.0, 1.0), (0.1, f64::NAN), (0.2, 3.0)]), false).unwrap();
        assert_eq!(device.skipped_samples(), 1);
        let xs = next_xs(&mut device, 3);
        assert_eq!(xs, [1.0, 3.0, 3.0]);
    }

    #[test]
    fn play_once_says_so_at_the_end() {
        let mut device = ReplayDevice::new(&trace(&[(0.0, 1.0), (0.1, 2.0)]), false).unwrap();
        assert!(device.end_message("run.csv").is_none());
        device.read_state().unwrap();
        device.read_state().unwrap();
        assert_eq!(
            device.end_message("run.csv").unwrap(),
            "replay: end of run.csv after 2 samples (0.100 s); holding the last position; use --device \
             replay:run.csv,loop to repeat"
        );
        let points: Vec<(f64, f64)> = (0..10).map(|i| (i as f64 * 0.1, i as f64)).collect();
        let seeked = ReplayOptions {
            seek_s: 0.45,
            ..ReplayOptions::default()
        };
        let device = ReplayDevice::with_options(&trace(&points), seeked).unwrap();
        assert!(device
            .end_text("t.csv")
            .starts_with("replay: end of t.csv after 5 samples (0.400 s)"));
    }

    #[test]
    fn seek_and_speed() {
        let points: Vec<(f64, f64)> = (0..10).map(|i| (i as f64 * 0.1, i as f64)).collect();
        let options = ReplayOptions {
            seek_s: 0.45,
            speed: 2.0,
            looped: false,
        };
        let mut device = ReplayDevice::with_options(&trace(&points), options).unwrap();
        let first = device.read_state().unwrap();
        assert_eq!(first.position_m.x, 5.0);
        // Twice as fast: every other sample, velocity doubled (10 m/s recorded).
        assert!((first.velocity_m_per_s.x - 20.0).abs() < 1e-9);
        assert_eq!(device.read_state().unwrap().position_m.x, 7.0);
        device.seek(0.0);
        assert_eq!(device.read_state().unwrap().position_m.x, 0.0);
        let slow = ReplayOptions {
            speed: 0.5,
            ..ReplayOptions::default()
        };
        let mut device = ReplayDevice::with_options(&trace(&points), slow).unwrap();
        let xs = next_xs(&mut device, 4);
        assert_eq!(xs, [0.0, 0.0, 1.0, 1.0]);
    }

    #[test]
    fn replay_specs_parse_and_bad_ones_are_named() {
        let (path, options) = parse_replay_spec("run.csv,seek=2.5,speed=0.5,loop").unwrap();
        assert_eq!(path, PathBuf::from("run.csv"));
        assert_eq!(
            options,
            ReplayOptions {
                seek_s: 2.5,
                speed: 0.5,
                looped: true
            }
        );
        assert_eq!(
            parse_replay_spec("run.csv").unwrap().1,
            ReplayOptions::default()
        );
        assert!(parse_replay_spec("run.csv,speed=0")
            .unwrap_err()
            .to_string()
            .contains("speed"));
        assert!(parse_replay_spec("run.csv,speed=nan").is_err());
        assert!(parse_replay_spec("run.csv,fast")
            .unwrap_err()
            .to_string()
            .contains("fast"));
        assert!(parse_replay_spec("").is_err());
    }

    #[test]
    fn records_the_forces_it_is_sent() {
        let mut device = ReplayDevice::new(&trace(&[(0.0, 0.0)]), false).unwrap();
        device.write_force(DVec3::new(0.5, 0.0, 0.0)).unwrap();
        assert_eq!(device.last_force_n(), DVec3::new(0.5, 0.0, 0.0));
        assert_eq!(device.forces_received(), 1);
    }
}
