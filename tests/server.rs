//! The visualiser server against a real session (simulated arm, built-in scene, 1 kHz) on 127.0.0.1:0: the
//! state stream's rate, the control API's token and validation, the client cap, a client that never reads,
//! clean shutdown, slices and the page. Contract: protocol/VISUALISER.md.
//!
//! By topic: [`stream`] the state stream and its clients; [`control`] the control API; [`endpoints`] slices, the
//! page and the read endpoints; [`connections`] connection limits below HTTP. The session and the HTTP and
//! WebSocket clients are tests/util/server.rs.

mod connections;
mod control;
mod endpoints;
mod stream;
