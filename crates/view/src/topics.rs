//! The Foxglove topics voxhap publishes, shared by the live view (`crates/server/src/foxglove.rs`, over the
//! Foxglove WebSocket protocol) and the MCAP trace writer (`mcap_trace.rs`), so a recorded session opens in
//! Foxglove or Lichtblick with the same topics, frames, schemas and colours as a live one.
//!
//! Messages are the Foxglove SDK's well-known schemas (`foxglove::messages`), protobuf-encoded through
//! the SDK's [`foxglove::Encode`] implementations. Pose, velocity and force topics carry CRTK names (the
//! Collaborative Robotics Toolkit conventions of dVRK and sawSensablePhantom):
//!
//! | topic | schema | content | old name (live view only, deprecated) |
//! |---|---|---|---|
//! | [`MEASURED_CP_TOPIC`] | `foxglove.FrameTransform` | frame [`PROBE_FRAME`] in [`WORLD_FRAME`]: the device position (m) | [`PROBE_TOPIC`] |
//! | [`SETPOINT_CP_TOPIC`] | `foxglove.FrameTransform` | frame [`PROXY_FRAME`] in [`WORLD_FRAME`]: the proxy, the coupling spring's set point (m) | [`PROXY_TOPIC`] |
//! | [`MEASURED_CV_TOPIC`] | `foxglove.Vector3` | probe velocity (m/s); live view only | |
//! | [`SETPOINT_CF_TOPIC`] | `foxglove.Vector3` | force commanded to the device after safety (N) | [`SERVO_CF_TOPIC`], [`FORCE_TOPIC`] |
//! | [`OPERATING_STATE_TOPIC`] | `voxhap.OperatingState` (JSON) | CRTK `state`, `is_homed`, `is_busy` | |
//! | [`PRIMITIVES_TOPIC`] | `foxglove.SceneUpdate` | probe, proxy, force arrow, the tick's primitives (live: and the hand target) | |
//! | [`VOLUME_TOPIC`] | `foxglove.SceneUpdate` | the volume's bounding box (with the [`CameraFraming`] in its metadata) and the surface mode's iso-surface mesh, once per scene | |
//! | [`VOLUME_FRAME_TOPIC`] | `foxglove.FrameTransform` | frame [`VOLUME_FRAME`] at the volume's centre and frame [`VIEW_FRAME`], which the shipped layout's camera follows ([`CameraFraming`]) | |
//! | `/voxhap/volume/slice_x`, `_y`, `_z` | `foxglove.Grid` | slices through the proxy (live 128², recorded 64²) | |
//!
//! A recording (`voxhap_record::foxglove_scene`) draws its scene with the same code ([`super::messages`]).
//!
//! World space is voxhap's world space (RAS, metres); rotations are the identity. Colours come from the one
//! palette ([`super::palette`]).

use super::palette::{palette, Rgb};
use ::foxglove::messages::{
    line_primitive, scene_entity_deletion, ArrowPrimitive, Color, FrameTransform, KeyValuePair,
    LinePrimitive, Point3, Pose, Quaternion, SceneEntity, SceneEntityDeletion, SceneUpdate,
    SpherePrimitive, Timestamp, TriangleListPrimitive, Vector3,
};
use glam::{DQuat, DVec3};
use voxhap_core::volume::isosurface::Mesh;

