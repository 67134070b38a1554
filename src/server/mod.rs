//! The visualiser servers that run on tokio inside `voxhap serve`: the axum HTTP/WebSocket server with the
//! built-in page and the control API, and the Foxglove live view. Both read the servo only through
//! [`crate::servo::SessionApi`] (triple-buffer snapshots and atomic statistics), so the servo thread never waits
//! on them.

pub mod foxglove;
