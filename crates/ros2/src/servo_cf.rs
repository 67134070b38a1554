//! The force channel in: with `serve --ros2 --external-force`, voxhap subscribes to `/voxhap/servo_cf`
//! (`geometry_msgs/msg/WrenchStamped`, CRTK's Cartesian force setpoint) and hands each wrench's force to the
//! session's external force input, which adds it to the rendered force before the safety pipeline and drops
//! it after the staleness timeout (the servo crate's `external_force` module).
//!
//! Where it sits: a thread of its own waits on the subscription (mio, as ros2-client's listener example
//! does) and calls the sink the caller gives (`SessionApi::control` with `set_external_force` in `serve`),
//! which checks the force and writes it into a triple buffer: the servo thread is never touched from here.
//!
//! What is taken: the force, in the scene frame (`frame_id` `world`, the frame voxhap publishes in, or empty).
//! A wrench in another frame, with a component that is not finite, or refused by the sink (above 1000 N)
//! is refused whole and reported on stderr (the first at once, then at most one line a second) and counted.
//! voxhap's devices render force, not torque: a non-zero torque is ignored, said once, and counted.

use crate::crtk::FRAME_ID;
use crate::error::Ros2Error;
use crate::messages::{Vector3, WrenchStamped};
use ros2_client::dds::rustdds::mio1::{Events, Interest, Poll, Token, Waker};
use ros2_client::Subscription;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use voxhap_api::ControlError;

/// Where a wrench's force goes (`set_external_force` on the session in `serve`).
pub type ExternalForceSink = Box<dyn Fn([f64; 3]) -> Result<(), ControlError> + Send + 'static>;

/// What the subscription did, reported when it stops.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServoCfStats {
    /// Wrenches whose force went to the session.
    pub taken: u64,
    /// Wrenches refused (frame, non-finite, too large, input not available).
    pub refused: u64,
    /// Taken wrenches whose non-zero torque was ignored.
    pub torque_ignored: u64,
}

/// Why a wrench was refused before it reached the sink.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WrenchError {
    /// The frame is not the scene frame.
    #[error("frame_id {0:?} is not the scene frame {FRAME_ID:?} (or empty); voxhap does not transform forces")]
    Frame(String),
    /// A torque component is not finite.
    #[error("torque {0:?} is not finite")]
    Torque([f64; 3]),
}

