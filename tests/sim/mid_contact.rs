//! Damping, transfer-function and haptic-mode changes made in the middle of a contact, scripted with a sim's
//! `[[events]]` at the bottom of a press-and-leave cycle, end to end through the sim runner and its energy
//! ledger (docs/stability.md, "Changes in contact").
//!
//! Expected values come from the physics: over the closed cycle the change may give the hand no more energy
//! than the same cycle without it, beyond the sampled coupling's own zero-order-hold share
//! `k/2 Σ|Δx|²` of the run (the most a sampled spring held against the arm's motion generates, which the
//! arm's damping `b` absorbs while `b > k T/2`: Colgate and Schenkel 1997); and the force sent may rise by
//! no more than the safety pipeline's default slew limit, 0.5 N per millisecond (docs/safety.md), from one
//! tick to the next around the change. Applied at once (`[passivity] mode = "off"`), the mode switch jumps by
//! more than that: the continuity check can fail.

use super::sweep::run_text;
use voxhap::record::TraceSample;
use voxhap::sim::SimSummary;

/// The safety pipeline's default slew limit (N per ms; crates/device/src/safety.rs `SafetyConfig`).
const SLEW_N_PER_MS: f64 = 0.5;

/// A press-and-leave cycle on planes at 1 kHz, k = 500 N/m, the default arm (0.1 kg, 1 N s/m): the hand
/// (300 N/m grip) moves from 5 mm above the plane at z = 0 to 6 mm below it and back out to 10 mm above, at
/// 2 cm/s; the bottom of the press is at t = 0.55 s. `modes` are the `[[modes]]` tables, `events` the
/// `[[events]]` tables, `extra` any further tables.
fn press_cycle(events: &str, modes: &str, extra: &str) -> String {
    format!(
        "name = \"mid-contact\"\nduration_s = 1.6\nk_n_per_m = 500.0\nvolumes = []\n\n{events}\n{modes}\n\
         [arm]\nmass_kg = 0.1\ndamping_n_s_per_m = 1.0\nworkspace = {{ shape = \"unbounded\" }}\n\n\
         [hand]\nstiffness_n_per_m = 300.0\ndamping_n_s_per_m = 4.0\n\n[path]\nkind = \"waypoints\"\n\
         points_m = [[0.0, 0.0, 0.005], [0.0, 0.0, -0.006], [0.0, 0.0, 0.01]]\nspeed_m_per_s = 0.02\n{extra}"
    )
}

const TABLE: &str =
    "[[modes]]\nkind = \"support_plane\"\nname = \"table\"\npoint_m = [0.0, 0.0, 0.0]\n\
                     normal = [0.0, 0.0, 1.0]\nstrength_n = 50.0\n";
/// A second plane 2 mm above the table, off until an event switches it on.
const RAISED: &str = "[[modes]]\nkind = \"support_plane\"\nname = \"raised\"\nenabled = false\n\
                      point_m = [0.0, 0.0, 0.002]\nnormal = [0.0, 0.0, 1.0]\nstrength_n = 50.0\n";

/// What a run gave the hand and how its force moved.
struct Cycle {
    summary: SimSummary,
    samples: Vec<TraceSample>,
}

impl Cycle {
    fn run(text: &str) -> Cycle {
        let (summary, samples) = run_text(text, "mid-contact");
        Cycle { summary, samples }
    }

    /// The ledger's generated energy over the run (J).
    fn generated_j(&self) -> f64 {
        self.summary.energy.generated_j
    }

    /// The zero-order-hold share `k/2 Σ|Δx|²` of the run at stiffness `k` (J).
    fn hold_share_j(&self, k: f64) -> f64 {
        self.samples
            .windows(2)
            .map(|p| 0.5 * k * (p[1].probe_m - p[0].probe_m).length_squared())
            .sum()
    }

    /// The largest rise of the sent force's magnitude from one tick to the next (N).
    fn largest_rise_n(&self) -> f64 {
        self.samples
            .windows(2)
            .map(|p| p[1].force_n.length() - p[0].force_n.length())
            .fold(0.0, f64::max)
    }

    /// The force at the event tick is that of a probe in contact.
    fn in_contact_at(&self, t_s: f64) -> bool {
        self.samples
            .iter()
            .find(|s| s.t_s >= t_s - 1e-9)
            .is_some_and(|s| s.force_n.length() > 0.5)
    }
}

/// Runs the cycle with and without `events` and checks the two rules of the module docs; returns the run
/// with the events for further checks.
fn check_change(what: &str, events: &str, modes: &str, extra: &str, k_max: f64) -> Cycle {
    let without = Cycle::run(&press_cycle("", modes, extra));
    let with = Cycle::run(&press_cycle(events, modes, extra));
    assert!(with.summary.events_applied >= 1, "{what}: no event applied");
    assert!(
        without.in_contact_at(0.55),
        "{what}: the event is not in contact"
    );
    let tolerance = with.hold_share_j(k_max);
    eprintln!(
        "{what}: generated with {:.5} mJ, without {:.5} mJ, tolerance {:.5} mJ, largest rise {:.4} N (without {:.4} N), \
         {} introduced passively",
        with.generated_j() * 1e3,
        without.generated_j() * 1e3,
        tolerance * 1e3,
        with.largest_rise_n(),
        without.largest_rise_n(),
        with.summary.changes_introduced
    );
    assert!(
        with.generated_j() <= without.generated_j() + tolerance,
        "{what}: generated {} J with the change, {} J without, tolerance {} J",
        with.generated_j(),
        without.generated_j(),
        tolerance
    );
    assert!(!with.summary.energy.oscillating(), "{what}: a limit cycle");
    // 1 ms ticks: the slew limit is the most the force may rise from one tick to the next.
    let slew = SLEW_N_PER_MS;
    assert!(
        with.largest_rise_n() <= slew,
        "{what}: the force rose by {} N in one tick (slew limit {slew} N)",
        with.largest_rise_n()
    );
    with
}

