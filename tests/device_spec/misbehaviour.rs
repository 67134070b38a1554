//! Random misbehaviour: a seeded mix of every fault the spec device can play keeps the device-side invariants.

use crate::util::spec_device::{SpecDeviceConfig, Trigger};
use crate::util::spec_serve::{
    into_the_wall, longest_nonzero_run_while_not_enabled, run_until, summary, take_turn,
    SLEW_LIMIT_N_PER_MS, SLEW_MARGIN_N_PER_MS,
};
use std::time::Duration;

// ---------------------------------------------------------------------------------------------------------------
// Random misbehaviour.

/// A device with a random mix of faults, delays, glitches, absurd velocities, noise and silence (seeded, so a
/// failure names its scenario), checked for the device-side invariants: finite, never above `max_force_n`, never
/// rising faster than the slew limit, and zero while not enabled (up to 3 frames in flight after the device left
/// Enabled, the host's 3-period staleness bound).
#[test]
fn random_misbehaviour_keeps_the_device_side_invariants() {
    let mut seed = 0x5eed_u64;
    let mut next = move |below: u64| {
        seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (seed >> 33) % below
    };
    for scenario in 0..3 {
        let at = |ms: u64| Trigger::AfterFirstEnable(Duration::from_millis(300 + ms));
        let max_force_n = 1.0 + next(7) as f32;
        let mut config = SpecDeviceConfig {
            max_force_n,
            handle: into_the_wall(0.3 + next(5) as f64 * 0.1),
            reply_delay: Duration::from_micros(next(3000)),
            seed: next(1000) + 1,
            ..SpecDeviceConfig::default()
        };
        if next(2) == 0 {
            config.fault = Some((at(next(1200)), next(8) as u8));
        }
        if next(2) == 0 {
            let jump = (next(2001) as f32 - 1000.0) * 1e-5;
            config.position_glitch = Some((at(next(1200)), [jump, 0.0, 0.0]));
        }
        if next(2) == 0 {
            let speed = [0.5, 10.0, 1e30][next(3) as usize];
            config.velocity_override = Some((at(next(1200)), [speed, 0.0, 0.0]));
        }
        if next(2) == 0 {
            config.corrupt_fraction = next(30) as f64 * 1e-4;
            config.noise_from = Some(at(0));
        }
        if next(2) == 0 {
            config.silence = Some((at(next(1200)), Duration::from_millis(next(100))));
        }
        let description = format!(
            "scenario {scenario}: max {max_force_n} N, delay {:?}, fault {:?}, glitch {:?}, velocity {:?}, \
             noise {}, silence {:?}",
            config.reply_delay,
            config.fault,
            config.position_glitch,
            config.velocity_override,
            config.corrupt_fraction,
            config.silence
        );
        let _turn = take_turn();
        let reply_delay = config.reply_delay;
        // Every misbehaviour has come, and the host has been watched for 300 of its ticks after the last one.
        let triggers: Vec<Trigger> = [
            config.fault.map(|(t, _)| t),
            config.position_glitch.map(|(t, _)| t),
            config.velocity_override.map(|(t, _)| t),
            config.noise_from,
            config.silence.map(|(t, _)| t),
        ]
        .into_iter()
        .flatten()
        .collect();
        let (device, _status, output) = run_until(
            config,
            2.0,
            "every misbehaviour, then 300 host ticks",
            move |device| {
                let fired: Option<Vec<_>> = triggers.iter().map(|&t| device.fired(t)).collect();
                let Some(fired) = fired else {
                    return false;
                };
                let last = fired.iter().map(|f| f.index).max();
                device.force_count() >= 300
                    && last.is_none_or(|index| device.force_count_after_index(index) >= 300)
            },
        );
        let forces = device.forces();
        assert!(
            forces.len() > 200,
            "{description}: too few SetForce ({}); serve said {output}",
            forces.len()
        );
        assert_eq!(device.non_finite_forces(), 0, "{description}");
        assert!(
            device.max_force_n() <= max_force_n * (1.0 + 1e-6),
            "{description}: {}",
            summary(&forces)
        );
        let slew = device.max_slew_n_per_ms();
        assert!(
            slew <= SLEW_LIMIT_N_PER_MS + SLEW_MARGIN_N_PER_MS,
            "{description}: |force| rose by {slew} N in one tick"
        );
        // Forces already on their way when the device dropped out: one per period of reply delay, plus one.
        let in_flight = 2 + reply_delay.as_micros() as usize / 1000;
        let run = longest_nonzero_run_while_not_enabled(&forces);
        assert!(
            run <= in_flight,
            "{description}: {run} non-zero SetForce in a row while the device was not Enabled (at most \
             {in_flight} may be in flight)"
        );
    }
}
