//! The one proxy problem of a [`Scene`] file, solved and timed as `voxhap solve` and the Python
//! `voxhap.solve` both report it: the chosen solver ([`SceneSolver`]), the median wall time of up to
//! [`TIMING_RUNS`] solves from the same cold start (stopping after [`TIMING_WALL_S`] seconds, at least one),
//! and the answer as one JSON object ([`TimedSolve::to_json`]).
//!
//! The exact solver always has a budget (sweeps and wall time, [`SceneSolveConfig`]), so a solve never hangs:
//! when it runs out, the answer is the best found with its honest bound and status.

use crate::scene::Scene;
use serde_json::json;
use std::time::Instant;
use voxhap_core::clock::MonotonicClock;
use voxhap_core::haptics::baselines::{constraint, euler, BaselineSolution};
use voxhap_solver::{Solution, SolveError, Solver, SolverConfig};

/// Times reported are the median of up to this many solves of the same scene (each from the same cold start)...
pub const TIMING_RUNS: usize = 101;
/// ... or of those that fit in this many seconds (at least one).
pub const TIMING_WALL_S: f64 = 2.0;

voxhap_core::named_enum! {
    /// Which solver solves the scene.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum SceneSolver {
        /// The certified exact solver (dual sweeps plus an active-set finish).
        Exact => "exact",
        /// The paper's adaptive-step Euler solver on f_res (section 4.3).
        Euler => "euler",
        /// The constraint approach (paper eq. 1-2): constraint movements added.
        Constraint => "constraint",
    }
}

/// A solver name that is not one of [`SceneSolver`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("solver {given:?}: expected exact, euler or constraint")]
pub struct UnknownSolver {
    pub given: String,
}

impl SceneSolver {
    /// The solver of that name.
    pub fn from_name(name: &str) -> Result<SceneSolver, UnknownSolver> {
        Self::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .ok_or_else(|| UnknownSolver {
                given: name.to_owned(),
            })
    }
}

/// The exact solver's budget for a scene solve; the defaults are `voxhap solve`'s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneSolveConfig {
    /// Stop when the certified error bound is at most this (m).
    pub tolerance_m: f64,
    /// Most passes over the primitives per solve.
    pub max_sweeps: u32,
    /// Most wall-clock milliseconds per solve.
    pub budget_ms: f64,
}

impl SceneSolveConfig {
    pub const DEFAULT: SceneSolveConfig = SceneSolveConfig {
        tolerance_m: SolverConfig::DEFAULT.tolerance_m,
        max_sweeps: SolverConfig::DEFAULT.max_sweeps,
        budget_ms: 1000.0,
    };

    /// The solver configuration: the defaults with this budget.
    pub fn solver_config(&self) -> SolverConfig {
        SolverConfig {
            tolerance_m: self.tolerance_m,
            max_sweeps: self.max_sweeps,
            max_time_ns: (self.budget_ms * 1e6) as u64,
            ..SolverConfig::DEFAULT
        }
    }
}

impl Default for SceneSolveConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One solver's answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SceneAnswer {
    /// The exact solver's, with its certificate.
    Exact(Solution),
    /// A baseline's, with its residual (no certificate).
    Baseline(BaselineSolution),
}

impl SceneAnswer {
    /// The proxy position (m).
    pub fn proxy_m(&self) -> glam::DVec3 {
        match self {
            SceneAnswer::Exact(sol) => sol.proxy_m,
            SceneAnswer::Baseline(sol) => sol.proxy_m,
        }
    }

    /// The force sent to the device (N).
    pub fn force_n(&self) -> glam::DVec3 {
        match self {
            SceneAnswer::Exact(sol) => sol.force_n,
            SceneAnswer::Baseline(sol) => sol.force_n,
        }
    }
}

/// The answer of the last of `runs` solves, with their median wall time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedSolve {
    pub solver: SceneSolver,
    pub answer: SceneAnswer,
    /// Median wall time of one solve (ns).
    pub median_ns: u64,
    /// How many solves were timed.
    pub runs: usize,
}

