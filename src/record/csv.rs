//! CSV force traces: the writer ([`CsvTraceWriter`]) and the reader ([`read_csv_trace`]).
//!
//! Layout: a header line, then one line per tick, fields separated by `,` with no quoting (no field can
//! contain a comma: mode names are restricted to `[A-Za-z0-9_-]`) and `\n` line ends. Columns:
//! `tick,t_s,probe_{x,y,z}_m,proxy_{x,y,z}_m,force_{x,y,z}_n,primitives_<mode>...,sweeps,error_bound_m,flags`.
//! Floats are written with Rust's `{:?}` formatting, the shortest text that parses back to the same
//! bits (`0.001`, `-0.0`, `1e-17`, `inf`), so write-then-read is exact. The reader is strict: it checks
//! the header, every field and the trace rules (finite positions, increasing ticks) and names the line
//! and column of the first problem.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::meta::{csv_columns, is_valid_mode_name};
use super::{
    check_sample, sidecar_path, SampleChecker, Sidecar, Trace, TraceError, TraceFormat, TraceMeta,
    TraceReadError, TraceSample, TraceSummary, TraceWriter, MAX_MODES,
};
use glam::DVec3;

/// Columns before the per-mode primitive counts.
const LEADING_COLUMNS: [&str; 11] = [
    "tick",
    "t_s",
    "probe_x_m",
    "probe_y_m",
    "probe_z_m",
    "proxy_x_m",
    "proxy_y_m",
    "proxy_z_m",
    "force_x_n",
    "force_y_n",
    "force_z_n",
];
/// Columns after the per-mode primitive counts.
const TRAILING_COLUMNS: [&str; 3] = ["sweeps", "error_bound_m", "flags"];
const PRIMITIVES_PREFIX: &str = "primitives_";

/// Writes a CSV trace and its sidecar.
pub struct CsvTraceWriter {
    path: PathBuf,
    out: BufWriter<File>,
    checker: SampleChecker,
    sidecar: Sidecar,
}

impl CsvTraceWriter {
    /// Creates (truncates) `path` and `path.json`, writes the header and a provisional sidecar.
    pub fn create(path: &Path, meta: &TraceMeta) -> Result<Self, TraceError> {
        meta.validate()?;
        let io_error = |source| TraceError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = File::create(path).map_err(io_error)?;
        let mut out = BufWriter::new(file);
        let header: Vec<String> = csv_columns(&meta.mode_names)
            .into_iter()
            .map(|c| c.name.into_owned())
            .collect();
        writeln!(out, "{}", header.join(",")).map_err(io_error)?;
        let sidecar = Sidecar::new(meta, TraceFormat::Csv, path);
        sidecar.write(&sidecar_path(path))?;
        Ok(CsvTraceWriter {
            path: path.to_path_buf(),
            out,
            checker: SampleChecker::new(meta.mode_names.len()),
            sidecar,
        })
    }

    fn io_error(&self, source: std::io::Error) -> TraceError {
        TraceError::Io {
            path: self.path.clone(),
            source,
        }
    }
}

fn write_row(out: &mut impl Write, s: &TraceSample) -> std::io::Result<()> {
    write!(out, "{},{:?}", s.tick, s.t_s)?;
    for v in [s.probe_m, s.proxy_m, s.force_n] {
        write!(out, ",{:?},{:?},{:?}", v.x, v.y, v.z)?;
    }
    for count in s.primitives() {
        write!(out, ",{count}")?;
    }
    writeln!(out, ",{},{:?},{}", s.sweeps, s.error_bound_m, s.flags)
}

impl TraceWriter for CsvTraceWriter {
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError> {
        self.checker.check(sample)?;
        write_row(&mut self.out, sample).map_err(|e| self.io_error(e))
    }

    fn flush(&mut self) -> Result<(), TraceError> {
        if self.checker.finished {
            return Err(TraceError::Finished);
        }
        self.out.flush().map_err(|e| self.io_error(e))
    }

    fn finish(&mut self) -> Result<TraceSummary, TraceError> {
        if self.checker.finished {
            return Err(TraceError::Finished);
        }
        self.out.flush().map_err(|e| self.io_error(e))?;
        self.out
            .get_ref()
            .sync_all()
            .map_err(|e| self.io_error(e))?;
        self.checker.finished = true;
        self.sidecar.complete(&self.path, self.checker.count)
    }

