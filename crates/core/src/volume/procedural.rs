//! Procedural volumes: analytic fields sampled onto a grid, for demos, sims and tests.
//!
//! All in SI units, centred at the world origin, sampled onto the grid the caller gives (the built-ins: a cube
//! grid centred at the origin, [`Grid::centred_cube`]).
//!
//! Densities (1 inside, 0 outside) use a smooth edge two voxels wide so the gradient is defined and
//! continuous at the surface: with `d` the signed distance to the surface (negative inside) and `w`
//! the edge width, `density = smoothstep(clamp(1/2 - d/w, 0, 1))`, `smoothstep(s) = s²(3 - 2s)`.
//! **The density gradient points inward** (up-hill, towards denser material); the outward surface
//! normal is `-∇V/|∇V|`.
//!
//! Flows (velocities in m/s, vortex axis along world z through the origin), in cylindrical
//! coordinates `(r, θ, z)`:
//! - Rankine vortex, core radius `a`, circulation `Γ` (m²/s): `v_θ = Γ r / (2π a²)` for `r < a`
//!   (solid-body rotation, curl `Γ/(π a²)` ẑ), `v_θ = Γ / (2π r)` outside (irrotational, curl 0).
//!   Divergence 0 everywhere.
//! - Burgers vortex, core radius `δ`, circulation `Γ`, strain rate `α` (1/s):
//!   `v_r = -α r / 2`, `v_z = α z`, `v_θ = Γ / (2π r) · (1 - exp(-r²/δ²))`. Divergence
//!   `-α + α = 0`; axial vorticity `Γ/(π δ²) · exp(-r²/δ²)`.

use super::any::AnyVolume;
use super::error::VolumeError;
pub use super::error::BUILTIN_NAMES;
use super::grid::Grid;
use super::scalar::ScalarVolume;
use super::vector::VectorVolume;
use glam::DVec3;
use std::f64::consts::PI;

/// Default grid of the built-in volumes: 64³ voxels.
pub const BUILTIN_DIMS: [usize; 3] = [64; 3];
/// Default half extent of the built-in volumes: a 0.1 m cube, the size of a haptic workspace.
pub const BUILTIN_HALF_EXTENT_M: f64 = 0.05;

/// Width of the smooth density edge, in voxels.
const EDGE_WIDTH_VOXELS: f64 = 2.0;