impl TimedSolve {
    /// The answer as `voxhap solve --json` prints it: solver, proxy, force, iterations, time_ns, and for the
    /// exact solver its sweeps, Newton passes, active-set rounds, gap, error bound and status, for a baseline
    /// its residual.
    pub fn to_json(&self) -> serde_json::Value {
        let solver = self.solver.name();
        let time_ns = self.median_ns;
        match &self.answer {
            SceneAnswer::Exact(sol) => json!({
                "solver": solver,
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
            SceneAnswer::Baseline(sol) => json!({
                "solver": solver,
                "proxy": sol.proxy_m.to_array(),
                "force": sol.force_n.to_array(),
                "iterations": sol.iterations,
                "time_ns": time_ns,
                "residual": sol.residual_n,
            }),
        }
    }
}

/// One solve of `scene` by `solver`; `exact` is the exact solver's workspace (reset first, so every solve
/// starts cold from the scene's previous proxy, or its probe).
pub fn solve_once(
    scene: &Scene,
    solver: SceneSolver,
    exact: &mut Solver,
) -> Result<SceneAnswer, SolveError> {
    let start = scene.previous_proxy_m.unwrap_or(scene.probe_m);
    Ok(match solver {
        SceneSolver::Exact => {
            exact.reset();
            SceneAnswer::Exact(exact.solve_with_clock(&scene.problem(), &MonotonicClock::new())?)
        }
        SceneSolver::Euler => SceneAnswer::Baseline(euler::solve(
            scene.stiffness_n_per_m,
            scene.probe_m,
            start,
            &scene.primitives,
            &euler::EulerConfig::default(),
        )),
        SceneSolver::Constraint => SceneAnswer::Baseline(constraint::solve(
            scene.stiffness_n_per_m,
            scene.probe_m,
            start,
            &scene.primitives,
        )),
    })
}

/// Solves `scene` up to [`TIMING_RUNS`] times (for at most [`TIMING_WALL_S`] seconds after the first) and
/// returns the last answer with the median wall time.
pub fn solve_timed(
    scene: &Scene,
    solver: SceneSolver,
    config: &SceneSolveConfig,
) -> Result<TimedSolve, SolveError> {
    let mut exact = Solver::with_capacity(config.solver_config(), scene.primitives.len());
    let mut times = Vec::with_capacity(TIMING_RUNS);
    let wall = Instant::now();
    let mut timed = || {
        let started = Instant::now();
        let answer = solve_once(scene, solver, &mut exact)?;
        times.push(u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX));
        Ok::<_, SolveError>(answer)
    };
    let mut answer = timed()?;
    for _ in 1..TIMING_RUNS {
        if wall.elapsed().as_secs_f64() >= TIMING_WALL_S {
            break;
        }
        answer = timed()?;
    }
    times.sort_unstable();
    Ok(TimedSolve {
        solver,
        answer,
        median_ns: times[times.len() / 2],
        runs: times.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solver_names_round_trip_and_an_unknown_one_is_named() {
        for s in SceneSolver::ALL {
            assert_eq!(SceneSolver::from_name(s.name()), Ok(s));
        }
        let err = SceneSolver::from_name("newton").unwrap_err();
        assert_eq!(
            err.to_string(),
            "solver \"newton\": expected exact, euler or constraint"
        );
    }

    #[test]
    fn a_plane_scene_is_solved_by_each_solver_to_the_plane() {
        // A probe 4 mm below a plane z = 0 of strength 1 N, k = 500 N/m, from a proxy on the plane: the energy
        // k/2 (z + 4 mm)^2 + 1 N max(0, -z) is least where k (z + 4 mm) = 1 N, at z = -2 mm (and the
        // constraint approach moves the proxy the 4 mm asked less the 2 mm the plane holds back: the same).
        let scene = Scene::parse(
            r#"{"k": 500, "probe": [0, 0, -0.004], "previous_proxy": [0, 0, 0], "primitives": [
                {"type": "plane", "position": [0, 0, 0], "direction": [0, 0, 1], "strength": 1}]}"#,
            "test",
        )
        .unwrap();
        for s in SceneSolver::ALL {
            let timed = solve_timed(&scene, s, &SceneSolveConfig::DEFAULT).unwrap();
            assert!(timed.runs >= 1 && timed.runs <= TIMING_RUNS);
            let z = timed.answer.proxy_m().z;
            assert!((z + 0.002).abs() < 1e-6, "{}: z = {z}", s.name());
            let json = timed.to_json();
            assert_eq!(json["solver"], s.name());
            assert_eq!(json["time_ns"], timed.median_ns);
        }
    }
}
