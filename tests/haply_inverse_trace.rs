//! `voxhap serve --record` against the Inverse Service double (tests/util/inverse_service.rs, written from Haply's
//! documents), end to end: the trace's columns are checked against what the double sent, read from the CSV file
//! as plain text (not through voxhap's trace reader).
//!
//! - `device_force_{x,y,z}_n` is the `current_cursor_force` of the state the tick used (docs.haply.co tutorial
//!   "01. Print Inverse3": "State fields read ... current_cursor_force"): every value in the trace is one the
//!   double reported (the `haply-inverse` profile's mapping is the identity rotation, and forces are only
//!   rotated between frames: docs/workspace.md), and some are not zero, so the check cannot pass vacuously.
//! - Each documented safety event on the events channel (docs.haply.co "Events & Monitoring":
//!   `device-safety-triggered`, table "device-safety-triggered sub-types": `ebrake_triggered` level error,
//!   `stall_detected` and `stability_ceiling` level warning) is the device fault docs/devices/haply-inverse3.md
//!   names for it, with the code of voxhap's fault table (docs/safety.md: 1 emergency stop, 8 motor stall,
//!   9 stability ceiling reached): from the row after the first one whose latched faults hold that bit to the
//!   end, the force sent is zero, the latched faults are that bit alone, `flag_device_faulted` is true and the
//!   force-off cause is `device_fault` (or, on rows where a busy machine's link is down or has just come back,
//!   a cause docs/traces.md ranks before it and possibly no fault; at least 100 rows name the fault, and the
//!   last row still holds it); stderr names the fault as docs/safety.md shows it (`device FAULT motor stall
//!   (code 8, ...`). The arm's side, from the double's log of what it received: every non-zero force is, in
//!   order, one the trace's rows sent, and none of them was sent after the fault's row.
//! - A control-rate report (Haply's client's `system-rate-report`, crate `haply` 1.3.1,
//!   src/interfaces/events.rs) is a notice: stderr carries its four frequencies as the double sent them, and
//!   nothing is faulted by it.

use crate::util::inverse_service::InverseService;
use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// The CSV trace as rows of named text cells.
struct Csv {
    columns: HashMap<String, usize>,
    rows: Vec<Vec<String>>,
}

impl Csv {
    fn read(path: &std::path::Path) -> Csv {
        let text = std::fs::read_to_string(path).expect("read the trace");
        let mut lines = text.lines().skip_while(|line| !line.starts_with("tick,"));
        let header = lines.next().expect("the trace has a header line");
        let columns = header
            .split(',')
            .enumerate()
            .map(|(i, name)| (name.to_owned(), i))
            .collect();
        let rows = lines
            .filter(|line| !line.is_empty())
            .map(|line| line.split(',').map(str::to_owned).collect())
            .collect();
        Csv { columns, rows }
    }

    fn cell<'a>(&self, row: &'a [String], name: &str) -> &'a str {
        let at = *self
            .columns
            .get(name)
            .unwrap_or_else(|| panic!("the trace has no column {name}"));
        &row[at]
    }

    fn f64(&self, row: &[String], name: &str) -> f64 {
        let cell = self.cell(row, name);
        cell.parse()
            .unwrap_or_else(|_| panic!("{name}: {cell:?} is not a number"))
    }

    fn vector(&self, row: &[String], prefix: &str) -> [f64; 3] {
        ["x", "y", "z"].map(|axis| self.f64(row, &format!("{prefix}_{axis}_n")))
    }
}

