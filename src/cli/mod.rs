//! The command-line interface: argument parsing (clap) and one module per subcommand.
//!
//! `voxhap` with no subcommand runs the default job, `voxhap serve` (and takes its flags: `voxhap
//! --no-foxglove`): the simulated arm exploring the built-in scene (sims/scenes/explore.toml) at 1 kHz until
//! Ctrl-C, watched on http://127.0.0.1:8080 and ws://127.0.0.1:8765 (Foxglove).

pub mod bench_loop;
pub mod calibrate;
pub mod clear_fault;
pub mod compare;
pub mod devices;
pub mod info;
pub mod mock_device;
pub mod plot;
pub mod serve;
pub mod shell;
pub mod sim;
pub mod solve;
pub mod sweep;
pub mod trace;

use clap::{Args, Parser, Subcommand};
use std::process::ExitCode;

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
/// `--solver`: one of the names of [`SolverKind`] (`exact`, `euler`, `constraint`), listed in `--help`.
pub fn solver_kind_parser(
) -> impl clap::builder::TypedValueParser<Value = crate::haptics::tick::SolverKind> {
    use crate::haptics::tick::SolverKind;
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(SolverKind::ALL.map(SolverKind::name)).map(|name| {
        SolverKind::ALL
            .into_iter()
            .find(|kind| kind.name() == name)
            .unwrap_or_default()
    })
}

/// `--format`: `csv`, `mcap` or `parquet` ([`TraceFormat`](crate::record::TraceFormat)), listed in `--help`.
pub fn trace_format_parser(
) -> impl clap::builder::TypedValueParser<Value = crate::record::TraceFormat> {
    use crate::record::TraceFormat;
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(TraceFormat::ALL.map(TraceFormat::name)).map(|name| {
        TraceFormat::ALL
            .into_iter()
            .find(|format| format.name() == name)
            .unwrap_or(TraceFormat::Csv)
    })
}

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

/// voxhap: haptic proxy rendering for volume data.
///
/// With no subcommand, voxhap runs `voxhap serve` and takes its flags (`voxhap --no-http`, `voxhap --http ADDR`).
#[derive(Debug, Parser)]
#[command(
    name = "voxhap",
    version,
    about,
    args_conflicts_with_subcommands = true
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
    /// Without a subcommand voxhap serves, so it takes `voxhap serve`'s flags (`voxhap --no-foxglove`).
    #[command(flatten)]
    pub serve: serve::ServeArgs,
}

// Parsed once at start: the size of the largest variant (serve's flags) does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Solve one proxy problem from a JSON scene file.
    Solve(solve::SolveArgs),
    /// Print what the loader reads from a volume file (or builtin:NAME).
    Info(info::InfoArgs),
    /// Plot a recorded force trace (CSV or MCAP) to a PNG or SVG image.
    Plot(plot::PlotArgs),
    /// List serial ports and HID devices, naming the haptic devices voxhap recognises.
    Devices(devices::DevicesArgs),
    /// Serve the simulated arm over voxhap's device protocol on a pseudo-terminal, with fault injection.
    MockDevice(mock_device::MockDeviceArgs),
    /// Run a scenario headless (simulated arm, mock clock) and record its force trace.
    Sim(sim::SimArgs),
    /// Run the real-time servo loop on a device (default: the simulated arm and the built-in scene).
    Serve(serve::ServeArgs),
    /// Run the servo loop on the simulated arm for a while and print its timing histograms.
    BenchLoop(bench_loop::BenchLoopArgs),
    /// Acknowledge a device fault that needs a person: a running `voxhap serve` sends ClearFault and enables
    /// the device again.
    ClearFault(clear_fault::ClearFaultArgs),
    /// Work on recorded traces: `voxhap trace repair FILE` recovers what a crash left.
    Trace(trace::TraceArgs),
    /// Run a scenario for every combination of --set value lists, in parallel, one trace per point.
    Sweep(sweep::SweepArgs),
    /// Compare a trace with a reference within tolerances; exit 1 when they differ.
    Compare(compare::CompareArgs),
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell) generated from these flags.
    Completions(shell::CompletionsArgs),
    /// Print the voxhap(1) man page, or write one page per command with --dir.
    Man(shell::ManArgs),
    /// Record the box the handle reaches (move it to every limit) and write it as a device profile.
    Calibrate(calibrate::CalibrateArgs),
}

/// The README's example scene, built into the binary for the default run.
pub const EXAMPLE_SCENE: &str = include_str!("../../sims/scenes/plane_point.json");

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

/// Parses the arguments, runs the subcommand and maps errors to a non-zero exit code: 1 for errors, 2 for
/// bad arguments (clap), the code of an [`ExitWith`] otherwise.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => match err.downcast_ref::<ExitWith>() {
            Some(exit) => {
                eprintln!("{}", exit.message);
                ExitCode::from(exit.code)
            }
            None => {
                eprintln!("error: {err:#}");
                ExitCode::FAILURE
            }
        },
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Some(Command::Solve(args)) => solve::run(&args),
        Some(Command::Info(args)) => info::run(&args),
        Some(Command::Plot(args)) => plot::run(args),
        Some(Command::Devices(args)) => devices::run(&args),
        Some(Command::MockDevice(args)) => mock_device::run(&args),
        Some(Command::Sim(args)) => sim::run(&args),
        Some(Command::Serve(args)) => serve::run(&args),
        Some(Command::BenchLoop(args)) => bench_loop::run(&args),
        Some(Command::ClearFault(args)) => clear_fault::run(&args),
        Some(Command::Trace(args)) => trace::run(&args),
        Some(Command::Sweep(args)) => sweep::run(&args),
        Some(Command::Compare(args)) => compare::run(&args),
        Some(Command::Completions(args)) => shell::run_completions(&args),
        Some(Command::Man(args)) => shell::run_man(&args),
        Some(Command::Calibrate(args)) => calibrate::run(&args),
        None => {
            print_out("voxhap: no subcommand given; serving the simulated arm on the built-in scene (voxhap serve).")?;
            print_out("See `voxhap --help` for the other commands.")?;
            serve::run(&cli.serve)
        }
    }
}