/// CRTK `measured_cp`: the probe (device) position as a transform of [`PROBE_FRAME`] in [`WORLD_FRAME`].
pub const MEASURED_CP_TOPIC: &str = "/voxhap/measured_cp";
/// CRTK `setpoint_cp`: the proxy position (the coupling spring pulls the probe towards it) as a transform of
/// [`PROXY_FRAME`] in [`WORLD_FRAME`].
pub const SETPOINT_CP_TOPIC: &str = "/voxhap/setpoint_cp";
/// CRTK `measured_cv`: the probe velocity (m/s), linear part, as a `foxglove.Vector3`.
pub const MEASURED_CV_TOPIC: &str = "/voxhap/measured_cv";
/// CRTK `setpoint_cf`: the force the device is commanded with after the safety pipeline (N), as a
/// `foxglove.Vector3`.
pub const SETPOINT_CF_TOPIC: &str = "/voxhap/setpoint_cf";
/// The old name of [`SETPOINT_CF_TOPIC`] (recordings made before the rename have it; the live view still
/// publishes it in this release). On ROS 2, CRTK `servo_cf` is the external force voxhap takes in.
pub const SERVO_CF_TOPIC: &str = "/voxhap/servo_cf";
/// CRTK `operating_state` (JSON).
pub const OPERATING_STATE_TOPIC: &str = "/voxhap/operating_state";
/// The scene markers as a `foxglove.SceneUpdate`.
pub const PRIMITIVES_TOPIC: &str = "/voxhap/primitives";
/// The volume's bounds and iso-surface as a `foxglove.SceneUpdate`.
pub const VOLUME_TOPIC: &str = "/voxhap/volume";
/// Frame [`VOLUME_FRAME`] at the volume's centre.
pub const VOLUME_FRAME_TOPIC: &str = "/voxhap/volume_frame";
/// The certificate bound (JSON `voxhap.Bound`).
pub const BOUND_TOPIC: &str = "/voxhap/bound";
/// Statistics (JSON), once a second.
pub const STATS_TOPIC: &str = "/voxhap/stats";
/// Deprecated name of [`MEASURED_CP_TOPIC`]; the live view still publishes it in this release.
pub const PROBE_TOPIC: &str = "/voxhap/probe";
/// Deprecated name of [`SETPOINT_CP_TOPIC`]; the live view still publishes it in this release.
pub const PROXY_TOPIC: &str = "/voxhap/proxy";
/// Deprecated name of [`SERVO_CF_TOPIC`]; the live view still publishes it in this release.
pub const FORCE_TOPIC: &str = "/voxhap/force";
/// The slices through the proxy, normal to x, y and z (`foxglove.Grid`).
pub const SLICE_TOPICS: [&str; 3] = [
    "/voxhap/volume/slice_x",
    "/voxhap/volume/slice_y",
    "/voxhap/volume/slice_z",
];
/// The frame at the volume's centre, axes parallel to [`WORLD_FRAME`].
pub const VOLUME_FRAME: &str = "volume";
/// The frame the shipped layout's 3D panel follows ([`CameraFraming`]): on the line of sight through the
/// volume's centre, placed so that Foxglove's orbit camera frames the volume. Published on
/// [`VOLUME_FRAME_TOPIC`] with [`VOLUME_FRAME`].
pub const VIEW_FRAME: &str = "volume_view";
/// The fixed frame everything is expressed in (voxhap world space, metres).
pub const WORLD_FRAME: &str = "world";
/// The frame that follows the probe.
pub const PROBE_FRAME: &str = "probe";
/// The frame that follows the proxy.
pub const PROXY_FRAME: &str = "proxy";

/// A Foxglove vector from a glam one.
pub fn vector3(v: DVec3) -> Vector3 {
    Vector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// A Foxglove timestamp `ns` nanoseconds after the Unix epoch (saturating at the protobuf range, which
/// ends in 2106).
pub fn timestamp_from_ns(ns: u64) -> Timestamp {
    let sec = u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (ns % 1_000_000_000) as u32)
}

/// A transform of `child` in [`WORLD_FRAME`] at `position_m`, identity rotation, stamped `time_ns`.
/// Reuse one per topic and update it with [`set_translation`] to avoid rebuilding the frame names.
pub fn frame_transform(child: &str, position_m: DVec3, time_ns: u64) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp_from_ns(time_ns)),
        parent_frame_id: WORLD_FRAME.to_owned(),
        child_frame_id: child.to_owned(),
        translation: Some(vector3(position_m)),
        rotation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

/// Moves `transform` to `position_m` at `time_ns` (no allocation).
pub fn set_translation(transform: &mut FrameTransform, position_m: DVec3, time_ns: u64) {
    transform.timestamp = Some(timestamp_from_ns(time_ns));
    transform.translation = Some(vector3(position_m));
}

/// The shipped layout's 3D camera (`contrib/foxglove/voxhap-layout.json`, `cameraState`): its distance
/// from the followed frame (m), which [`CameraFraming`] corrects for, ...
pub const LAYOUT_CAMERA_DISTANCE_M: f64 = 0.25;
/// ... its polar angle from +z (degrees: 60 looks down at 30 degrees from above), ...
pub const LAYOUT_CAMERA_PHI_DEG: f64 = 60.0;
/// ... its azimuth offset (degrees), ...
pub const LAYOUT_CAMERA_THETA_OFFSET_DEG: f64 = 35.0;
/// ... and its vertical field of view (degrees).
pub const LAYOUT_CAMERA_FOVY_DEG: f64 = 45.0;
/// Room around the volume's bounding sphere: the camera stands this many times farther than the distance
/// at which the sphere just touches the top and bottom of the view.
pub const FRAMING_MARGIN: f64 = 1.1;
/// The closest the framing puts the camera (m), for a degenerate (flat or empty) volume.
pub const MIN_CAMERA_DISTANCE_M: f64 = 0.01;

