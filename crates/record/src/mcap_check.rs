//! The structural checks an MCAP trace passes before the mcap crate reads it: every length field fits
//! inside what contains it, and chunks are uncompressed with consistent sizes, so a damaged length can
//! never make the reader reserve gigabytes.

/// What is damaged in an MCAP file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum McapDamage {
    /// The file does not start with the MCAP magic.
    #[error("not an MCAP file (magic missing at the start)")]
    NotMcap,
    /// A finished file has no footer record.
    #[error("damaged file: no footer record before the closing magic")]
    NoFooter,
    /// A record claims more bytes than remain in what contains it.
    #[error("damaged file: a record claims {length} bytes, more than remain at byte {at}")]
    RecordTooLong { at: usize, length: u64 },
    /// Another structural fault, at a byte offset.
    #[error("damaged file: {what} at byte {at}")]
    Damaged { at: usize, what: &'static str },
}

/// Walks the file's records (and the records inside each chunk) and checks that every length field fits
/// inside what contains it, and that chunks are uncompressed with an `uncompressed_size` equal to their
/// records' length (voxhap writes them so; the reader is built without decompressors).
///
/// Returns how many bytes the reader may use: all of a finished file; for an unfinished one (a crash: no
/// footer and no end magic), the complete records before the one the crash cut.
pub(crate) fn check_record_lengths(bytes: &[u8], finished: bool) -> Result<usize, McapDamage> {
    const HEADER: usize = 9; // opcode + u64 length
    let u64_at = |at: usize| -> Option<u64> {
        bytes
            .get(at..at.checked_add(8)?)
            .map(|b| u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
    };
    let u32_at = |at: usize| -> Option<u32> {
        bytes
            .get(at..at.checked_add(4)?)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let damaged = |at: usize, what: &'static str| McapDamage::Damaged { at, what };
    // Checks the records in bytes[start..end]; returns where the footer starts if one is met, or (when `cut`
    // is allowed) where a record the end cut short starts.
    let walk = |mut at: usize, end: usize, top_level: bool| -> Result<Option<usize>, McapDamage> {
        while at < end {
            let opcode = bytes[at];
            let Some(length) = u64_at(at + 1).filter(|_| at + HEADER <= end) else {
                if !finished {
                    return Ok(Some(at));
                }
                return Err(damaged(at, "a record header runs past its container"));
            };
            let content = at + HEADER;
            let Some(record_end) = usize::try_from(length)
                .ok()
                .and_then(|l| content.checked_add(l))
                .filter(|&e| e <= end)
            else {
                if !finished {
                    return Ok(Some(at));
                }
                return Err(McapDamage::RecordTooLong { at, length });
            };
            if top_level && opcode == 0x02 {
                return Ok(Some(at));
            }
            if opcode != 0x06 {
                check_record_fields(opcode, &bytes[content..record_end])
                    .map_err(|what| damaged(at, what))?;
            }
            if top_level && opcode == 0x06 {
                // Chunk: start time, end time, uncompressed size, CRC, compression, records.
                let uncompressed = u64_at(content + 16);
                let compression_len = u32_at(content + 28).map(|l| l as usize);
                let records_len_at = compression_len.and_then(|l| (content + 32).checked_add(l));
                let records_len = records_len_at.and_then(u64_at);
                let (Some(uncompressed), Some(0), Some(records_len_at), Some(records_len)) =
                    (uncompressed, compression_len, records_len_at, records_len)
                else {
                    return Err(damaged(
                        at,
                        "a chunk header is cut short or names a compression (voxhap writes none)",
                    ));
                };
                let records_start = records_len_at + 8;
                let records_end = usize::try_from(records_len)
                    .ok()
                    .and_then(|l| records_start.checked_add(l))
                    .filter(|&e| e <= record_end && uncompressed == records_len)
                    .ok_or_else(|| damaged(at, "a chunk's sizes do not match its length"))?;
                walk_inner(bytes, records_start, records_end)
                    .map_err(|at| damaged(at, "a record inside a chunk runs past the chunk"))?;
            }
            at = record_end;
        }
        Ok(None)
    };
    let magic = mcap::MAGIC.len();
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(McapDamage::NotMcap);
    }
    if finished {
        match walk(magic, bytes.len() - magic, true)? {
            Some(_) => Ok(bytes.len()),
            None => Err(McapDamage::NoFooter),
        }
    } else {
        Ok(walk(magic, bytes.len(), true)?.unwrap_or(bytes.len()))
    }
}

/// Checks the records packed in a chunk (`bytes[at..end]`); on failure returns the bad record's offset.
fn walk_inner(bytes: &[u8], mut at: usize, end: usize) -> Result<(), usize> {
    while at < end {
        let length = bytes
            .get(at + 1..at + 9)
            .filter(|_| at + 9 <= end)
            .map(|b| u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
            .ok_or(at)?;
        let record_end = usize::try_from(length)
            .ok()
            .and_then(|l| (at + 9).checked_add(l))
            .filter(|&e| e <= end)
            .ok_or(at)?;
        check_record_fields(bytes[at], &bytes[at + 9..record_end]).map_err(|_| at)?;
        at = record_end;
    }
    Ok(())
}

/// Reads the length-prefixed fields of one record's content in turn (MCAP specification, records 0x01 to
/// 0x0F), checking each length against the bytes that remain: the mcap crate reserves a string's or a byte
/// array's claimed length before reading it.
struct Fields<'a> {
    content: &'a [u8],
    at: usize,
}

impl Fields<'_> {
    const SHORT: &'static str = "a record's field runs past the record";

    fn skip(&mut self, count: usize) -> Result<(), &'static str> {
        self.at = self
            .at
            .checked_add(count)
            .filter(|&end| end <= self.content.len())
            .ok_or(Self::SHORT)?;
        Ok(())
    }

    fn length(&mut self, width: usize) -> Result<usize, &'static str> {
        let field = self
            .content
            .get(self.at..self.at + width)
            .ok_or(Self::SHORT)?;
        let mut raw = [0u8; 8];
        raw[..width].copy_from_slice(field);
        self.at += width;
        usize::try_from(u64::from_le_bytes(raw)).map_err(|_| Self::SHORT)
    }

    /// A string or byte array with a u32 (or, for `width` 8, u64) length prefix; also a map's byte length.
    fn prefixed(&mut self, width: usize) -> Result<(), &'static str> {
        let length = self.length(width)?;
        self.skip(length)
    }

    /// A map of fixed-size entries (`Map<u16, u64>`: 10 bytes each): a u32 byte length that must be a whole
    /// number of entries, or the mcap crate reads past it and takes the next bytes as lengths.
    fn fixed_map(&mut self, entry: usize) -> Result<(), &'static str> {
        let length = self.length(4)?;
        if length % entry != 0 {
            return Err("a map's length is not a whole number of entries");
        }
        self.skip(length)
    }

    /// A map from string to string: a u32 byte length, then pairs of u32-prefixed strings inside it.
    fn string_map(&mut self) -> Result<(), &'static str> {
        let length = self.length(4)?;
        let end = self.at.checked_add(length).ok_or(Self::SHORT)?;
        if end > self.content.len() {
            return Err(Self::SHORT);
        }
        let mut inner = Fields {
            content: &self.content[..end],
            at: self.at,
        };
        while inner.at < end {
            inner.prefixed(4)?;
            inner.prefixed(4)?;
        }
        self.at = end;
        Ok(())
    }
}

