//! Header edits the format modules' property tests share: bytes overwritten at random places, and one
//! `key<separator>value` line given another value; and the property tests of the formats whose header is
//! such lines ([`header_property_tests`]).

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

/// The property tests of a format whose header is `key<separator>value` lines, in the module that invokes it:
/// `parse(bytes, path)` (`path` a file that does not exist, so no data file is read) never panics on arbitrary
/// bytes (each also after every one of `prefixes`), on `tiny` with up to five bytes overwritten (and what still
/// loads has a finite spacing), nor on `tiny` with one of its header lines `lines` given any printable value.
macro_rules! header_property_tests {
    (
        parse: $parse:path,
        tiny: $tiny:expr,
        path: $path:literal,
        prefixes: [$($prefix:literal),* $(,)?],
        lines: $lines:expr,
        separator: $separator:literal $(,)?
    ) => {
        proptest::proptest! {
            #[test]
            fn arbitrary_bytes_never_panic(
                bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400),
            ) {
                let prefixes: &[&[u8]] = &[$($prefix),*];
                for prefix in prefixes {
                    let mut prefixed = prefix.to_vec();
                    prefixed.extend_from_slice(&bytes);
                    let _ = $parse(&prefixed, std::path::Path::new($path));
                }
            }

            #[test]
            fn mutated_headers_never_panic(
                edits in proptest::collection::vec(
                    (0usize..$tiny.len(), proptest::prelude::any::<u8>()),
                    1..6,
                ),
            ) {
                let bytes = crate::test_edits::with_bytes_edited($tiny, edits);
                if let Ok(loaded) = $parse(&bytes, std::path::Path::new($path)) {
                    proptest::prop_assert!(loaded.volume.grid().spacing_m().is_finite());
                }
            }

            #[test]
            fn mutated_field_values_never_panic(line in $lines, value in "[ -~]{0,30}") {
                let text = crate::test_edits::with_field_value($tiny, line, $separator, &value);
                let _ = $parse(text.as_bytes(), std::path::Path::new($path));
            }
        }
    };
}
pub(crate) use header_property_tests;
