//! What every subcommand shares: the duration and size flag parsers, the volume loaders' limit flags,
//! printing to stdout through a closed pipe, and [`ExitWith`] (an outcome with its own exit code).

use clap::Args;

/// Longest duration any `--duration`/`--seconds` flag takes (s): about 31 years, far below where
/// `std::time::Duration` overflows (1.8e19 s).
pub const MAX_SECONDS: f64 = 1e9;

/// Parses a duration flag: a finite number of seconds in (0, [`MAX_SECONDS`]].
pub fn parse_seconds(text: &str) -> Result<f64, String> {
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if seconds.is_finite() && seconds > 0.0 && seconds <= MAX_SECONDS {
        Ok(seconds)
    } else {
        Err(format!(
            "{text} s is out of range: give a number of seconds > 0 and <= {MAX_SECONDS:e}"
        ))
    }
}

/// Parses a byte count: a whole number with an optional suffix `K`, `M`, `G`, `T` (powers of 1024; `KiB`,
/// `MiB`, `GiB`, `TiB` and `B` also accepted), e.g. `4G`, `512MiB`, `1000000`.
pub fn parse_bytes(text: &str) -> Result<u64, String> {
    let trimmed = text.trim();
    let split = trimmed
        .find(|c: char| !c.is_ascii_digit())
        .unwrap_or(trimmed.len());
    let (digits, suffix) = trimmed.split_at(split);
    let shift = match suffix.trim().to_ascii_uppercase().as_str() {
        "" | "B" => 0,
        "K" | "KIB" | "KB" => 10,
        "M" | "MIB" | "MB" => 20,
        "G" | "GIB" | "GB" => 30,
        "T" | "TIB" | "TB" => 40,
        _ => {
            return Err(format!(
                "{text:?} is not a byte count (e.g. 4G, 512M, 1000000)"
            ))
        }
    };
    digits
        .parse::<u64>()
        .ok()
        .and_then(|n| n.checked_mul(1u64 << shift))
        .ok_or_else(|| format!("{text:?} is not a byte count (e.g. 4G, 512M, 1000000)"))
}

/// Range of `--max-volume-bytes`: 1 MiB to 1 TiB.
pub const MAX_VOLUME_BYTES_RANGE: std::ops::RangeInclusive<u64> = (1 << 20)..=(1 << 40);

fn parse_max_volume_bytes(text: &str) -> Result<u64, String> {
    let bytes = parse_bytes(text)?;
    if MAX_VOLUME_BYTES_RANGE.contains(&bytes) {
        Ok(bytes)
    } else {
        Err(format!(
            "{bytes} bytes is out of range: give 1M (1048576) to 1T (1099511627776)"
        ))
    }
}

/// The volume loaders' limits, on every command that loads volumes (`info`, `serve`, `sim`).
#[derive(Debug, Clone, Args)]
pub struct VolumeLimitArgs {
    /// Most memory one volume load may use: bytes read or inflated from its files plus 4 bytes per value
    /// (suffixes K, M, G, T). A header describing more is refused before anything is read.
    #[arg(long, value_name = "BYTES", default_value = "4G", value_parser = parse_max_volume_bytes)]
    pub max_volume_bytes: u64,
    /// Let a data file named inside a volume header (or a volume file named in a scene file) lie outside
    /// that file's folder (after following symlinks). Off by default: a crafted header cannot read
    /// /etc/passwd.
    #[arg(long)]
    pub allow_outside_paths: bool,
}

impl VolumeLimitArgs {
    /// Makes these the limits of every volume load in this process.
    pub fn apply(&self) {
        crate::volume::io::set_process_options(crate::volume::io::LoadOptions {
            max_volume_bytes: self.max_volume_bytes,
            allow_outside_paths: self.allow_outside_paths,
        });
    }
}

/// Prints `text` and a newline to stdout. A closed pipe (`voxhap ... | head`) ends the output quietly instead of
/// panicking as `println!` would.
pub fn print_out(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}").and_then(|()| out.flush()) {
        Err(err) if err.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

/// An outcome that ends voxhap with a particular exit code (`--fail-on` conditions: 3; `voxhap compare`
/// finding a difference: 1).
#[derive(Debug)]
pub struct ExitWith {
    /// The process exit code.
    pub code: u8,
    /// What to print on stderr.
    pub message: String,
}

impl std::fmt::Display for ExitWith {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for ExitWith {}

/// `--solver` on the command line: the kinds of [`SolverKind`](crate::haptics::tick::SolverKind), with the
/// help text `--help` shows for each.
#[derive(Clone, Copy, clap::ValueEnum)]
enum SolverArg {
    /// The certified exact solver (docs/solver.md).
    Exact,
    /// The paper's adaptive Euler solver (baseline, uncertified).
    Euler,
    /// The constraint approach (baseline, uncertified; shows the non-orthogonal artifact).
    Constraint,
}

/// `--solver`: `exact`, `euler` or `constraint`, listed with their help in `--help`.
pub fn solver_kind_parser(
) -> impl clap::builder::TypedValueParser<Value = crate::haptics::tick::SolverKind> {
    use crate::haptics::tick::SolverKind;
    use clap::builder::TypedValueParser as _;
    clap::builder::EnumValueParser::<SolverArg>::new().map(|arg| match arg {
        SolverArg::Exact => SolverKind::Exact,
        SolverArg::Euler => SolverKind::Euler,
        SolverArg::Constraint => SolverKind::Constraint,
    })
}

/// `--format` on the command line: the formats of [`TraceFormat`](crate::record::TraceFormat), with the help
/// text `--help` shows for each.
#[derive(Clone, Copy, clap::ValueEnum)]
enum TraceFormatArg {
    /// Comma-separated text, one row per tick.
    Csv,
    /// MCAP: voxhap's JSON-encoded state and solver messages, plus the probe, proxy and force as Foxglove
    /// protobuf messages; readable by the `mcap` Python package, Foxglove and Lichtblick.
    Mcap,
    /// Apache Parquet: the CSV columns, typed and compressed, one row group per second; readable by
    /// pandas, polars and DuckDB.
    Parquet,
}

/// `--format`: `csv`, `mcap` or `parquet`, listed with their help in `--help`.
pub fn trace_format_parser(
) -> impl clap::builder::TypedValueParser<Value = crate::record::TraceFormat> {
    use crate::record::TraceFormat;
    use clap::builder::TypedValueParser as _;
    clap::builder::EnumValueParser::<TraceFormatArg>::new().map(|arg| match arg {
        TraceFormatArg::Csv => TraceFormat::Csv,
        TraceFormatArg::Mcap => TraceFormat::Mcap,
        TraceFormatArg::Parquet => TraceFormat::Parquet,
    })
}
