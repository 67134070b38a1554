//! CRC-16/CCITT-FALSE (also catalogued as CRC-16/IBM-3740), the checksum that closes every serial frame.
//!
//! Where it sits: [`crate::serial`] computes it over `type ‖ payload` before COBS stuffing and checks it after
//! unstuffing. HID reports carry no CRC (USB already protects them).
//!
//! Parameters (Rocksoft model): width 16, poly 0x1021, init 0xFFFF, refin false, refout false, xorout 0x0000,
//! check value (CRC of the ASCII bytes "123456789") 0x29B1. Hamming distance 4 for every frame this protocol can
//! produce (at most 65 bytes), so any 1, 2 or 3 bit errors and every burst up to 16 bits are caught.
//!
//! Computation: MSB-first polynomial division, one byte at a time `crc = (crc << 8) ^ T0[(crc >> 8) ^ byte]`,
//! where `T0[x]` is the CRC (from zero) of the single byte `x`. That loop is a chain of dependent table loads, so
//! this module "slices by 8" (Intel's slicing-by-N): by linearity of the CRC over GF(2), the register folds into the
//! first two bytes of an 8-byte block (`x0 = b0 ^ crc >> 8`, `x1 = b1 ^ crc & 0xFF`), and the block's CRC is
//! `T7[x0] ^ T6[x1] ^ T5[b2] ^ ... ^ T0[b7]`, with `Tk[x]` the CRC of `x` followed by `k` zero bytes
//! (`Tk[x] = (Tk-1[x] << 8) ^ T0[Tk-1[x] >> 8]`). Eight independent loads per block instead of eight dependent ones;
//! the tables (4 KiB) are built at compile time. Firmware short of flash can use the byte loop with `T0` alone
//! (512 bytes); the result is identical (tested).

/// The generator polynomial, MSB-first, x^16 implied.
pub const CRC16_POLY: u16 = 0x1021;
/// The register value before the first byte.
pub const CRC16_INIT: u16 = 0xFFFF;
/// CRC of the ASCII string "123456789" (the catalogue's check value).
pub const CRC16_CHECK: u16 = 0x29B1;

const TABLES: [[u16; 256]; 8] = build_tables();

const fn build_tables() -> [[u16; 256]; 8] {
    let mut tables = [[0u16; 256]; 8];
    let mut index = 0;
    while index < 256 {
        let mut crc = (index as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ CRC16_POLY
            } else {
                crc << 1
            };
            bit += 1;
        }
        tables[0][index] = crc;
        index += 1;
    }
    let mut k = 1;
    while k < 8 {
        let mut index = 0;
        while index < 256 {
            let previous = tables[k - 1][index];
            tables[k][index] = (previous << 8) ^ tables[0][(previous >> 8) as usize];
            index += 1;
        }
        k += 1;
    }
    tables
}

/// CRC-16/CCITT-FALSE of `bytes`.
pub fn crc16(bytes: &[u8]) -> u16 {
    crc16_update(CRC16_INIT, bytes)
}

/// Continue a CRC-16/CCITT-FALSE computation: `crc16_update(crc16(a), b) == crc16(a ‖ b)`.
pub fn crc16_update(mut crc: u16, bytes: &[u8]) -> u16 {
    let t = &TABLES;
    let mut blocks = bytes.chunks_exact(8);
    for b in &mut blocks {
        let [hi, lo] = crc.to_be_bytes();
        crc = t[7][usize::from(b[0] ^ hi)]
            ^ t[6][usize::from(b[1] ^ lo)]
            ^ t[5][usize::from(b[2])]
            ^ t[4][usize::from(b[3])]
            ^ t[3][usize::from(b[4])]
            ^ t[2][usize::from(b[5])]
            ^ t[1][usize::from(b[6])]
            ^ t[0][usize::from(b[7])];
    }
    crc16_update_bytewise(crc, blocks.remainder())
}

/// The byte-at-a-time loop with the single 512-byte table: the reference for firmware that cannot spare 4 KiB.
pub fn crc16_update_bytewise(mut crc: u16, bytes: &[u8]) -> u16 {
    for &byte in bytes {
        crc = (crc << 8) ^ TABLES[0][usize::from((crc >> 8) as u8 ^ byte)];
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
                crc = if crc & 0x8000 != 0 {
                    (crc << 1) ^ CRC16_POLY
                } else {
                    crc << 1
                };
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
        fn tables_match_bitwise(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            prop_assert_eq!(crc16(&bytes), crc16_bitwise(&bytes));
            prop_assert_eq!(crc16_update_bytewise(CRC16_INIT, &bytes), crc16_bitwise(&bytes));
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
