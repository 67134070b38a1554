//! Unit tests of the primal Newton method.

use super::*;
use crate::bench_scenes::{random_scene, SplitMix};
use crate::item::subgradient;

/// The gradient of the smooth terms at `x` (points and lines off their kink: their subgradient), for
/// finite differences.
fn smooth_gradient(items: &[Item], x: DVec3) -> DVec3 {
    items.iter().map(|item| subgradient(item, x)).sum()
}

/// `third_order` is the third derivative applied twice: it matches the second central difference of the
/// gradient along `d`, `(g(x + h d) - 2 g(x) + g(x - h d)) / h^2`, on random points and lines.
#[test]
fn third_order_matches_finite_differences_of_the_gradient() {
    let mut rng = SplitMix(42);
    for scene in 0..50 {
        let items: Vec<Item> = (0..6)
            .map(|i| Item {
                kind: if i % 2 == 0 {
                    PrimitiveKind::Point
                } else {
                    PrimitiveKind::Line
                },
                position_m: rng.vec(0.01),
                direction: if i % 2 == 0 {
                    DVec3::ZERO
                } else {
                    rng.vec(1.0).normalize()
                },
                strength_n: rng.range(0.1, 2.0),
            })
            .collect();
        let x = rng.vec(0.01);
        let d = rng.vec(1e-3);
        let mut workspace = Workspace::<crate::storage::Heap>::with_capacity(items.len());
        // A pass at x writes each smooth item's force there (its subgradient) as its dual value.
        let dual: Vec<DVec3> = items.iter().map(|item| subgradient(item, x)).collect();
        for (i, item) in items.iter().enumerate() {
            workspace.active.push(i as u32);
            workspace.state.push(State::Smooth);
            workspace
                .kink_distance_m
                .push(kink_distance_squared(item, x).sqrt());
        }
        let analytic = workspace.third_order(&items, &dual, d);
        let h = 1e-3;
        let numeric = (smooth_gradient(&items, x + h * d) - 2.0 * smooth_gradient(&items, x)
            + smooth_gradient(&items, x - h * d))
            / (h * h);
        let error = (analytic - numeric).length();
        assert!(
            error <= 1e-4 * analytic.length(),
            "scene {scene}: analytic {analytic:?}, numeric {numeric:?}"
        );
    }
}

/// The iteration compiled with the pass inlined (scenes of up to `INLINE_PASS_MAX_ITEMS`) and with it called
/// (larger scenes) is the same computation: on small random scenes, cold and warm, both give the same point,
/// dual, passes and certificate to the bit. Fails if either copy's pass or iteration drifts from the other.
#[test]
fn the_inlined_and_the_called_pass_iterate_alike() {
    let k = 500.0;
    let mut certified = 0;
    for seed in 1..=300u64 {
        let n = 1 + (seed as usize) % INLINE_PASS_MAX_ITEMS;
        let (probe, primitives) = random_scene(seed * 7_919 + n as u64, n);
        let items: Vec<Item> = primitives
            .iter()
            .filter(|p| p.kind() != PrimitiveKind::Directed)
            .map(|p| Item {
                kind: p.kind(),
                position_m: p.position_m(),
                direction: p.direction(),
                strength_n: p.strength_n(),
            })
            .collect();
        let frame = Frame {
            y: probe,
            k,
            y_error_m: 0.0,
            strength_over_k_m: items.iter().map(|item| item.strength_n).sum::<f64>() / k,
            rebalance: true,
        };
        let limits = Limits {
            tolerance_m: 1e-12,
            max_passes: 60,
            screening: true,
        };
        for start in [None, Some(probe + DVec3::new(1e-3, -2e-3, 5e-4))] {
            let attempt = Attempt {
                items: &items,
                frame: &frame,
                start,
                limits,
            };
            let run = |inline: bool| {
                let mut workspace = Workspace::<crate::storage::Heap>::with_capacity(items.len());
                let mut dual = vec![DVec3::splat(f64::NAN); items.len()];
                let solve = if inline {
                    Workspace::solve_with::<true>
                } else {
                    Workspace::solve_with::<false>
                };
                let outcome = solve(&mut workspace, &attempt, &mut dual, &mut || false);
                (outcome, dual)
            };
            let ((inlined, inlined_dual), (called, called_dual)) = (run(true), run(false));
            let bits = |v: DVec3| v.to_array().map(f64::to_bits);
            let context = format!("seed {seed}, {} items, start {start:?}", items.len());
            assert_eq!(bits(inlined.x), bits(called.x), "{context}");
            assert_eq!(inlined.passes, called.passes, "{context}");
            assert_eq!(inlined.certified, called.certified, "{context}");
            assert_eq!(
                inlined.certificate.map(|c| c.bound_m.to_bits()),
                called.certificate.map(|c| c.bound_m.to_bits()),
                "{context}"
            );
            let dual_bits = |dual: &[DVec3]| dual.iter().map(|&u| bits(u)).collect::<Vec<_>>();
            assert_eq!(
                dual_bits(&inlined_dual),
                dual_bits(&called_dual),
                "{context}"
            );
            certified += usize::from(inlined.certified);
        }
    }
    // Most attempts certify: the comparison covers whole iterations, not only first passes.
    assert!(certified >= 500, "{certified} of 600 attempts certified");
}