/// The camera framing of a volume: the target is the centre of its bounds, the distance makes the bounding
/// sphere (radius = half the box's diagonal) fill the vertical field of view with [`FRAMING_MARGIN`]:
/// `distance = margin * radius / sin(fovy / 2)`.
///
/// How Foxglove gets it: a 3D panel's camera orbits the frame it follows at the layout's fixed distance,
/// and no message sets that distance. So the shipped layout follows [`VIEW_FRAME`] (position only) at
/// [`LAYOUT_CAMERA_DISTANCE_M`], and voxhap puts that frame on the line of sight through the centre,
/// `distance - LAYOUT_CAMERA_DISTANCE_M` in front of it ([`CameraFraming::view_frame_m`]): the camera
/// then stands `distance` from the centre and looks straight at it. Foxglove's orbit camera in the
/// followed frame sits at `d (-sin phi sin theta, -sin phi cos theta, cos phi)` (`theta` = the layout's
/// `thetaOffset`; three.js spherical coordinates turned 90 degrees about x, as Foxglove's renderer
/// does), see [`camera_direction`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraFraming {
    /// The centre of the volume's bounds (m, world).
    pub target_m: DVec3,
    /// The bounding sphere's radius (m).
    pub radius_m: f64,
    /// From the camera to [`CameraFraming::target_m`] (m).
    pub distance_m: f64,
    /// Where [`VIEW_FRAME`] goes (m, world).
    pub view_frame_m: DVec3,
}

/// The unit vector from the followed frame to Foxglove's orbit camera for a layout's `phi` and
/// `thetaOffset` (degrees).
pub fn camera_direction(phi_deg: f64, theta_offset_deg: f64) -> DVec3 {
    let (phi, theta) = (phi_deg.to_radians(), theta_offset_deg.to_radians());
    DVec3::new(
        -phi.sin() * theta.sin(),
        -phi.sin() * theta.cos(),
        phi.cos(),
    )
}

impl CameraFraming {
    /// The framing of the box `min_m ..= max_m` for the shipped layout's camera. A box with a non-finite
    /// corner is framed as a point at the origin.
    pub fn of_bounds(min_m: DVec3, max_m: DVec3) -> CameraFraming {
        let (min_m, max_m) = if min_m.is_finite() && max_m.is_finite() {
            (min_m, max_m)
        } else {
            (DVec3::ZERO, DVec3::ZERO)
        };
        let target_m = (min_m + max_m) * 0.5;
        let radius_m = 0.5 * (max_m - min_m).length();
        let half_fovy = 0.5 * LAYOUT_CAMERA_FOVY_DEG.to_radians();
        let distance_m = (FRAMING_MARGIN * radius_m / half_fovy.sin()).max(MIN_CAMERA_DISTANCE_M);
        let towards_camera =
            camera_direction(LAYOUT_CAMERA_PHI_DEG, LAYOUT_CAMERA_THETA_OFFSET_DEG);
        CameraFraming {
            target_m,
            radius_m,
            distance_m,
            view_frame_m: target_m + (distance_m - LAYOUT_CAMERA_DISTANCE_M) * towards_camera,
        }
    }

    /// Where the layout's camera stands (m, world).
    pub fn camera_m(&self) -> DVec3 {
        self.view_frame_m
            + LAYOUT_CAMERA_DISTANCE_M
                * camera_direction(LAYOUT_CAMERA_PHI_DEG, LAYOUT_CAMERA_THETA_OFFSET_DEG)
    }
}

/// The volume's frames, both in [`WORLD_FRAME`] with identity rotation, stamped `time_ns`:
/// [`VOLUME_FRAME`] at the centre of `min_m ..= max_m` and [`VIEW_FRAME`] where [`CameraFraming`] puts it.
pub fn volume_frames(min_m: DVec3, max_m: DVec3, time_ns: u64) -> [FrameTransform; 2] {
    let framing = CameraFraming::of_bounds(min_m, max_m);
    [
        frame_transform(VOLUME_FRAME, framing.target_m, time_ns),
        frame_transform(VIEW_FRAME, framing.view_frame_m, time_ns),
    ]
}

