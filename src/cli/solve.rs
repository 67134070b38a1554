//! `voxhap solve`: solve one proxy problem from a JSON scene file and print the answer, as text or JSON.

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
}

/// Times reported are the median of this many solves of the same scene (each from the same cold start).
const TIMING_RUNS: usize = 101;

enum Answer {
    Exact(Solution),
    Baseline(BaselineSolution),
}

fn solve_once(scene: &Scene, choice: SolverChoice, solver: &mut Solver) -> anyhow::Result<Answer> {
    let start = scene.previous_proxy_m.unwrap_or(scene.probe_m);
    Ok(match choice {
        SolverChoice::Exact => {
            solver.reset();
            Answer::Exact(solver.solve(&scene.problem())?)
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
fn solve_timed(scene: &Scene, choice: SolverChoice) -> anyhow::Result<(Answer, u64)> {
    let mut solver = Solver::with_capacity(SolverConfig::default(), scene.primitives.len());
    let mut times = Vec::with_capacity(TIMING_RUNS);
    let mut answer = None;
    for _ in 0..TIMING_RUNS {
        let started = Instant::now();
        let result = solve_once(scene, choice, &mut solver)?;
        times.push(u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX));
        answer = Some(result);
    }
    times.sort_unstable();
    let answer = answer.context("no solve ran")?;
    Ok((answer, times[times.len() / 2]))
}

pub fn run(args: &SolveArgs) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene)?;
    super::print_out(&report(&scene, args.solver, args.json)?)
}

/// Solves `scene` and formats the report (text, or one JSON object).
pub fn report(scene: &Scene, choice: SolverChoice, as_json: bool) -> anyhow::Result<String> {
    let (answer, time_ns) = solve_timed(scene, choice)?;
    let value = match &answer {
        Answer::Exact(sol) => json!({
            "solver": choice.name(),
            "proxy": sol.proxy_m.to_array(),
            "force": sol.force_n.to_array(),
            "iterations": sol.sweeps + sol.active_set_rounds,
            "sweeps": sol.sweeps,
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
                "iterations   {} ({} sweeps, {} active-set rounds)\n",
                sol.sweeps + sol.active_set_rounds,
                sol.sweeps,
                sol.active_set_rounds
            ));
            out.push_str(&format!(
                "time         {time_ns} ns (median of {TIMING_RUNS} solves)\n"
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
                "time         {time_ns} ns (median of {TIMING_RUNS} solves)\n"
            ));
            out.push_str(&format!(
                "residual     {:.3e} N (|f_res| at the answer; no certificate)",
                sol.residual_n
            ));
        }
    }
    Ok(out)
}
