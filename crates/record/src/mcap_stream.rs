//! Reading an MCAP trace from its file one record at a time (`voxhap plot`), so the memory it needs is one
//! chunk (the writer closes a chunk after 1 000 ticks or 1 MiB) however long the trace is.
//!
//! It reads what [`crate::mcap_trace::McapTraceWriter`] writes (MCAP specification, records 0x01 to 0x0F): the
//! magic, a header, the voxhap metadata record before any chunk, uncompressed chunks holding the schemas,
//! channels and messages, then the summary, which it does not need. Every length field is checked against what
//! contains it before anything is read or reserved (a record against the bytes left in the file, a field
//! against its record), so a damaged length cannot make it allocate more than the file holds. A file the
//! writer never finished (no end magic: a crash) is read up to its last complete record, with the warning
//! [`crate::mcap_read`] gives, and to the last tick whose two messages both made it. Samples are paired and
//! checked by the same code as the in-memory reader ([`crate::mcap_read::Pairing`]).

use crate::error::TraceReadError;
use crate::mcap_check::McapDamage;
use crate::mcap_read::{cut_warning, mode_names_from, trace_without_samples, Pairing};
use crate::mcap_trace::METADATA_NAME;
use crate::meta::TRACE_FORMAT_VERSION;
use crate::sample::TraceSample;
use crate::trace::Trace;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

const OP_FOOTER: u8 = 0x02;
const OP_CHANNEL: u8 = 0x04;
const OP_MESSAGE: u8 = 0x05;
const OP_CHUNK: u8 = 0x06;
const OP_METADATA: u8 = 0x0C;
/// Opcode and u64 length.
const RECORD_HEADER: u64 = 9;

/// Length-prefixed fields read in turn from one record's content, each checked against what remains.
struct Fields<'a> {
    bytes: &'a [u8],
}

impl<'a> Fields<'a> {
    const SHORT: &'static str = "a record's field runs past the record";

    fn take(&mut self, count: u64) -> Result<&'a [u8], &'static str> {
        let count = usize::try_from(count)
            .ok()
            .filter(|&c| c <= self.bytes.len())
            .ok_or(Self::SHORT)?;
        let (head, rest) = self.bytes.split_at(count);
        self.bytes = rest;
        Ok(head)
    }

    fn u16(&mut self) -> Result<u16, &'static str> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self) -> Result<u32, &'static str> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self) -> Result<u64, &'static str> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes([
            b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7],
        ]))
    }

    /// A u32-prefixed string.
    fn string(&mut self) -> Result<&'a str, &'static str> {
        let length = self.u32()?;
        std::str::from_utf8(self.take(u64::from(length))?).map_err(|_| "a string is not UTF-8")
    }

    /// The next record (opcode and content) packed in these bytes, `None` at their end.
    fn record(&mut self) -> Result<Option<(u8, &'a [u8])>, &'static str> {
        if self.bytes.is_empty() {
            return Ok(None);
        }
        let opcode = self.take(1)?[0];
        let length = self.u64()?;
        Ok(Some((opcode, self.take(length)?)))
    }
}

/// What a channel's messages are to the trace.
struct Channel {
    id: u16,
    topic: String,
}

