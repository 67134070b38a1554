//! The passivity controller and passive changes in contact, end to end through `voxhap sim` with the exact
//! zero-order-hold simulated arm. Expected values come from the physics, not from the code under test: the
//! uncompensated stable limit is the passivity bound b > K (T/2 + tau) (Colgate and Schenkel; Hulin et al.
//! with delay), and the energy the hand is given is summed here from the trace (the force that acted over each
//! step, `latency` ticks after it was sent, times the step), plus the coupling spring's energy at the end.

use crate::util::sim::{run_text, sims_dir, voxhap};
use std::ffi::OsStr;
use voxhap::record::TraceSample;
use voxhap::sim::{Scenario, SimSummary};

/// Runs sims/`name` with its text edited by `edit`, returning the summary, the trace's samples and the scenario.
fn run(name: &str, edit: impl Fn(String) -> String) -> (SimSummary, Vec<TraceSample>, Scenario) {
    let text = edit(std::fs::read_to_string(sims_dir().join(name)).unwrap());
    run_text(&text, name)
}

/// Energy the coupling gave the hand over the run (J): `sum F_{n-d} . (x_{n+1} - x_n)` with `d` the latency
/// in ticks (the force sent at tick `n - d` acts over the step from tick `n`), plus the coupling spring's
/// energy at the end less at the start (`k_end`, `k_start` the stiffness then).
fn generated_j(samples: &[TraceSample], latency_ticks: usize, k_start: f64, k_end: f64) -> f64 {
    let mut work = 0.0;
    for n in latency_ticks..samples.len() - 1 {
        let dx = samples[n + 1].probe_m - samples[n].probe_m;
        work += samples[n - latency_ticks].sent_force_n.dot(dx);
    }
    let spring = |s: &TraceSample, k: f64| 0.5 * k * (s.proxy_m - s.probe_m).length_squared();
    work + spring(samples.last().unwrap(), k_end) - spring(&samples[0], k_start)
}

fn set_mode(mode: &'static str) -> impl Fn(String) -> String {
    move |text| text.replace("mode = \"control\"", &format!("mode = \"{mode}\""))
}

/// 1 ms of latency at 1 kHz, the default arm released on a plane (b = 1 N s/m): the bound puts the
/// uncompensated limit at b / (T/2 + tau) = 1 / 1.5 ms = 667 N/m, and the scenario renders 3 x 667 = 2 000 N/m.
/// With the controller on, the contact settles (no limit cycle; the force at rest is the hand's 1 N push) and
/// the energy generated stays below 0.1 mJ; with it off, the same scene bounces for ever.
#[test]
fn at_three_times_the_delayed_bound_the_controller_keeps_contact_still() {
    let (b, period_s, latency_s) = (1.0, 1e-3, 1e-3);
    let bound = b / (period_s / 2.0 + latency_s);
    let (summary, samples, scenario) = run("passivity_latency.toml", |t| t);
    assert!(
        (scenario.k_n_per_m - 3.0 * bound).abs() < 1.0,
        "{}",
        scenario.k_n_per_m
    );
    assert!(!summary.energy.oscillating(), "{:?}", summary.energy);
    let k = scenario.k_n_per_m;
    let generated = generated_j(&samples, 1, k, k);
    assert!(generated < 1e-4, "generated {generated} J");
    // The arm's own ringing on the contact spring decays as exp(-b t / (2 m)) = exp(-5 t) from about 2 N
    // (an impact at 0.14 m/s on 2 000 N/m): below 3 mN after 1.3 s. So in the last 0.2 s: in contact every
    // tick, the force the hand's 1 N push within 1 %.
    eprintln!(
        "control at {} N/m: generated {generated:e} J, dissipated {:e} J in {} ticks, largest controller force {} N",
        k, summary.passivity.dissipated_j, summary.passivity.active_ticks, summary.passivity.max_force_n
    );
    let last = &samples[samples.len() - 200..];
    for s in last {
        assert!(
            (s.sent_force_n.z - 1.0).abs() < 0.01,
            "t = {}: {}",
            s.t_s,
            s.sent_force_n
        );
    }
    assert!(
        summary.passivity.dissipated_j > 0.0,
        "{:?}",
        summary.passivity
    );
    assert!(
        (summary.energy.passivity_dissipated_j - summary.passivity.dissipated_j).abs() < 1e-15,
        "the ledger books the controller's dissipation"
    );

    // Off: the same scene is a limit cycle (so the checks above can fail).
    let (off, samples, _) = run("passivity_latency.toml", set_mode("off"));
    assert!(off.energy.oscillating(), "{:?}", off.energy);
    let last = &samples[samples.len() - 500..];
    assert!(
        last.iter().any(|s| s.sent_force_n.z < 1e-3),
        "contact is lost in the last 0.5 s"
    );
    // Observe only: books the same bouncing, dissipates nothing.
    let (observed, _, _) = run("passivity_latency.toml", set_mode("observe"));
    assert!(observed.energy.oscillating());
    assert_eq!(observed.passivity.dissipated_j, 0.0);
    assert!(
        observed.passivity.generated_j > 1e-4,
        "{:?}",
        observed.passivity
    );
}

