//! The passivity controller acting on a real device process, told the link's latency by the whole chain:
//! `voxhap mock-device` on a pseudo-terminal, its handle a physical model (the simulated arm: 0.1 kg,
//! 1 N s/m, held by a hand with a 200 N/m, 0.5 N s/m grip that presses it into a plane) behind a link whose
//! states come 1 ms late, and `voxhap serve` rendering the plane at 2 000 N/m. The scene writes no
//! `[passivity] latency_s`: the protocol driver measures the link's round trips at open, the supervisor hands
//! the figure to `Session::start`, and the observer pairs with it (serve's notice says so, and the figure it
//! names is at least the 1 ms the mock adds to every reply). The energy is summed from the device's own log
//! (`--handle-log`: the handle's position each control cycle and the force held on it over the cycle), so it
//! is what the device was given, whatever the host thought it sent: `W(t) = sum F_c . (x_{c+1} - x_c)`,
//! exact under the force held over each cycle.
//!
//! Expected from the analysis, not from the controller: the contact's damping is at most the arm's and the
//! grip's, `b` = 1.5 N s/m, and its delay at least the link's 1 ms, so the passivity bound
//! `b / (T/2 + tau)` (Colgate and Schenkel; with delay, Hulin et al.) is at most 1 000 N/m at 1 kHz: at
//! 2 000 N/m the uncompensated contact is active, giving the handle energy every bounce, without bound. A
//! passive coupling that starts at rest never gives the handle more than it took from it, so `W` stays at or
//! below zero but for what the controller has not answered yet, bounded as follows.
//!
//! **The tolerance, derived.** The controller lets the energy the host books as generated beyond the coupling
//! spring's reference rise to `threshold_j` (1 µJ, its default) and damps any excess over it. The host's
//! books are the device's own sum over the same positions (the mock samples the handle at its last control
//! cycle and applies each force from its next one; the observer pairs each step with the force sent `d`
//! ticks before it), except for what the host has not seen or answered yet: a cycle's motion reaches the host
//! only with the State that reports it, up to `d` ticks later (`d` the link's depth in ticks, at most the
//! measured latency rounded up to whole ticks), and the damping the controller sends in answer reaches the
//! handle `d` ticks after that, held for one more. So at any time the controller has answered all the energy
//! the device was given but that of at most the last `2 (d + 1)` control cycles, and
//! `max_t W(t) <= threshold_j + max over any 2 (d + 1) consecutive cycles of sum max(0, F_c . dx_c)`
//! (the unobserved window at the power the log shows in it) `+ q`, where `q` bounds the rounding of positions
//! and forces (summed by parts: `delta_x (2 max|F| + sum |dF|) + delta_F sum |dx|`, with `delta_x` half the
//! larger of the log's 1e-12 m and an f32's step at the largest position on the wire, `delta_F` half the
//! larger of 1e-9 N and an f32's step at the largest force). Both sides come from the device's log and `d`
//! from serve's notice. The bound assumes the delay never exceeds what was measured at open, which a host that is not
//! real-time cannot promise: on the shared 2-core VM, otherwise idle, one run gave 0.126 mJ against a bound of
//! 0.085 mJ (`d` = 2). So the bound is printed and the test asserts what holds whatever the timing (see the
//! test). It held with the controller on, `W` at most 0.7 µJ against a bound of 2.6 µJ with
//! `d` = 3 (on a machine at load average 20: 67 µJ against 108 µJ with `d` = 3, and 93 µJ against 244 µJ
//! where the round trips made `d` = 7); it fails, as it must, when the observer is told no latency
//! (`latency_s = 0`: 14 mJ against 2.5 mJ, 74 mJ against 2.6 mJ) and with the controller off (320 mJ against
//! 8 mJ, 238 mJ against 7 mJ): those two are asserted against the bound, since a late host only adds delay
//! and so only more energy.

use crate::util::mock_process::MockProcess as Mock;
use std::path::Path;

/// The handle: the simulated arm held by a hand that waits above the plane while serve connects and engages
/// (up 10 mm over 2 s), then presses it 3 mm past the plane at z = -5 mm (the grip's 200 N/m: 0.6 N) and
/// holds it there.
const HANDLE: &str = r#"
[arm]
mass_kg = 0.1
damping_n_s_per_m = 1.0
workspace = { shape = "unbounded" }

[hand]
stiffness_n_per_m = 200.0
damping_n_s_per_m = 0.5

[path]
kind = "waypoints"
points_m = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.01], [0.0, 0.0, -0.008]]
speed_m_per_s = 0.005
"#;

