//! Contact stability end to end: sims/contact_stability.toml (the default arm, 0.1 kg and 1 N s/m, released on
//! a plane at 1 kHz) below and above the exact zero-order-hold boundary 2 003 N/m (computed in
//! crates/device/src/sim/boundary_tests.rs), through the `voxhap` binary: the energy ledger in the summary
//! line, the warning, and `--fail-on active,oscillation,beyond-bound`.

use crate::util::sim::{sims_dir, voxhap};
use std::ffi::OsStr;

fn run(k: &str, fail_on: &str, out: &std::path::Path) -> std::process::Output {
    let set = format!("k_n_per_m={k}");
    voxhap(&[
        OsStr::new("sim"),
        sims_dir().join("contact_stability.toml").as_os_str(),
        OsStr::new("--out"),
        out.as_os_str(),
        OsStr::new("--set"),
        OsStr::new(&set),
        OsStr::new("--fail-on"),
        OsStr::new(fail_on),
    ])
}

#[test]
fn below_the_zoh_boundary_contact_settles_and_passes_fail_on_active_and_oscillation() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(
        "1500",
        "active,oscillation,beyond-bound",
        &dir.path().join("t.csv"),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("passivity bound"), "{stderr}");
}

#[test]
fn above_the_zoh_boundary_the_ledger_sees_a_limit_cycle_and_the_bound_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = run("2600", "active,oscillation", &dir.path().join("t.csv"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("oscillation: "), "{stderr}");
    // The warning names the figures the bound came from: damping 1 N s/m, period 1 ms, no latency.
    assert!(
        stderr.contains("warning: k_n_per_m = 2600 N/m is above the arm's passivity bound")
            && stderr.contains("stiffness cap 2000 N/m")
            && stderr.contains("damping 1 N s/m, period 1 ms, latency 0 ms"),
        "{stderr}"
    );
    // The trace is still written.
    assert!(dir.path().join("t.csv").exists());
}

#[test]
fn fail_on_beyond_bound_refuses_to_start() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("t.csv");
    let out = run("2600", "beyond-bound", &trace);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("--fail-on: beyond-bound: k_n_per_m = 2600 N/m"),
        "{stderr}"
    );
    assert!(!trace.exists());
}

/// With 1 ms of transport latency the same arm's bound falls to b / (T/2 + tau) = 667 N/m: 1 500 N/m is
/// refused before the run and bounces when run.
#[test]
fn latency_lowers_the_bound_and_the_arm_feels_it() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("t.csv");
    let out = voxhap(&[
        OsStr::new("sim"),
        sims_dir().join("contact_stability.toml").as_os_str(),
        OsStr::new("--out"),
        trace.as_os_str(),
        OsStr::new("--set"),
        OsStr::new("arm.latency_s=0.001"),
        OsStr::new("--fail-on"),
        OsStr::new("oscillation"),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("stiffness cap 667 N/m"), "{stderr}");
    assert!(stderr.contains("oscillation: "), "{stderr}");
}
