//! `voxhap solve`: solve one proxy problem from a JSON scene file and print the answer, as text or JSON.
//!
//! It never hangs: the exact solver gets a budget (`--max-sweeps`, `--budget-ms`) and always prints its best
//! answer with its honest bound and status (`certified`, `budget_exhausted`, `stalled`); the timing repeats
//! stop after `TIMING_WALL_S` seconds of solving whatever the count.

use crate::haptics::scene::Scene;
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use voxhap_io::scene_solve::{solve_timed, SceneAnswer, SceneSolveConfig, SceneSolver, TimedSolve};

/// Which solver `voxhap solve` runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SolverChoice {
    /// The certified exact solver (dual sweeps plus an active-set finish).
    Exact,
    /// The paper's adaptive-step Euler solver on f_res (section 4.3).
    Euler,
    /// The constraint approach (paper eq. 1-2): constraint movements added.
    Constraint,
}

impl SolverChoice {
    pub fn name(self) -> &'static str {
        SceneSolver::from(self).name()
    }
}

impl From<SolverChoice> for SceneSolver {
    fn from(choice: SolverChoice) -> Self {
        match choice {
            SolverChoice::Exact => SceneSolver::Exact,
            SolverChoice::Euler => SceneSolver::Euler,
            SolverChoice::Constraint => SceneSolver::Constraint,
        }
    }
}

#[derive(Debug, Args)]
pub struct SolveArgs {
    /// Scene file (JSON): k, probe, optional previous_proxy, primitives.
    #[arg(long)]
    pub scene: PathBuf,
    #[arg(long, value_enum, default_value_t = SolverChoice::Exact)]
    pub solver: SolverChoice,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Exact solver: stop when the certified error bound is at most this (m).
    #[arg(long, default_value_t = SceneSolveConfig::DEFAULT.tolerance_m, value_parser = parse_tolerance)]
    pub tolerance_m: f64,
    /// Exact solver: most block-coordinate sweeps per solve.
    #[arg(long, default_value_t = SceneSolveConfig::DEFAULT.max_sweeps, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_sweeps: u32,
    /// Exact solver: most wall-clock milliseconds per solve; the best answer so far is printed with its bound
    /// when it runs out.
    #[arg(long, default_value_t = SceneSolveConfig::DEFAULT.budget_ms, value_parser = parse_budget_ms)]
    pub budget_ms: f64,
}

fn parse_tolerance(text: &str) -> Result<f64, String> {
    let value: f64 = text.parse().map_err(|e| format!("{e}"))?;
    let (lo, hi) = crate::sim::scenario::TOLERANCE_RANGE_M;
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(format!("must be a number from {lo:e} to {hi:e} m"))
    }
}

fn parse_budget_ms(text: &str) -> Result<f64, String> {
    let value: f64 = text.parse().map_err(|e| format!("{e}"))?;
    if value.is_finite() && value > 0.0 && value <= 3_600_000.0 {
        Ok(value)
    } else {
        Err("must be a number of milliseconds > 0 and at most 3600000 (an hour)".to_owned())
    }
}

/// The exact solver's budget from the flags.
fn solve_config(args: &SolveArgs) -> SceneSolveConfig {
    SceneSolveConfig {
        tolerance_m: args.tolerance_m,
        max_sweeps: args.max_sweeps,
        budget_ms: args.budget_ms,
    }
}

pub fn run(args: &SolveArgs) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene)?;
    super::common::print_out(&report(
        &scene,
        args.solver,
        args.json,
        &solve_config(args),
    )?)
}

/// Solves `scene` and formats the report (text, or one JSON object).
pub fn report(
    scene: &Scene,
    choice: SolverChoice,
    as_json: bool,
    config: &SceneSolveConfig,
) -> anyhow::Result<String> {
    let timed = solve_timed(scene, choice.into(), config)?;
    if as_json {
        return Ok(serde_json::to_string_pretty(&timed.to_json())?);
    }
    let TimedSolve {
        answer,
        median_ns: time_ns,
        runs,
        ..
    } = timed;
    let v3 = |v: glam::DVec3| format!("[{:+.9e}, {:+.9e}, {:+.9e}]", v.x, v.y, v.z);
    let mut out = String::new();
    out.push_str(&format!("solver       {}\n", choice.name()));
    out.push_str(&format!("proxy        {} m\n", v3(answer.proxy_m())));
    out.push_str(&format!(
        "force        {} N (|f| = {:.6} N)\n",
        v3(answer.force_n()),
        answer.force_n().length()
    ));
    let time = format!("time         {time_ns} ns (median of {runs} solves)\n");
    match answer {
        SceneAnswer::Exact(sol) => {
            out.push_str(&format!(
                "iterations   {} ({} sweeps, of which {} Newton passes; {} active-set rounds)\n",
                sol.sweeps + sol.active_set_rounds,
                sol.sweeps,
                sol.newton_passes,
                sol.active_set_rounds
            ));
            out.push_str(&time);
            out.push_str(&format!("gap          {:.3e} J\n", sol.gap_j));
            let status = serde_json::to_value(sol.status)?;
            out.push_str(&format!(
                "error bound  {:.3e} m ({})",
                sol.error_bound_m,
                status.as_str().unwrap_or("unknown")
            ));
        }
        SceneAnswer::Baseline(sol) => {
            out.push_str(&format!("iterations   {}\n", sol.iterations));
            out.push_str(&time);
            out.push_str(&format!(
                "residual     {:.3e} N (|f_res| at the answer; no certificate)",
                sol.residual_n
            ));
        }
    }
    Ok(out)
}
