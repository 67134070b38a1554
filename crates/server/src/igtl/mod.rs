//! The OpenIGTLink server behind `voxhap serve --igtl`: voxhap as a tracked, force-rendering tool for 3D
//! Slicer (OpenIGTLinkIF) and other OpenIGTLink clients, and a way for them to send a volume in.
//!
//! Where it sits (docs/design.md, "Threads"): tasks on `voxhap serve`'s tokio runtime that read the servo only
//! through [`SessionApi`] (the triple-buffer snapshot) and change it only through
//! [`SessionApi::control`] on the blocking pool. A streamer task samples the session at `--igtl-rate`
//! (default 60 Hz) and puts one encoded frame per new tick on a bounded broadcast queue
//! ([`CLIENT_QUEUE_FRAMES`]); a client that falls behind loses the oldest frames (counted), so no client can
//! slow another or the servo.
//!
//! What a client receives (every message with a valid CRC-64; header version 1, i.e. protocol 2, until the
//! client itself sends a version-2 header, i.e. protocol 3, and from then on version 2):
//!
//! | device name | type | content |
//! |---|---|---|
//! | `Probe` | TRANSFORM | the device (stylus) position, RAS millimetres, identity rotation (voxhap's probe is a point) |
//! | `Proxy` | TRANSFORM | the proxy position, RAS millimetres, identity rotation |
//! | `ProbeVelocity` | TRANSFORM | identity rotation, translation = probe velocity in mm/s, RAS (as PLUS's OpenHaptics device sends `StylusVelocity`) |
//! | `Force` | TRANSFORM | identity rotation, translation = the force sent to the device in newtons, RAS (the convention of PLUS's `Force` tool) |
//! | `voxhap` | STATUS | once a second and on connect: 1 OK (connected and engaged), 13 not ready (ramping in), 15 disabled (no device) |
//!
//! The velocity and force conventions are PLUS's (PlusToolkit/PlusLib,
//! src/PlusDataCollection/OpenHaptics/vtkPlusOpenHapticsDevice.cxx at commit 063daba7): its `positionCallback`
//! puts `HD_CURRENT_VELOCITY` into the translation column of an otherwise identity matrix for the
//! `StylusVelocity` tool, and reads the force for `HD_CURRENT_FORCE` (newtons) from elements (0..2, 3), the
//! translation, of the `Force` tool's matrix, both in RAS after its `rasCorrection`.
//!
//! What a client may send (replies are STATUS messages with the request's device name):
//!
//! - STRING `token <T>`: authorises this connection for control (the token `voxhap serve` prints as
//!   `igtl: control token T`, the same one the HTTP server takes). A protocol-3 message may instead carry
//!   the metadata entry `token` = T. Reply: 1 OK, or 5 access denied.
//! - IMAGE (a scalar volume, any device name; needs the token): decoded ([`codec::decode_image`], RAS or
//!   LPS, the position is the image centre), written to the server's private folder
//!   ([`volume_file`]) and loaded with `load_volume`, replacing the scene's first volume (or the one named
//!   by the metadata entry `volume`). The scene is built on the blocking pool, never on the servo thread.
//!   Reply: 1 OK with the new volume's size, or the error (5 without the token).
//! - TRANSFORM `ProbeTarget` (needs the token): pulls the simulated arm's hand to the translation (RAS mm);
//!   only the newest target is applied when they come faster than the session takes them. Replies only on
//!   failure.
//! - GET_STATUS: answered with the current STATUS. Anything else is read and ignored.
//!
//! Who may connect, and what a client can make the server hold (the bounds are the constants below):
//!
//! - **Connections:** [`MAX_CLIENTS`]. A new client always gets in: when the table is full, the connection
//!   that matters least is closed to make room (STATUS 6 "Evicted" with the reason, counted in
//!   `clients_evicted`), chosen by [`choose_victim`]: one without the token before one with it, then one
//!   whose stream the server cannot write (it does not read) before one that reads, then the one silent
//!   longest (nothing received from it), then the oldest. A client that must stay connected under pressure
//!   sends the token.
//! - **Idle timeout** (`--igtl-idle-timeout`, default [`DEFAULT_IDLE_TIMEOUT`]): a connection to which a
//!   message could not be written for that long (the client does not read, so its socket buffers are full)
//!   is closed (counted in `idle_closed`). Reading the stream is what keeps a client connected; a
//!   viewer that only reads (Slicer's connector) stays as long as it reads. Each accepted socket's kernel
//!   send buffer is [`SEND_BUFFER_BYTES`], so a client that stops reading stalls after a few seconds of
//!   stream.
//! - **Authentication before large bodies:** a client without the token may send bodies of at most
//!   [`UNAUTHENTICATED_BODY_BYTES`]; a larger one is refused from its header alone (STATUS 5, then the
//!   connection is closed after discarding at most [`LINGER_BYTES`] for at most [`LINGER_TIME`], so that
//!   the client can read the STATUS), and none of it is stored. So a large IMAGE needs the token sent first
//!   (STRING `token <T>`, or the metadata entry on an earlier small message).
//! - **Bodies with the token:** up to [`MAX_BODY_BYTES`] each; all bodies over
//!   [`UNAUTHENTICATED_BODY_BYTES`] being read or handled at once, over all clients, share a budget of
//!   [`LARGE_BODY_BUDGET_BYTES`] (a client waits for its share at most [`MESSAGE_TIMEOUT`]); IMAGEs are
//!   decoded one at a time, up to [`MAX_IMAGE_VOXELS`] (4 bytes each once decoded).
//! - **Time:** once a message's first byte arrived, its header must follow within [`MESSAGE_TIMEOUT`],
//!   and its body within [`MESSAGE_TIMEOUT`] after that.
//!
//! So a client without the token makes the server hold at most one body of
//! [`UNAUTHENTICATED_BODY_BYTES`], [`REPLY_QUEUE`] short replies, one stream frame being written and the
//! [`SEND_BUFFER_BYTES`] kernel buffer; all token holders together at most [`LARGE_BODY_BUDGET_BYTES`] of
//! bodies plus one decoded image. A bad CRC is answered with STATUS 9 and the message dropped; a header
//! that cannot be framed closes the connection.

pub mod codec;
pub mod volume_file;

mod client;
mod config;
mod read;
mod server;
mod session;
mod state;
mod stream;
#[cfg(test)]
mod tests;

pub use config::{
    IgtlArgs, IgtlConfig, IgtlError, CLIENT_QUEUE_FRAMES, DEFAULT_ADDR, DEFAULT_IDLE_TIMEOUT,
    DEFAULT_RATE_HZ, FORCE_DEVICE, IDLE_TIMEOUT_RANGE_S, LARGE_BODY_BUDGET_BYTES, LINGER_BYTES,
    LINGER_TIME, MAX_BODY_BYTES, MAX_CLIENTS, MAX_IMAGE_VOXELS, MESSAGE_TIMEOUT, PROBE_DEVICE,
    PROBE_TARGET_DEVICE, PROBE_VELOCITY_DEVICE, PROXY_DEVICE, RATE_RANGE_HZ, REPLY_QUEUE,
    SEND_BUFFER_BYTES, STATUS_DEVICE, STATUS_INTERVAL, STOP_TIMEOUT, TOKEN_METADATA_KEY,
    UNAUTHENTICATED_BODY_BYTES,
};
pub use server::IgtlServer;
pub use state::{choose_victim, Candidate, IgtlStats};
