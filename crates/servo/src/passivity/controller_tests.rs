use super::super::latency::ObserverLatency;
use super::*;

/// Presses a spring of stiffness `k` at constant speed (`dx` per tick of `dt`), the force the spring's
/// sampled value plus the controller's, for `ticks` ticks; returns the totals.
fn press(mode: PassivityMode, latency_ticks: usize, ticks: u64) -> (PassivityTotals, f64) {
    let (k, dx, dt) = (1000.0, 1e-5, 1e-3);
    let settings = PassivitySettings::default();
    let mut pc = PassivityController::new(mode, &settings, latency_ticks);
    let velocity = DVec3::new(dx / dt, 0.0, 0.0);
    for n in 0..=ticks {
        let x = DVec3::new(n as f64 * dx, 0.0, 0.0);
        let spring = -k * x;
        let reference = 0.5 * k * x.length_squared();
        let control = pc.observe_and_control(x, velocity, reference, dt);
        pc.sent(spring + control, spring + control);
    }
    (pc.totals(), 0.5 * k * dx * dx)
}

/// Without latency a sampled spring pressed at constant speed generates `k dx^2 / 2` a step beyond its
/// stored energy (the force held over the step is the one from its start): the zero-order hold's excess.
#[test]
fn the_observer_books_the_zero_order_hold_excess() {
    let (totals, half_k_dx2) = press(PassivityMode::Observe, 0, 200);
    assert!(
        (totals.generated_j - 200.0 * half_k_dx2).abs() < 1e-15,
        "{totals:?}"
    );
    assert_eq!(totals.active_ticks, 0);
    assert_eq!(totals.dissipated_j, 0.0);
}

/// With one tick of latency the step from `x_{n-1}` to `x_n` moves under `F_{n-2} = -k x_{n-2}`: each step
/// generates `k dx (x_{n-1} - x_{n-2}) + k dx^2 / 2 = 3 k dx^2 / 2`, the first one (no force yet) `k dx^2 / 2`.
#[test]
fn the_observer_pairs_each_step_with_the_force_that_acted_over_it() {
    let (totals, half_k_dx2) = press(PassivityMode::Observe, 1, 200);
    let expected = half_k_dx2 + 3.0 * half_k_dx2 * 199.0;
    assert!(
        (totals.generated_j - expected).abs() < 1e-15,
        "{totals:?} vs {expected}"
    );
}

/// In control the damper takes what the observer saw generated: the excess never builds beyond the
/// threshold plus what `d + 1` steps generate before the damper's work is observed (`(1 + 2d) k dx^2 / 2` a
/// step with `d` ticks of latency, as above), and what was generated is dissipated.
#[test]
fn the_controller_dissipates_the_excess_as_it_comes() {
    for latency in [0usize, 1, 3] {
        let (totals, half_k_dx2) = press(PassivityMode::Control, latency, 400);
        let d = latency as f64;
        let per_step = (1.0 + 2.0 * d) * half_k_dx2;
        let threshold = PassivitySettings::default().threshold_j;
        assert!(
            totals.excess_j <= threshold + (d + 1.0) * per_step + 1e-15,
            "latency {latency}: {totals:?}"
        );
        assert!(
            totals.dissipated_j > 0.0 && totals.active_ticks > 0,
            "{totals:?}"
        );
        // What stays generated is at most the excess plus the threshold's dead band.
        assert!(
            totals.generated_j <= totals.excess_j + 1e-6 + 1e-12,
            "{totals:?}"
        );
        // Broken controller (observe only): the same press keeps all of it.
        let (observed, _) = press(PassivityMode::Observe, latency, 400);
        assert!(observed.generated_j > 300.0 * half_k_dx2, "{observed:?}");
    }
}

#[test]
fn off_books_nothing_and_adds_no_force() {
    let (totals, _) = press(PassivityMode::Off, 0, 50);
    assert_eq!(totals, PassivityTotals::default());
}

/// The default settings changed by `edit`.
fn settings_with(edit: impl FnOnce(&mut PassivitySettings)) -> PassivitySettings {
    let mut settings = PassivitySettings::default();
    edit(&mut settings);
    settings
}