/// One field of a record's layout.
#[derive(Debug, Clone, Copy)]
enum Field {
    /// Fixed-size fields, this many bytes together.
    Bytes(usize),
    /// A string or byte array with a length prefix this many bytes wide ([`Fields::prefixed`]).
    Prefixed(usize),
    /// A map of entries this many bytes each ([`Fields::fixed_map`]).
    FixedMap(usize),
    /// A map from string to string ([`Fields::string_map`]).
    StringMap,
}

/// The fields of each record type in order, as far as the check reads them (MCAP specification, records 0x01
/// to 0x0F).
fn record_layout(opcode: u8) -> &'static [Field] {
    use Field::*;
    match opcode {
        0x01 => &[Prefixed(4), Prefixed(4)],
        0x02 => &[Bytes(20)],
        0x03 => &[Bytes(2), Prefixed(4), Prefixed(4), Prefixed(4)],
        0x04 => &[Bytes(4), Prefixed(4), Prefixed(4), StringMap],
        0x05 => &[Bytes(22)],
        0x07 => &[Bytes(2), Prefixed(4)],
        0x08 => &[Bytes(32), FixedMap(10), Bytes(8), Prefixed(4), Bytes(16)],
        0x09 => &[Bytes(16), Prefixed(4), Prefixed(4), Prefixed(8), Bytes(4)],
        0x0A => &[Bytes(40), Prefixed(4), Prefixed(4)],
        0x0B => &[Bytes(42), FixedMap(10)],
        0x0C => &[Prefixed(4), StringMap],
        0x0D => &[Bytes(16), Prefixed(4)],
        0x0E => &[Bytes(17)],
        0x0F => &[Bytes(4)],
        _ => &[], // unknown records are skipped whole by the reader
    }
}

fn check_record_fields(opcode: u8, content: &[u8]) -> Result<(), &'static str> {
    let mut fields = Fields { content, at: 0 };
    record_layout(opcode)
        .iter()
        .try_for_each(|field| match *field {
            Field::Bytes(count) => fields.skip(count),
            Field::Prefixed(width) => fields.prefixed(width),
            Field::FixedMap(entry) => fields.fixed_map(entry),
            Field::StringMap => fields.string_map(),
        })
}
