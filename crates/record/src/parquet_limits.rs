//! The sizes a Parquet file claims, checked against its real size before any page is decoded, so a crafted
//! file cannot make the reader allocate more than its bytes justify.
//!
//! Two places claim sizes: the footer's column chunks ([`check_claimed_sizes`]) and each page's header
//! ([`check_page_headers`]); the Parquet library sizes a page's decompression buffer from its header's
//! `uncompressed_page_size` before it decompresses anything. A page header is a Thrift compact-protocol
//! struct (parquet-format's `PageHeader`: field 2 `uncompressed_page_size`, field 3 `compressed_page_size`,
//! both i32), read here with a small skipping decoder that follows the Thrift compact protocol
//! specification, since the library keeps its own decoder private.

use parquet::file::metadata::ParquetMetaData;
use parquet::file::reader::ChunkReader;

use crate::error::ParquetProblem;

/// Snappy's largest expansion (a 3-byte copy tag yields at most 64 bytes), with margin: a column chunk or a
/// page cannot hold more uncompressed bytes than this many times its compressed bytes.
pub(crate) const MAX_DECOMPRESSION_RATIO: u64 = 32;
/// What a page may claim beyond [`MAX_DECOMPRESSION_RATIO`] times its compressed size (bytes): a tiny page's
/// fixed overhead.
const PAGE_ALLOWANCE_BYTES: u64 = 1024;
/// Bytes read for a page header first, and the most a page header may take (a voxhap trace's page headers
/// hold only numeric statistics: a few hundred bytes).
const PAGE_HEADER_FIRST_READ: usize = 4 * 1024;
const PAGE_HEADER_MAX_BYTES: usize = 1024 * 1024;

/// Checks the sizes the footer claims against the file's real size: every column chunk lies inside the file
/// and claims at most [`MAX_DECOMPRESSION_RATIO`] times its compressed size (plus 64 KiB for page headers)
/// once uncompressed.
pub(crate) fn check_claimed_sizes(
    metadata: &ParquetMetaData,
    file_bytes: u64,
) -> Result<(), ParquetProblem> {
    for (group, row_group) in metadata.row_groups().iter().enumerate() {
        for (column, chunk) in row_group.columns().iter().enumerate() {
            let compressed = u64::try_from(chunk.compressed_size()).unwrap_or(u64::MAX);
            let uncompressed = u64::try_from(chunk.uncompressed_size()).unwrap_or(u64::MAX);
            let (start, _) = chunk.byte_range();
            if start.saturating_add(compressed) > file_bytes {
                return Err(ParquetProblem::ChunkPastEnd {
                    group,
                    column,
                    compressed,
                    start,
                    file_bytes,
                });
            }
            if uncompressed > compressed.saturating_mul(MAX_DECOMPRESSION_RATIO) + (64 << 10) {
                return Err(ParquetProblem::ChunkExpansion {
                    group,
                    column,
                    uncompressed,
                    compressed,
                    ratio: MAX_DECOMPRESSION_RATIO,
                });
            }
        }
    }
    Ok(())
}

/// Walks every page header of every column chunk (run [`check_claimed_sizes`] first, so the chunks lie in the
/// file) and checks that each page lies inside its chunk and claims at most [`MAX_DECOMPRESSION_RATIO`] times
/// its compressed size (plus 1 KiB) once uncompressed. Reads only the headers: a few KiB per page.
pub(crate) fn check_page_headers(
    file: &impl ChunkReader,
    metadata: &ParquetMetaData,
) -> Result<(), ParquetProblem> {
    for (group, row_group) in metadata.row_groups().iter().enumerate() {
        for (column, chunk) in row_group.columns().iter().enumerate() {
            let (start, length) = chunk.byte_range();
            let chunk_end = start.saturating_add(length);
            let mut offset = start;
            while offset < chunk_end {
                let header_problem = |problem| ParquetProblem::PageHeader {
                    group,
                    column,
                    offset,
                    problem,
                };
                let sizes = read_page_header(file, offset, chunk_end).map_err(header_problem)?;
                let compressed = u64::try_from(sizes.compressed)
                    .map_err(|_| header_problem("compressed_page_size is negative"))?;
                let uncompressed = u64::try_from(sizes.uncompressed)
                    .map_err(|_| header_problem("uncompressed_page_size is negative"))?;
                let page_end = offset + sizes.header_bytes + compressed;
                if page_end > chunk_end {
                    return Err(ParquetProblem::PagePastChunk {
                        group,
                        column,
                        offset,
                        compressed,
                        chunk_end,
                    });
                }
                if uncompressed > compressed * MAX_DECOMPRESSION_RATIO + PAGE_ALLOWANCE_BYTES {
                    return Err(ParquetProblem::PageExpansion {
                        group,
                        column,
                        offset,
                        uncompressed,
                        compressed,
                        ratio: MAX_DECOMPRESSION_RATIO,
                    });
                }
                offset = page_end;
            }
        }
    }
    Ok(())
}