/// Why `validate` refuses the default settings changed by `edit`.
fn refusal(edit: impl FnOnce(&mut PassivitySettings)) -> String {
    settings_with(edit).validate().unwrap_err().to_string()
}

#[test]
fn parameters_out_of_range_name_their_key() {
    assert!(refusal(|s| s.max_damping_n_s_per_m = f64::NAN)
        .starts_with("passivity.max_damping_n_s_per_m:"));
    assert!(refusal(|s| s.threshold_j = -1.0).starts_with("passivity.threshold_j:"));
    assert!(PassivitySettings::default().validate().is_ok());
}

/// The observer's latency in whole ticks, by hand: `[passivity] latency_s` over the declared figure; a
/// fraction of a tick rounds up (0.4 ms at 1 kHz is 1 tick, 2.5 ms is 3); whole figures stay whole
/// (1 ms at 4 kHz is 4 ticks, not 5 from rounding error; 1 ms at 3 kHz is 3, three periods of 1/3 ms exactly,
/// where whole nanoseconds, 333 333 ns a period, would round 3.000003 up to 4); nothing known is 0.
#[test]
fn the_observer_latency_is_the_written_or_declared_one_rounded_up() {
    let ticks = |settings: &PassivitySettings, declared_s: Option<f64>, period_s: f64| {
        ObserverLatency::choose(settings, declared_s, None, period_s).ticks
    };
    let none = PassivitySettings::default();
    assert_eq!(ticks(&none, None, 1e-3), 0);
    assert_eq!(ticks(&none, Some(0.002), 1e-3), 2);
    assert_eq!(ticks(&none, Some(0.0004), 1e-3), 1);
    assert_eq!(ticks(&none, Some(0.0025), 1e-3), 3);
    assert_eq!(ticks(&none, Some(0.001), 2.5e-4), 4);
    assert_eq!(ticks(&none, Some(0.001), 1.0 / 3000.0), 3);
    let written = |latency_s| settings_with(|s| s.latency_s = Some(latency_s));
    assert_eq!(ticks(&written(0.0), Some(0.002), 1e-3), 0);
    assert_eq!(ticks(&written(0.003), None, 1e-3), 3);
    for bad in [f64::NAN, -1e-3, 0.06] {
        assert!(refusal(|s| s.latency_s = Some(bad)).starts_with("passivity.latency_s:"));
    }
}

/// A directed force pushing a free hand along (`vector_force` in free space) does the work the scene asks
/// for; the coupling stores and generates nothing (the proxy sits `d / k` ahead of the probe, so the spring
/// without the directed part is unstretched). Booked as active, it leaves the observer at zero and the
/// controller silent; booked as coupling work it would be `|d| dx` a tick, and the controller would damp it.
#[test]
fn a_directed_force_pushing_a_free_hand_is_not_damped() {
    let (d, dx, dt) = (DVec3::new(1.0, 0.0, 0.0), 1e-4, 1e-3);
    let settings = PassivitySettings::default();
    let velocity = DVec3::new(dx / dt, 0.0, 0.0);
    let run = |split: bool| {
        let mut pc = PassivityController::new(PassivityMode::Control, &settings, 0);
        let mut largest_control = 0.0f64;
        for n in 0..=500 {
            let x = DVec3::new(n as f64 * dx, 0.0, 0.0);
            let control = pc.observe_and_control(x, velocity, 0.0, dt);
            largest_control = largest_control.max(control.length());
            let sent = d + control;
            if split {
                pc.sent_with_active(sent, sent, d);
            } else {
                pc.sent(sent, sent);
            }
        }
        (pc.totals(), largest_control)
    };
    let (totals, largest) = run(true);
    assert_eq!(largest, 0.0, "{totals:?}");
    assert!(
        totals.generated_j.abs() < 1e-15 && totals.dissipated_j == 0.0,
        "{totals:?}"
    );
    // Without the split the same push reads as 0.1 mJ a tick generated, and the controller acts.
    let (unsplit, largest) = run(false);
    assert!(unsplit.dissipated_j > 0.0 && largest > 0.0, "{unsplit:?}");
}
