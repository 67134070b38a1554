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
//! longest round trip of the run rounded up to whole ticks), and the damping the controller sends in answer reaches the
//! handle `d` ticks after that, held for one more. So at any time the controller has answered all the energy
//! the device was given but that of at most the last `2 (d + 1)` control cycles, and
//! `max_t W(t) <= threshold_j + max over any 2 (d + 1) consecutive cycles of sum max(0, F_c . dx_c)`
//! (the unobserved window at the power the log shows in it) `+ q`, where `q` bounds the rounding of positions
//! and forces (summed by parts: `delta_x (2 max|F| + sum |dF|) + delta_F sum |dx|`, with `delta_x` half the
//! larger of the log's 1e-12 m and an f32's step at the largest position on the wire, `delta_F` half the
//! larger of 1e-9 N and an f32's step at the largest force). Both sides come from the device's log.
//!
//! **Which `d`.** The window's `d` is the link's depth during the run, not at open, and its longest, not
//! its usual: a host that is not real-time sometimes answers later than the round trips open measured (on
//! the shared 2-core VM, otherwise idle, a run once gave 0.126 mJ against a bound of 0.085 mJ computed with
//! open's `d` = 2), and a stall (the servo thread or the device double not running for a while) holds one
//! force on the handle over every cycle of it, cycles whose motion the host sees only after the stall and
//! answers a round trip later. A round trip runs from the write of a force to the decoding of the State
//! that echoes it, so it covers both the motion's way to the host and the force's way to the device, and
//! any stall between them; at any time a force is on the wire (the servo writes before it reads), so every
//! stall lies inside some round trip. The protocol driver times the round trip of every force it sends and
//! serve's run summary prints the longest (`link delay: worst round trip seen ... ms (d ticks)`): the bound
//! of each run takes the `d` of that run. A stall of `S` ticks makes the round trip it lies in at least `S`
//! ticks long, so `d >= S` as well as `d >= u`, the usual round trip's ticks, and the window
//! `2 (d + 1) >= S + u + 2` covers the stall's `S` cycles and the answer to the last of them (a round trip,
//! both ways, held one more cycle).
//!
//! **Which pairing.** The observer's pairing is another figure: the delay of each step in ticks, which a
//! stall does not change (the servo loop skips the ticks it missed, the mock skips the cycles it missed, and
//! the step that spans a stall was moved under the last force sent before it). The observer pairs with the
//! median round trip the driver timed plus one servo period (a tick long rather than short on a loaded
//! host), never below open's figure (`voxhap_servo::passivity::link_delay`), and the test checks that from
//! the run summary. Paired with a stall's length instead, the observer would book every later step with a
//! force sent that much too early and, for this contact's 24 Hz, book the loop's generation as absorbed
//! (docs/stability.md, "While the servo runs").
//!
//! The bound must fail with the controller off, and is asserted to (against that run's own bound: a late
//! host only adds delay and so only more energy). Told no latency (`latency_s = 0`), the controller must let
//! more through than when told the measured one; that run's own bound is printed, not asserted (below). Measured on the shared 2-core VM, 15 runs (10 at load average 6 to 9 while other builds ran,
//! 5 at about 1): with the controller on the device was given at most 0.0052 mJ, always within the bound
//! computed with that run's `d` (6 to 18; the bound at least 1.9 times what was given); told no latency
//! 0.016 mJ once (bound 0.011 mJ) and 29 to 81 mJ otherwise; off 225 to 372 mJ. One run of the 15 failed
//! before the bound: the controller-on run never pressed the plane (its driver had timed only half the
//! run's round trips, so the link had most likely been lost and reopened).
//!
//! **A run that did not press, or pressed too briefly.** On a busy machine the force's engagement can start
//! over while the hand holds the handle in the plane: after a dropped and reopened link, a servo thread
//! stalled past the host watchdog or the stall monitor (20 ms), or a device watchdog trip. Force then ramps in
//! only once the rendered force has been small (at most 1 N, docs/safety.md), which it never is while the
//! handle stays 3 mm deep (6 N): that run has too little contact to show anything, and the host did the right
//! thing. A stall can also make the run's `d` so large that its window `2 (d + 1)` covers most of the
//! contact, and then neither check means anything: if every step with work lies within one window, that
//! window's positive work is at least `max_t W(t)`, so the bound holds whatever the controller did (the
//! controller-on check cannot fail) and the controller-off check cannot pass. A contact longer than one
//! window is therefore necessary for either check to decide; [`press`] asks for more than four windows (the
//! window forgives at most a quarter of the contact; one ordinary run on the shared 2-core VM had 5 024,
//! 3 625 and 1 846 steps with work at `d` = 9, 22 and 29: 250, 80 and 30 windows) and more than 100 cycles
//! pressing the plane. It runs a run that falls short again (at most three runs in all) and says why in the
//! test's output; a setup that never presses long enough still fails. Every assertion below is made on runs
//! that did.

use crate::util::mock_process::{pressing_handle, MockProcess as Mock};
use std::path::Path;

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

