//! Slices of the scene's volumes for visualisers: a volume sampled on an axis-aligned plane through a point
//! (usually the proxy), as a `size` x `size` image spanning the volume's bounding box.
//!
//! Off the real-time path: [`SessionApi::slice`](super::SessionApi::slice) clones the volume handle
//! (the samples are shared through an `Arc`, so this copies no voxels) under the control lock, releases it,
//! and samples here on the caller's thread. The servo thread is never involved.
//!
//! Sampling follows the volume rules ([`voxhap_core::volume`]): trilinear, clamp-to-edge outside the grid. A plane
//! outside the box therefore shows the nearest face; a rotated grid's bounding box has clamped corners. A vector
//! volume is shown as its magnitude.

use super::{ControlError, NamedVolume, Slice, SliceAxis, SliceRequest, SLICE_SIZE_RANGE};
use glam::DVec3;
use voxhap_core::volume::AnyVolume;

/// The volume named `name`, or the first scalar volume (the first volume if none is scalar).
pub fn pick_volume<'a>(
    volumes: &'a [NamedVolume],
    name: Option<&str>,
) -> Result<&'a NamedVolume, ControlError> {
    match name {
        Some(name) => volumes.iter().find(|v| v.name == name).ok_or_else(|| {
            let names: Vec<&str> = volumes.iter().map(|v| v.name.as_str()).collect();
            ControlError::NotFound(format!("no volume named {name:?} (volumes: {names:?})"))
        }),
        None => volumes
            .iter()
            .find(|v| matches!(v.volume, AnyVolume::Scalar(_)))
            .or_else(|| volumes.first())
            .ok_or_else(|| ControlError::NotFound("the scene has no volume".to_owned())),
    }
}

/// Checks the size and the point of `request` (before any lock is taken).
pub fn check_request(request: &SliceRequest) -> Result<(), ControlError> {
    let (min, max) = SLICE_SIZE_RANGE;
    if !(min..=max).contains(&request.size) {
        return Err(ControlError::Invalid(format!(
            "size must be {min} ..= {max} samples, got {}",
            request.size
        )));
    }
    if let Some(at) = request.at_m {
        if !at.is_finite() {
            return Err(ControlError::Invalid(
                "at must be three finite numbers (m)".to_owned(),
            ));
        }
    }
    Ok(())
}

/// The in-plane unit axes (u along the width, v along the height) of a plane normal to `axis`.
fn plane_axes(axis: SliceAxis) -> (DVec3, DVec3, DVec3) {
    match axis {
        SliceAxis::X => (DVec3::Y, DVec3::Z, DVec3::X),
        SliceAxis::Y => (DVec3::X, DVec3::Z, DVec3::Y),
        SliceAxis::Z => (DVec3::X, DVec3::Y, DVec3::Z),
    }
}