    fn sample_count(&self) -> u64 {
        self.checker.count
    }
}

/// Reads a CSV trace, and its sidecar `path.json` when that file exists.
pub fn read_csv_trace(path: &Path) -> Result<Trace, TraceReadError> {
    // A regular file only; reading stops at the size it had when opened.
    let (file, size_bytes) = super::open_trace_file(path)?;
    let reader = BufReader::new(std::io::Read::take(file, size_bytes));
    let (mode_names, samples) = parse_csv_lines(reader, path)?;
    let sidecar = read_sidecar(&sidecar_path(path))?;
    Ok(Trace {
        mode_names,
        samples,
        sidecar,
    })
}

/// Reads a sidecar if it exists; a missing file is `None`, a malformed one an error.
pub(crate) fn read_sidecar(path: &Path) -> Result<Option<Sidecar>, TraceReadError> {
    let read = crate::volume::io::read_regular(
        path,
        crate::volume::io::MAX_TEXT_FILE_BYTES,
        "a trace sidecar (16 MiB)",
    )
    .map_err(|error| match error {
        crate::volume::io::FileError::Io(source) => source,
        other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other.to_string()),
    });
    match read {
        Ok(bytes) => {
            serde_json::from_slice(&bytes)
                .map(Some)
                .map_err(|source| TraceReadError::Sidecar {
                    path: path.to_path_buf(),
                    source,
                })
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(TraceReadError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Parses CSV trace text from any reader; returns the mode names and the samples.
pub fn parse_csv_trace(
    reader: impl BufRead,
) -> Result<(Vec<String>, Vec<TraceSample>), TraceReadError> {
    parse_csv_lines(reader, Path::new("<input>"))
}

fn parse_csv_lines(
    mut reader: impl BufRead,
    path: &Path,
) -> Result<(Vec<String>, Vec<TraceSample>), TraceReadError> {
    let mut buffer = Vec::new();
    let mut line_number = 0usize;
    let mut next_line = |buffer: &mut Vec<u8>| -> Result<Option<usize>, TraceReadError> {
        buffer.clear();
        let read = reader
            .read_until(b'\n', buffer)
            .map_err(|source| TraceReadError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        if read == 0 {
            return Ok(None);
        }
        line_number += 1;
        if buffer.last() == Some(&b'\n') {
            buffer.pop();
            if buffer.last() == Some(&b'\r') {
                buffer.pop();
            }
        }
        Ok(Some(line_number))
    };

    let Some(_) = next_line(&mut buffer)? else {
        return Err(TraceReadError::Empty);
    };
    let header = std::str::from_utf8(&buffer).map_err(|_| TraceReadError::NotText { line: 1 })?;
    let mode_names = parse_header(header)?;
    let columns: Vec<String> = csv_columns(&mode_names)
        .into_iter()
        .map(|c| c.name.into_owned())
        .collect();

    let mut samples = Vec::new();
    let mut last_tick = None;
    while let Some(line) = next_line(&mut buffer)? {
        let text = std::str::from_utf8(&buffer).map_err(|_| TraceReadError::NotText { line })?;
        let sample = parse_row(text, line, &columns, mode_names.len())?;
        if let Err(problem) = check_sample(&sample, mode_names.len(), last_tick) {
            return Err(rule_error(problem, text, line, &columns));
        }
        last_tick = Some(sample.tick);
        samples.push(sample);
    }
    Ok((mode_names, samples))
}

fn parse_header(header: &str) -> Result<Vec<String>, TraceReadError> {
    let fields: Vec<&str> = header.split(',').collect();
    let mismatch = |column: usize, expected: &str| TraceReadError::Header {
        column: column + 1,
        expected: expected.to_string(),
        found: fields.get(column).copied().unwrap_or("").to_string(),
    };
    for (i, expected) in LEADING_COLUMNS.iter().enumerate() {
        if fields.get(i) != Some(expected) {
            return Err(mismatch(i, expected));
        }
    }
    let mut mode_names = Vec::new();
    let mut column = LEADING_COLUMNS.len();
    while let Some(name) = fields
        .get(column)
        .and_then(|f| f.strip_prefix(PRIMITIVES_PREFIX))
    {
        if !is_valid_mode_name(name) || mode_names.iter().any(|m| m == name) {
            return Err(mismatch(
                column,
                "primitives_<mode> with a unique mode name of letters, digits, '_' or '-'",
            ));
        }
        if mode_names.len() == MAX_MODES {
            return Err(mismatch(column, "at most 8 primitives_<mode> columns"));
        }
        mode_names.push(name.to_string());
        column += 1;
    }
    for expected in TRAILING_COLUMNS {
        if fields.get(column) != Some(&expected) {
            return Err(mismatch(column, expected));
        }
        column += 1;
    }
    if fields.len() > column {
        return Err(mismatch(column, "the end of the line"));
    }
    Ok(mode_names)
}

/// Field cursor for one row: parses the next field and names it in errors.
struct Fields<'a> {
    fields: std::str::Split<'a, char>,
    index: usize,
    line: usize,
    columns: &'a [String],
}

impl<'a> Fields<'a> {
    fn next_str(&mut self) -> (usize, &'a str) {
        let index = self.index;
        self.index += 1;
        (index, self.fields.next().unwrap_or(""))
    }

    fn error(&self, index: usize, value: &str, problem: &'static str) -> TraceReadError {
        TraceReadError::Field {
            line: self.line,
            column: index + 1,
            name: self.columns[index].clone(),
            value: value.to_string(),
            problem,
        }
    }

    fn integer<T: std::str::FromStr>(
        &mut self,
        problem: &'static str,
    ) -> Result<T, TraceReadError> {
        let (index, text) = self.next_str();
        // Rust's integer parsing accepts a leading '+'; the format never writes one.
        if text.starts_with('+') {
            return Err(self.error(index, text, problem));
        }
        text.parse().map_err(|_| self.error(index, text, problem))
    }

    fn float(&mut self) -> Result<f64, TraceReadError> {
        let (index, text) = self.next_str();
        text.parse()
            .map_err(|_| self.error(index, text, "not a number"))
    }

    fn vector(&mut self) -> Result<DVec3, TraceReadError> {
        Ok(DVec3::new(self.float()?, self.float()?, self.float()?))
    }
}

fn parse_row(
    text: &str,
    line: usize,
    columns: &[String],
    mode_count: usize,
) -> Result<TraceSample, TraceReadError> {
    let found = text.split(',').count();
    if found != columns.len() {
        return Err(TraceReadError::FieldCount {
            line,
            expected: columns.len(),
            found,
        });
    }
    let mut fields = Fields {
        fields: text.split(','),
        index: 0,
        line,
        columns,
    };
    let tick = fields.integer("not an unsigned 64-bit integer")?;
    let t_s = fields.float()?;
    let probe_m = fields.vector()?;
    let proxy_m = fields.vector()?;
    let force_n = fields.vector()?;
    let mut primitives_per_mode = [0u16; MAX_MODES];
    for slot in primitives_per_mode.iter_mut().take(mode_count) {
        *slot = fields.integer("not an integer from 0 to 65535")?;
    }
    let sweeps = fields.integer("not an unsigned 32-bit integer")?;
    let error_bound_m = fields.float()?;
    let flags = fields.integer("not an unsigned 32-bit integer")?;
    Ok(TraceSample {
        tick,
        t_s,
        probe_m,
        proxy_m,
        force_n,
        primitives_per_mode,
        mode_count: mode_count as u8,
        sweeps,
        error_bound_m,
        flags,
    })
}

/// Turns a broken trace rule into an error naming the line and the first column concerned.
fn rule_error(problem: TraceError, text: &str, line: usize, columns: &[String]) -> TraceReadError {
    let (column_name, message): (&str, &'static str) = match problem {
        TraceError::TickOrder { .. } => ("tick", "tick does not increase"),
        TraceError::NegativeTime { .. } => ("t_s", "negative time"),
        TraceError::InvalidErrorBound { .. } => ("error_bound_m", "must be >= 0 or inf"),
        TraceError::NonFinite { field, .. } => (
            match field {
                "probe_m" => "probe_x_m",
                "proxy_m" => "proxy_x_m",
                "force_n" => "force_x_n",
                other => other,
            },
            "not finite (checked from this column on)",
        ),
        _ => ("tick", "invalid sample"),
    };
    let index = columns.iter().position(|c| c == column_name).unwrap_or(0);
    TraceReadError::Field {
        line,
        column: index + 1,
        name: columns[index].clone(),
        value: text.split(',').nth(index).unwrap_or("").to_string(),
        problem: message,
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::{meta, samples};
    use super::super::{create_trace_writer, TraceFormat};
    use super::*;

    fn write_csv(path: &Path, modes: &[&str], data: &[TraceSample]) {
        let mut writer = create_trace_writer(path, TraceFormat::Csv, &meta(modes)).unwrap();
        for sample in data {
            writer.write_sample(sample).unwrap();
        }
        let summary = writer.finish().unwrap();
        assert_eq!(summary.sample_count, data.len() as u64);
    }

    #[test]
    fn write_then_read_round_trips_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.csv");
        let data = samples(500, 3);
        write_csv(&path, &["surface", "friction", "vector-follow"], &data);
        let trace = read_csv_trace(&path).unwrap();
        assert_eq!(trace.mode_names, ["surface", "friction", "vector-follow"]);
        assert_eq!(trace.samples.len(), data.len());
        for (read, written) in trace.samples.iter().zip(&data) {
            // Bit-exact, including -0.0 and inf.
            assert_eq!(read.t_s.to_bits(), written.t_s.to_bits());
            for (a, b) in [
                (read.probe_m, written.probe_m),
                (read.proxy_m, written.proxy_m),
                (read.force_n, written.force_n),
            ] {
                assert_eq!(
                    a.to_array().map(f64::to_bits),
                    b.to_array().map(f64::to_bits)
                );
            }
            assert_eq!(
                read.error_bound_m.to_bits(),
                written.error_bound_m.to_bits()
            );
            assert_eq!(read, written);
        }
        let sidecar = trace.sidecar.expect("sidecar written");
        assert!(sidecar.complete);
        assert_eq!(sidecar.sample_count, 500);
        assert_eq!(sidecar.trace_file, "run.csv");
        assert_eq!(
            sidecar.meta,
            meta(&["surface", "friction", "vector-follow"])
        );
        assert_eq!(sidecar.columns.len(), 11 + 3 + 3);
    }

    #[test]
    fn zero_modes_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("none.csv");
        let data = samples(10, 0);
        write_csv(&path, &[], &data);
        let trace = read_csv_trace(&path).unwrap();
        assert!(trace.mode_names.is_empty());
        assert_eq!(trace.samples, data);
    }

    #[test]
    fn two_identical_runs_give_identical_files() {
        let dir = tempfile::tempdir().unwrap();
        let data = samples(300, 2);
        let a = dir.path().join("a.csv");
        let b = dir.path().join("b.csv");
        write_csv(&a, &["surface", "viscosity"], &data);
        write_csv(&b, &["surface", "viscosity"], &data);
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        // The sidecars differ only in the trace file name.
        let sa = std::fs::read_to_string(sidecar_path(&a)).unwrap();
        let sb = std::fs::read_to_string(sidecar_path(&b)).unwrap();
        assert_eq!(sa.replace("a.csv", "b.csv"), sb);
    }

    #[test]
    fn writer_rejects_bad_samples_naming_the_tick() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.csv");
        let mut writer = CsvTraceWriter::create(&path, &meta(&["surface"])).unwrap();
        let mut sample = TraceSample::zeroed(1);
        sample.tick = 5;
        writer.write_sample(&sample).unwrap();
        let err = writer.write_sample(&sample).unwrap_err().to_string();
        assert!(err.contains("tick 5"), "{err}");
        sample.tick = 6;
        sample.force_n.y = f64::NAN;
        let err = writer.write_sample(&sample).unwrap_err().to_string();
        assert!(err.contains("force_n") && err.contains("tick 6"), "{err}");
        sample.force_n.y = 0.0;
        sample.mode_count = 2;
        assert!(matches!(
            writer.write_sample(&sample),
            Err(TraceError::ModeCountMismatch { .. })
        ));
        sample.mode_count = 1;
        sample.error_bound_m = -1.0;
        assert!(writer.write_sample(&sample).is_err());
        writer.finish().unwrap();
        assert!(matches!(
            writer.write_sample(&sample),
            Err(TraceError::Finished)
        ));
        assert_eq!(read_csv_trace(&path).unwrap().samples.len(), 1);
    }

    fn valid_text() -> String {
        let mut out = Vec::new();
        let header: Vec<String> = csv_columns(&["surface".to_string()])
            .into_iter()
            .map(|c| c.name.into_owned())
            .collect();
        writeln!(out, "{}", header.join(",")).unwrap();
        for sample in samples(4, 1) {
            write_row(&mut out, &sample).unwrap();
        }
        String::from_utf8(out).unwrap()
    }

    fn read_err(text: &str) -> String {
        parse_csv_trace(text.as_bytes()).unwrap_err().to_string()
    }

    #[test]
    fn malformed_csv_errors_name_the_line_and_column() {
        let good = valid_text();
        assert_eq!(parse_csv_trace(good.as_bytes()).unwrap().1.len(), 4);

        let lines: Vec<&str> = good.lines().collect();
        // A bad float on line 3, column 4 (probe_y_m).
        let mut fields: Vec<&str> = lines[2].split(',').collect();
        fields[3] = "0.0x1";
        let broken = [lines[0], lines[1], &fields.join(","), lines[3]].join("\n");
        let err = read_err(&broken);
        assert!(
            err.contains("line 3, column 4 (probe_y_m)") && err.contains("0.0x1"),
            "{err}"
        );
        // A missing field on line 4.
        let short = lines[3].rsplit_once(',').unwrap().0;
        let err = read_err(&[lines[0], lines[1], lines[2], short].join("\n"));
        assert!(err.contains("line 4") && err.contains("fields"), "{err}");
        // Ticks going backwards on line 3.
        let err = read_err(&[lines[0], lines[2], lines[1]].join("\n"));
        assert!(err.contains("line 3") && err.contains("tick"), "{err}");
        // A NaN position.
        let nan_row = lines[1].replacen(",0.02,", ",NaN,", 1);
        assert_ne!(nan_row, lines[1]);
        let err = read_err(&[lines[0], &nan_row].join("\n"));
        assert!(
            err.contains("line 2") && err.contains("not finite"),
            "{err}"
        );
        // A wrong header.
        let err = read_err(&good.replacen("probe_x_m", "probe_x_mm", 1));
        assert!(err.contains("line 1, column 3"), "{err}");
        // An empty file.
        assert!(matches!(
            parse_csv_trace(&b""[..]),
            Err(TraceReadError::Empty)
        ));
        // Negative primitive count.
        let mut fields: Vec<&str> = lines[1].split(',').collect();
        fields[11] = "-1";
        let err = read_err(&[lines[0], &fields.join(",")].join("\n"));
        assert!(err.contains("column 12 (primitives_surface)"), "{err}");
    }

    #[test]
    fn crlf_line_ends_are_accepted() {
        let text = valid_text().replace('\n', "\r\n");
        assert_eq!(parse_csv_trace(text.as_bytes()).unwrap().1.len(), 4);
    }

    proptest::proptest! {
        /// Arbitrary bytes never panic the reader.
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400)) {
            let _ = parse_csv_trace(&bytes[..]);
        }

        /// A valid trace with bytes overwritten, inserted or deleted never panics the reader, and
        /// whatever it accepts obeys the trace rules.
        #[test]
        fn mutated_traces_never_panic(
            edits in proptest::collection::vec((0usize..10_000, proptest::prelude::any::<u8>(), 0u8..3), 1..8)
        ) {
            let mut bytes = valid_text().into_bytes();
            for (position, byte, kind) in edits {
                let at = position % (bytes.len() + 1);
                match kind {
                    0 if at < bytes.len() => bytes[at] = byte,
                    1 => bytes.insert(at, byte),
                    _ if at < bytes.len() => { bytes.remove(at); }
                    _ => {}
                }
            }
            if let Ok((modes, samples)) = parse_csv_trace(&bytes[..]) {
                let mut last = None;
                for sample in &samples {
                    proptest::prop_assert!(check_sample(sample, modes.len(), last).is_ok());
                    last = Some(sample.tick);
                }
            }
        }
    }
}
