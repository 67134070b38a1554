//! The OpenIGTLink server against a client written here from the specification (openigtlink/OpenIGTLink,
//! Documents/Protocol/header.md, transform.md, status.md, string.md, image.md), not from voxhap's codec:
//! the CRC-64 is computed bit by bit from the ECMA-182 polynomial, the messages packed by hand. A real
//! session on the simulated arm, the server on 127.0.0.1 port 0.
//!
//! By topic: [`messages`] what the server sends and accepts; [`clients`] clients that misbehave. The client and
//! the fixture are tests/util/igtl_client.rs.

mod clients;
mod messages;