/// What a page header says about its page's size, and the header's own length.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PageSizes {
    pub uncompressed: i32,
    pub compressed: i32,
    pub header_bytes: u64,
}

/// Reads the page header at `offset` (it must end before `chunk_end`).
fn read_page_header(
    file: &impl ChunkReader,
    offset: u64,
    chunk_end: u64,
) -> Result<PageSizes, &'static str> {
    let available = usize::try_from(chunk_end - offset).unwrap_or(usize::MAX);
    let mut want = available.min(PAGE_HEADER_FIRST_READ);
    loop {
        let bytes = file
            .get_bytes(offset, want)
            .map_err(|_| "cannot read the page header")?;
        match parse_page_header(&bytes) {
            Err(HeaderError::Truncated) if want < available.min(PAGE_HEADER_MAX_BYTES) => {
                want = available.min(PAGE_HEADER_MAX_BYTES);
            }
            Err(HeaderError::Truncated) if want >= PAGE_HEADER_MAX_BYTES => {
                return Err("longer than 1 MiB")
            }
            Err(HeaderError::Truncated) => return Err("runs past the end of its column chunk"),
            Err(HeaderError::Invalid(problem)) => return Err(problem),
            Ok(sizes) => return Ok(sizes),
        }
    }
}

/// Why a page header did not decode.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum HeaderError {
    /// The bytes ended inside the header.
    Truncated,
    /// The bytes are not a page header.
    Invalid(&'static str),
}

/// Thrift compact-protocol field types (Thrift's compact protocol specification, "Field types").
const T_BOOL_TRUE: u8 = 1;
const T_BOOL_FALSE: u8 = 2;
const T_BYTE: u8 = 3;
const T_I16: u8 = 4;
const T_I32: u8 = 5;
const T_I64: u8 = 6;
const T_DOUBLE: u8 = 7;
const T_BINARY: u8 = 8;
const T_LIST: u8 = 9;
const T_SET: u8 = 10;
const T_MAP: u8 = 11;
const T_STRUCT: u8 = 12;
/// Deepest nesting skipped (a page header nests three levels: header, data page header, statistics).
const MAX_DEPTH: usize = 16;

/// Decodes a Thrift compact-protocol `PageHeader` at the start of `bytes`: its two size fields and its length.
pub(crate) fn parse_page_header(bytes: &[u8]) -> Result<PageSizes, HeaderError> {
    let mut reader = Compact { bytes, at: 0 };
    let (mut uncompressed, mut compressed) = (None, None);
    let mut field_id: i16 = 0;
    loop {
        let byte = reader.byte()?;
        let field_type = byte & 0x0F;
        if field_type == 0 {
            break;
        }
        let delta = byte >> 4;
        field_id = if delta == 0 {
            i16::try_from(reader.zigzag()?).map_err(|_| HeaderError::Invalid("bad field id"))?
        } else {
            field_id.saturating_add(i16::from(delta))
        };
        match (field_id, field_type) {
            (2, T_I32) => uncompressed = Some(reader.i32()?),
            (3, T_I32) => compressed = Some(reader.i32()?),
            _ => reader.skip(field_type, 0)?,
        }
    }
    match (uncompressed, compressed) {
        (Some(uncompressed), Some(compressed)) => Ok(PageSizes {
            uncompressed,
            compressed,
            header_bytes: reader.at as u64,
        }),
        _ => Err(HeaderError::Invalid("no page sizes")),
    }
}

