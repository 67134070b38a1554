//! The volume in the Foxglove view: the bounding box and the surface mode's iso-surface (once per scene
//! change), and three orthogonal slices through the proxy (a few times a second) as `foxglove.Grid` planes.
//!
//! Where it sits: the live view's publisher task (`super`) calls these on tokio's blocking pool; they read
//! the session only through [`SessionApi::scene`] and [`SessionApi::slice`] (which samples the volume off
//! the servo thread). The iso-surface is computed from an `n`³ grid of slices by
//! [`voxhap_core::volume::isosurface::bounded_isosurface`], at most [`MAX_TRIANGLES`] triangles.
//!
//! Which volume: the volume of the scene's first surface mode, else the first scalar volume. The
//! iso-value is where the surface mode's transfer function first reaches half its largest strength: for the
//! usual ramp from 0 N at `x0` to `s` N at `x1` that is `(x0 + x1) / 2`, the middle of the shell in which
//! the surface is felt.

use crate::palette::{palette, Rgb};
use crate::topics::{identity, pose, quaternion, timestamp_from_ns, WORLD_FRAME};
use ::foxglove::messages::packed_element_field::NumericType;
use ::foxglove::messages::{Grid, PackedElementField, Vector2};
use glam::{DMat3, DQuat, DVec3};
use voxhap_api::{ControlError, SessionApi, Slice, SliceAxis, SliceRequest};
use voxhap_core::haptics::modes::{ModeKind, TransferFunction};
use voxhap_core::volume::isosurface::{bounded_isosurface, Mesh, SampledGrid};

/// Largest iso-surface mesh sent (triangles).
pub const MAX_TRIANGLES: usize = 60_000;
/// Samples per axis the iso-surface starts from (lowered until the mesh fits [`MAX_TRIANGLES`]).
pub const ISOSURFACE_SAMPLES: usize = 64;
/// Samples per side of a slice.
pub const SLICE_SAMPLES: usize = 128;
/// Opacity of a slice's brightest cells (0 ..= 255); darker cells are more transparent, the darkest fully.
pub const SLICE_ALPHA: u8 = 210;

/// The volume picture of one scene.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumePicture {
    /// The volume drawn, and where it came from.
    pub description: String,
    pub min_m: DVec3,
    pub max_m: DVec3,
    /// The iso-surface, its colour (the surface mode's) and iso-value; `None` without a surface mode.
    pub surface: Option<(Mesh, Rgb, f64)>,
    /// The volume sliced (its scene name).
    pub volume_name: String,
}

/// The value at which `transfer` first reaches half its largest strength; `None` when it is zero everywhere.
pub fn half_strength_value(transfer: &TransferFunction) -> Option<f64> {
    let half = 0.5 * transfer.max_strength_n();
    if half <= 0.0 {
        return None;
    }
    let points = transfer.points();
    if points[0][1] >= half {
        return Some(points[0][0]);
    }
    points.windows(2).find_map(|pair| {
        let ([x0, y0], [x1, y1]) = (pair[0], pair[1]);
        (y0 < half && y1 >= half).then(|| x0 + (half - y0) / (y1 - y0) * (x1 - x0))
    })
}

/// The volume to draw: its scene name, description, bounds and, for a surface mode, its colour and
/// iso-value.
struct Chosen {
    name: String,
    description: String,
    min_m: DVec3,
    max_m: DVec3,
    iso: Option<(Rgb, f64)>,
}

/// The volume to draw and, for a surface mode, its colour and iso-value.
fn choose(api: &dyn SessionApi) -> Result<Chosen, ControlError> {
    let scene = api.scene();
    let surface = scene
        .modes
        .iter()
        .enumerate()
        .find(|(_, mode)| mode.kind == ModeKind::Surface);
    let surface_volume = surface.and_then(|(_, mode)| mode.volume.clone());
    let report = surface_volume
        .as_deref()
        .and_then(|name| scene.volumes.iter().find(|v| v.name == name))
        .or_else(|| scene.volumes.iter().find(|v| v.kind == "scalar"))
        .or_else(|| scene.volumes.first())
        .ok_or_else(|| ControlError::NotFound("the scene has no volume".to_owned()))?;
    let iso = surface.and_then(|(index, mode)| {
        let value = half_strength_value(mode.transfer.as_ref()?)?;
        (report.kind == "scalar").then_some((palette().mode(index), value))
    });
    Ok(Chosen {
        name: report.name.clone(),
        description: format!("{} ({})", report.name, report.source),
        min_m: report.min_m,
        max_m: report.max_m,
        iso,
    })
}