fn scene(passivity: &str) -> String {
    format!(
        "name = \"pressed-plane\"\nk_n_per_m = 2000.0\ndamping_n_s_per_m = 0.0\nstart_m = [0.0, 0.0, 0.0]\n\
         volumes = []\n\n[passivity]\n{passivity}\n\n[[modes]]\nkind = \"support_plane\"\n\
         point_m = [0.0, 0.0, -0.005]\nnormal = [0.0, 0.0, 1.0]\nstrength_n = 30.0\n"
    )
}

/// One control cycle of the handle log (`HANDLE_LOG_HEADER`): time (µs), position (m), force (N).
struct Cycle {
    z_m: f64,
    position_m: [f64; 3],
    force_n: [f64; 3],
}

fn read_handle_log(path: &Path) -> Vec<Cycle> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(voxhap::device::mock::HANDLE_LOG_HEADER));
    lines
        .map(|line| {
            let f: Vec<f64> = line.split(',').map(|v| v.parse().unwrap()).collect();
            assert_eq!(f.len(), 7, "{line}");
            Cycle {
                z_m: f[3],
                position_m: [f[1], f[2], f[3]],
                force_n: [f[4], f[5], f[6]],
            }
        })
        .collect()
}

/// The work of each cycle's held force over its step (J).
fn step_work_j(cycles: &[Cycle]) -> Vec<f64> {
    cycles
        .windows(2)
        .map(|pair| {
            (0..3)
                .map(|i| pair[0].force_n[i] * (pair[1].position_m[i] - pair[0].position_m[i]))
                .sum()
        })
        .collect()
}

/// The most energy the device was given by the host's force, `max_t W(t)` (J; 0 at the start).
fn max_given_j(cycles: &[Cycle]) -> f64 {
    let mut total = 0.0;
    let mut most: f64 = 0.0;
    for work in step_work_j(cycles) {
        total += work;
        most = most.max(total);
    }
    most
}

/// The most the device may be given with the controller on (J): chosen, four times the most measured (module
/// docs, "The tolerance, derived", says why the derived bound is not asserted).
const ON_LIMIT_J: f64 = 0.5e-3;

/// The derived bound (module docs): the controller's threshold, the positive work over the worst window of
/// `2 (d + 1)` cycles, and the rounding of positions and forces.
fn bound_j(cycles: &[Cycle], d: usize) -> f64 {
    let window = 2 * (d + 1);
    let positive: Vec<f64> = step_work_j(cycles).iter().map(|w| w.max(0.0)).collect();
    let unanswered = positive
        .windows(window.min(positive.len()).max(1))
        .map(|w| w.iter().sum::<f64>())
        .fold(0.0, f64::max);
    let largest = |f: &dyn Fn(&Cycle) -> [f64; 3]| {
        cycles
            .iter()
            .flat_map(f)
            .fold(0.0, |m: f64, v| m.max(v.abs()))
    };
    let f32_step = |v: f64| v * f64::from(f32::EPSILON);
    let delta_x = 0.5 * 1e-12_f64.max(f32_step(largest(&|c| c.position_m)));
    let max_force = largest(&|c| c.force_n);
    let delta_f = 0.5 * 1e-9_f64.max(f32_step(max_force));
    let (mut force_variation, mut path) = (0.0, 0.0);
    for pair in cycles.windows(2) {
        for i in 0..3 {
            force_variation += (pair[1].force_n[i] - pair[0].force_n[i]).abs();
            path += (pair[1].position_m[i] - pair[0].position_m[i]).abs();
        }
    }
    let rounding = delta_x * (2.0 * max_force + force_variation) + delta_f * path;
    voxhap::servo::passivity::settings::DEFAULT_THRESHOLD_J + unanswered + rounding
}