/// Smooth step from 1 (inside, `signed_distance < 0`) to 0 across `width`.
fn smooth_inside(signed_distance: f64, width: f64) -> f64 {
    let s = (0.5 - signed_distance / width).clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// The cube grid of half extent `half_extent_m` centred at the origin, with a bad half extent refused by name.
fn cube(dims: [usize; 3], half_extent_m: f64) -> Result<Grid, VolumeError> {
    positive("half_extent_m", half_extent_m)?;
    Grid::centred_cube(dims, half_extent_m)
}

fn positive(name: &'static str, value: f64) -> Result<(), VolumeError> {
    require(
        name,
        value,
        value.is_finite() && value > 0.0,
        "must be finite and positive",
    )
}

fn finite(name: &'static str, value: f64) -> Result<(), VolumeError> {
    require(name, value, value.is_finite(), "must be finite")
}

/// `Ok` when `holds`, else the parameter `name` = `value` refused for `reason`.
fn require(
    name: &'static str,
    value: f64,
    holds: bool,
    reason: &'static str,
) -> Result<(), VolumeError> {
    if holds {
        Ok(())
    } else {
        Err(VolumeError::BadParameter {
            name,
            value,
            reason,
        })
    }
}

fn edge_width_m(grid: &Grid) -> f64 {
    EDGE_WIDTH_VOXELS * grid.spacing_m().max_element()
}

/// A solid of density 1 on `grid`: inside where `signed_distance_m(p)` < 0, with the smooth edge
/// ([`smooth_inside`] over [`edge_width_m`]).
fn solid(
    grid: Grid,
    signed_distance_m: impl Fn(DVec3) -> f64,
) -> Result<ScalarVolume, VolumeError> {
    let width = edge_width_m(&grid);
    ScalarVolume::from_fn(grid, |p| smooth_inside(signed_distance_m(p), width))
}

/// A solid ball of density 1 and radius `radius_m`, centred at the origin.
pub fn sphere(radius_m: f64, grid: Grid) -> Result<ScalarVolume, VolumeError> {
    positive("radius_m", radius_m)?;
    solid(grid, |p| p.length() - radius_m)
}

/// A solid torus of density 1 around the z axis: ring radius `major_radius_m`, tube radius
/// `minor_radius_m`.
pub fn torus(
    major_radius_m: f64,
    minor_radius_m: f64,
    grid: Grid,
) -> Result<ScalarVolume, VolumeError> {
    positive("major_radius_m", major_radius_m)?;
    positive("minor_radius_m", minor_radius_m)?;
    solid(grid, |p| {
        let ring = (p.x.hypot(p.y) - major_radius_m).hypot(p.z);
        ring - minor_radius_m
    })
}

/// `shell_count` nested spherical shells of density 1, each `thickness_m` thick, centred on radii
/// `outer_radius_m · n / shell_count` for `n = 1..=shell_count`.
pub fn shells(
    outer_radius_m: f64,
    shell_count: usize,
    thickness_m: f64,
    grid: Grid,
) -> Result<ScalarVolume, VolumeError> {
    positive("outer_radius_m", outer_radius_m)?;
    positive("thickness_m", thickness_m)?;
    positive("shell_count", shell_count as f64)?;
    let pitch = outer_radius_m / shell_count as f64;
    solid(grid, |p| {
        let r = p.length();
        // Distance to the nearest shell's mid radius.
        let nearest = (r / pitch).round().clamp(1.0, shell_count as f64) * pitch;
        (r - nearest).abs() - thickness_m / 2.0
    })
}

/// Rankine vortex velocity at `p` (axis z through the origin).
fn rankine_velocity(p: DVec3, core_radius_m: f64, circulation_m2_per_s: f64) -> DVec3 {
    let r = p.x.hypot(p.y);
    let tangential_per_r = if r < core_radius_m {
        circulation_m2_per_s / (2.0 * PI * core_radius_m * core_radius_m)
    } else {
        circulation_m2_per_s / (2.0 * PI * r * r)
    };
    // (-y, x)/r · v_θ = (-y, x) · v_θ/r, finite at r = 0.
    DVec3::new(-p.y, p.x, 0.0) * tangential_per_r
}

/// A Rankine vortex around the z axis (m/s).
pub fn rankine_vortex(
    core_radius_m: f64,
    circulation_m2_per_s: f64,
    grid: Grid,
) -> Result<VectorVolume, VolumeError> {
    positive("core_radius_m", core_radius_m)?;
    finite("circulation_m2_per_s", circulation_m2_per_s)?;
    VectorVolume::from_fn(grid, |p| {
        rankine_velocity(p, core_radius_m, circulation_m2_per_s)
    })
}

/// Burgers vortex velocity at `p` (axis z through the origin).
fn burgers_velocity(
    p: DVec3,
    core_radius_m: f64,
    circulation_m2_per_s: f64,
    strain_rate_per_s: f64,
) -> DVec3 {
    let r2 = p.x * p.x + p.y * p.y;
    let delta2 = core_radius_m * core_radius_m;
    // v_θ / r = Γ (1 - exp(-r²/δ²)) / (2π r²), which tends to Γ / (2π δ²) at the axis.
    let tangential_per_r = if r2 > 1e-12 * delta2 {
        circulation_m2_per_s * (-(-r2 / delta2).exp_m1()) / (2.0 * PI * r2)
    } else {
        circulation_m2_per_s / (2.0 * PI * delta2)
    };
    DVec3::new(-p.y, p.x, 0.0) * tangential_per_r
        + DVec3::new(-p.x / 2.0, -p.y / 2.0, p.z) * strain_rate_per_s
}

/// A Burgers vortex around the z axis (m/s): a Gaussian-cored swirl stretched along z by an axial
/// strain `strain_rate_per_s`, fed by a radial inflow.
pub fn burgers_vortex(
    core_radius_m: f64,
    circulation_m2_per_s: f64,
    strain_rate_per_s: f64,
    grid: Grid,
) -> Result<VectorVolume, VolumeError> {
    positive("core_radius_m", core_radius_m)?;
    finite("circulation_m2_per_s", circulation_m2_per_s)?;
    finite("strain_rate_per_s", strain_rate_per_s)?;
    VectorVolume::from_fn(grid, |p| {
        burgers_velocity(p, core_radius_m, circulation_m2_per_s, strain_rate_per_s)
    })
}

/// A density ball (radius 0.6 of the half extent) with a Burgers vortex running through it along z
/// (core radius 0.15, circulation and strain scaled to the half extent): multi-modal demo data on one
/// grid, the cube grid of `dims` voxels centred at the origin.
pub fn density_and_flow(
    dims: [usize; 3],
    half_extent_m: f64,
) -> Result<(ScalarVolume, VectorVolume), VolumeError> {
    let grid = cube(dims, half_extent_m)?;
    let density = sphere(0.6 * half_extent_m, grid.clone())?;
    let core_radius_m = 0.15 * half_extent_m;
    // Peak swirl ~0.1 m/s at the core edge for a 5 cm half extent.
    let circulation_m2_per_s = 2.0 * PI * core_radius_m * 0.16;
    let flow = burgers_vortex(core_radius_m, circulation_m2_per_s, 1.0, grid)?;
    Ok((density, flow))
}

/// The volumes of a built-in: a scalar field, a vector field, or both on the same grid.
#[derive(Debug, Clone, PartialEq)]
pub struct BuiltinVolumes {
    pub scalar: Option<ScalarVolume>,
    pub vector: Option<VectorVolume>,
}

impl BuiltinVolumes {
    /// The volumes as a list (scalar first).
    pub fn into_volumes(self) -> Vec<AnyVolume> {
        let mut volumes = Vec::new();
        volumes.extend(self.scalar.map(AnyVolume::Scalar));
        volumes.extend(self.vector.map(AnyVolume::Vector));
        volumes
    }
}

/// A named built-in volume at the default size ([`BUILTIN_DIMS`] over a 0.1 m cube):
///
/// | name | contents |
/// |---|---|
/// | `sphere` | ball, radius 3 cm |
/// | `torus` | torus around z, ring radius 2.5 cm, tube radius 1 cm |
/// | `shells` | 3 nested shells, outer radius 4 cm, 5 mm thick |
/// | `rankine` | Rankine vortex, core radius 1 cm, circulation 0.01 m²/s |
/// | `burgers` | Burgers vortex, core radius 1 cm, circulation 0.01 m²/s, strain 1/s |
/// | `density-flow` | [`density_and_flow`]: ball of radius 3 cm plus a Burgers vortex |
pub fn builtin(name: &str) -> Result<BuiltinVolumes, VolumeError> {
    let grid = || cube(BUILTIN_DIMS, BUILTIN_HALF_EXTENT_M);
    let scalar = |volume| BuiltinVolumes {
        scalar: Some(volume),
        vector: None,
    };
    let vector = |volume| BuiltinVolumes {
        scalar: None,
        vector: Some(volume),
    };
    Ok(match name {
        "sphere" => scalar(sphere(0.03, grid()?)?),
        "torus" => scalar(torus(0.025, 0.01, grid()?)?),
        "shells" => scalar(shells(0.04, 3, 0.005, grid()?)?),
        "rankine" => vector(rankine_vortex(0.01, 0.01, grid()?)?),
        "burgers" => vector(burgers_vortex(0.01, 0.01, 1.0, grid()?)?),
        "density-flow" => {
            let (density, flow) = density_and_flow(BUILTIN_DIMS, BUILTIN_HALF_EXTENT_M)?;
            BuiltinVolumes {
                scalar: Some(density),
                vector: Some(flow),
            }
        }
        _ => {
            return Err(VolumeError::UnknownBuiltin {
                name: name.to_owned(),
            })
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const DIMS: [usize; 3] = [48; 3];
    const HALF: f64 = 0.05;

    /// The tests' grid: a 0.1 m cube of 48³ voxels.
    fn grid() -> Grid {
        Grid::centred_cube(DIMS, HALF).unwrap()
    }

    /// The built-in ball's surface normal from the sampled gradient is within 1 degree of the analytic sphere
    /// normal everywhere on the surface (radius where the density is 1/2, and 0.1 mm either side): what
    /// friction needs (tan 1 degree = 0.017 is 3.5 % of mu = 0.5).
    #[test]
    fn the_ball_gradient_normal_is_within_a_degree_of_the_sphere_normal() {
        let ball = sphere(0.03, cube(BUILTIN_DIMS, BUILTIN_HALF_EXTENT_M).unwrap()).unwrap();
        let mut worst: f64 = 0.0;
        // A Fibonacci lattice of directions covers the sphere evenly.
        let count = 4000;
        for i in 0..count {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / count as f64;
            let phi = i as f64 * PI * (3.0 - 5f64.sqrt());
            let r = (1.0 - z * z).sqrt();
            let normal = DVec3::new(r * phi.cos(), r * phi.sin(), z);
            for radius in [0.0299, 0.03, 0.0301] {
                let outward = -ball.gradient(normal * radius).normalize();
                worst = worst.max(outward.dot(normal).clamp(-1.0, 1.0).acos().to_degrees());
            }
        }
        assert!(worst < 1.0, "normal up to {worst} degrees off");
    }

    #[test]
    fn sphere_is_dense_inside_empty_outside_with_inward_gradient() {
        let radius = 0.03;
        let volume = sphere(radius, grid()).unwrap();
        assert!(volume.sample(DVec3::ZERO) > 0.99);
        assert!(volume.sample(DVec3::new(0.045, 0.0, 0.0)) < 0.01);
        let (min, max) = volume.value_range();
        assert!(min >= 0.0 && max <= 1.0);
        for direction in [
            DVec3::X,
            DVec3::new(1.0, 2.0, -0.5).normalize(),
            DVec3::new(-0.3, -0.3, 0.9).normalize(),
        ] {
            let on_surface = direction * radius;
            let (value, gradient) = volume.sample_with_gradient(on_surface);
            assert!((value - 0.5).abs() < 0.1, "surface value {value}");
            // Inward: against the outward radial direction, and nearly parallel to it.
            let cosine = gradient.normalize().dot(-direction);
            assert!(cosine > 0.98, "gradient {gradient} at {on_surface}");
        }
    }

    #[test]
    fn torus_tube_is_dense_and_hole_is_empty() {
        let volume = torus(0.025, 0.01, grid()).unwrap();
        assert!(volume.sample(DVec3::new(0.025, 0.0, 0.0)) > 0.99);
        assert!(volume.sample(DVec3::new(0.0, -0.025, 0.0)) > 0.99);
        assert!(volume.sample(DVec3::ZERO) < 0.01);
        assert!(volume.sample(DVec3::new(0.025, 0.0, 0.02)) < 0.01);
    }

    #[test]
    fn shells_alternate_along_a_ray() {
        let volume = shells(0.04, 3, 0.006, grid()).unwrap();
        let along = |r: f64| volume.sample(DVec3::new(0.0, r, 0.0));
        let pitch = 0.04 / 3.0;
        for n in 1..=3 {
            assert!(along(pitch * n as f64) > 0.9, "shell {n}");
            assert!(
                along(pitch * (n as f64 - 0.5)) < 0.1,
                "gap before shell {n}"
            );
        }
        assert!(along(0.048) < 0.1);
    }

    #[test]
    fn rankine_curl_is_axial_in_the_core_and_vanishes_outside() {
        let core = 0.015;
        let circulation = 0.02;
        let volume = rankine_vortex(core, circulation, grid()).unwrap();
        let expected_core_curl = circulation / (PI * core * core);
        for p in [
            DVec3::new(0.003, -0.002, 0.01),
            DVec3::new(-0.005, 0.0, -0.02),
        ] {
            let curl = volume.curl(p);
            assert!(
                (curl.z - expected_core_curl).abs() < 0.03 * expected_core_curl,
                "core curl {curl} vs {expected_core_curl}"
            );
            assert!(curl.truncate().length() < 1e-3 * expected_core_curl);
        }
        for p in [
            DVec3::new(0.03, 0.01, 0.0),
            DVec3::new(-0.025, -0.025, 0.02),
        ] {
            let curl = volume.curl(p);
            assert!(
                curl.length() < 0.05 * expected_core_curl,
                "outer curl {curl} should be ~0"
            );
        }
        // Swirl is counter-clockwise about +z for positive circulation.
        assert!(volume.sample(DVec3::new(0.02, 0.0, 0.0)).y > 0.0);
    }

    #[test]
    fn solenoidal_fields_have_near_zero_divergence() {
        let rankine = rankine_vortex(0.015, 0.02, grid()).unwrap();
        let burgers = burgers_vortex(0.01, 0.02, 2.0, grid()).unwrap();
        let curl_scale = 0.02 / (PI * 0.015 * 0.015);
        for p in [
            DVec3::new(0.004, 0.003, 0.0),
            DVec3::new(0.02, -0.011, 0.01),
            DVec3::new(-0.031, 0.012, -0.03),
        ] {
            assert!(rankine.divergence(p).abs() < 0.02 * curl_scale);
            // The strain part alone has |∂v_z/∂z| = 2/s: divergence must cancel it.
            assert!(
                burgers.divergence(p).abs() < 0.05 * 2.0,
                "{}",
                burgers.divergence(p)
            );
        }
    }

    #[test]
    fn burgers_vorticity_peaks_on_the_axis() {
        let core = 0.01;
        let circulation = 0.02;
        let volume = burgers_vortex(core, circulation, 1.0, grid()).unwrap();
        let on_axis = volume.curl(DVec3::new(0.0, 0.0, 0.01)).z;
        let expected = circulation / (PI * core * core);
        assert!(
            (on_axis - expected).abs() < 0.05 * expected,
            "{on_axis} vs {expected}"
        );
        let off_axis = volume.curl(DVec3::new(0.02, 0.0, 0.01)).z;
        let expected_off = expected * (-4.0f64).exp();
        assert!(
            (off_axis - expected_off).abs() < 0.2 * expected,
            "{off_axis}"
        );
    }

    #[test]
    fn builtins_exist_and_unknown_names_are_rejected() {
        for name in BUILTIN_NAMES {
            let volumes = builtin(name).unwrap().into_volumes();
            assert!(!volumes.is_empty(), "{name}");
            for volume in &volumes {
                assert_eq!(volume.grid().dims(), BUILTIN_DIMS);
                let (min, max) = volume.grid().bounds_world();
                assert!((max - min - DVec3::splat(0.1)).length() < 1e-12);
            }
        }
        assert_eq!(builtin("density-flow").unwrap().into_volumes().len(), 2);
        assert!(matches!(
            builtin("cube"),
            Err(VolumeError::UnknownBuiltin { .. })
        ));
    }

    #[test]
    fn bad_parameters_are_rejected() {
        assert!(sphere(-1.0, grid()).is_err());
        assert!(matches!(
            density_and_flow(DIMS, f64::NAN),
            Err(VolumeError::BadParameter {
                name: "half_extent_m",
                ..
            })
        ));
        assert!(matches!(
            density_and_flow([1, 4, 4], HALF),
            Err(VolumeError::ZeroDimension { .. })
        ));
        assert!(shells(0.04, 0, 0.005, grid()).is_err());
        assert!(rankine_vortex(0.01, f64::INFINITY, grid()).is_err());
    }
}