/// An `n`³ grid of the volume `name` over `min_m ..= max_m`, from `n` z-slices.
fn grid_from_slices(
    api: &dyn SessionApi,
    name: &str,
    min_m: DVec3,
    max_m: DVec3,
    n: usize,
) -> Result<SampledGrid, ControlError> {
    let n = n.clamp(16, 512);
    let centre = (min_m + max_m) * 0.5;
    let dz = (max_m.z - min_m.z) / (n - 1) as f64;
    let mut values = Vec::with_capacity(n * n * n);
    let mut first: Option<Slice> = None;
    for k in 0..n {
        let request = SliceRequest {
            axis: SliceAxis::Z,
            size: n,
            at_m: Some(DVec3::new(centre.x, centre.y, min_m.z + dz * k as f64)),
            volume: Some(name.to_owned()),
        };
        let mut slice = api.slice(request)?;
        values.append(&mut slice.values);
        first.get_or_insert(slice);
    }
    let first = first.ok_or_else(|| ControlError::Invalid("no slices".to_owned()))?;
    Ok(SampledGrid {
        dims: [n, n, n],
        origin_m: DVec3::new(first.origin_m.x, first.origin_m.y, min_m.z),
        step_m: DVec3::new(first.u_m.x, first.v_m.y, dz),
        values,
    })
}

/// The bounding box and iso-surface of the scene's volume (blocking: samples the volume).
pub fn volume_picture(api: &dyn SessionApi) -> Result<VolumePicture, ControlError> {
    let Chosen {
        name,
        description,
        min_m,
        max_m,
        iso,
    } = choose(api)?;
    let surface = match iso {
        Some((rgb, value)) => {
            let (mesh, _) =
                bounded_isosurface(value as f32, ISOSURFACE_SAMPLES, MAX_TRIANGLES, |n| {
                    grid_from_slices(api, &name, min_m, max_m, n)
                })?;
            Some((mesh, rgb, value))
        }
        None => None,
    };
    Ok(VolumePicture {
        description,
        min_m,
        max_m,
        surface,
        volume_name: name,
    })
}

/// The three slices through `at_m` of volume `name` as Foxglove grids (blocking: samples the volume).
pub fn slice_grids(
    api: &dyn SessionApi,
    name: &str,
    at_m: DVec3,
    time_ns: u64,
) -> Result<[Grid; 3], ControlError> {
    let grid = |axis| -> Result<Grid, ControlError> {
        let slice = api.slice(SliceRequest {
            axis,
            size: SLICE_SAMPLES,
            at_m: Some(at_m),
            volume: Some(name.to_owned()),
        })?;
        Ok(slice_grid(&slice, time_ns))
    };
    Ok([
        grid(SliceAxis::X)?,
        grid(SliceAxis::Y)?,
        grid(SliceAxis::Z)?,
    ])
}

/// A slice as a `foxglove.Grid` in [`WORLD_FRAME`]: one cell per sample, fields `value` (float32) and
/// `red`, `green`, `blue`, `alpha` (uint8). Each cell's level `t` is its value between the slice's minimum
/// (0) and maximum (1); grey is `t` x 255 and the opacity follows the data too, `t` x [`SLICE_ALPHA`], so
/// empty space (the minimum) is fully transparent and the iso-surface behind it stays visible. A constant
/// slice has no range of its own and is measured against zero: a positive constant is material everywhere
/// on the plane (`t` = 1, white), zero or a negative constant nothing (`t` = 0, transparent), never a
/// mid-grey that would read as half-density material.
pub fn slice_level(value: f32, min: f32, max: f32) -> f32 {
    let span = max - min;
    let t = if span > 0.0 {
        (value - min) / span
    } else if value > 0.0 {
        1.0
    } else {
        0.0
    };
    if t.is_nan() {
        0.0
    } else {
        t.clamp(0.0, 1.0)
    }
}

