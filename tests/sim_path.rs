//! The simulated arm's scripted path and start point are scene positions (workspace mapping, docs/workspace.md): under a
//! mapping (a fixed one with scale 2 and a translation, or the one `--fit-volume` computes when the device
//! connects) a `hold` path at a scene point brings the probe, which the session reports in the scene frame, to
//! that point, and an arm pushed by no force stays at its scene start point. With the identity mapping (the
//! default for the simulated arm) scene and device positions are the same. Read through a real session's
//! `SessionApi::snapshot`.

use glam::{DMat3, DVec3};
use std::time::{Duration, Instant};
use voxhap::device::mapping::WorkspaceMapping;
use voxhap::device::profile::{DeviceProfile, MappingChoice};
use voxhap::device::sim::{ForceProfile, HandPath};
use voxhap::servo::api::SessionApi;
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{Session, SessionConfig};

/// Where the probe starts: a scene point near the held one, both inside the built-in scene's volume, so that
/// under the fitted mapping (scale 0.05) the arm's move stays within its workspace and plausible speed.
const START_M: DVec3 = DVec3::new(0.01, 0.0, 0.02);
/// The held scene point.
const HOLD_M: DVec3 = DVec3::new(0.012, 0.002, 0.02);

/// A session on the simulated arm under `mapping`, with no haptic modes (only the hand moves the arm), the
/// arm starting at [`START_M`] and following `path`.
fn session(mapping: MappingChoice, path: HandPath) -> Session {
    let mut setup = SceneSetup::builtin().unwrap();
    setup.modes.clear();
    setup.arm.path = path;
    setup.start_m = START_M;
    let mut config = SessionConfig::new(DeviceSpec::Sim, setup);
    config.rt = voxhap::servo::rt::RtMode::Off;
    config.profile = DeviceProfile {
        mapping,
        ..DeviceProfile::default()
    };
    Session::start(config).unwrap()
}

/// The probe (scene frame) once it has been within `within_m` of `point` for 200 ticks, or the last one
/// after 5 s.
fn probe_near(session: &Session, point: DVec3, within_m: f64) -> DVec3 {
    let api = session.api();
    let started = Instant::now();
    let mut near_since_tick = None;
    loop {
        if let Some(snapshot) = api.snapshot() {
            let probe = snapshot.probe_m;
            assert!(probe.is_finite(), "{probe}");
            if (probe - point).length() >= within_m {
                near_since_tick = None;
            } else if snapshot.tick
                >= near_since_tick
                    .get_or_insert(snapshot.tick)
                    .saturating_add(200)
            {
                return probe;
            }
            if started.elapsed() > Duration::from_secs(5) {
                return probe;
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn scale_2_translated() -> WorkspaceMapping {
    WorkspaceMapping::new(DMat3::IDENTITY, 2.0, DVec3::new(0.1, -0.05, 0.02)).unwrap()
}

#[test]
fn a_hold_path_in_the_scene_frame_puts_the_probe_at_its_scene_point_under_any_mapping() {
    let hold = HandPath::Hold { at_m: HOLD_M };
    for (name, mapping) in [
        // HOLD_M is the device point (-0.044, 0.026, 0) m. Were the path read in the device frame, the probe
        // would settle at 2 HOLD_M + t = (0.124, -0.046, 0.06) m.
        (
            "scale 2, translated",
            MappingChoice::Fixed(scale_2_translated()),
        ),
        // The built-in scene's first volume (±5 cm) fitted into the arm's ±1 m box: scale 0.05, known only
        // once the device has connected. Read in the device frame, the path would put the probe at
        // 0.05 HOLD_M, 2 cm away.
        (
            "--fit-volume",
            MappingChoice::FitVolume {
                rotation: DMat3::IDENTITY,
            },
        ),
        ("identity", MappingChoice::Fixed(WorkspaceMapping::IDENTITY)),
    ] {
        let identity = matches!(mapping, MappingChoice::Fixed(m) if m.is_identity());
        let running = session(mapping, hold.clone());
        // The session prints the mapping in force when it is not the identity.
        let mapped_notice = running.notices().iter().any(|n| n.contains("scene = "));
        assert_eq!(mapped_notice, !identity, "{name}: {:?}", running.notices());
        let probe = probe_near(&running, HOLD_M, 1e-4);
        let summary = running.stop();
        assert!(
            (probe - HOLD_M).length() < 1e-4,
            "{name}: the probe settled at {probe}, not at the held scene point {HOLD_M}"
        );
        assert!(summary.stats.ticks > 200, "{name}: {:?}", summary.stats);
    }
}

#[test]
fn the_start_point_is_a_scene_point_under_a_mapping() {
    // A hand pushing with no force: the arm stays where it started.
    let still = HandPath::Force {
        profile: ForceProfile::Constant {
            force_n: DVec3::ZERO,
        },
    };
    for mapping in [scale_2_translated(), WorkspaceMapping::IDENTITY] {
        let running = session(MappingChoice::Fixed(mapping), still.clone());
        let probe = probe_near(&running, START_M, 1e-9);
        running.stop();
        assert!(
            (probe - START_M).length() < 1e-9,
            "under {mapping:?} the probe is at {probe}, not at the scene start point {START_M}"
        );
    }
}
