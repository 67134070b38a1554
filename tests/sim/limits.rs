//! Degenerate values are refused naming the key, the value and the range; a scenario over the 16 MiB limit is
//! refused everywhere it is read; a budget-cut tick never moves the proxy to higher energy.

use crate::util::sim::{sims_dir, voxhap};
use voxhap::haptics::tick::SolverKind;
use voxhap::sim::LoadedScenario;

/// Finite values that make a run meaningless (they overflow to infinity or NaN within the run, or ask for
/// more than any arm or hand can do) are refused by `sim`, `sim --set` and `sweep`, before any trace is
/// written, with the key, the value and the allowed range. Without the limits, a path speed of 1e300 m/s runs
/// with exit 0 and writes a trace whose every sample is NaN.
#[test]
fn degenerate_values_are_refused_with_the_key_the_value_and_the_range() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = sims_dir().join("sphere_surface.toml");
    // (override, what the error must contain)
    let cases: &[(&str, &str)] = &[
        (
            "path.speed_m_per_s=1e300",
            "path.speed_m_per_s = 1e300 is out of range: give a number > 0 and at most 100 m/s",
        ),
        (
            "k_n_per_m=1e300",
            "k_n_per_m: 1e300 N/m is out of range: give a number from 0.001 to 10000000 N/m",
        ),
        (
            "arm.mass_kg=1e300",
            "arm.mass_kg = 1e300 is out of range: give a number > 0 and at most 1000 kg",
        ),
        (
            "path.points_m=[[0.0, 0.0, 1e300]]",
            "path.points_m has a component of 1e300 m, out of range: each of x, y, z must be from -1000 to 1000 m",
        ),
        (
            "start_m=[0.0, 1e300, 0.0]",
            "start_m: must be three finite numbers from -1000 to 1000 m",
        ),
    ];
    for (i, (set, expected)) in cases.iter().enumerate() {
        let out = dir.path().join(format!("t{i}.csv"));
        let output = voxhap(&[
            "sim".as_ref(),
            scenario.as_os_str(),
            "--set".as_ref(),
            set.as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "--set {set}: {stderr}");
        assert!(stderr.contains(expected), "--set {set}: {stderr}");
        assert!(!out.exists(), "--set {set}: a trace was written");
    }
    // The same keys written in the file (no --set), for kinds of path the shipped scenario does not use.
    let text = std::fs::read_to_string(&scenario).unwrap();
    let (head, _) = text.split_once("[path]").unwrap();
    let paths: &[(&str, &str)] = &[
        (
            "kind = \"line\"\nfrom_m = [0.0, 0.0, 0.04]\nto_m = [0.0, 0.0, 0.0]\nduration_s = 1e-300\n",
            "path.duration_s = 1e-300 is out of range: give a number from 0.001 to 1000000 s",
        ),
        (
            "kind = \"circle\"\ncenter_m = [0.0, 0.0, 0.02]\nradius_m = 0.02\nnormal = [0.0, 0.0, 1.0]\nperiod_s = 1e-300\n",
            "path.period_s = 1e-300 is out of range: give a number from 0.001 to 1000000 s",
        ),
        (
            "kind = \"raster\"\norigin_m = [0.0, 0.0, 0.03]\nsweep_m = [0.01, 0.0, 0.0]\nstep_m = [0.0, 0.01, 0.0]\nlines = 4000000000\nspeed_m_per_s = 0.02\n",
            "path.lines = 4000000000 is out of range: give a number from 1 to 10000 lines",
        ),
        (
            "kind = \"force\"\nprofile = { shape = \"sine\", offset_n = [0.0, 0.0, 0.0], amplitude_n = [0.0, 0.0, 1.0], frequency_hz = 1e300 }\n",
            "path.profile.frequency_hz = 1e300 is out of range: give a number > 0 and at most 10000 Hz",
        ),
        (
            "kind = \"force\"\nprofile = { shape = \"constant\", force_n = [0.0, 0.0, -1e300] }\n",
            "path.profile.force_n has a component of -1e300 N, out of range: each of x, y, z must be from -1000 to 1000 N",
        ),
    ];
    for (i, (path, expected)) in paths.iter().enumerate() {
        let file = dir.path().join(format!("path{i}.toml"));
        let start = if path.contains("force") {
            "start_m = [0.0, 0.0, 0.03]\n"
        } else {
            ""
        };
        std::fs::write(&file, format!("{start}{head}[path]\n{path}")).unwrap();
        let out = dir.path().join(format!("p{i}.csv"));
        let output = voxhap(&[
            "sim".as_ref(),
            file.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{path}: {stderr}");
        assert!(stderr.contains(expected), "{path}: {stderr}");
        assert!(!out.exists(), "{path}: a trace was written");
    }
    // A sweep refuses a list with one such value before running any point.
    let out_dir = dir.path().join("sweep");
    let output = voxhap(&[
        "sweep".as_ref(),
        scenario.as_os_str(),
        "--set".as_ref(),
        "path.speed_m_per_s=0.02,1e300".as_ref(),
        "--out-dir".as_ref(),
        out_dir.as_os_str(),
    ]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("path.speed_m_per_s = 1e300 is out of range"),
        "{stderr}"
    );
    assert!(
        !out_dir.join("point-000.csv").exists(),
        "a sweep with a refused point ran the others"
    );
}

/// A scenario file larger than the documented 16 MiB limit is refused, naming the file and the limit, by
/// `sim` with and without `--set` and by `sweep`, without reading it, and by the library call the Python
/// `voxhap.sim` makes (`voxhap::cli::sim::load_scenario`). The file is sparse: 629 MB on paper, no disk used.
#[test]
fn a_scenario_over_the_16_mib_limit_is_refused_everywhere_it_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("big.toml");
    let file = std::fs::File::create(&big).unwrap();
    file.set_len(629_000_000).unwrap();
    drop(file);
    let limit = "it is 629000000 bytes, more than the 16777216-byte limit for a text file (16 MiB)";
    let out = dir.path().join("t.csv");
    for args in [
        vec![
            "sim".as_ref(),
            big.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ],
        vec![
            "sim".as_ref(),
            big.as_os_str(),
            "--set".as_ref(),
            "k_n_per_m=400".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ],
        vec![
            "sweep".as_ref(),
            big.as_os_str(),
            "--set".as_ref(),
            "k_n_per_m=400,500".as_ref(),
            "--out-dir".as_ref(),
            dir.path().join("sweep").as_os_str(),
        ],
    ] {
        let output = voxhap(&args);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(
            stderr.contains(&big.display().to_string()) && stderr.contains(limit),
            "{args:?}: {stderr}"
        );
    }
    for overrides in [Vec::new(), vec!["k_n_per_m=400".to_owned()]] {
        let err = voxhap::cli::sim::load_scenario(&big, &overrides, None, Some(500.0))
            .expect_err("refused");
        let message = format!("{err:#}");
        assert!(
            message.contains(&big.display().to_string()) && message.contains(limit),
            "{message}"
        );
    }
}

/// The servo tick with a budget cut short (one pass per tick, or a time budget spent after a few clock reads):
/// on every tick of the multi-modal scene (surface, friction, vortex and the rest, the probe pushed through the
/// sphere and along it), the new proxy has no higher energy than the previous proxy, the tick's start, for the
/// tick's own primitives (their energy terms, crates/solver/src/primitive.rs), and the bound holds against the
/// double-double reference minimiser.
#[test]
fn a_budget_cut_tick_never_moves_the_proxy_to_higher_energy() {
    use voxhap::haptics::primitive::total_energy_j;
    use voxhap::haptics::tick::{tick, tick_timed, TickState, TickWorkspace};
    use voxhap::haptics::SolverConfig;

    struct SteppingClock(std::cell::Cell<u64>);
    impl voxhap::clock::Clock for SteppingClock {
        fn now_ns(&self) -> u64 {
            let now = self.0.get();
            self.0.set(now + 1000);
            now
        }
    }

    let loaded = LoadedScenario::from_file(&sims_dir().join("multimodal.toml")).unwrap();
    let k = loaded.scene.stiffness_n_per_m();
    for timed in [false, true] {
        let config = SolverConfig {
            max_sweeps: if timed { 100_000 } else { 1 },
            max_time_ns: 2_000,
            ..SolverConfig::default()
        };
        let mut workspace = TickWorkspace::new(&loaded.scene, SolverKind::Exact, config);
        let mut state = TickState::new(loaded.start_m);
        let mut checked = 0;
        for i in 0..600 {
            let t = i as f64 / 600.0;
            // Down into the scene's volume and across it, with a wobble.
            let probe =
                loaded.start_m + glam::DVec3::new(0.02 * (6.0 * t).sin(), 0.01 * t, -0.05 * t);
            let previous = state.proxy_m;
            let clock = SteppingClock(std::cell::Cell::new(0));
            let out = if timed {
                tick_timed(
                    &mut state,
                    &loaded.scene,
                    probe,
                    1e-3,
                    &mut workspace,
                    &clock,
                )
            } else {
                tick(&mut state, &loaded.scene, probe, 1e-3, &mut workspace)
            };
            let primitives = workspace.primitives();
            // The viscosity mode is a backward-Euler damper c = b / dt between the proxy and where it was
            // (crates/core/src/haptics/tick.rs, module docs): with the coupling, one spring of stiffness k + c
            // towards (k probe + c previous) / (k + c). That is the problem the tick solves and certifies.
            let damper: f64 = (0..loaded.scene.modes().len())
                .map(|m| loaded.scene.damping_n_s_per_m(m, previous) / 1e-3)
                .sum();
            let (k_solve, target) = (k + damper, (k * probe + damper * previous) / (k + damper));
            let e_previous = total_energy_j(k_solve, target, primitives, previous);
            let e_new = total_energy_j(k_solve, target, primitives, out.proxy_m);
            assert!(
                e_new <= e_previous + 1e-12 * (1.0 + e_previous.abs()),
                "tick {i} (timed {timed}): energy {e_new} J > {e_previous} J at the previous proxy: {out:?}"
            );
            if i % 10 == 0 {
                let reference = voxhap::haptics::reference::minimise(k_solve, target, primitives);
                let error = reference.distance_m(out.proxy_m);
                assert!(
                    error <= out.error_bound_m + reference.error_bound_m,
                    "tick {i}: true error {error:e} > bound {:e}",
                    out.error_bound_m
                );
            }
            checked += 1;
        }
        assert_eq!(checked, 600);
    }
}