fn array(v: &Vector3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// The force of `message` for the sink, and whether a non-zero torque is being ignored. The force's own
/// checks (finite, magnitude) are the sink's, so every channel refuses the same forces with the same words.
pub fn wrench_force(message: &WrenchStamped) -> Result<([f64; 3], bool), WrenchError> {
    let frame = message.header.frame_id.as_str();
    if !(frame.is_empty() || frame == FRAME_ID) {
        return Err(WrenchError::Frame(frame.to_owned()));
    }
    let torque = array(&message.wrench.torque);
    if !torque.iter().all(|t| t.is_finite()) {
        return Err(WrenchError::Torque(torque));
    }
    Ok((array(&message.wrench.force), torque != [0.0; 3]))
}

/// Prints refusals on stderr: the first at once, then at most one line a second (with how many were not
/// printed), so a sender that keeps sending bad wrenches at 1 kHz cannot flood the terminal.
struct Reporter {
    last: Option<Instant>,
    unprinted: u64,
}

impl Reporter {
    fn refused(&mut self, why: &str) {
        let now = Instant::now();
        if self
            .last
            .is_some_and(|last| now.duration_since(last) < Duration::from_secs(1))
        {
            self.unprinted += 1;
            return;
        }
        let more = if self.unprinted > 0 {
            format!(" ({} more refused since the last report)", self.unprinted)
        } else {
            String::new()
        };
        eprintln!("warning: ros2: /voxhap/servo_cf: wrench refused: {why}{more}");
        self.last = Some(now);
        self.unprinted = 0;
    }
}

/// The running subscription thread.
pub(crate) struct ServoCfInput {
    stop: Arc<AtomicBool>,
    waker: Arc<Waker>,
    thread: Option<JoinHandle<ServoCfStats>>,
}

const WAKE: Token = Token(0);
const WRENCH: Token = Token(1);

impl ServoCfInput {
    /// Starts taking wrenches from `subscription` into `sink`.
    pub(crate) fn start(
        mut subscription: Subscription<WrenchStamped>,
        sink: ExternalForceSink,
    ) -> Result<ServoCfInput, Ros2Error> {
        let poll_error = |cause: std::io::Error| Ros2Error::Create {
            what: "the /voxhap/servo_cf subscription's poll".to_owned(),
            cause: cause.to_string(),
        };
        let poll = Poll::new().map_err(poll_error)?;
        let waker = Arc::new(Waker::new(poll.registry(), WAKE).map_err(poll_error)?);
        poll.registry()
            .register(&mut subscription, WRENCH, Interest::READABLE)
            .map_err(poll_error)?;
        let stop = Arc::new(AtomicBool::new(false));
        let thread_stop = stop.clone();
        let thread = std::thread::Builder::new()
            .name("ros2-servo-cf".to_owned())
            .spawn(move || run(poll, &subscription, &sink, &thread_stop))
            .map_err(Ros2Error::SubscriberThread)?;
        Ok(ServoCfInput {
            stop,
            waker,
            thread: Some(thread),
        })
    }

    /// Stops taking wrenches; what was taken.
    pub(crate) fn stop(mut self) -> ServoCfStats {
        self.shutdown()
    }

    fn shutdown(&mut self) -> ServoCfStats {
        self.stop.store(true, Ordering::Release);
        let _ = self.waker.wake();
        self.thread
            .take()
            .and_then(|thread| thread.join().ok())
            .unwrap_or_default()
    }
}

impl Drop for ServoCfInput {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn run(
    mut poll: Poll,
    subscription: &Subscription<WrenchStamped>,
    sink: &ExternalForceSink,
    stop: &AtomicBool,
) -> ServoCfStats {
    let mut stats = ServoCfStats::default();
    let mut reporter = Reporter {
        last: None,
        unprinted: 0,
    };
    let mut torque_said = false;
    let mut events = Events::with_capacity(8);
    while !stop.load(Ordering::Acquire) {
        // A one-second timeout as well as the waker: a lost wake-up cannot keep the thread forever.
        if poll
            .poll(&mut events, Some(Duration::from_secs(1)))
            .is_err()
        {
            std::thread::sleep(Duration::from_millis(10));
        }
        // Edge-triggered: take everything that has arrived, whatever woke the poll.
        loop {
            let message = match subscription.take() {
                Ok(Some((message, _))) => message,
                Ok(None) => break,
                Err(error) => {
                    stats.refused += 1;
                    reporter.refused(&format!("cannot be read: {error:?}"));
                    break;
                }
            };
            let outcome =
                wrench_force(&message)
                    .map_err(|e| e.to_string())
                    .and_then(|(force, torque)| {
                        sink(force).map_err(|e| e.to_string())?;
                        Ok(torque)
                    });
            match outcome {
                Ok(torque) => {
                    stats.taken += 1;
                    if torque {
                        stats.torque_ignored += 1;
                        if !torque_said {
                            torque_said = true;
                            eprintln!(
                                "warning: ros2: /voxhap/servo_cf: torque ignored (voxhap's devices render force only); \
                                 the force is taken"
                            );
                        }
                    }
                }
                Err(why) => {
                    stats.refused += 1;
                    reporter.refused(&why);
                }
            }
        }
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::{Header, Wrench};

    fn wrench(frame: &str, force: [f64; 3], torque: [f64; 3]) -> WrenchStamped {
        let v = |a: [f64; 3]| Vector3 {
            x: a[0],
            y: a[1],
            z: a[2],
        };
        WrenchStamped {
            header: Header {
                frame_id: frame.to_owned(),
                ..Header::default()
            },
            wrench: Wrench {
                force: v(force),
                torque: v(torque),
            },
        }
    }

    #[test]
    fn the_force_is_taken_in_the_scene_frame_and_torque_is_set_aside() {
        assert_eq!(
            wrench_force(&wrench("world", [1.0, 2.0, 3.0], [0.0; 3])),
            Ok(([1.0, 2.0, 3.0], false))
        );
        assert_eq!(
            wrench_force(&wrench("", [0.5, 0.0, 0.0], [0.1, 0.0, 0.0])),
            Ok(([0.5, 0.0, 0.0], true))
        );
        let error = wrench_force(&wrench("base_link", [1.0, 0.0, 0.0], [0.0; 3]))
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("\"base_link\"") && error.contains("\"world\""),
            "{error}"
        );
        assert!(matches!(
            wrench_force(&wrench("world", [1.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0])),
            Err(WrenchError::Torque(_))
        ));
        // A non-finite force passes here: the sink refuses it, with the words every channel uses.
        assert!(wrench_force(&wrench("world", [f64::INFINITY, 0.0, 0.0], [0.0; 3])).is_ok());
    }
}
