//! Numbers that SPEC.md states in prose and tables, checked against the crate so that the document cannot drift:
//! the frame-size table of section 4.2, the CRC table entries and example, and the limits firmware authors rely on.

use std::path::Path;

use voxhap_protocol::crc::{crc16, crc16_update};
use voxhap_protocol::{encode_frame, Message, MAX_WIRE_FRAME_LEN};

fn spec_text() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("SPEC.md");
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The rows of the "Sizes" table: (names, payload, unstuffed, stuffed, wire).
fn size_rows(spec: &str) -> Vec<(String, [usize; 4])> {
    let start = spec
        .find("| message | payload | unstuffed | stuffed | on the wire")
        .expect("SPEC.md has the sizes table");
    spec[start..]
        .lines()
        .skip(2)
        .take_while(|line| line.trim_start().starts_with('|'))
        .map(|line| {
            let cells: Vec<&str> = line
                .trim()
                .trim_matches('|')
                .split('|')
                .map(str::trim)
                .collect();
            let numbers = [1, 2, 3, 4].map(|i| {
                cells[i]
                    .trim_matches('*')
                    .parse::<usize>()
                    .unwrap_or_else(|e| panic!("{line}: {e}"))
            });
            (cells[0].to_owned(), numbers)
        })
        .collect()
}

fn name(message_type: u8) -> &'static str {
    match message_type {
        0x01 => "Hello",
        0x02 => "Enable",
        0x03 => "Disable",
        0x04 => "SetForce",
        0x05 => "Heartbeat",
        0x06 => "ClearFault",
        0x07 => "SetStateRate",
        0x81 => "DeviceInfo",
        0x82 => "State",
        0x83 => "HeartbeatReply",
        0x84 => "Fault",
        0x85 => "Rejected",
        0x08 => "LocalModel",
        0x86 => "LocalState",
        other => panic!("unknown type {other:#04x}"),
    }
}

fn check<M: Message>(message: &M, rows: &[(String, [usize; 4])]) {
    let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
    let wire = encode_frame(message, &mut frame).expect("encodes");
    let mut payload = [0u8; voxhap_protocol::MAX_PAYLOAD_LEN];
    let payload_len = message.write_payload(&mut payload);
    let name = name(message.message_type());
    let (_, numbers) = rows
        .iter()
        .find(|(names, _)| names.split(", ").any(|n| n == name))
        .unwrap_or_else(|| panic!("{name} is not in the sizes table"));
    assert_eq!(
        *numbers,
        [payload_len, payload_len + 3, wire - 1, wire],
        "{name}: payload, unstuffed, stuffed, wire"
    );
}

#[test]
fn the_sizes_table_matches_the_encoder() {
    let spec = spec_text();
    let rows = size_rows(&spec);
    assert_eq!(rows.len(), 10, "{rows:?}");
    let vectors = crate::vectors::expected_vectors();
    assert!(vectors.len() >= 12);
    for (_, expected) in &vectors {
        match expected {
            crate::vectors::Expected::Host(message) => check(message, &rows),
            crate::vectors::Expected::Device(message) => check(message, &rows),
        }
    }
    assert!(spec.contains("`MAX_WIRE_FRAME_LEN`"));
    assert_eq!(
        MAX_WIRE_FRAME_LEN, 67,
        "SPEC section 4.2: the longest wire frame is 67 bytes"
    );
}

#[test]
fn the_crc_recipe_and_its_examples_hold() {
    // T[x] is the CRC of the single byte x from a zero register.
    for (index, entry) in [(0u8, 0x0000u16), (1, 0x1021), (2, 0x2042), (255, 0x1EF0)] {
        assert_eq!(crc16_update(0, &[index]), entry, "T[{index}]");
    }
    assert_eq!(crc16(&[0x01, 0x01, 0x01]), 0xD8BC, "Hello(1.1)");
    assert_eq!(crc16(&[0x01, 0x01, 0x00]), 0xC89D, "Hello(1.0)");
    assert_eq!(crc16(b"123456789"), 0x29B1);
    assert_eq!(crc16(&[]), 0xFFFF);
    // The C recipe, with its masks, in a wide register as C's integer promotion makes it.
    let mut table = [0u32; 256];
    for (i, entry) in table.iter_mut().enumerate() {
        let mut t = (i as u32) << 8;
        for _ in 0..8 {
            t = if t & 0x8000 != 0 {
                ((t << 1) ^ 0x1021) & 0xFFFF
            } else {
                (t << 1) & 0xFFFF
            };
        }
        *entry = t;
    }
    let recipe = |bytes: &[u8]| {
        bytes.iter().fold(0xFFFFu32, |crc, &b| {
            ((crc << 8) & 0xFFFF) ^ table[(((crc >> 8) ^ u32::from(b)) & 0xFF) as usize]
        })
    };
    assert_eq!(recipe(b"123456789"), 0x29B1);
    // Without the register mask (a 32-bit `crc` in C) the register grows past 16 bits, and the next index
    // `(crc >> 8) ^ b` runs past the 256-entry table: the reason the SPEC insists on the masks.
    let mut crc = 0xFFFFu32;
    let mut largest_index = 0;
    for &b in b"123456789" {
        let index = (crc >> 8) ^ u32::from(b);
        largest_index = largest_index.max(index);
        crc = (crc << 8) ^ table[(index & 0xFF) as usize];
    }
    assert!(largest_index > 255, "largest index {largest_index}");
}
