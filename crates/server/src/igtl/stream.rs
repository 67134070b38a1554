//! The stream: samples the session at the configured rate and encodes one frame (the four transforms) per new
//! tick for both header versions, plus the STATUS message.

use super::codec;
use super::codec::{status_code, Transform};
use super::config::{
    FORCE_DEVICE, PROBE_DEVICE, PROBE_VELOCITY_DEVICE, PROXY_DEVICE, STATUS_DEVICE, STATUS_INTERVAL,
};
use super::state::{unix_now_ns, Frame, Shared};
use glam::DVec3;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use tokio::time::MissedTickBehavior;
use voxhap_api::Snapshot;

/// Metres to millimetres.
pub(super) const MM_PER_M: f64 = 1000.0;

/// The four transforms of `snapshot`, appended to `out` with header `version`.
pub(super) fn encode_stream(out: &mut Vec<u8>, version: u16, snapshot: &Snapshot, timestamp: u64) {
    let items = [
        (PROBE_DEVICE, snapshot.probe_m * MM_PER_M),
        (PROXY_DEVICE, snapshot.proxy_m * MM_PER_M),
        (
            PROBE_VELOCITY_DEVICE,
            snapshot.probe_velocity_m_per_s * MM_PER_M,
        ),
        (FORCE_DEVICE, snapshot.sent_force_n),
    ];
    for (device, translation) in items {
        // A non-finite value is never sent: it becomes zero (the snapshot's values are checked by the servo
        // already; this is the last guard before another program).
        let translation = if translation.is_finite() {
            translation
        } else {
            DVec3::ZERO
        };
        codec::encode_message(out, version, "TRANSFORM", device, timestamp, &[], |o| {
            Transform::translation(translation).encode(o)
        });
    }
}

/// The STATUS that describes `snapshot` (or a session that has not ticked yet).
pub(super) fn status_of(snapshot: Option<&Snapshot>) -> (u16, &'static str, String) {
    match snapshot {
        None => (
            status_code::DEVICE_NOT_READY,
            "NotReady",
            "the servo loop has not ticked yet".to_owned(),
        ),
        Some(s) => {
            let (code, name) = match (s.connected, s.engaged) {
                (true, true) => (status_code::OK, "OK"),
                (true, false) => (status_code::DEVICE_NOT_READY, "NotEngaged"),
                (false, _) => (status_code::DEVICE_DISABLED, "Disconnected"),
            };
            let bound = if s.error_bound_m.is_finite() {
                format!("{:.3e} m", s.error_bound_m)
            } else {
                "none".to_owned()
            };
            (
                code,
                name,
                format!(
                    "tick {} t {:.3} s; device {}, force {}; |force| {:.3} N; certificate bound {bound}",
                    s.tick,
                    s.t_s,
                    if s.connected { "connected" } else { "disconnected" },
                    if s.engaged { "engaged" } else { "not engaged" },
                    s.sent_force_n.length()
                ),
            )
        }
    }
}

pub(super) fn status_frame(shared: &Shared, snapshot: Option<&Snapshot>) -> Arc<Frame> {
    let (code, name, message) = status_of(snapshot);
    let timestamp = codec::timestamp_from_unix_ns(
        snapshot.map_or_else(unix_now_ns, |s| shared.clock.at(s.t_s)),
    );
    let encode = |version| {
        let mut out = Vec::with_capacity(128);
        codec::encode_message(
            &mut out,
            version,
            "STATUS",
            STATUS_DEVICE,
            timestamp,
            &[],
            |o| codec::encode_status(o, code, 0, name, &message),
        );
        out
    };
    Arc::new(Frame {
        v1: encode(1),
        v2: encode(2),
    })
}

/// The streamer: every `period`, when a client listens and the tick advanced, one frame of the four
/// transforms; every [`STATUS_INTERVAL`] a STATUS.
pub(super) async fn stream(shared: Arc<Shared>, period: Duration, mut stop: watch::Receiver<bool>) {
    let mut sample = tokio::time::interval(period);
    sample.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut status = tokio::time::interval(STATUS_INTERVAL);
    status.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut last_tick = None;
    loop {
        tokio::select! {
            _ = stop.changed() => break,
            _ = sample.tick() => {
                if shared.frames.receiver_count() == 0 {
                    continue;
                }
                let Some(snapshot) = shared.api.snapshot() else { continue };
                if last_tick == Some(snapshot.tick) {
                    continue;
                }
                last_tick = Some(snapshot.tick);
                let timestamp = codec::timestamp_from_unix_ns(shared.clock.at(snapshot.t_s));
                let mut v1 = Vec::with_capacity(4 * 106);
                encode_stream(&mut v1, 1, &snapshot, timestamp);
                let mut v2 = Vec::with_capacity(4 * 120);
                encode_stream(&mut v2, 2, &snapshot, timestamp);
                let _ = shared.frames.send(Arc::new(Frame { v1, v2 }));
            }
            _ = status.tick() => {
                let frame = status_frame(&shared, shared.api.snapshot().as_ref());
                if let Ok(mut slot) = shared.status.lock() {
                    *slot = Some(frame.clone());
                }
                if shared.frames.receiver_count() > 0 {
                    let _ = shared.frames.send(frame);
                }
            }
        }
    }
}
