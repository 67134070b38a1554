//! The command-line interface: argument parsing (clap) and one module per subcommand.
//!
//! `voxhap` with no subcommand runs the default job, `voxhap serve` (and takes its flags: `voxhap
//! --no-foxglove`): the simulated arm exploring the built-in scene (sims/scenes/explore.toml) at 1 kHz until
//! Ctrl-C, watched on http://127.0.0.1:8080 and ws://127.0.0.1:8765 (Foxglove).

pub mod bench_loop;
pub mod calibrate;
pub mod clear_fault;
pub mod common;
pub mod compare;
pub mod devices;
pub mod info;
pub mod mock_device;
pub mod plot;
pub mod ros2_output;
pub mod serve;
pub mod shell;
pub mod sim;
pub mod solve;
pub mod stability;
pub mod sweep;
pub mod trace;

pub use common::{
    parse_bytes, parse_seconds, print_out, ExitWith, VolumeLimitArgs, MAX_SECONDS,
    MAX_VOLUME_BYTES_RANGE,
};

use clap::{CommandFactory, Parser, Subcommand};
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

// Parsed once at start: the size of the largest variant (serve's flags) does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Solve one proxy problem from a JSON scene file.
    Solve(solve::SolveArgs),
    /// Print what the loader reads from a volume file (or builtin:NAME).
    Info(info::InfoArgs),
    /// Plot a recorded force trace (CSV, MCAP or Parquet) to a PNG or SVG image.
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
    /// Measure the largest stable stiffness per arm (host alone, host + local model, full-rate host), the
    /// force error of a local model along the shipped sims, and the link use of the models.
    Stability(stability::StabilityArgs),
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell) generated from these flags.
    Completions(shell::CompletionsArgs),
    /// Print the voxhap(1) man page, or write one page per command with --dir.
    Man(shell::ManArgs),
    /// Record the box the handle reaches (move it to every limit) and write it as a device profile.
    Calibrate(calibrate::CalibrateArgs),
}

/// The README's example scene, built into the binary for the default run.
pub const EXAMPLE_SCENE: &str = include_str!("../../sims/scenes/plane_point.json");

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
        Some(Command::Stability(args)) => stability::run(&args),
        Some(Command::Completions(args)) => shell::run_completions(&args, Cli::command()),
        Some(Command::Man(args)) => shell::run_man(&args, Cli::command()),
        Some(Command::Calibrate(args)) => calibrate::run(&args),
        None => {
            print_out("voxhap: no subcommand given; serving the simulated arm on the built-in scene (voxhap serve).")?;
            print_out("See `voxhap --help` for the other commands.")?;
            serve::run(&cli.serve)
        }
    }
}