/// What serve's run summary says of the link's delay (its `link delay:` line): the longest round trip the
/// driver timed during the run, in ticks and ms, their median (ms), the ticks the observer paired with at
/// the end, the times that pairing changed, and the line.
struct LinkDelay {
    worst_ticks: usize,
    worst_ms: f64,
    median_ms: f64,
    observer_ticks: usize,
    changes: u64,
    /// Device disconnects in the run (the summary's `disconnects N`): each reconnect measures the link again.
    disconnects: u64,
    line: String,
}

fn link_delay(stdout: &str) -> LinkDelay {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("link delay: worst round trip seen "))
        .unwrap_or_else(|| panic!("no link delay line in the run summary: {stdout}"))
        .to_owned();
    // The number after `before`, up to the next space or bracket.
    let after = |before: &str| -> f64 {
        let rest = &line[line
            .find(before)
            .unwrap_or_else(|| panic!("{before:?}: {line}"))
            + before.len()..];
        rest.split([' ', ')', ','])
            .next()
            .unwrap()
            .parse()
            .unwrap_or_else(|e| panic!("{before:?} in {line}: {e}"))
    };
    let disconnects = stdout
        .split("disconnects ")
        .nth(1)
        .and_then(|rest| rest.split([',', ' ']).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no disconnect count in the run summary: {stdout}"));
    LinkDelay {
        disconnects,
        worst_ms: after("worst round trip seen "),
        worst_ticks: after(" ms (") as usize,
        median_ms: after("median "),
        observer_ticks: after("observer pairs ") as usize,
        changes: after("(changed ") as u64,
        line: line.clone(),
    }
}

/// The control cycles in which the handle was in the plane with the host's force pushing it out.
fn pressed(cycles: &[Cycle]) -> usize {
    cycles
        .iter()
        .filter(|c| c.z_m < -0.005 && c.force_n[2] > 0.0)
        .count()
}

/// The steps in which the held force did work on the handle (non-zero `F_c . dx_c`): the contact.
fn contact_steps(cycles: &[Cycle]) -> usize {
    step_work_j(cycles).iter().filter(|w| **w != 0.0).count()
}

/// The contact a run needs before its bound can decide anything: more than four of the bound's windows of
/// `2 (d + 1)` steps (module docs, "A run that did not press, or pressed too briefly").
fn contact_needed(d: usize) -> usize {
    4 * 2 * (d + 1)
}

/// [`press_once`] until the run pressed the plane in more than 100 cycles and its contact was longer than
/// [`contact_needed`] for the run's own `d`, at most three runs (module docs, "A run that did not press, or
/// pressed too briefly").
fn press(passivity: &str) -> (Vec<Cycle>, String, LinkDelay) {
    let mut stderr_of_last = String::new();
    for run in 1..=3 {
        let (cycles, stderr, link) = press_once(passivity);
        let (count, contact) = (pressed(&cycles), contact_steps(&cycles));
        let needed = contact_needed(link.worst_ticks);
        if count > 100 && contact > needed {
            return (cycles, stderr, link);
        }
        eprintln!(
            "{passivity:?}, run {run}: {count} cycles pressing the plane, {contact} steps with work against \
             more than {needed} needed at d = {} ({} disconnects; {}); run again",
            link.worst_ticks, link.disconnects, link.line
        );
        stderr_of_last = stderr;
    }
    panic!(
        "{passivity:?}: three runs did not press the plane long enough; serve's stderr of the last: \
         {stderr_of_last}"
    );
}

