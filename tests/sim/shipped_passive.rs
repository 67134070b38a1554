//! Every shipped sim (sims/*.toml) is passive under its own settings: the energy ledger finds no rise of the
//! net generated energy above its 0.1 mJ tolerance (`--fail-on active`) and no contact limit cycle
//! (`--fail-on oscillation`). A sim meant to be active or unstable says so in a comment line beginning
//! [`ACTIVE_MARK`] with the reason, and must then be flagged by one of the two, so a sim cannot quietly stop
//! showing what it was written to show.
//!
//! The tolerance is the ledger's own (`voxhap_servo::energy::ACTIVE_TOLERANCE_J`, docs/stability.md): what
//! `--fail-on active` refuses. The ledger's net books the least the arm's damping dissipated, so a sim whose
//! hand does work under-reports; the oscillation test covers the contact limit cycles such a hand hides.

use super::sweep::run_text;
use crate::util::sim::sims_dir;
use voxhap::sim::SimSummary;

/// The comment that marks a sim as intentionally active or unstable.
const ACTIVE_MARK: &str = "# passivity: intentionally active";

/// The ledger's verdict: flagged active or oscillating.
fn flagged(summary: &SimSummary) -> bool {
    summary.energy.active() || summary.energy.oscillating()
}

/// Runs a sim's text from the repository root (the brain sim names its scan as `../data/...`, outside sims/,
/// which the loader refuses: it is run from the root with the path made relative to it).
fn run_shipped(name: &str, text: &str) -> SimSummary {
    let text = text.replace("\"../data/", "\"data/");
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scenario = voxhap::sim::Scenario::parse(&text, name).unwrap();
    let loaded = scenario.load(root, name).unwrap();
    let mut trace = super::sweep::MemoryTrace::default();
    voxhap::sim::run(
        &loaded,
        voxhap::haptics::tick::SolverKind::Exact,
        &mut trace,
        |_| {},
    )
    .unwrap()
}

#[test]
fn every_shipped_sim_is_passive_unless_it_says_it_is_active() {
    let mut names: Vec<String> = std::fs::read_dir(sims_dir())
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert!(names.len() >= 10, "{names:?}");
    let mut problems = Vec::new();
    for name in &names {
        let text = std::fs::read_to_string(sims_dir().join(name)).unwrap();
        let meant_active = text.lines().any(|l| l.starts_with(ACTIVE_MARK));
        let summary = run_shipped(name, &text);
        let e = summary.energy;
        eprintln!(
            "{name}: largest rise {:.4} mJ, net {:.4} mJ, longest cycle run {}, contacts {}",
            e.largest_rise_j * 1e3,
            e.net_generated_j * 1e3,
            e.longest_cycle_run,
            e.contacts
        );
        if flagged(&summary) != meant_active {
            problems.push(format!(
                "{name}: {} but the ledger {} it (largest rise {} J, longest cycle run {})",
                if meant_active {
                    "marked intentionally active"
                } else {
                    "not marked active"
                },
                if flagged(&summary) {
                    "flags"
                } else {
                    "does not flag"
                },
                e.largest_rise_j,
                e.longest_cycle_run
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The check can fail both ways: contact_stability.toml above its boundary (2 600 N/m, a limit cycle) is
/// flagged, so unmarked it would fail the test above; marked, the passive original would.
#[test]
fn the_passive_check_sees_an_unstable_sim_and_a_wrongly_marked_one() {
    let text = std::fs::read_to_string(sims_dir().join("contact_stability.toml")).unwrap();
    assert!(!flagged(&run_text(&text, "contact_stability.toml").0));
    let unstable = text.replace("k_n_per_m = 1500.0", "k_n_per_m = 2600.0");
    assert_ne!(unstable, text);
    assert!(flagged(&run_text(&unstable, "contact_stability.toml").0));
}