/// The observer pairs each force with the motion it meets after the device's latency (crate
/// `voxhap-servo`, `passivity::controller`, "Latency"). The default arm released on a plane with 2 ms of
/// latency at 1 kHz (2 ticks): the delayed loop's exact zero-order-hold boundary, computed from first
/// principles by `zoh_exact`, is about 402 N/m, and the scene renders three times it. With the declared
/// latency the controller keeps the energy the trace's forces gave the arm (each paired with the step it
/// met, 2 ticks after it was sent) below 0.1 mJ and the contact without a limit cycle. The old pairing
/// (`[passivity] latency_s = 0`: each force booked against the step right after it was sent) books about
/// a fifth of what the loop generates (`sin(w T/2)` against `sin(w 5T/2)`), and the same scene is a limit
/// cycle: the energy it gave the arm exceeds 1 mJ.
#[test]
fn the_observer_uses_the_declared_latency_above_the_exact_delayed_boundary() {
    use voxhap::device::sim::zoh_exact::exact_boundary;
    let (m, b, period_s, latency_ticks) = (0.1, 1.0, 1e-3, 2usize);
    let boundary = exact_boundary(m, b, period_s, latency_ticks);
    assert!((boundary - 402.0).abs() < 2.0, "{boundary}");
    let k = 3.0 * boundary;
    let scene = |extra: &'static str| {
        move |text: String| {
            let text = text
                .replace("k_n_per_m = 2000.0", &format!("k_n_per_m = {k:.1}"))
                .replace("latency_s = 0.001", "latency_s = 0.002")
                .replace("duration_s = 1.5", "duration_s = 3.0");
            text.replace(
                "mode = \"control\"\n",
                &format!("mode = \"control\"\n{extra}"),
            )
        }
    };
    let (declared, samples, scenario) = run("passivity_latency.toml", scene(""));
    assert_eq!(scenario.k_n_per_m, (k * 10.0).round() / 10.0);
    let declared_j = generated_j(
        &samples,
        latency_ticks,
        scenario.k_n_per_m,
        scenario.k_n_per_m,
    );
    let (ignored, samples, _) = run("passivity_latency.toml", scene("latency_s = 0.0\n"));
    let ignored_j = generated_j(
        &samples,
        latency_ticks,
        scenario.k_n_per_m,
        scenario.k_n_per_m,
    );
    eprintln!(
        "k = {k:.1} N/m (3 x exact boundary {boundary:.1}): declared latency: generated {declared_j:e} J, \
         dissipated {:e} J, oscillating {}; latency ignored: generated {ignored_j:e} J, dissipated {:e} J, \
         oscillating {}",
        declared.passivity.dissipated_j,
        declared.energy.oscillating(),
        ignored.passivity.dissipated_j,
        ignored.energy.oscillating()
    );
    assert!(
        declared_j < 1e-4,
        "declared latency: generated {declared_j} J"
    );
    assert!(!declared.energy.oscillating(), "{:?}", declared.energy);
    assert!(ignored_j > 1e-3, "latency ignored: generated {ignored_j} J");
    assert!(ignored.energy.oscillating(), "{:?}", ignored.energy);
}

fn without_events(text: String) -> String {
    let start = text.find("[[events]]").unwrap();
    let end = start + text[start..].find("[[modes]]").unwrap();
    format!("{}{}", &text[..start], &text[end..])
}

fn passivity_off(text: String) -> String {
    format!("{text}\n[passivity]\nmode = \"off\"\n")
}

/// A closed press-and-leave cycle with `set_stiffness` 500 -> 4 000 N/m at the bottom of the press gives the
/// hand no more energy than the same cycle without the change (within 0.05 mJ). Applied at once (passivity
/// off) the change gives it more than 1 mJ: the check can fail.
#[test]
fn a_stiffness_raised_in_contact_injects_no_energy_over_the_cycle() {
    let (plain, samples, _) = run("stiffen_in_contact.toml", without_events);
    assert_eq!(plain.events_applied, 0);
    let without = generated_j(&samples, 0, 500.0, 500.0);
    let (changed, samples, _) = run("stiffen_in_contact.toml", |t| t);
    assert_eq!((changed.events_applied, changed.changes_introduced), (1, 1));
    // The probe is out of contact at both ends of the cycle.
    assert!(
        samples[0].sent_force_n.length() < 1e-9
            && samples.last().unwrap().sent_force_n.length() < 1e-9
    );
    let with = generated_j(&samples, 0, 500.0, 4000.0);
    assert!(with <= without + 5e-5, "with {with} J, without {without} J");
    let (at_once, samples, _) = run("stiffen_in_contact.toml", passivity_off);
    let at_once_j = generated_j(&samples, 0, 500.0, 4000.0);
    eprintln!("stiffen: without {without:e} J, passive {with:e} J, at once {at_once_j:e} J");
    assert_eq!(at_once.changes_introduced, 0);
    assert!(
        at_once_j > without + 1e-3,
        "at once {at_once_j} J, without {without} J"
    );
}

