//! Device drivers, one per family, each on a transport (crates/device/src/transport) and each a
//! [`HapticDevice`](crate::HapticDevice):
//!
//! - [`protocol`]: voxhap's own wire protocol (protocol/SPEC.md) over serial or USB HID, for microcontroller arms
//!   and for `voxhap mock-device`;
//! - [`assemble`]: receive cores with no I/O (bytes in, whole replies out) for the request/reply drivers;
//! - [`exchange`]: the shared runner that reads a port into a receive core within a period-bounded wait;
//! - [`protocol_link`]: the links that driver talks through (framed serial, HID reports);
//! - [`protocol_rate`]: the State rate a local-model session needs on a link (SPEC section 10.4);
//! - [`woodenhaptics_serial`]: WoodenHaptics, Polhem and retrofitted PHANTOMs on the current Teensy firmware
//!   (text lines over USB serial; kinematics from hfabapi);
//! - [`woodenhaptics`]: WoodenHaptics 1.5 over USB HID (legacy mbed firmware);
//! - [`woodenhaptics_constants`]: the constants a device profile may replace, for both WoodenHaptics drivers;
//! - [`woodenhaptics_kinematics`]: the WoodenHaptics kinematics (capstan drive, serial chain, Polhem), one
//!   type used by both WoodenHaptics drivers;
//! - [`woodenhaptics_gravity`]: Polhem's gravity compensation, as hfabapi computes it;
//! - [`falcon`]: Novint Falcon over the FTDI serial port (`ftdi_sio`), with libnifalcon's frames, firmware upload
//!   and kinematics;
//! - [`falcon_frames`]: the Falcon's frames and their assembly from bytes (a protocol core without I/O);
//! - [`falcon_kinematics`]: the Falcon's kinematics (libnifalcon's delta-robot solution);
//! - [`haply`]: Haply 2DIY over USB serial (pantograph, planar);
//! - [`in_flight`]: the unanswered commands of a link whose replies may come ticks later (the Falcon's ages);
//! - [`reply_age`]: how old a request/reply driver's state may be, for devices without sequence numbers;
//! - [`reply_book`]: what the serial drivers keep for the host (the pose the host accepted, the state's age,
//!   the surplus count and its events), with the trait methods it answers written once;
//! - [`report_stream`]: the receive core of a device that streams reports (the newest kept, with its age);
//! - [`haply_inverse`]: Haply Inverse3 through the Haply Inverse Service (JSON over WebSocket, I/O thread);

pub mod assemble;
pub mod exchange;
pub mod falcon;
pub mod falcon_frames;
pub mod falcon_kinematics;
pub mod haply;
pub mod haply_inverse;
pub mod in_flight;
pub mod protocol;
pub mod protocol_link;
pub mod protocol_rate;
pub mod reply_age;
pub mod reply_book;
pub mod report_stream;
pub mod woodenhaptics;
pub mod woodenhaptics_constants;
pub mod woodenhaptics_gravity;
pub mod woodenhaptics_kinematics;
pub mod woodenhaptics_serial;

pub use falcon::{Falcon, FalconConfig};
pub use haply::{Haply2Diy, Haply2DiyConfig};
pub use haply_inverse::{HaplyInverse, HaplyInverseConfig};
pub use protocol::{HidLink, MessageLink, ProtocolConfig, ProtocolDevice, SerialLink};
pub use woodenhaptics::WoodenHaptics;
pub use woodenhaptics_serial::{WoodenHapticsSerial, WoodyConfig, WoodyKinematics, WoodyModel};
