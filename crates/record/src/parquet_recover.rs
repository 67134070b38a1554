//! Finding the row groups of a Parquet trace cut off before its final footer (a crash): the writer follows
//! every row group with a row-group footer ending in `VXRG` (see [`crate::parquet_trace`]), and a reader
//! follows that chain back from the end of the file. Reads through positioned reads, a block at a time, so
//! memory does not grow with the file.

use parquet::file::metadata::{
    FileMetaData, ParquetMetaData, ParquetMetaDataReader, RowGroupMetaData,
};
use parquet::file::reader::ChunkReader;

use crate::parquet_schema::{MAGIC, ROW_GROUP_FOOTER_MAGIC};

/// Bytes read at a time while looking for the last row-group footer's magic from the end.
const SCAN_BLOCK: u64 = 64 * 1024;
/// Largest row-group footer read (bytes): one row group's metadata is a few KiB.
const MAX_ROW_GROUP_FOOTER: u64 = 16 * 1024 * 1024;

/// Finds the row groups a crash left whole: the last row-group footer whose row group ends where the
/// footer starts, then the chain of footers before it back to the first row group. Returns their
/// metadata (`None` when there is no complete row group) and how many bytes at the end were skipped.
pub(crate) fn recover_row_groups(file: &impl ChunkReader) -> (Option<ParquetMetaData>, u64) {
    let size = file.len();
    let nothing = (None, size.saturating_sub(MAGIC.len() as u64));
    let Some((group, group_start, footer_end)) = last_row_group_footer(file) else {
        return nothing;
    };
    let mut groups = vec![group];
    let mut start = group_start;
    while start > MAGIC.len() as u64 {
        match footer_ending_at(file, start) {
            Some((group, group_start)) if group_start < start => {
                groups.push(group);
                start = group_start;
            }
            // A broken chain: the contiguous run found from the end would not start at the file's first
            // row group; report nothing rather than a trace with a hole.
            _ => return nothing,
        }
    }
    groups.reverse();
    let schema = groups[0].schema_descr_ptr();
    let rows = groups.iter().map(|g| g.num_rows()).sum();
    let metadata =
        ParquetMetaData::new(FileMetaData::new(1, rows, None, None, schema, None), groups);
    (Some(metadata), size - footer_end)
}

/// The last row-group footer in the file (scanning back from the end for its magic): its row group, where
/// that starts, and where the footer ends.
fn last_row_group_footer(file: &impl ChunkReader) -> Option<(RowGroupMetaData, u64, u64)> {
    let size = file.len();
    let mut block_end = size;
    while block_end >= 12 {
        // Overlap by 3 bytes so a magic across two blocks is seen.
        let block_start = block_end.saturating_sub(SCAN_BLOCK);
        let block = file
            .get_bytes(block_start, (block_end - block_start) as usize)
            .ok()?;
        let mut end = block.len();
        while end >= 4 {
            if &block[end - 4..end] == ROW_GROUP_FOOTER_MAGIC {
                let at = block_start + end as u64;
                if let Some((group, start)) = footer_ending_at(file, at) {
                    return Some((group, start, at));
                }
            }
            end -= 1;
        }
        if block_start == 0 {
            break;
        }
        block_end = block_start + 3;
    }
    None
}

/// The row group described by a row-group footer ending at `end` (just after its magic), and where
/// that row group starts, if the footer decodes and its one row group ends exactly where the footer
/// begins.
fn footer_ending_at(file: &impl ChunkReader, end: u64) -> Option<(RowGroupMetaData, u64)> {
    if end < 12 {
        return None;
    }
    let tail = file.get_bytes(end - 8, 8).ok()?;
    if &tail[4..] != ROW_GROUP_FOOTER_MAGIC {
        return None;
    }
    let length = u64::from(u32::from_le_bytes(tail[..4].try_into().ok()?));
    let footer_start = (end - 8).checked_sub(length)?;
    if footer_start < MAGIC.len() as u64 || length > MAX_ROW_GROUP_FOOTER {
        return None;
    }
    let footer = file.get_bytes(footer_start, length as usize).ok()?;
    let metadata = ParquetMetaDataReader::decode_metadata(&footer).ok()?;
    let [group] = metadata.row_groups() else {
        return None;
    };
    let mut first = u64::MAX;
    let mut last = 0u64;
    for column in group.columns() {
        let (start, length) = column.byte_range();
        first = first.min(start);
        last = last.max(start.checked_add(length)?);
    }
    (last == footer_start && first >= MAGIC.len() as u64 && first < last)
        .then(|| (group.clone(), first))
}