/// Waits up to 120 s for `done`, failing if serve exits first.
fn wait_until(child: &mut std::process::Child, what: &str, done: impl Fn() -> bool) {
    let start = Instant::now();
    while !done() {
        if child.try_wait().unwrap().is_some() || start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("serve exited or 120 s passed waiting for {what}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// What one `serve --record` run against the double gave.
struct Run {
    /// Every `current_cursor_force` the double reported.
    reported: Vec<[f64; 3]>,
    /// Every force vector the double received, in order.
    received: Vec<[f64; 3]>,
    csv: Csv,
    /// stderr, then stdout.
    said: String,
}

/// Runs `voxhap serve --record` against the double with the handle sweeping the reachable box; once force
/// flows and the events channel is connected, `before` runs, then `event`; 300 states later serve is stopped.
fn serve_through(before: impl Fn(&InverseService), event: impl Fn(&InverseService)) -> Run {
    use std::process::Stdio;
    let _turn = crate::util::spec_serve::take_turn();
    let service = InverseService::start();
    // The handle moves through the whole reachable box, through the scene's fields and surfaces.
    service.sweep();
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("trace.csv");
    let mut child = crate::util::serve_headless(&format!(
        "haply-inverse:{},events={}",
        service.url(),
        service.events_url()
    ))
    .arg("--record")
    .arg(&trace)
    .stdout(Stdio::piped())
    .stderr(Stdio::piped())
    .spawn()
    .expect("start voxhap serve");
    let reported = || service.shared.reported_forces.lock().unwrap().clone();
    // Force reached the arm and came back as current_cursor_force, on the events channel's watch.
    wait_until(&mut child, "a force reported back", || {
        reported().iter().any(|f| f.iter().any(|c| *c != 0.0))
            && service
                .shared
                .event_clients_accepted
                .load(Ordering::Acquire)
                > 0
    });
    before(&service);
    let at_before = reported().len();
    wait_until(&mut child, "50 states after the first event", || {
        reported().len() >= at_before + 50
    });
    event(&service);
    let at_event = reported().len();
    wait_until(&mut child, "300 states after the event", || {
        reported().len() >= at_event + 300
    });
    // SAFETY: plain kill(2) on our own child's pid.
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) },
        0
    );
    let output = child.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&output.stderr).into_owned()
        + &String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{said}");
    // Shown when a test fails (or with --nocapture): what serve said, e.g. why a link dropped.
    eprintln!("voxhap serve said:\n{said}");
    let csv = Csv::read(&trace);
    assert!(!csv.rows.is_empty(), "an empty trace");
    Run {
        reported: reported(),
        received: service.forces(),
        csv,
        said,
    }
}

/// What the arm was sent, from the double's own log: every force finite and within the host's 3 N force limit
/// (docs/safety.md, the limits table: min(host limit 3 N, the device's `max_force_n`)), and the last one zero
/// (serve's stop zeroes the arm before it exits).
fn assert_what_the_arm_received_is_safe(run: &Run) {
    assert!(!run.received.is_empty(), "the double received no force");
    for f in &run.received {
        let norm = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        assert!(
            norm.is_finite() && norm <= 3.0 + 1e-9,
            "the arm was sent {f:?}"
        );
    }
    assert_eq!(
        *run.received.last().unwrap(),
        [0.0; 3],
        "the last force the arm received"
    );
}

/// The arm's log against the trace: every non-zero force the double received is, in order, one the trace's
/// rows sent (its `force` column; the profile's mapping is the identity rotation, so the frames agree). The
/// I/O thread may coalesce queued forces to the newest, so some rows' forces never go out, and zeros can come
/// from no row (a dropped link, serve's stop), so zeros are not matched. Returns the row the last non-zero
/// force the arm received was sent on: no non-zero force reached the arm from a later row.
fn last_row_whose_force_reached_the_arm(run: &Run) -> usize {
    let sent: Vec<[f64; 3]> = run
        .csv
        .rows
        .iter()
        .map(|row| run.csv.vector(row, "force"))
        .collect();
    let (mut next, mut last) = (0, None);
    for (i, f) in run.received.iter().enumerate() {
        if *f == [0.0; 3] {
            continue;
        }
        let at = sent[next..]
            .iter()
            .position(|s| (0..3).all(|k| (s[k] - f[k]).abs() <= 1e-12))
            .unwrap_or_else(|| {
                panic!(
                    "force {i} the arm received, {f:?}, is no force the trace sent after row {next} \
                     (of {})",
                    sent.len()
                )
            });
        last = Some(next + at);
        next += at + 1;
    }
    last.expect("the arm received no non-zero force: the check proved nothing")
}

