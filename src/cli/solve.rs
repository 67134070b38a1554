//! `voxhap solve`: solve one proxy problem from a JSON scene file and print the answer, as text or JSON.
//!
//! It never hangs: the exact solver gets a budget (`--max-sweeps`, `--budget-ms`) and always prints its best
//! answer with its honest bound and status (`certified`, `budget_exhausted`, `stalled`); the timing repeats
//! stop after `TIMING_WALL_S` seconds of solving whatever the count.

use crate::clock::MonotonicClock;
use crate::haptics::baselines::{constraint, euler, BaselineSolution};
use crate::haptics::scene::Scene;
use crate::haptics::solver::{Solution, Solver, SolverConfig};
use anyhow::Context;
use clap::{Args, ValueEnum};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

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
        match self {
            SolverChoice::Exact => "exact",
            SolverChoice::Euler => "euler",
            SolverChoice::Constraint => "constraint",
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
    #[arg(long, default_value_t = 1e-12, value_parser = parse_tolerance)]
    pub tolerance_m: f64,
    /// Exact solver: most block-coordinate sweeps per solve.
    #[arg(long, default_value_t = 100_000, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_sweeps: u32,
    /// Exact solver: most wall-clock milliseconds per solve; the best answer so far is printed with its bound
    /// when it runs out.
    #[arg(long, default_value_t = 1000.0, value_parser = parse_budget_ms)]
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
fn solver_config(args: &SolveArgs) -> SolverConfig {
    SolverConfig {
        tolerance_m: args.tolerance_m,
        max_sweeps: args.max_sweeps,
        max_time_ns: (args.budget_ms * 1e6) as u64,
        ..SolverConfig::default()
    }
}

/// Times reported are the median of up to this many solves of the same scene (each from the same cold start)...
const TIMING_RUNS: usize = 101;
/// ... or of those that fit in this many seconds (at least one).
const TIMING_WALL_S: f64 = 2.0;

enum Answer {
    Exact(Solution),
    Baseline(BaselineSolution),
}

fn solve_once(scene: &Scene, choice: SolverChoice, solver: &mut Solver) -> anyhow::Result<Answer> {
    let start = scene.previous_proxy_m.unwrap_or(scene.probe_m);
    Ok(match choice {
        SolverChoice::Exact => {
            solver.reset();
            Answer::Exact(solver.solve_with_clock(&scene.problem(), &MonotonicClock::new())?)
        }
        SolverChoice::Euler => Answer::Baseline(euler::solve(
            scene.stiffness_n_per_m,
            scene.probe_m,
            start,
            &scene.primitives,
            &euler::EulerConfig::default(),
        )),
        SolverChoice::Constraint => Answer::Baseline(constraint::solve(
            scene.stiffness_n_per_m,
            scene.probe_m,
            start,
            &scene.primitives,
        )),
    })
}

/// Solves the scene `TIMING_RUNS` times and returns the answer with the median wall time.
fn solve_timed(
    scene: &Scene,
    choice: SolverChoice,
    config: SolverConfig,
) -> anyhow::Result<(Answer, u64, usize)> {
    let mut solver = Solver::with_capacity(config, scene.primitives.len());
    let mut times = Vec::with_capacity(TIMING_RUNS);
    let mut answer = None;
    let wall = Instant::now();
    for _ in 0..TIMING_RUNS {
        if answer.is_some() && wall.elapsed().as_secs_f64() >= TIMING_WALL_S {
            break;
        }
        let started = Instant::now();
        let result = solve_once(scene, choice, &mut solver)?;
        times.push(u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX));
        answer = Some(result);
    }
    times.sort_unstable();
    let answer = answer.context("no solve ran")?;
    Ok((answer, times[times.len() / 2], times.len()))
}

pub fn run(args: &SolveArgs) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene)?;
    super::common::print_out(&report(
        &scene,
        args.solver,
        args.json,
        solver_config(args),
    )?)
}

/// Solves `scene` and formats the report (text, or one JSON object).
pub fn report(
    scene: &Scene,
    choice: SolverChoice,
    as_json: bool,
    config: SolverConfig,
) -> anyhow::Result<String> {
    let (answer, time_ns, runs) = solve_timed(scene, choice, config)?;
    let value = match &answer {
        Answer::Exact(sol) => json!({
            "solver": choice.name(),
            "proxy": sol.proxy_m.to_array(),
            "force": sol.force_n.to_array(),
            "iterations": sol.sweeps + sol.active_set_rounds,
            "sweeps": sol.sweeps,
            "newton_passes": sol.newton_passes,
            "active_set_rounds": sol.active_set_rounds,
            "time_ns": time_ns,
            "gap": sol.gap_j,
            "error_bound": sol.error_bound_m,
            "status": sol.status,
        }),
        Answer::Baseline(sol) => json!({
            "solver": choice.name(),
            "proxy": sol.proxy_m.to_array(),
            "force": sol.force_n.to_array(),
            "iterations": sol.iterations,
            "time_ns": time_ns,
            "residual": sol.residual_n,
        }),
    };
    if as_json {
        return Ok(serde_json::to_string_pretty(&value)?);
    }
    let v3 = |v: glam::DVec3| format!("[{:+.9e}, {:+.9e}, {:+.9e}]", v.x, v.y, v.z);
    let mut out = String::new();
    out.push_str(&format!("solver       {}\n", choice.name()));
    match answer {
        Answer::Exact(sol) => {
            out.push_str(&format!("proxy        {} m\n", v3(sol.proxy_m)));
            out.push_str(&format!(
                "force        {} N (|f| = {:.6} N)\n",
                v3(sol.force_n),
                sol.force_n.length()
            ));
            out.push_str(&format!(
                "iterations   {} ({} sweeps, of which {} Newton passes; {} active-set rounds)\n",
                sol.sweeps + sol.active_set_rounds,
                sol.sweeps,
                sol.newton_passes,
                sol.active_set_rounds
            ));
            out.push_str(&format!(
                "time         {time_ns} ns (median of {runs} solves)\n"
            ));
            out.push_str(&format!("gap          {:.3e} J\n", sol.gap_j));
            let status = serde_json::to_value(sol.status)?;
            out.push_str(&format!(
                "error bound  {:.3e} m ({})",
                sol.error_bound_m,
                status.as_str().unwrap_or("unknown")
            ));
        }
        Answer::Baseline(sol) => {
            out.push_str(&format!("proxy        {} m\n", v3(sol.proxy_m)));
            out.push_str(&format!(
                "force        {} N (|f| = {:.6} N)\n",
                v3(sol.force_n),
                sol.force_n.length()
            ));
            out.push_str(&format!("iterations   {}\n", sol.iterations));
            out.push_str(&format!(
                "time         {time_ns} ns (median of {runs} solves)\n"
            ));
            out.push_str(&format!(
                "residual     {:.3e} N (|f_res| at the answer; no certificate)",
                sol.residual_n
            ));
        }
    }
    Ok(out)
}
