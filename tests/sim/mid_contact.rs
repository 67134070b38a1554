//! Damping, transfer-function and haptic-mode changes made in the middle of a contact, scripted with a sim's
//! `[[events]]`, end to end through the sim runner and its energy ledger (docs/stability.md, "Changes in
//! contact").
//!
//! Each test checks what the analysis says the change must do, and each check is also run on the run where
//! the change does not act, where it must fail: a damping raise on a contact whose undamped sampled loop is
//! active must make it settle (the one-tick matrix's eigenvalues, computed here); a transfer lowered in the
//! middle of a press must let the spring give way at once to the new strength, exactly as with the passivity
//! off; a mode switch must be introduced passively (no more energy over the closed cycle than without it,
//! beyond the sampled coupling's own zero-order-hold share `k/2 Σ|Δx|²`, Colgate and Schenkel 1997) and
//! continuously (the force rising by no more than the safety pipeline's default slew limit, 0.5 N per
//! millisecond, docs/safety.md), where applied at once it jumps by more.

use crate::util::sim::run_text;
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
        let (summary, samples, _) = run_text(text, "mid-contact");
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
            .map(|p| p[1].sent_force_n.length() - p[0].sent_force_n.length())
            .fold(0.0, f64::max)
    }

    /// The force at the event tick is that of a probe in contact.
    fn in_contact_at(&self, t_s: f64) -> bool {
        self.samples
            .iter()
            .find(|s| s.t_s >= t_s - 1e-9)
            .is_some_and(|s| s.sent_force_n.length() > 0.5)
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

/// Spectral radius test of the sampled contact loop, from first principles: the default arm (`m`, `b`)
/// released on a plane (a constant push adds nothing to stability), `F_n = -K x_n - B v_n` sampled at each
/// tick from the exact position and velocity and held for the period `T`. The zero-order-hold solution of
/// `m v' = -b v + F` over one tick is `v+ = a v + g2 F`, `x+ = x + phi v + g1 F`, with `a = exp(-T b / m)`,
/// `g2 = (1 - a) / b`, `phi = (m / b)(1 - a)`, `g1 = (T - phi) / b`; the closed loop's matrix is
/// `[[1 - K g1, phi - B g1], [-K g2, a - B g2]]`, and a 2 x 2 matrix has both eigenvalues inside the unit
/// circle iff `|det| < 1` and `|trace| < 1 + det` (Jury). Returns (stable, det), `det` the product of the
/// eigenvalues (their squared modulus when they are complex: the decay per tick squared).
fn damped_contact_is_stable(m: f64, b: f64, period_s: f64, k: f64, damping: f64) -> (bool, f64) {
    let a = (-period_s * b / m).exp();
    let g2 = (1.0 - a) / b;
    let phi = m / b * (1.0 - a);
    let g1 = (period_s - phi) / b;
    let (m11, m12, m21, m22) = (1.0 - k * g1, phi - damping * g1, -k * g2, a - damping * g2);
    let (trace, det) = (m11 + m22, m11 * m22 - m12 * m21);
    (det.abs() < 1.0 && trace.abs() < 1.0 + det, det)
}

/// A released hand (a constant 1 N push) rests the default arm on a plane at 1 kHz with k = 3 000 N/m, half
/// again the exact zero-order-hold boundary (2 003 N/m): without coupling damping the contact is active and
/// bounces for ever. By the analysis above, 2 N s/m of coupling damping on the exact velocity makes the same
/// loop stable, its oscillation decaying by `sqrt(det)` a tick (0.9925: to a fifth in 0.2 s). So `set_damping`
/// 0 -> 2 N s/m made in contact must end the bouncing: in the run with the change the contact settles (in the
/// last 0.3 s never lost, the force the hand's 1 N within 1 %) and it generates less than the run without
/// it, which still bounces then. Broken, a damping change that does not reach the coupling (or reaches it
/// late, or with the wrong sign) leaves the bounce: the check fails.
#[test]
fn a_damping_raise_in_contact_ends_an_active_contact_as_the_analysis_says() {
    let (m, b, period_s, k, raised) = (0.1, 1.0, 1e-3, 3000.0, 2.0);
    let (undamped_stable, _) = damped_contact_is_stable(m, b, period_s, k, 0.0);
    let (damped_stable, det) = damped_contact_is_stable(m, b, period_s, k, raised);
    assert!(!undamped_stable && damped_stable, "analysis: det {det}");
    let decay_per_tick = det.sqrt();
    assert!(decay_per_tick < 0.995, "{decay_per_tick}");
    let text = |events: &str| {
        format!(
            "name = \"damping-raise\"\nduration_s = 1.6\nk_n_per_m = {k:.1}\nstart_m = [0.0, 0.0, 0.001]\n\
             volumes = []\n\n{events}\n{TABLE}\n[arm]\nmass_kg = {m:.1}\ndamping_n_s_per_m = {b:.1}\n\
             workspace = {{ shape = \"unbounded\" }}\n\n[hand]\nstiffness_n_per_m = 200.0\n\
             damping_n_s_per_m = 2.0\n\n[path]\nkind = \"force\"\n\
             profile = {{ shape = \"constant\", force_n = [0.0, 0.0, -1.0] }}\n"
        )
    };
    let without = Cycle::run(&text(""));
    // The change is made in contact: the first tick from 0.5 s on where the bouncing arm presses the plane.
    let at = without
        .samples
        .iter()
        .find(|s| s.t_s >= 0.5 && s.sent_force_n.z > 0.5)
        .expect("the arm is in contact after 0.5 s")
        .t_s;
    let events =
        format!("[[events]]\nt_s = {at:.3}\ncommand = \"set_damping\"\ndamping = {raised:.1}\n");
    let with = Cycle::run(&text(&events));
    assert_eq!(with.summary.events_applied, 1);
    let last = |c: &Cycle| c.samples[c.samples.len() - 300..].to_vec();
    let lost = |c: &Cycle| last(c).iter().filter(|s| s.sent_force_n.z < 1e-3).count();
    let worst = |c: &Cycle| {
        last(c)
            .iter()
            .map(|s| (s.sent_force_n.z - 1.0).abs())
            .fold(0.0, f64::max)
    };
    eprintln!(
        "set_damping at {at:.3} s: without: oscillating {}, {} ticks out of contact in the last 0.3 s, \
         generated {:.4} mJ; with: oscillating {}, {} out, largest |F - 1 N| {:.2e} N, generated {:.4} mJ; \
         analysis: decay {decay_per_tick:.5} a tick",
        without.summary.energy.oscillating(),
        lost(&without),
        without.generated_j() * 1e3,
        with.summary.energy.oscillating(),
        lost(&with),
        worst(&with),
        with.generated_j() * 1e3
    );
    // The premise: without the change the contact is active.
    assert!(without.summary.energy.oscillating() && lost(&without) > 0);
    // With it, settled (the ledger's limit-cycle flag covers the whole run, the bounces before the raise
    // included, so the settling is read from the trace).
    assert_eq!(lost(&with), 0, "contact lost after the damping raise");
    assert!(
        worst(&with) < 0.01,
        "force off the hand's push by {} N",
        worst(&with)
    );
    // And the change gave the hand no energy: less generated than the bouncing run.
    assert!(with.generated_j() < without.generated_j());
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

/// A surface on the built-in ball (radius 3 cm) pressed from above until it yields at its strength, 2 N; at
/// the bottom of the press `set_transfer` halves the strength. A surface's plane passes through the proxy, so
/// a transfer change only sets how hard the spring may pull before the proxy yields (docs/modes.md): by the
/// analysis the spring pulling with `f0` above 1 N must give way at once to at most 1 N, its stored energy
/// falling from `f0^2 / (2k)` to at most `(1 N)^2 / (2k)` = 1 mJ at k = 500 N/m (the difference is
/// dissipated, never given to the hand), and the passive introduction has nothing to introduce (the new
/// coupling holds less energy): it applies the change at once, exactly as with `[passivity] mode = "off"`.
/// Broken: a transfer that does not reach the mode, or a transition that holds the old force (a virtual
/// proxy kept at the old stretch), leaves the spring pulling with `f0` after the change: the checks below
/// fail, as they do on the run without the change.
#[test]
fn a_transfer_lowered_in_contact_gives_way_at_once_as_the_analysis_says() {
    let k = 500.0;
    let text = |events: &str, extra: &str| {
        format!(
            "name = \"mid-contact-transfer\"\nduration_s = 1.6\nk_n_per_m = {k:.1}\n\n[[volumes]]\nname = \"density\"\n\
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
    let stored = |c: &Cycle, i: usize| {
        0.5 * k * (c.samples[i].proxy_m - c.samples[i].probe_m).length_squared()
    };
    // Tick 549 is the last before the change (t = 0.549 s); 552 is 2 ms after it.
    let (before, after) = (549, 552);
    let f0 = with.samples[before].sent_force_n.length();
    // What the analysis says of the spring: before, it pulls with `f0` (above the new strength) and holds
    // `f0^2 / (2k)`; after, at most 1 N and `(1 N)^2 / (2k)`.
    let gave_way = |c: &Cycle| {
        c.samples[after].sent_force_n.length() <= 1.0 + 1e-9
            && stored(c, after) <= 1.0 / (2.0 * k) + 1e-12
    };
    eprintln!(
        "set_transfer: before {f0:.4} N {:.4} mJ; after: with {:.4} N {:.4} mJ, without {:.4} N {:.4} mJ; \
         {} introduced passively",
        stored(&with, before) * 1e3,
        with.samples[after].sent_force_n.length(),
        stored(&with, after) * 1e3,
        without.samples[after].sent_force_n.length(),
        stored(&without, after) * 1e3,
        with.summary.changes_introduced
    );
    assert!(
        f0 > 1.05,
        "the press pulls above the new strength before the change: {f0} N"
    );
    let spring_j = f0 * f0 / (2.0 * k);
    assert!((stored(&with, before) - spring_j).abs() < 0.01 * spring_j);
    assert!(gave_way(&with), "the spring did not give way at once");
    assert!(!gave_way(&without), "the check cannot fail");
    // Nothing to introduce: applied at once, the same run tick for tick as with the passivity off.
    assert_eq!(with.summary.changes_introduced, 0);
    for (a, b) in with.samples.iter().zip(&at_once.samples) {
        assert_eq!(
            (a.sent_force_n, a.probe_m),
            (b.sent_force_n, b.probe_m),
            "t = {}",
            a.t_s
        );
    }
    assert!(!with.summary.energy.oscillating());
    assert!(with.largest_rise_n() <= SLEW_N_PER_MS);
}