/// Arrow length per newton of force (m/N): 1 N draws a 1 cm arrow.
pub const FORCE_ARROW_M_PER_N: f64 = 0.01;
/// Longest arrow drawn (m); stronger forces are drawn at this length.
pub const MAX_ARROW_M: f64 = 0.05;
/// Diameter of the probe and proxy spheres (m).
pub const MARKER_DIAMETER_M: f64 = 0.003;
/// Opacity of the iso-surface mesh.
pub const SURFACE_ALPHA: f64 = 0.45;

/// A Foxglove colour from a palette colour.
pub fn color(rgb: Rgb, alpha: f64) -> Color {
    Color {
        r: rgb.r,
        g: rgb.g,
        b: rgb.b,
        a: alpha,
    }
}

/// The identity rotation.
pub fn identity() -> Quaternion {
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 1.0,
    }
}

/// A Foxglove quaternion from a glam one.
pub fn quaternion(q: DQuat) -> Quaternion {
    Quaternion {
        x: q.x,
        y: q.y,
        z: q.z,
        w: q.w,
    }
}

/// A pose at `position_m` with `orientation`.
pub fn pose(position_m: DVec3, orientation: Quaternion) -> Option<Pose> {
    Some(Pose {
        position: Some(vector3(position_m)),
        orientation: Some(orientation),
    })
}

/// The rotation taking `from` to the unit vector `to` (identity when `to` is not a usable direction).
pub fn rotation_to(from: DVec3, to: DVec3) -> Quaternion {
    match to.try_normalize() {
        Some(to) => quaternion(DQuat::from_rotation_arc(from, to)),
        None => identity(),
    }
}

/// Key-value metadata of an entity.
pub fn metadata(pairs: &[(&str, String)]) -> Vec<KeyValuePair> {
    pairs
        .iter()
        .map(|(key, value)| KeyValuePair {
            key: (*key).to_owned(),
            value: value.clone(),
        })
        .collect()
}

/// An empty entity `id` in [`WORLD_FRAME`].
pub fn entity(id: String, timestamp: Timestamp, metadata: Vec<KeyValuePair>) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp),
        frame_id: WORLD_FRAME.to_owned(),
        id,
        metadata,
        ..SceneEntity::default()
    }
}

/// A sphere of `diameter_m` at `position_m`.
pub fn sphere(position_m: DVec3, diameter_m: f64, color: Color) -> SpherePrimitive {
    SpherePrimitive {
        pose: pose(position_m, identity()),
        size: Some(vector3(DVec3::splat(diameter_m))),
        color: Some(color),
    }
}

/// An arrow from `start_m` along `vector` (any length), `length_m` long (at most [`MAX_ARROW_M`]); `None`
/// for a zero length or a direction that is not finite.
pub fn arrow(start_m: DVec3, vector: DVec3, length_m: f64, color: Color) -> Option<ArrowPrimitive> {
    let direction = vector.try_normalize()?;
    if !(length_m.is_finite() && length_m > 1e-6) {
        return None;
    }
    let length_m = length_m.min(MAX_ARROW_M);
    let head_length = (0.25 * length_m).min(0.003);
    Some(ArrowPrimitive {
        pose: pose(start_m, rotation_to(DVec3::X, direction)),
        shaft_length: length_m - head_length,
        shaft_diameter: 0.0006,
        head_length,
        head_diameter: 0.0018,
        color: Some(color),
    })
}

/// The markers of one moment: probe, proxy, hand target (when set) and the force arrow from the proxy.
pub fn marker_entities(
    probe_m: DVec3,
    proxy_m: DVec3,
    hand_target_m: Option<DVec3>,
    force_n: DVec3,
    timestamp: Timestamp,
) -> Vec<SceneEntity> {
    let colours = palette();
    let marker = |id: &str, at_m: DVec3, rgb: Rgb| {
        let mut marker = entity(id.to_owned(), timestamp, Vec::new());
        marker
            .spheres
            .push(sphere(at_m, MARKER_DIAMETER_M, color(rgb, 1.0)));
        marker
    };
    let mut entities = Vec::with_capacity(4);
    entities.push(marker("probe", probe_m, colours.probe));
    entities.push(marker("proxy", proxy_m, colours.proxy));
    if let Some(target) = hand_target_m {
        entities.push(marker("hand_target", target, colours.hand));
    }
    let mut force = entity(
        "force".to_owned(),
        timestamp,
        metadata(&[("force_n", force_n.length().to_string())]),
    );
    force.arrows.extend(arrow(
        proxy_m,
        force_n,
        force_n.length() * FORCE_ARROW_M_PER_N,
        color(colours.force, 1.0),
    ));
    entities.push(force);
    entities
}