/// Reads the MCAP trace at `path` one record at a time, handing each sample to `sink` in file order; returns the
/// trace without its samples (mode names, sidecar, warnings) and how many were read. Reads what
/// [`crate::read_trace_as`] reads as MCAP, with the same errors for what both check.
pub(crate) fn stream_mcap_samples(
    path: &Path,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<(Trace, u64), TraceReadError> {
    let io = |source| TraceReadError::Io {
        path: path.to_path_buf(),
        source,
    };
    let problem = |problem: String| TraceReadError::Mcap {
        path: path.to_path_buf(),
        problem,
    };
    let damaged = |at: u64, what: &'static str| {
        problem(
            McapDamage::Damaged {
                at: usize::try_from(at).unwrap_or(usize::MAX),
                what,
            }
            .to_string(),
        )
    };
    let (mut file, size) = crate::trace::open_trace_file(path)?;
    let magic_len = mcap::MAGIC.len() as u64;
    let mut magic = [0u8; 8];
    if size < magic_len {
        return Err(problem(McapDamage::NotMcap.to_string()));
    }
    file.read_exact(&mut magic).map_err(io)?;
    if magic[..] != *mcap::MAGIC {
        return Err(problem(McapDamage::NotMcap.to_string()));
    }
    let mut end_magic = [0u8; 8];
    let finished = size >= 2 * magic_len && {
        file.seek(SeekFrom::End(-(magic_len as i64))).map_err(io)?;
        file.read_exact(&mut end_magic).map_err(io)?;
        end_magic[..] == *mcap::MAGIC
    };
    file.seek(SeekFrom::Start(magic_len)).map_err(io)?;
    let mut reader = BufReader::with_capacity(1 << 16, file);
    // Records end where the closing magic starts (finished) or where the file ends (cut off).
    let end = if finished { size - magic_len } else { size };
    let mut at = magic_len;
    let mut content = Vec::new();
    let mut mode_names: Option<Vec<String>> = None;
    let mut channels: Vec<Channel> = Vec::new();
    // Mode names outlive the pairing that borrows them: moved into `names_slot` at the first message.
    let names_slot: std::cell::OnceCell<Vec<String>> = std::cell::OnceCell::new();
    let mut pairing: Option<Pairing<'_>> = None;
    let mut footer = false;
    while at < end {
        if end - at < RECORD_HEADER {
            if finished {
                return Err(damaged(at, "a record header runs past its container"));
            }
            break;
        }
        let mut header = [0u8; RECORD_HEADER as usize];
        reader.read_exact(&mut header).map_err(io)?;
        let opcode = header[0];
        let length = u64::from_le_bytes([
            header[1], header[2], header[3], header[4], header[5], header[6], header[7], header[8],
        ]);
        if length > end - at - RECORD_HEADER {
            if finished {
                return Err(problem(
                    McapDamage::RecordTooLong {
                        at: usize::try_from(at).unwrap_or(usize::MAX),
                        length,
                    }
                    .to_string(),
                ));
            }
            break;
        }
        if opcode == OP_FOOTER {
            footer = true;
            break;
        }
        if opcode == OP_METADATA || opcode == OP_CHUNK {
            // `length` fits in the file (checked above), so this reserves at most the file's size; the writer's
            // chunks are about 1 MiB.
            content.resize(
                usize::try_from(length).map_err(|_| damaged(at, "a record too long"))?,
                0,
            );
            reader.read_exact(&mut content).map_err(io)?;
        } else {
            let skipped =
                std::io::copy(&mut (&mut reader).take(length), &mut std::io::sink()).map_err(io)?;
            if skipped != length {
                return Err(damaged(at, "the file ended inside a record"));
            }
        }
        let mut fields = Fields { bytes: &content };
        if opcode == OP_METADATA {
            let name = fields.string().map_err(|what| damaged(at, what))?;
            if name == METADATA_NAME && mode_names.is_none() {
                let map_length = fields.u32().map_err(|what| damaged(at, what))?;
                let mut map = Fields {
                    bytes: fields
                        .take(u64::from(map_length))
                        .map_err(|what| damaged(at, what))?,
                };
                let mut entries = Vec::new();
                while !map.bytes.is_empty() {
                    let key = map.string().map_err(|what| damaged(at, what))?;
                    let value = map.string().map_err(|what| damaged(at, what))?;
                    entries.push((key, value));
                }
                let get = |key: &str| entries.iter().find(|(k, _)| *k == key).map(|(_, v)| *v);
                let (names, version) =
                    mode_names_from(get).map_err(|error| problem(error.to_string()))?;
                if version != TRACE_FORMAT_VERSION {
                    return Err(TraceReadError::OldFormat {
                        path: path.to_path_buf(),
                        found: version,
                        expected: TRACE_FORMAT_VERSION,
                        hint: "its metadata record says so",
                    });
                }
                mode_names = Some(names);
            }
        } else if opcode == OP_CHUNK {
            // Start and end times, uncompressed size, CRC, compression, then the records.
            fields.take(16).map_err(|what| damaged(at, what))?;
            let uncompressed = fields.u64().map_err(|what| damaged(at, what))?;
            fields.u32().map_err(|what| damaged(at, what))?;
            let compression = fields.string().map_err(|what| damaged(at, what))?;
            let records_length = fields.u64().map_err(|what| damaged(at, what))?;
            if !compression.is_empty() || uncompressed != records_length {
                return Err(damaged(
                    at,
                    "a chunk header is cut short or names a compression (voxhap writes none)",
                ));
            }
            let mut records = Fields {
                bytes: fields
                    .take(records_length)
                    .map_err(|_| damaged(at, "a chunk's sizes do not match its length"))?,
            };
            let inner = |what| damaged(at, what);
            while let Some((inner_opcode, body)) = records.record().map_err(inner)? {
                let mut body = Fields { bytes: body };
                match inner_opcode {
                    OP_CHANNEL => {
                        let id = body.u16().map_err(inner)?;
                        body.u16().map_err(inner)?;
                        let topic = body.string().map_err(inner)?.to_owned();
                        channels.retain(|c| c.id != id);
                        channels.push(Channel { id, topic });
                    }
                    OP_MESSAGE => {
                        let channel_id = body.u16().map_err(inner)?;
                        let sequence = body.u32().map_err(inner)?;
                        body.take(16).map_err(inner)?;
                        let topic = channels
                            .iter()
                            .find(|c| c.id == channel_id)
                            .map(|c| c.topic.as_str())
                            .ok_or_else(|| {
                                inner("a message on a channel no channel record defined")
                            })?;
                        if pairing.is_none() {
                            let names = mode_names.take().ok_or_else(|| {
                                problem(crate::mcap_read::McapContentError::NotVoxhap.to_string())
                            })?;
                            pairing = Some(Pairing::new(names_slot.get_or_init(|| names)));
                        }
                        if let Some(pairing) = pairing.as_mut() {
                            pairing
                                .message(topic, sequence, body.bytes, sink)
                                .map_err(|error| problem(error.to_string()))?;
                        }
                    }
                    _ => {}
                }
            }
        }
        at += RECORD_HEADER + length;
    }
    if finished && !footer {
        return Err(problem(McapDamage::NoFooter.to_string()));
    }
    let (names, count) = match pairing {
        Some(pairing) => {
            let count = pairing
                .finish(!finished)
                .map_err(|error| problem(error.to_string()))?;
            (names_slot.get().cloned().unwrap_or_default(), count)
        }
        None => (
            mode_names.ok_or_else(|| {
                problem(crate::mcap_read::McapContentError::NotVoxhap.to_string())
            })?,
            0,
        ),
    };
    let mut warnings = Vec::new();
    if !finished {
        warnings.push(cut_warning(
            path,
            count,
            "the file ends without its summary",
        ));
    }
    trace_without_samples(path, names, count, warnings)
}

#[cfg(test)]
#[path = "mcap_stream_tests.rs"]
mod tests;
