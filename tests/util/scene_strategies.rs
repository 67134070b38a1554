//! The random scenes of the solver's property tests (tests/solver_props.rs), shared with
//! examples/uncertified.rs, which counts how often such scenes are not certified: coordinates partly on a 2 mm
//! lattice and directions partly axis-aligned, so that coincident primitives, probes exactly on kinks and
//! parallel planes come up often.

use glam::DVec3;
use proptest::prelude::*;

/// Coordinates drawn partly from a small lattice and partly at random.
pub fn coordinate() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => (-2i32..=2).prop_map(|i| i as f64 * 0.002),
        3 => -0.01f64..0.01,
    ]
}

pub fn vector() -> impl Strategy<Value = DVec3> {
    (coordinate(), coordinate(), coordinate()).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

pub fn direction() -> impl Strategy<Value = DVec3> {
    prop_oneof![
        Just(DVec3::Z),
        Just(DVec3::X),
        Just(DVec3::new(0.0175, 0.0, 1.0)),
        (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0).prop_map(|(x, y, z)| DVec3::new(x, y, z + 0.05)),
    ]
}

pub fn strength() -> impl Strategy<Value = f64> {
    prop_oneof![1 => Just(0.0), 4 => 0.0f64..3.0]
}