/// A scene update that first deletes everything drawn before on its topic, then draws `entities`.
pub fn replace_all(entities: Vec<SceneEntity>, timestamp: Timestamp) -> SceneUpdate {
    SceneUpdate {
        deletions: vec![SceneEntityDeletion {
            timestamp: Some(timestamp),
            r#type: scene_entity_deletion::Type::All as i32,
            id: String::new(),
        }],
        entities,
    }
}

fn point3(p: DVec3) -> Point3 {
    Point3 {
        x: p.x,
        y: p.y,
        z: p.z,
    }
}

/// The volume picture: `volume/bounds` (the 12 edges of the world-space bounding box `min_m ..= max_m`,
/// with metadata `volume`, `min_m`, `max_m` and the camera framing: `camera_target_m`,
/// `camera_distance_m`, `bounding_radius_m`, see [`CameraFraming`]) and,
/// when given, `volume/surface` (the iso-surface `mesh` in the surface mode's colour, translucent). Entities
/// never expire; the update replaces the previous volume picture.
pub fn volume_scene(
    min_m: DVec3,
    max_m: DVec3,
    mesh: Option<&(Mesh, Rgb, f64)>,
    description: &str,
    timestamp: Timestamp,
) -> SceneUpdate {
    let corner = |c: usize| {
        DVec3::new(
            if c & 1 == 0 { min_m.x } else { max_m.x },
            if c & 2 == 0 { min_m.y } else { max_m.y },
            if c & 4 == 0 { min_m.z } else { max_m.z },
        )
    };
    let edges = [
        (0, 1),
        (2, 3),
        (4, 5),
        (6, 7),
        (0, 2),
        (1, 3),
        (4, 6),
        (5, 7),
        (0, 4),
        (1, 5),
        (2, 6),
        (3, 7),
    ];
    let framing = CameraFraming::of_bounds(min_m, max_m);
    let mut bounds = entity(
        "volume/bounds".to_owned(),
        timestamp,
        metadata(&[
            ("volume", description.to_owned()),
            ("min_m", format!("{:?}", min_m.to_array())),
            ("max_m", format!("{:?}", max_m.to_array())),
            (
                "camera_target_m",
                format!("{:?}", framing.target_m.to_array()),
            ),
            ("camera_distance_m", framing.distance_m.to_string()),
            ("bounding_radius_m", framing.radius_m.to_string()),
        ]),
    );
    bounds.lines.push(LinePrimitive {
        r#type: line_primitive::Type::LineList as i32,
        pose: pose(DVec3::ZERO, identity()),
        thickness: 2.0,
        scale_invariant: true,
        points: edges
            .iter()
            .flat_map(|&(a, b)| [point3(corner(a)), point3(corner(b))])
            .collect(),
        color: Some(color(palette().bounds, 1.0)),
        colors: Vec::new(),
        indices: Vec::new(),
    });
    let mut entities = vec![bounds];
    if let Some((mesh, rgb, iso)) = mesh {
        let (rgb, iso) = (*rgb, *iso);
        let mut surface = entity(
            "volume/surface".to_owned(),
            timestamp,
            metadata(&[
                ("iso_value", iso.to_string()),
                ("triangles", mesh.triangles.len().to_string()),
            ]),
        );
        surface.triangles.push(TriangleListPrimitive {
            pose: pose(DVec3::ZERO, identity()),
            points: mesh.vertices.iter().map(|&v| point3(v)).collect(),
            color: Some(color(rgb, SURFACE_ALPHA)),
            colors: Vec::new(),
            indices: mesh.triangles.iter().flatten().copied().collect(),
        });
        entities.push(surface);
    }
    replace_all(entities, timestamp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ::foxglove::{Decode, Encode};

    #[test]
    fn frame_transforms_round_trip_through_the_sdk_encoding() {
        let mut transform = frame_transform(PROBE_FRAME, DVec3::new(0.01, -0.02, 0.03), 5);
        set_translation(&mut transform, DVec3::new(0.5, 0.25, -0.125), 1_500_000_001);
        let mut bytes = Vec::new();
        transform.encode(&mut bytes).unwrap();
        let back = FrameTransform::decode(&bytes[..]).unwrap();
        assert_eq!(back, transform);
        assert_eq!(back.timestamp.unwrap().sec(), 1);
        assert_eq!(back.timestamp.unwrap().nsec(), 500_000_001);
        assert_eq!(back.parent_frame_id, "world");
        assert_eq!(back.child_frame_id, "probe");
        let schema = FrameTransform::get_schema().unwrap();
        assert_eq!(schema.name, "foxglove.FrameTransform");
        assert_eq!(schema.encoding, "protobuf");
        assert_eq!(FrameTransform::get_message_encoding(), "protobuf");
        assert_eq!(Vector3::get_schema().unwrap().name, "foxglove.Vector3");
    }

    #[test]
    fn the_camera_is_framed_on_the_bounding_sphere_of_a_small_and_a_large_volume() {
        // The built-in scene's 10 cm cube: radius 5 sqrt(3) cm, distance 1.1 r / sin(22.5 degrees).
        let small = CameraFraming::of_bounds(DVec3::splat(-0.05), DVec3::splat(0.05));
        assert_eq!(small.target_m, DVec3::ZERO);
        assert!((small.radius_m - 0.086_602_540).abs() < 1e-9, "{small:?}");
        assert!((small.distance_m - 0.248_933_7).abs() < 1e-6, "{small:?}");
        // A 0.4 x 0.3 x 1.2 m box off the origin: diagonal 1.3 m.
        let min_m = DVec3::new(0.1, -0.2, 0.3);
        let large = CameraFraming::of_bounds(min_m, min_m + DVec3::new(0.4, 0.3, 1.2));
        assert!((large.target_m - DVec3::new(0.3, -0.05, 0.9)).length() < 1e-12);
        assert!((large.radius_m - 0.65).abs() < 1e-12);
        assert!((large.distance_m - 1.868_385_0).abs() < 1e-6, "{large:?}");
        // The camera stands `distance` from the centre, and the followed frame lies between them, on the
        // line of sight, so the camera looks at the centre.
        for framing in [small, large] {
            let to_camera = framing.camera_m() - framing.target_m;
            assert!((to_camera.length() - framing.distance_m).abs() < 1e-12);
            let to_frame = framing.view_frame_m - framing.target_m;
            assert!(to_frame.cross(to_camera).length() < 1e-12);
            assert!(
                (to_frame.length() - (framing.distance_m - LAYOUT_CAMERA_DISTANCE_M).abs()).abs()
                    < 1e-12
            );
        }
        // Foxglove's orbit camera: phi 0 looks straight down from +z; phi 90, theta 0 stands on -y.
        assert!((camera_direction(0.0, 0.0) - DVec3::Z).length() < 1e-12);
        assert!((camera_direction(90.0, 0.0) + DVec3::Y).length() < 1e-12);
        assert!((camera_direction(90.0, 90.0) + DVec3::X).length() < 1e-12);
        // A degenerate box is framed from the closest distance, never NaN.
        let point = CameraFraming::of_bounds(DVec3::ONE, DVec3::ONE);
        assert_eq!(point.distance_m, MIN_CAMERA_DISTANCE_M);
        let bad = CameraFraming::of_bounds(DVec3::NAN, DVec3::ONE);
        assert!(bad.view_frame_m.is_finite() && bad.distance_m.is_finite());
        // The picture carries the framing; the frames put `volume` at the centre.
        let update = volume_scene(
            min_m,
            min_m + DVec3::new(0.4, 0.3, 1.2),
            None,
            "box",
            timestamp_from_ns(0),
        );
        let bounds = &update.entities[0].metadata;
        let value = |key: &str| {
            bounds
                .iter()
                .find(|kv| kv.key == key)
                .unwrap()
                .value
                .clone()
        };
        assert_eq!(
            value("camera_distance_m").parse::<f64>().unwrap(),
            large.distance_m
        );
        assert_eq!(
            value("bounding_radius_m").parse::<f64>().unwrap(),
            large.radius_m
        );
        let [volume, view] = volume_frames(min_m, min_m + DVec3::new(0.4, 0.3, 1.2), 7);
        assert_eq!(
            (volume.child_frame_id.as_str(), view.child_frame_id.as_str()),
            (VOLUME_FRAME, VIEW_FRAME)
        );
        let at = |t: &FrameTransform| {
            let v = t.translation.as_ref().unwrap();
            DVec3::new(v.x, v.y, v.z)
        };
        assert_eq!(at(&volume), large.target_m);
        assert_eq!(at(&view), large.view_frame_m);
    }

    #[test]
    fn timestamps_saturate_instead_of_wrapping() {
        let far = timestamp_from_ns(u64::MAX);
        assert_eq!(far.sec(), u32::MAX);
        assert!(far.nsec() < 1_000_000_000);
    }
}
