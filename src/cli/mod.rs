//! The command-line interface: argument parsing (clap) and one module per subcommand.
//!
//! `voxhap` with no subcommand runs the default job, `voxhap serve` (and takes its flags: `voxhap
//! --no-foxglove`): the simulated arm exploring the built-in scene (sims/scenes/explore.toml) at 1 kHz until
//! Ctrl-C, watched on http://127.0.0.1:8080 and ws://127.0.0.1:8765 (Foxglove).

pub mod bench_loop;
pub mod compare;
pub mod devices;
pub mod info;
pub mod mock_device;
pub mod plot;
pub mod serve;
pub mod sim;
pub mod solve;
pub mod sweep;
pub mod trace;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

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
    /// Work on recorded traces: `voxhap trace repair FILE` recovers what a crash left.
    Trace(trace::TraceArgs),
    /// Run a scenario for every combination of --set value lists, in parallel, one trace per point.
    Sweep(sweep::SweepArgs),
    /// Compare a trace with a reference within tolerances; exit 1 when they differ.
    Compare(compare::CompareArgs),
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
        Some(Command::Trace(args)) => trace::run(&args),
        Some(Command::Sweep(args)) => sweep::run(&args),
        Some(Command::Compare(args)) => compare::run(&args),
        None => {
            print_out("voxhap: no subcommand given; serving the simulated arm on the built-in scene (voxhap serve).")?;
            print_out("See `voxhap --help` for the other commands.")?;
            serve::run(&cli.serve)
        }
    }
}
