//! CRC-16/CCITT-FALSE (also catalogued as CRC-16/IBM-3740), the checksum that closes every serial frame.
//!
//! Where it sits: [`crate::serial`] computes it over `type ‖ payload` before COBS stuffing and checks it after
//! unstuffing. HID reports carry no CRC (USB already protects them).
//!
//! Parameters (Rocksoft model): width 16, poly 0x1021, init 0xFFFF, refin false, refout false, xorout 0x0000,
//! check value (CRC of the ASCII bytes "123456789") 0x29B1. It is the MSB-first polynomial division
//! `crc = (crc << 8) ^ TABLE[(crc >> 8) ^ byte]`, one 256-entry table (512 bytes of flash) built at compile time,
//! so a microcontroller pays one load, one shift and two XORs per byte. Hamming distance 4 for every frame this
//! protocol can produce (at most 65 bytes), so any 1, 2 or 3 bit errors and every burst up to 16 bits are caught.

/// The generator polynomial, MSB-first, x^16 implied.
pub const CRC16_POLY: u16 = 0x1021;
/// The register value before the first byte.
pub const CRC16_INIT: u16 = 0xFFFF;
/// CRC of the ASCII string "123456789" (the catalogue's check value).
pub const CRC16_CHECK: u16 = 0x29B1;

const TABLE: [u16; 256] = build_table();

const fn build_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut index = 0;
    while index < 256 {
        let mut crc = (index as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ CRC16_POLY } else { crc << 1 };
            bit += 1;
        }
        table[index] = crc;
        index += 1;
    }
    table
}

/// CRC-16/CCITT-FALSE of `bytes`.
pub fn crc16(bytes: &[u8]) -> u16 {
    crc16_update(CRC16_INIT, bytes)
}

/// Continue a CRC-16/CCITT-FALSE computation: `crc16_update(crc16(a), b) == crc16(a ‖ b)`.
pub fn crc16_update(mut crc: u16, bytes: &[u8]) -> u16 {
    for &byte in bytes {
        crc = (crc << 8) ^ TABLE[usize::from((crc >> 8) as u8 ^ byte)];
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Bit-at-a-time reference straight from the Rocksoft model, to check the table.
    fn crc16_bitwise(bytes: &[u8]) -> u16 {
        let mut crc = CRC16_INIT;
        for &byte in bytes {
            crc ^= u16::from(byte) << 8;
            for _ in 0..8 {
                crc = if crc & 0x8000 != 0 { (crc << 1) ^ CRC16_POLY } else { crc << 1 };
            }
        }
        crc
    }

    #[test]
    fn check_value_of_123456789() {
        assert_eq!(crc16(b"123456789"), CRC16_CHECK);
    }

    #[test]
    fn empty_input_is_init() {
        assert_eq!(crc16(&[]), CRC16_INIT);
    }

    proptest! {
        #[test]
        fn table_matches_bitwise(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            prop_assert_eq!(crc16(&bytes), crc16_bitwise(&bytes));
        }

        #[test]
        fn update_is_incremental(a in proptest::collection::vec(any::<u8>(), 0..80),
                                 b in proptest::collection::vec(any::<u8>(), 0..80)) {
            let mut joined = a.clone();
            joined.extend_from_slice(&b);
            prop_assert_eq!(crc16_update(crc16(&a), &b), crc16(&joined));
        }

        #[test]
        fn single_bit_flips_are_detected(bytes in proptest::collection::vec(any::<u8>(), 1..65),
                                         bit in any::<usize>()) {
            let mut flipped = bytes.clone();
            let bit = bit % (bytes.len() * 8);
            flipped[bit / 8] ^= 1 << (bit % 8);
            prop_assert_ne!(crc16(&bytes), crc16(&flipped));
        }
    }
}