/// Samples `named` on the plane normal to `request.axis` through `at_m`.
pub fn sample_slice(
    named: &NamedVolume,
    request: &SliceRequest,
    at_m: DVec3,
) -> Result<Slice, ControlError> {
    check_request(request)?;
    if !at_m.is_finite() {
        return Err(ControlError::Invalid(
            "the slice point is not finite".to_owned(),
        ));
    }
    let (min_m, max_m) = named.volume.grid().bounds_world();
    let (u_axis, v_axis, normal) = plane_axes(request.axis);
    let size = request.size;
    let steps = (size - 1) as f64;
    let u_m = u_axis * ((max_m - min_m).dot(u_axis) / steps);
    let v_m = v_axis * ((max_m - min_m).dot(v_axis) / steps);
    let origin_m = min_m * (u_axis + v_axis) + normal * at_m.dot(normal);
    let sample: Box<dyn Fn(DVec3) -> f32> = match &named.volume {
        AnyVolume::Scalar(volume) => Box::new(move |p| volume.sample(p) as f32),
        AnyVolume::Vector(volume) => Box::new(move |p| volume.sample(p).length() as f32),
    };
    let mut values = Vec::with_capacity(size * size);
    let (mut min, mut max) = (f32::INFINITY, f32::NEG_INFINITY);
    for j in 0..size {
        let row = origin_m + v_m * j as f64;
        for i in 0..size {
            // Stored values are finite and trilinear weights are in [0, 1]: the sample is finite.
            let value = sample(row + u_m * i as f64);
            min = min.min(value);
            max = max.max(value);
            values.push(value);
        }
    }
    Ok(Slice {
        axis: request.axis,
        width: size,
        height: size,
        origin_m,
        u_m,
        v_m,
        min,
        max,
        values,
        volume: named.name.clone(),
        volume_kind: named.volume.kind(),
        volume_min_m: min_m,
        volume_max_m: max_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in serve scene's volumes (sims/scenes/explore.toml): density (scalar) and flow (vector).
    struct Volumes {
        volumes: Vec<NamedVolume>,
    }

    fn builtin_scene() -> Volumes {
        let built = voxhap_core::volume::procedural::builtin("density-flow").unwrap();
        let named = |name: &str, volume| NamedVolume {
            name: name.to_owned(),
            source: "builtin:density-flow".to_owned(),
            volume,
        };
        Volumes {
            volumes: vec![
                named("density", AnyVolume::Scalar(built.scalar.unwrap())),
                named("flow", AnyVolume::Vector(built.vector.unwrap())),
            ],
        }
    }

    #[test]
    fn a_slice_spans_the_bounding_box_and_is_row_major_v_outer() {
        let setup = builtin_scene();
        let named = pick_volume(&setup.volumes, None).unwrap();
        assert_eq!(named.name, "density");
        let request = SliceRequest {
            axis: SliceAxis::Y,
            size: 16,
            ..SliceRequest::default()
        };
        let slice = sample_slice(named, &request, DVec3::new(0.0, 0.001, 0.0)).unwrap();
        let (min_m, max_m) = named.volume.grid().bounds_world();
        assert_eq!(slice.values.len(), 256);
        assert!(slice.values.iter().all(|v| v.is_finite()));
        assert_eq!(slice.origin_m, DVec3::new(min_m.x, 0.001, min_m.z));
        let far = slice.origin_m + slice.u_m * 15.0 + slice.v_m * 15.0;
        assert!((far - DVec3::new(max_m.x, 0.001, max_m.z)).length() < 1e-12);
        assert_eq!(slice.u_m.y, 0.0);
        assert_eq!(slice.v_m.x, 0.0);
        // values[j * width + i] is the sample at origin + i u + j v.
        let AnyVolume::Scalar(volume) = &named.volume else {
            panic!("density is scalar")
        };
        let (i, j) = (3, 11);
        let p = slice.origin_m + slice.u_m * i as f64 + slice.v_m * j as f64;
        assert_eq!(slice.values[j * 16 + i], volume.sample(p) as f32);
        assert!(slice.min <= slice.max && slice.max > slice.min);
    }

    #[test]
    fn bad_requests_name_the_problem() {
        let setup = builtin_scene();
        let mut request = SliceRequest {
            size: 8,
            ..SliceRequest::default()
        };
        let err = check_request(&request).unwrap_err();
        assert!(err.to_string().contains("size must be 16 ..= 512"), "{err}");
        request.size = 16;
        request.at_m = Some(DVec3::new(0.0, f64::NAN, 0.0));
        assert!(check_request(&request)
            .unwrap_err()
            .to_string()
            .contains("at must be"));
        let err = pick_volume(&setup.volumes, Some("nope")).unwrap_err();
        assert_eq!(err.http_status(), 404);
        assert!(err.to_string().contains("\"density\""), "{err}");
        // A vector volume by name gives its magnitude.
        let flow = pick_volume(&setup.volumes, Some("flow")).unwrap();
        let slice = sample_slice(flow, &SliceRequest::default(), DVec3::ZERO).unwrap();
        assert_eq!(slice.volume_kind, "vector");
        assert!(slice.values.iter().all(|v| *v >= 0.0));
    }
}