/// Runs the mock and `serve` for the handle's press; returns the device's log and serve's stderr.
fn press(passivity: &str) -> (Vec<Cycle>, String) {
    let dir = tempfile::tempdir().unwrap();
    let (arm, log, scene_path) = (
        dir.path().join("handle.toml"),
        dir.path().join("handle.csv"),
        dir.path().join("scene.toml"),
    );
    std::fs::write(&arm, HANDLE).unwrap();
    std::fs::write(&scene_path, scene(passivity)).unwrap();
    let mut mock = Mock::start(&[
        "--pty",
        "--arm",
        arm.to_str().unwrap(),
        "--latency-ms",
        "1",
        "--duration",
        "14",
        "--handle-log",
        log.to_str().unwrap(),
    ]);
    let output = crate::util::serve_headless(&format!("mock:{}", mock.path))
        .args(["--scene", scene_path.to_str().unwrap(), "--duration", "10"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .output()
        .expect("run voxhap serve");
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(
        output.status.success(),
        "serve: {}: {stderr}",
        output.status
    );
    loop {
        let line = mock.next_line();
        if line.starts_with("done:") || line.is_empty() {
            assert!(
                line.starts_with("done:"),
                "the mock did not finish: {line:?}"
            );
            break;
        }
    }
    (read_handle_log(&log), stderr)
}

/// The latency serve's notice says the observer pairs with: whole ticks and milliseconds, and the notice.
fn observer_latency(stderr: &str) -> (usize, f64, String) {
    let notice = stderr
        .lines()
        .find(|l| {
            l.starts_with(
                "notice: passivity control: the observer pairs each force with the motion ",
            )
        })
        .unwrap_or_else(|| panic!("no passivity notice: {stderr}"))
        .to_owned();
    let rest = &notice[notice.find("motion ").unwrap() + "motion ".len()..];
    let ticks = rest.split(' ').next().unwrap().parse().unwrap();
    let ms = rest[rest.find('(').unwrap() + 1..]
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    (ticks, ms, notice)
}

#[test]
fn the_measured_link_latency_keeps_a_delayed_stiff_contact_passive_on_the_device() {
    let (on, stderr) = press("mode = \"control\"");
    let (d, latency_ms, notice) = observer_latency(&stderr);
    // The whole chain: the driver measured it (no scene value), and a round trip through a link that holds
    // every reply 1 ms cannot be shorter than 1 ms, so the observer pairs at least one tick.
    assert!(
        notice.contains("driver measured at open") && latency_ms >= 1.0 && d >= 1,
        "{notice}"
    );
    let zero = press("mode = \"control\"\nlatency_s = 0.0").0;
    let off = press("mode = \"off\"").0;
    let pressed = |c: &[Cycle]| {
        c.iter()
            .filter(|c| c.z_m < -0.005 && c.force_n[2] > 0.0)
            .count()
    };
    // The bound counts the link's depth d, the same link in every run, whatever the observer is told.
    let [(on_j, on_bound), (zero_j, zero_bound), (off_j, off_bound)] =
        [&on, &zero, &off].map(|c| (max_given_j(c), bound_j(c, d)));
    eprintln!(
        "{notice}\ncontroller on, measured latency: {} cycles, {} pressing the plane, given at most {:.4} mJ, \
         bound {:.4} mJ; told no latency: {} pressing, {:.4} mJ, bound {:.4} mJ; off: {} pressing, {:.4} mJ, \
         bound {:.4} mJ",
        on.len(),
        pressed(&on),
        on_j * 1e3,
        on_bound * 1e3,
        pressed(&zero),
        zero_j * 1e3,
        zero_bound * 1e3,
        pressed(&off),
        off_j * 1e3,
        off_bound * 1e3
    );
    // Every run pressed the handle into the plane with the force on (the setup did what it says; how long
    // depends on how fast the loaded machine ran the mock's cycles, so only that it did).
    assert!(pressed(&on) > 100 && pressed(&zero) > 100 && pressed(&off) > 100);
    // The derived bound holds only while the link's delay stays within the figure measured at open, and a
    // host that is not real-time breaks that now and then: on the shared 2-core VM, with the machine otherwise
    // idle, the device was given 0.126 mJ against a bound of 0.085 mJ (latency measured 1.3 ms, d = 2). So
    // the bound is printed, not asserted, and what is asserted holds whatever the timing: far less than the
    // same contact gives the device told no latency or with the controller off, and at most ON_LIMIT_J, a
    // tolerance chosen from the runs measured (at most 0.126 mJ), not derived.
    assert!(
        on_j <= ON_LIMIT_J && on_j < zero_j && on_j < off_j,
        "controller on: the device was given up to {on_j} J (derived bound {on_bound} J, limit {ON_LIMIT_J} \
         J); told no latency {zero_j} J; off {off_j} J"
    );
    // The check can fail: paired without the latency the controller books about a third of what the delayed
    // loop generates, and off it books nothing; either way the contact pumps energy into the handle.
    assert!(
        zero_j > zero_bound,
        "told no latency: the device was given at most {zero_j} J, within the bound {zero_bound} J"
    );
    assert!(
        off_j > off_bound,
        "controller off: the device was given at most {off_j} J, within the bound {off_bound} J"
    );
}