/// The checks of the module docs for a device fault with `code`, named `name` in docs/safety.md's table: from
/// the row after the first that holds the bit, to the end, zero force, that bit alone, flagged, the cause
/// named; no row before it is faulted. Returns the rows before the fault. On a busy machine the link may
/// drop and reconnect meanwhile: docs/traces.md lists `disconnected` and `stale_link` before `device_fault`
/// ("the first that applies"), so those rows may carry them, and a row without a link (or the first row of a
/// new link, whose faults and flags the supervisor sets before the new link reports the latched fault again)
/// may report no fault; but the force stays zero, no other fault appears, every row of a settled link holds
/// the fault, at least 100 rows name it, and the last row still holds it (a reconnect does not clear it).
fn assert_faulted_from_the_next_row(run: &Run, code: u32, name: &str) -> usize {
    assert_what_the_arm_received_is_safe(run);
    let csv = &run.csv;
    let bit = 1u64 << code;
    let mut faulted_from = None;
    let (mut named, mut link_was_down) = (0, false);
    for (i, row) in csv.rows.iter().enumerate() {
        let faults: u64 = csv.cell(row, "device_fault_bits").parse().unwrap();
        let tick = csv.cell(row, "tick");
        // From the row after the one that read the event (that tick's force went out before it was read).
        if let Some(from) = faulted_from {
            assert_eq!(
                csv.vector(row, "force"),
                [0.0; 3],
                "tick {tick} ({} rows after the fault)",
                i - from
            );
            let cause = csv.cell(row, "force_off_cause");
            assert!(
                ["device_fault", "disconnected", "stale_link"].contains(&cause),
                "tick {tick}: force-off cause {cause}"
            );
            let link_down = cause != "device_fault";
            if link_down || link_was_down {
                assert!(
                    faults == bit || faults == 0,
                    "tick {tick}: latched faults {faults:#x} (cause {cause})"
                );
            } else {
                assert_eq!(faults, bit, "tick {tick}: latched faults {faults:#x}");
                assert_eq!(csv.cell(row, "flag_device_faulted"), "true", "tick {tick}");
            }
            named += usize::from(!link_down);
            link_was_down = link_down;
        } else if faults & bit != 0 {
            faulted_from = Some(i);
        } else {
            assert_eq!(
                faults, 0,
                "tick {tick}: latched faults {faults:#x} before any row holds bit {code} ({name})"
            );
        }
    }
    let last = csv
        .rows
        .last()
        .map(|row| csv.cell(row, "device_fault_bits"));
    assert_eq!(
        last,
        Some(bit.to_string().as_str()),
        "the last row's latched faults: the fault must outlast any reconnect"
    );
    let from = faulted_from.unwrap_or_else(|| panic!("no row holds fault bit {code} ({name})"));
    // The zero rows from the one after the fault on are zero at the arm too, from the double's own log.
    let last_pushed = last_row_whose_force_reached_the_arm(run);
    assert!(
        last_pushed <= from,
        "the arm received the non-zero force of row {last_pushed}, after the fault's row {from}"
    );
    assert!(
        named >= 100,
        "only {named} of the {} rows after the fault name it as the cause",
        csv.rows.len() - from
    );
    let told = format!("device FAULT {name} (code {code}, ");
    assert!(
        run.said.contains(&told),
        "stderr does not name the fault as {told:?}: {}",
        run.said
    );
    from
}

#[test]
fn serve_records_the_arms_force_and_an_ebrake_as_a_device_fault() {
    let run = serve_through(|_| {}, InverseService::ebrake);
    let csv = &run.csv;
    let mut nonzero = 0;
    for (i, row) in csv.rows.iter().enumerate() {
        let device_force = csv.vector(row, "device_force");
        if !device_force[0].is_nan() {
            assert!(
                run.reported
                    .iter()
                    .any(|f| (0..3).all(|k| (f[k] - device_force[k]).abs() <= 1e-12)),
                "row {i}: device force {device_force:?} is none the service reported"
            );
            nonzero += usize::from(device_force.iter().any(|c| *c != 0.0));
        }
    }
    assert!(
        nonzero > 0,
        "no row carries a non-zero force from the arm: the check above proved nothing"
    );
    assert_faulted_from_the_next_row(&run, 1, "emergency stop");
}

/// A stall (`stall_detected`) after a control-rate report: the report is a notice carrying Haply's
/// frequencies, the stall the motor-stall fault; force flowed before it, so the zero after it is the fault's.
#[test]
fn serve_records_a_stall_as_a_motor_stall_fault_after_a_rate_notice() {
    let run = serve_through(
        |service| service.rate_report(310, 1020, 900, 950),
        |service| service.safety_event("stall_detected"),
    );
    // Every problem at once: the rate notice's, then the fault's (its own assertion message is printed above).
    let missing: Vec<&str> = [
        "min_frequency 310",
        "max_frequency 1020",
        "mean_frequency 900",
        "median_frequency 950",
    ]
    .into_iter()
    .filter(|frequency| !run.said.contains(frequency))
    .collect();
    let fault =
        std::panic::catch_unwind(|| assert_faulted_from_the_next_row(&run, 8, "motor stall"));
    assert!(
        missing.is_empty() && fault.is_ok(),
        "the rate report's {missing:?} not on stderr; the stall's fault checks {}: {}",
        if fault.is_ok() { "passed" } else { "failed" },
        run.said
    );
    let from = fault.unwrap();
    let pushed = run.csv.rows[..from]
        .iter()
        .filter(|row| run.csv.vector(row, "force").iter().any(|c| *c != 0.0))
        .count();
    assert!(
        pushed > 0,
        "no force before the stall: the zero after it proves nothing"
    );
}

/// Haply's stability ceiling (`stability_ceiling`) is its own fault (9), not a notice.
#[test]
fn serve_records_the_stability_ceiling_as_its_own_fault() {
    let run = serve_through(|_| {}, |service| service.safety_event("stability_ceiling"));
    assert_faulted_from_the_next_row(&run, 9, "stability ceiling reached");
}
