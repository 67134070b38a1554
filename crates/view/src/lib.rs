//! How a session is drawn for Foxglove and Lichtblick: the topics, frames and schemas ([`topics`]), the
//! scene markers and JSON messages made from a [`Snapshot`](voxhap_api::Snapshot) ([`messages`]), the
//! volume's picture and slices ([`volume`]) and the one palette ([`palette`], web/style.css). The live view
//! (`voxhap_server::foxglove`) and the MCAP trace writer (`voxhap_record`) both draw with this code, so a
//! recording opens with the same topics and colours as a live session. Pure: builds messages, does no I/O.

pub mod messages;
pub mod palette;
pub mod topics;
pub mod volume;