#[test]
fn a_damping_change_in_contact_is_passive_and_continuous() {
    // 0 -> 0.5 N s/m of coupling damping at the bottom of the press; the bound b > k T/2 + B allows
    // 1 - 0.25 = 0.75 N s/m.
    let events = "[[events]]\nt_s = 0.55\ncommand = \"set_damping\"\ndamping = 0.5\n";
    check_change("set_damping", events, TABLE, "", 500.0);
}

#[test]
fn a_mode_switch_in_contact_is_passive_and_continuous_and_at_once_it_jumps() {
    // The table is switched off and a plane 2 mm above it on, in the same tick: at once the force would jump
    // by k 2 mm = 1 N, twice the slew limit.
    let events = "[[events]]\nt_s = 0.55\ncommand = \"set_mode_enabled\"\nmode = \"table\"\nenabled = false\n\n\
                  [[events]]\nt_s = 0.55\ncommand = \"set_mode_enabled\"\nmode = \"raised\"\nenabled = true\n";
    let modes = format!("{TABLE}\n{RAISED}");
    let with = check_change("mode switch", events, &modes, "", 500.0);
    assert_eq!(with.summary.changes_introduced, 1);
    let at_once = Cycle::run(&press_cycle(
        events,
        &modes,
        "\n[passivity]\nmode = \"off\"\n",
    ));
    assert!(
        at_once.largest_rise_n() > SLEW_N_PER_MS,
        "at once: largest rise {} N",
        at_once.largest_rise_n()
    );
}

#[test]
fn a_transfer_change_in_contact_is_passive_and_continuous() {
    // A surface on the built-in ball (radius 3 cm) pressed from above until it yields at its strength, 2 N;
    // at the bottom of the press the transfer function halves the strength, so the proxy breaks through to
    // where the spring pulls with 1 N. The surface's plane passes through the proxy, so a transfer change
    // never moves the proxy towards the hand: it can only lower the force (docs/modes.md).
    let text = |events: &str, extra: &str| {
        format!(
            "name = \"mid-contact-transfer\"\nduration_s = 1.6\nk_n_per_m = 500.0\n\n[[volumes]]\nname = \"density\"\n\
             builtin = \"sphere\"\n\n{events}\n[[modes]]\nkind = \"surface\"\nname = \"skin\"\nvolume = \"density\"\n\
             transfer = [[0.45, 0.0], [0.5, 2.0]]\n\n[arm]\nmass_kg = 0.1\ndamping_n_s_per_m = 1.0\n\
             workspace = {{ shape = \"unbounded\" }}\n\n[hand]\nstiffness_n_per_m = 300.0\ndamping_n_s_per_m = 4.0\n\n\
             [path]\nkind = \"waypoints\"\npoints_m = [[0.0, 0.0, 0.035], [0.0, 0.0, 0.024], [0.0, 0.0, 0.04]]\n\
             speed_m_per_s = 0.02\n{extra}"
        )
    };
    let events = "[[events]]\nt_s = 0.55\ncommand = \"set_transfer\"\nmode = \"skin\"\n\
                  transfer = [[0.45, 0.0], [0.5, 1.0]]\n";
    let without = Cycle::run(&text("", ""));
    let with = Cycle::run(&text(events, ""));
    let at_once = Cycle::run(&text(events, "\n[passivity]\nmode = \"off\"\n"));
    assert_eq!(with.summary.events_applied, 1);
    assert!(without.in_contact_at(0.55), "the event is not in contact");
    let tolerance = with.hold_share_j(500.0);
    eprintln!(
        "set_transfer: generated with {:.5} mJ, without {:.5} mJ, at once {:.5} mJ, tolerance {:.5} mJ, largest \
         rise {:.4} N (at once {:.4} N), {} introduced passively",
        with.generated_j() * 1e3,
        without.generated_j() * 1e3,
        at_once.generated_j() * 1e3,
        tolerance * 1e3,
        with.largest_rise_n(),
        at_once.largest_rise_n(),
        with.summary.changes_introduced
    );
    // The change acted: 10 ms after it the force is held to the new strength, 1 N, where the run without
    // it pulls harder.
    let after = |c: &Cycle| c.samples[560].force_n.length();
    assert!(
        after(&with) <= 1.0 + 1e-9 && after(&without) > 1.0,
        "force after the change {} N, without it {} N",
        after(&with),
        after(&without)
    );
    assert!(with.generated_j() <= without.generated_j() + tolerance);
    assert!(!with.summary.energy.oscillating());
    assert!(with.largest_rise_n() <= SLEW_N_PER_MS);
}
