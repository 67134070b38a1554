//! The Inverse3's frame and limits as data, each number with the vendor file, line or document it comes from
//! ([`LIMITS`]). The driver's capability record and the host's input checks use these: the workspace box is
//! the measured reachable box, so a handle anywhere the arm can go is never refused as implausible.
//!
//! Frame: Haply's own (preset `defaults`, basis `XYZ`, identity mount and workspace transform, which the
//! session sets and reads back): right-handed, +X right, +Y forward, +Z up, origin on the device's mounting
//! plate, metres and newtons.

/// One number and where it comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SourcedLimit {
    /// What it is.
    pub name: &'static str,
    /// The value (SI units as `unit` says).
    pub value: f64,
    /// Its unit.
    pub unit: &'static str,
    /// The vendor file and line, or document, it comes from; or "voxhap" where no vendor publishes one.
    pub source: &'static str,
}

/// SOFA's Haply plugin's measured reachable box (the source named below).
const SOFA_BOX: &str = "SOFA Haply plugin (InfinyTech3D/SofaHaplyRobotics) measured reachable box, as recorded \
                        in voxhap's shared REFERENCES.md (Haply Inverse3 section); the plugin's stored source \
                        (commit 9cf92e9) does not print it";

/// Lower corner of the reachable box in Haply's frame (m).
pub const REACHABLE_MIN_M: [f64; 3] = [-0.245, -0.262, 0.011];
/// Upper corner of the reachable box in Haply's frame (m).
pub const REACHABLE_MAX_M: [f64; 3] = [0.259, 0.152, 0.317];
/// Haply's documented example handle position in its default frame (m).
pub const DOCUMENTED_EXAMPLE_POSITION_M: [f64; 3] = [0.0, -0.12, 0.15];
/// voxhap's default force cap (N): Haply's service documentation publishes no force limit.
pub const DEFAULT_MAX_FORCE_N: f64 = 3.0;
/// Stiffness cap (N/m): the stiffness of Haply's own floor tutorial.
pub const MAX_STIFFNESS_N_PER_M: f64 = 1000.0;

/// Every number, with its source.
pub const LIMITS: [SourcedLimit; 13] = [
    SourcedLimit { name: "reachable x min", value: REACHABLE_MIN_M[0], unit: "m", source: SOFA_BOX },
    SourcedLimit { name: "reachable y min", value: REACHABLE_MIN_M[1], unit: "m", source: SOFA_BOX },
    SourcedLimit { name: "reachable z min", value: REACHABLE_MIN_M[2], unit: "m", source: SOFA_BOX },
    SourcedLimit { name: "reachable x max", value: REACHABLE_MAX_M[0], unit: "m", source: SOFA_BOX },
    SourcedLimit { name: "reachable y max", value: REACHABLE_MAX_M[1], unit: "m", source: SOFA_BOX },
    SourcedLimit { name: "reachable z max", value: REACHABLE_MAX_M[2], unit: "m", source: SOFA_BOX },
    SourcedLimit {
        name: "documented example position x",
        value: DOCUMENTED_EXAMPLE_POSITION_M[0],
        unit: "m",
        source: "docs.haply.co/inverseSDK/service/realtime/websocket-protocol, step 1 (initial inventory example, \
                 preset \"defaults\", identity mount)",
    },
    SourcedLimit {
        name: "documented example position y",
        value: DOCUMENTED_EXAMPLE_POSITION_M[1],
        unit: "m",
        source: "docs.haply.co/inverseSDK/service/realtime/websocket-protocol, step 1",
    },
    SourcedLimit {
        name: "documented example position z",
        value: DOCUMENTED_EXAMPLE_POSITION_M[2],
        unit: "m",
        source: "docs.haply.co/inverseSDK/service/realtime/websocket-protocol, step 1",
    },
    SourcedLimit {
        name: "default force cap",
        value: DEFAULT_MAX_FORCE_N,
        unit: "N",
        source: "voxhap: Haply's service documentation publishes no force limit; SOFA's Haply plugin zeroes any \
                 axis above 5 N (src/SofaHaplyRobotics/Haply_Inverse3Controller.cpp:273, commit 9cf92e9)",
    },
    SourcedLimit {
        name: "per-axis force the SOFA plugin refuses",
        value: 5.0,
        unit: "N",
        source: "src/SofaHaplyRobotics/Haply_Inverse3Controller.cpp:273 (InfinyTech3D/SofaHaplyRobotics 9cf92e9)",
    },
    SourcedLimit {
        name: "stiffness cap",
        value: MAX_STIFFNESS_N_PER_M,
        unit: "N/m",
        source: "docs.haply.co/inverseSDK/service/tutorials/07-basis-and-mount, Parameters: STIFFNESS 1000 N/m",
    },
    SourcedLimit {
        name: "tutorial target-clamp sphere radius (Inverse3)",
        value: 0.10,
        unit: "m",
        source: "docs.haply.co/inverseSDK/service/tutorials/06-combined, Parameters: RADIUS_INVERSE3 0.10 m \
                 (a clamp for set_cursor_position targets about the centred origin, not the reachable space)",
    },
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_documented_example_position_lies_in_the_reachable_box() {
        for axis in 0..3 {
            assert!(REACHABLE_MIN_M[axis] < DOCUMENTED_EXAMPLE_POSITION_M[axis]);
            assert!(DOCUMENTED_EXAMPLE_POSITION_M[axis] < REACHABLE_MAX_M[axis]);
        }
    }

    #[test]
    fn every_limit_names_its_source() {
        for limit in LIMITS {
            assert!(limit.value.is_finite(), "{}", limit.name);
            assert!(
                !limit.source.is_empty() && !limit.unit.is_empty(),
                "{}",
                limit.name
            );
        }
    }
}