/// Runs the mock and `serve` for the handle's press; returns the device's log, serve's stderr and what its
/// run summary says of the link's delay.
fn press_once(passivity: &str) -> (Vec<Cycle>, String, LinkDelay) {
    let dir = tempfile::tempdir().unwrap();
    let (arm, log, scene_path) = (
        dir.path().join("handle.toml"),
        dir.path().join("handle.csv"),
        dir.path().join("scene.toml"),
    );
    // The hand waits above the plane while serve connects and engages (up 10 mm over 2 s), then presses the
    // handle 3 mm past the plane and holds it there (util::mock_process).
    std::fs::write(&arm, pressing_handle(0.01)).unwrap();
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
        .stdout(std::process::Stdio::piped())
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
    let summary = link_delay(&String::from_utf8_lossy(&output.stdout));
    (read_handle_log(&log), stderr, summary)
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
    let (on, stderr, on_link) = press("mode = \"control\"");
    let (d_open, latency_ms, notice) = observer_latency(&stderr);
    // The whole chain: the driver measured it (no scene value), and a round trip through a link that holds
    // every reply 1 ms cannot be shorter than 1 ms, so the observer pairs at least one tick, at open and
    // during the run. Without a reconnect (which measures the link again and replaces the figure) the
    // pairing at the end is the median round trip the driver timed plus one period, in whole ticks, or
    // open's figure if that is longer (module docs, "Which pairing"); it changed during the run if it is
    // not open's.
    assert!(
        notice.contains("driver measured at open") && latency_ms >= 1.0 && d_open >= 1,
        "{notice}"
    );
    assert!(
        on_link.worst_ms >= 1.0 && on_link.worst_ticks >= 1 && on_link.observer_ticks >= 1,
        "{notice}\n{}",
        on_link.line
    );
    if on_link.disconnects == 0 {
        let median_ticks =
            voxhap::device::latency::ticks_rounded_up(on_link.median_ms * 1e-3 + 1e-3, 1e-3)
                as usize;
        assert!(
            on_link.observer_ticks == median_ticks.max(d_open).min(255)
                && (on_link.observer_ticks == d_open || on_link.changes > 0),
            "{notice}\n{}",
            on_link.line
        );
    }
    let (zero, _, zero_link) = press("mode = \"control\"\nlatency_s = 0.0");
    let (off, _, off_link) = press("mode = \"off\"");
    // Told its latency, the observer keeps it: the scene's 0 never changes.
    assert_eq!(zero_link.observer_ticks, 0, "{}", zero_link.line);
    // Each run's bound counts the link's depth that run: the longest round trip its driver timed, in ticks.
    let [(on_j, on_bound), (zero_j, zero_bound), (off_j, off_bound)] =
        [(&on, &on_link), (&zero, &zero_link), (&off, &off_link)]
            .map(|(c, link)| (max_given_j(c), bound_j(c, link.worst_ticks)));
    eprintln!(
        "{notice}\ncontroller on: {}; {} cycles, {} pressing the plane, {} with work, given at most {:.4} mJ, \
         bound {:.4} mJ (d = {}); told no latency: {} pressing, {} with work, {:.4} mJ, bound {:.4} mJ (d = {}); \
         off: {} pressing, {} with work, {:.4} mJ, bound {:.4} mJ (d = {})",
        on_link.line,
        on.len(),
        pressed(&on),
        contact_steps(&on),
        on_j * 1e3,
        on_bound * 1e3,
        on_link.worst_ticks,
        pressed(&zero),
        contact_steps(&zero),
        zero_j * 1e3,
        zero_bound * 1e3,
        zero_link.worst_ticks,
        pressed(&off),
        contact_steps(&off),
        off_j * 1e3,
        off_bound * 1e3,
        off_link.worst_ticks
    );
    // Every run pressed the handle into the plane with the force on (`press` ran it again when it did not;
    // how long depends on how fast the loaded machine ran the mock's cycles, so only that it did).
    // The derived bound (module docs), with the delay the driver actually saw during the run.
    assert!(
        on_j <= on_bound,
        "controller on: the device was given up to {on_j} J, above the derived bound {on_bound} J ({})",
        on_link.line
    );
    assert!(
        on_j < zero_j && on_j < off_j,
        "controller on: the device was given up to {on_j} J; told no latency {zero_j} J; off {off_j} J"
    );
    // The check can fail: off, the controller books nothing and the contact pumps energy into the handle
    // far past the bound. (Paired without the latency it books about a third of what the delayed loop
    // generates; that run exceeded its own bound in 14 of 15 runs, once by only 1.4 times, so only its
    // comparison with the controller-on run above is asserted, and its bound is printed.)
    assert!(
        off_j > off_bound,
        "controller off: the device was given at most {off_j} J, within the bound {off_bound} J"
    );
}

/// The necessary condition behind [`contact_needed`], on a made-up log: an energy-pumping contact (the held
/// force in phase with the motion, so every step's work is positive and `W` only grows) whose steps with
/// work all lie within one window meets the bound whatever it pumped, and the same contact spread over many
/// windows exceeds it.
#[test]
fn a_contact_within_one_window_meets_its_bound_whatever_it_pumped() {
    // A handle oscillating about z = -5 mm with a growing amplitude, the force held on it `+z` while it moves
    // up and `-z` while it moves down: `F_c . dx_c > 0` on every step, so `max_t W(t)` is the total work.
    let log = |steps: usize| -> Vec<Cycle> {
        (0..=steps)
            .map(|c| {
                let amplitude = 1e-4 * (1.0 + c as f64 * 0.05);
                let z = -0.005 + amplitude * (c as f64 * 0.3).sin();
                let dz = -0.005 + amplitude * ((c + 1) as f64 * 0.3).sin() - z;
                let force = [0.0, 0.0, 6.0 * dz.signum()];
                Cycle {
                    z_m: z,
                    position_m: [0.0, 0.0, z],
                    force_n: force,
                }
            })
            .collect()
    };
    let d = 10;
    let window = 2 * (d + 1);
    let short = log(window - 1);
    assert!(contact_steps(&short) <= window);
    assert!(max_given_j(&short) > 0.0 && max_given_j(&short) <= bound_j(&short, d));
    let long = log(contact_needed(d) + 1);
    assert!(contact_steps(&long) > contact_needed(d));
    assert!(
        max_given_j(&long) > bound_j(&long, d),
        "{} J within the bound {} J",
        max_given_j(&long),
        bound_j(&long, d)
    );
}