/// A plane switched on 3 mm above a probe already below it, then the hand lifts out: no more energy than the
/// same cycle without the plane (within 0.05 mJ). Switched on at once it pushes the probe out.
#[test]
fn a_plane_appearing_above_the_probe_engages_without_pushing() {
    let (plain, samples, _) = run("plane_appears.toml", without_events);
    assert_eq!(plain.events_applied, 0);
    let without = generated_j(&samples, 0, 500.0, 500.0);
    let (changed, samples, _) = run("plane_appears.toml", |t| t);
    assert_eq!((changed.events_applied, changed.changes_introduced), (1, 1));
    let with = generated_j(&samples, 0, 500.0, 500.0);
    assert!(with <= without + 5e-5, "with {with} J, without {without} J");
    let (_, samples, _) = run("plane_appears.toml", passivity_off);
    let at_once_j = generated_j(&samples, 0, 500.0, 500.0);
    eprintln!("plane: without {without:e} J, passive {with:e} J, at once {at_once_j:e} J");
    assert!(
        at_once_j > without + 1e-3,
        "at once {at_once_j} J, without {without} J"
    );
}

/// The CLI runs the sims, and `--set passivity.mode=off` is the uncompensated scene `--fail-on
/// oscillation` catches (the commands docs/stability.md shows).
#[test]
fn the_cli_runs_the_controller_and_fails_on_the_uncompensated_scene() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("t.csv");
    let args = |extra: &[&'static str]| {
        let mut args = vec![
            OsStr::new("sim").to_owned(),
            sims_dir().join("passivity_latency.toml").into_os_string(),
            OsStr::new("--out").to_owned(),
            trace.clone().into_os_string(),
            OsStr::new("--force").to_owned(),
            OsStr::new("--fail-on").to_owned(),
            OsStr::new("oscillation").to_owned(),
        ];
        args.extend(extra.iter().map(|a| OsStr::new(a).to_owned()));
        args
    };
    let on = args(&[]);
    let out = voxhap(&on.iter().map(|a| a.as_os_str()).collect::<Vec<_>>());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("passivity: control"), "{stderr}");
    let off = args(&["--set", "passivity.mode=\"off\""]);
    let out = voxhap(&off.iter().map(|a| a.as_os_str()).collect::<Vec<_>>());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("oscillation: "), "{stderr}");
}

/// A released arm carried by the vortex's flow under `vector_force`, the controller on. The mode's push is
/// work the scene asks for (bounded by its power budget), and in free space the coupling spring without the
/// directed part is unstretched: it stores and generates nothing, so the controller has nothing to take.
/// Expected from that: the push does its work (the ledger's active work, at most budget x duration) and the
/// controller dissipates nothing. (Booked as coupling work, the push was nearly all damped away: 11.2 of
/// 11.8 mJ in this scene.)
#[test]
fn the_controller_leaves_a_directed_force_push_alone() {
    let text = r#"
name = "vector-force-push"
description = "a released arm carried by the vortex's flow under vector_force, the passivity controller on"
duration_s = 1.0
k_n_per_m = 500.0
start_m = [0.01, 0.0, 0.0]

[[volumes]]
name = "flow"
builtin = "density-flow"
part = "vector"

[passivity]
mode = "control"

[[modes]]
kind = "vector_force"
volume = "flow"
transfer = [[0.0, 0.0], [0.05, 0.5]]
power_budget_w = 0.2

[arm]
mass_kg = 0.1
damping_n_s_per_m = 1.0
workspace = { shape = "unbounded" }

[path]
kind = "force"
profile = { shape = "constant", force_n = [0.0, 0.0, 0.0] }
"#;
    let (summary, _, scenario) = run_text(text, "vector_force_push.toml");
    let active = summary.energy.active_work_j;
    eprintln!(
        "active work {active:e} J, dissipated {:e} J in {} ticks",
        summary.passivity.dissipated_j, summary.passivity.active_ticks
    );
    assert!(
        active > 1e-3 && active <= 0.2 * scenario.duration_s,
        "{active}"
    );
    assert!(
        summary.passivity.dissipated_j < 1e-6,
        "{:?}",
        summary.passivity
    );
}
