//! `voxhap serve --record` against the Inverse Service double (tests/util/inverse_service.rs, written from Haply's
//! documents), end to end: the trace's columns are checked against what the double sent, read from the CSV file
//! as plain text (not through voxhap's trace reader).
//!
//! - `device_force_{x,y,z}_n` is the `current_cursor_force` of the state the tick used (docs.haply.co tutorial
//!   "01. Print Inverse3": "State fields read ... current_cursor_force"): every value in the trace is one the
//!   double reported (the `haply-inverse` profile's mapping is the identity rotation, and forces are only
//!   rotated between frames: docs/workspace.md), and some are not zero, so the check cannot pass vacuously.
//! - An e-brake on the events channel (docs.haply.co "Events & Monitoring": `device-safety-triggered`,
//!   `safety_type` `ebrake_triggered`) is a device fault: from the first row whose latched faults hold the
//!   emergency stop (bit 1, voxhap's fault table in docs/safety.md), from the next row to the end, the force
//!   sent is zero, the bit stays set, `flag_device_faulted` is true and the force-off cause is `device_fault`.

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

#[test]
fn serve_records_the_arms_force_and_an_ebrake_as_a_device_fault() {
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
    service.ebrake();
    let at_ebrake = reported().len();
    wait_until(&mut child, "300 states after the e-brake", || {
        reported().len() >= at_ebrake + 300
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

    let sent = reported();
    let csv = Csv::read(&trace);
    assert!(!csv.rows.is_empty(), "an empty trace");
    let mut nonzero = 0;
    let mut faulted_from = None;
    for (i, row) in csv.rows.iter().enumerate() {
        let device_force = csv.vector(row, "device_force");
        if !device_force[0].is_nan() {
            assert!(
                sent.iter()
                    .any(|f| (0..3).all(|k| (f[k] - device_force[k]).abs() <= 1e-12)),
                "row {i}: device force {device_force:?} is none the service reported"
            );
            nonzero += usize::from(device_force.iter().any(|c| *c != 0.0));
        }
        let faults: u64 = csv.cell(row, "device_fault_bits").parse().unwrap();
        // From the row after the one that read the event (that tick's force went out before it was read).
        if let Some(from) = faulted_from {
            let tick = csv.cell(row, "tick");
            assert_ne!(
                faults & (1 << 1),
                0,
                "tick {tick}: the fault bit was cleared"
            );
            assert_eq!(
                csv.vector(row, "force"),
                [0.0; 3],
                "tick {tick} ({} rows after the fault)",
                i - from
            );
            assert_eq!(csv.cell(row, "flag_device_faulted"), "true", "tick {tick}");
            assert_eq!(
                csv.cell(row, "force_off_cause"),
                "device_fault",
                "tick {tick}"
            );
        } else if faults & (1 << 1) != 0 {
            faulted_from = Some(i);
        }
    }
    assert!(
        nonzero > 0,
        "no row carries a non-zero force from the arm: the check above proved nothing"
    );
    let from = faulted_from.expect("no row holds the e-brake's fault bit");
    assert!(
        csv.rows.len() - from >= 100,
        "only {} rows after the fault",
        csv.rows.len() - from
    );
}
