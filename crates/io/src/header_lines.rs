//! The text lines of a volume file's header held in memory (NRRD, MetaImage), one at a time without copying:
//! each line's number and where the next begins are kept, and a line that is not UTF-8 is an error naming it.
//! Also the number parse both formats' field values share ([`parse_value`]).

use crate::error::LoadProblem;

/// A field value, surrounding white space ignored, parsed as a `T`; one that does not parse goes, as written,
/// to `not_a_number` for the format's error.
pub(crate) fn parse_value<T: std::str::FromStr, E>(
    value: &str,
    not_a_number: impl FnOnce(String) -> E,
) -> Result<T, E> {
    value
        .trim()
        .parse()
        .map_err(|_| not_a_number(value.to_owned()))
}

/// The lines of a byte buffer from its start, each without its `\n`.
pub(crate) struct HeaderLines<'a> {
    bytes: &'a [u8],
    position: usize,
    line_number: usize,
}

impl<'a> HeaderLines<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Self {
            bytes,
            position: 0,
            line_number: 0,
        }
    }

    /// Where the line after the last one returned begins (bytes from the start).
    pub(crate) fn position(&self) -> usize {
        self.position
    }

    /// The number of the last line returned, from 1.
    pub(crate) fn line_number(&self) -> usize {
        self.line_number
    }
}

impl<'a> Iterator for HeaderLines<'a> {
    type Item = Result<&'a str, LoadProblem>;

    fn next(&mut self) -> Option<Self::Item> {
        let rest = self.bytes.get(self.position..).filter(|r| !r.is_empty())?;
        let end = rest.iter().position(|&b| b == b'\n');
        let raw_line = &rest[..end.unwrap_or(rest.len())];
        self.position += end.map_or(rest.len(), |e| e + 1);
        self.line_number += 1;
        Some(
            std::str::from_utf8(raw_line)
                .map_err(|_| LoadProblem::header(format!("line {} is not text", self.line_number))),
        )
    }
}
