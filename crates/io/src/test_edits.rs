//! Header edits the format modules' property tests share: bytes overwritten at random places, and one
//! `key<separator>value` line given another value.

/// `bytes` with each `(at, value)` of `edits` written over it.
pub(crate) fn with_bytes_edited(bytes: &[u8], edits: Vec<(usize, u8)>) -> Vec<u8> {
    let mut bytes = bytes.to_vec();
    for (at, value) in edits {
        bytes[at] = value;
    }
    bytes
}

/// `text` with the value of its `line`-th line (`key` `separator` value) replaced by `value`; other lines,
/// and a line without the separator, unchanged.
pub(crate) fn with_field_value(text: &[u8], line: usize, separator: &str, value: &str) -> String {
    let text = String::from_utf8_lossy(text);
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    if let Some((key, _)) = lines[line].clone().split_once(separator) {
        lines[line] = format!("{key}{separator}{value}");
    }
    lines.join("\n")
}