/// A cursor over Thrift compact-protocol bytes.
struct Compact<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Compact<'_> {
    fn byte(&mut self) -> Result<u8, HeaderError> {
        let byte = *self.bytes.get(self.at).ok_or(HeaderError::Truncated)?;
        self.at += 1;
        Ok(byte)
    }

    fn advance(&mut self, count: u64) -> Result<(), HeaderError> {
        let left = (self.bytes.len() - self.at) as u64;
        if count > left {
            return Err(HeaderError::Truncated);
        }
        self.at += count as usize;
        Ok(())
    }

    /// An unsigned LEB128 varint of at most 10 bytes.
    fn varint(&mut self) -> Result<u64, HeaderError> {
        let mut value = 0u64;
        for shift in (0..70).step_by(7) {
            let byte = self.byte()?;
            value |= u64::from(byte & 0x7F) << shift.min(63);
            if byte & 0x80 == 0 {
                return Ok(value);
            }
        }
        Err(HeaderError::Invalid("varint longer than 10 bytes"))
    }

    fn zigzag(&mut self) -> Result<i64, HeaderError> {
        let raw = self.varint()?;
        Ok((raw >> 1) as i64 ^ -((raw & 1) as i64))
    }

    fn i32(&mut self) -> Result<i32, HeaderError> {
        i32::try_from(self.zigzag()?).map_err(|_| HeaderError::Invalid("i32 out of range"))
    }

    /// Skips one value of `field_type`.
    fn skip(&mut self, field_type: u8, depth: usize) -> Result<(), HeaderError> {
        if depth > MAX_DEPTH {
            return Err(HeaderError::Invalid("nested too deeply"));
        }
        match field_type {
            T_BOOL_TRUE | T_BOOL_FALSE => Ok(()),
            T_BYTE => self.advance(1),
            T_I16 | T_I32 | T_I64 => self.varint().map(drop),
            T_DOUBLE => self.advance(8),
            T_BINARY => {
                let length = self.varint()?;
                self.advance(length)
            }
            T_LIST | T_SET => {
                let header = self.byte()?;
                let element = header & 0x0F;
                let count = match header >> 4 {
                    15 => self.varint()?,
                    short => u64::from(short),
                };
                self.skip_elements(element, count, depth)
            }
            T_MAP => {
                let count = self.varint()?;
                if count == 0 {
                    return Ok(());
                }
                let types = self.byte()?;
                for _ in 0..count {
                    self.skip_element(types >> 4, depth)?;
                    self.skip_element(types & 0x0F, depth)?;
                }
                Ok(())
            }
            T_STRUCT => loop {
                let byte = self.byte()?;
                let inner = byte & 0x0F;
                if inner == 0 {
                    return Ok(());
                }
                if byte >> 4 == 0 {
                    self.zigzag()?;
                }
                self.skip(inner, depth + 1)?;
            },
            _ => Err(HeaderError::Invalid("unknown Thrift field type")),
        }
    }

    fn skip_elements(&mut self, element: u8, count: u64, depth: usize) -> Result<(), HeaderError> {
        for _ in 0..count {
            // Every element takes at least one byte: a count past the bytes left ends here, not after 2^64
            // empty iterations.
            if self.at >= self.bytes.len() {
                return Err(HeaderError::Truncated);
            }
            self.skip_element(element, depth)?;
        }
        Ok(())
    }

    /// A collection element: a boolean takes one byte there (not none, as a struct field's does).
    fn skip_element(&mut self, element: u8, depth: usize) -> Result<(), HeaderError> {
        match element {
            T_BOOL_TRUE | T_BOOL_FALSE => self.advance(1),
            other => self.skip(other, depth + 1),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A page header encoded by hand from the Thrift compact protocol specification: field 1 (type, i32) = 0
    /// (DATA_PAGE), field 2 (uncompressed_page_size) and field 3 (compressed_page_size) as zigzag varints,
    /// field 5 (data_page_header, a struct) with field 1 (num_values, i32) = 3 and a nested statistics struct
    /// (field 5) holding a two-byte binary (field 1) and a list of three i32 (field 2), then the stops.
    fn header(uncompressed: &[u8], compressed: &[u8]) -> Vec<u8> {
        let mut bytes = vec![0x15, 0x00]; // field 1, i32, zigzag(0)
        bytes.push(0x15); // field 2 (delta 1), i32
        bytes.extend_from_slice(uncompressed);
        bytes.push(0x15); // field 3 (delta 1), i32
        bytes.extend_from_slice(compressed);
        bytes.push(0x2C); // field 5 (delta 2), struct
        bytes.extend_from_slice(&[0x15, 0x06]); // num_values = 3
        bytes.push(0x4C); // field 5 (delta 4), struct (statistics)
        bytes.extend_from_slice(&[0x18, 0x02, 0xAB, 0xCD]); // field 1, binary, 2 bytes
        bytes.extend_from_slice(&[0x19, 0x35, 0x02, 0x04, 0x06]); // field 2, list of 3 i32: 1, 2, 3
        bytes.extend_from_slice(&[0x00, 0x00, 0x00]); // stops: statistics, data page header, page header
        bytes
    }

    #[test]
    fn sizes_and_length_of_a_hand_encoded_header() {
        // zigzag(100) = 200 = 0xC8 0x01; zigzag(2^31 - 1) = 2^32 - 2 = 0xFE 0xFF 0xFF 0xFF 0x0F.
        let bytes = header(&[0xC8, 0x01], &[0xFE, 0xFF, 0xFF, 0xFF, 0x0F]);
        let sizes = parse_page_header(&bytes).unwrap();
        assert_eq!(sizes.uncompressed, 100);
        assert_eq!(sizes.compressed, i32::MAX);
        assert_eq!(sizes.header_bytes, bytes.len() as u64);
        // Trailing page bytes are not part of the header.
        let mut with_page = bytes.clone();
        with_page.extend_from_slice(&[0xFF; 16]);
        assert_eq!(parse_page_header(&with_page).unwrap(), sizes);
    }

    #[test]
    fn a_cut_header_is_truncated_and_never_read_past() {
        let bytes = header(&[0xC8, 0x01], &[0x08]);
        for cut in 0..bytes.len() {
            assert_eq!(
                parse_page_header(&bytes[..cut]),
                Err(HeaderError::Truncated),
                "cut at {cut}"
            );
        }
    }

    #[test]
    fn a_huge_list_count_ends_at_the_bytes() {
        // Field 1 of type list, element type i32, count as a varint of 2^63.
        let bytes = [
            0x19, 0xF5, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x80, 0x01,
        ];
        assert_eq!(parse_page_header(&bytes), Err(HeaderError::Truncated));
    }
}