/// The slice `slice` as a grid (see [`slice_level`] for its colours).
pub fn slice_grid(slice: &Slice, time_ns: u64) -> Grid {
    let (u_len, v_len) = (slice.u_m.length(), slice.v_m.length());
    let u_dir = slice.u_m.try_normalize().unwrap_or(DVec3::X);
    let v_dir = slice.v_m.try_normalize().unwrap_or(DVec3::Y);
    let rotation = DQuat::from_mat3(&DMat3::from_cols(u_dir, v_dir, u_dir.cross(v_dir)));
    // Cells are centred on the samples: the grid's corner is half a cell before sample (0, 0).
    let corner = slice.origin_m - 0.5 * (slice.u_m + slice.v_m);
    let mut data = Vec::with_capacity(slice.values.len() * 8);
    for &value in &slice.values {
        let t = slice_level(value, slice.min, slice.max);
        let grey = (t * 255.0).round() as u8;
        let alpha = (t * f32::from(SLICE_ALPHA)).round() as u8;
        data.extend_from_slice(&value.to_le_bytes());
        data.extend_from_slice(&[grey, grey, grey, alpha]);
    }
    let field = |name: &str, offset: u32, kind: NumericType| PackedElementField {
        name: name.to_owned(),
        offset,
        r#type: kind as i32,
    };
    Grid {
        timestamp: Some(timestamp_from_ns(time_ns)),
        frame_id: WORLD_FRAME.to_owned(),
        pose: pose(
            corner,
            if u_len > 0.0 {
                quaternion(rotation)
            } else {
                identity()
            },
        ),
        column_count: slice.width as u32,
        cell_size: Some(Vector2 { x: u_len, y: v_len }),
        row_stride: (slice.width * 8) as u32,
        cell_stride: 8,
        fields: vec![
            field("value", 0, NumericType::Float32),
            field("red", 4, NumericType::Uint8),
            field("green", 5, NumericType::Uint8),
            field("blue", 6, NumericType::Uint8),
            field("alpha", 7, NumericType::Uint8),
        ],
        data: data.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_iso_value_is_where_the_transfer_reaches_half_strength() {
        let ramp = TransferFunction::ramp(0.45, 0.5, 2.0).unwrap();
        assert!((half_strength_value(&ramp).unwrap() - 0.475).abs() < 1e-12);
        let steps =
            TransferFunction::new(vec![[0.0, 0.0], [1.0, 0.5], [2.0, 0.5], [3.0, 4.0]]).unwrap();
        assert!((half_strength_value(&steps).unwrap() - (2.0 + 1.5 / 3.5)).abs() < 1e-12);
        assert_eq!(
            half_strength_value(&TransferFunction::constant(0.0).unwrap()),
            None
        );
        assert_eq!(
            half_strength_value(&TransferFunction::constant(1.0).unwrap()),
            Some(0.0)
        );
    }

    /// A constant slice is drawn as what it is: material (a positive constant) white and opaque, empty space
    /// (zero, or a negative constant such as air in CT numbers) transparent; never the mid-grey (128) it was
    /// drawn as before, which reads as half-density material.
    #[test]
    fn a_constant_slice_is_material_or_nothing_not_mid_grey() {
        let constant = |value: f32| Slice {
            axis: SliceAxis::Z,
            width: 2,
            height: 1,
            origin_m: DVec3::ZERO,
            u_m: DVec3::X * 0.001,
            v_m: DVec3::Y * 0.001,
            min: value,
            max: value,
            values: vec![value; 2],
            volume: "v".to_owned(),
            volume_kind: "scalar",
            volume_min_m: DVec3::ZERO,
            volume_max_m: DVec3::ONE,
        };
        let cell = |grid: &Grid| grid.data[4..8].to_vec();
        assert_eq!(
            cell(&slice_grid(&constant(0.7), 0)),
            [255, 255, 255, SLICE_ALPHA]
        );
        assert_eq!(cell(&slice_grid(&constant(0.0), 0)), [0, 0, 0, 0]);
        assert_eq!(cell(&slice_grid(&constant(-1000.0), 0)), [0, 0, 0, 0]);
        assert_eq!(slice_level(f32::NAN, 0.0, 1.0), 0.0);
    }

    #[test]
    fn a_z_slice_grid_lies_flat_and_an_x_slice_stands_in_the_y_z_plane() {
        let slice = |axis, u_m: DVec3, v_m: DVec3| Slice {
            axis,
            width: 2,
            height: 2,
            origin_m: DVec3::new(0.0, 0.0, 0.01),
            u_m,
            v_m,
            min: 0.0,
            max: 1.0,
            values: vec![0.0, 1.0, 0.5, 1.0],
            volume: "v".to_owned(),
            volume_kind: "scalar",
            volume_min_m: DVec3::ZERO,
            volume_max_m: DVec3::ONE,
        };
        let flat = slice_grid(&slice(SliceAxis::Z, DVec3::X * 0.001, DVec3::Y * 0.002), 0);
        let q = flat.pose.as_ref().unwrap().orientation.as_ref().unwrap();
        assert!((q.w.abs() - 1.0).abs() < 1e-12);
        assert_eq!(flat.cell_size, Some(Vector2 { x: 0.001, y: 0.002 }));
        assert_eq!(flat.data.len(), 4 * 8);
        assert_eq!(&flat.data[12..16], &[255, 255, 255, SLICE_ALPHA]);
        // The transparency follows the data: the minimum is invisible, half-way is half as opaque.
        assert_eq!(&flat.data[4..8], &[0, 0, 0, 0]);
        assert_eq!(&flat.data[20..24], &[128, 128, 128, 105]);
        let standing = slice_grid(&slice(SliceAxis::X, DVec3::Y * 0.001, DVec3::Z * 0.001), 0);
        let q = standing
            .pose
            .as_ref()
            .unwrap()
            .orientation
            .as_ref()
            .unwrap();
        let rotation = DQuat::from_xyzw(q.x, q.y, q.z, q.w);
        assert!((rotation * DVec3::X - DVec3::Y).length() < 1e-12);
        assert!((rotation * DVec3::Y - DVec3::Z).length() < 1e-12);
    }
}
