//! Iso-surfaces of scalar volumes as triangle meshes, for visualisers (the Foxglove live view's
//! `/voxhap/volume` mesh and the same mesh in MCAP recordings): the surface a surface-mode user feels,
//! drawn where they feel it.
//!
//! Where it sits: off the real-time path. The Foxglove view builds the [`SampledGrid`] from slices it asks
//! the session for (`SessionApi::slice`, on tokio's blocking pool) and the MCAP writer from the volume it
//! loads when a recording starts; both call [`bounded_isosurface`] once per scene change. Nothing here runs
//! on the servo thread.
//!
//! The method is marching cubes in its table-free form, marching tetrahedra: each grid cell is split into
//! the six tetrahedra of the Kuhn (Freudenthal) triangulation, which all share the cell's main diagonal
//! (corner 0 to corner 7) and follow one permutation of the axes each. Neighbouring cells split their shared
//! faces the same way, so the mesh is closed wherever the surface does not leave the grid. In a tetrahedron
//! whose corners straddle the iso-value the surface is one triangle (one corner on the other side) or two
//! (two and two), its vertices linearly interpolated on the crossed edges. Vertices are shared between
//! triangles through the edge they lie on (indexed mesh). Triangles are wound so their normal (right-hand
//! rule) points towards lower values: out of a dense blob.
//!
//! Size bound: [`bounded_isosurface`] samples the volume's bounding box on an `n`³ grid, starting at
//! `start_samples` per axis, and lowers `n` (by a factor 0.75) until the mesh has at most `max_triangles`.

use glam::DVec3;
use std::collections::HashMap;

/// A scalar field sampled on an axis-aligned regular grid: sample `(i, j, k)` is at
/// `origin_m + (i, j, k) * step_m` and is `values[i + nx (j + ny k)]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SampledGrid {
    pub dims: [usize; 3],
    pub origin_m: DVec3,
    pub step_m: DVec3,
    pub values: Vec<f32>,
}

impl SampledGrid {
    /// Samples `field` on `dims` points spanning `min_m ..= max_m` (each dimension at least 2).
    pub fn from_fn(
        min_m: DVec3,
        max_m: DVec3,
        dims: [usize; 3],
        mut field: impl FnMut(DVec3) -> f32,
    ) -> SampledGrid {
        let dims = dims.map(|d| d.max(2));
        let step_m = (max_m - min_m)
            / DVec3::new(
                (dims[0] - 1) as f64,
                (dims[1] - 1) as f64,
                (dims[2] - 1) as f64,
            );
        let mut values = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let at = min_m + DVec3::new(i as f64, j as f64, k as f64) * step_m;
                    values.push(field(at));
                }
            }
        }
        SampledGrid {
            dims,
            origin_m: min_m,
            step_m,
            values,
        }
    }

    fn position(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.origin_m + DVec3::new(i as f64, j as f64, k as f64) * self.step_m
    }
}

/// An indexed triangle mesh in world coordinates (m).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Mesh {
    pub vertices: Vec<DVec3>,
    /// Vertex indices, three per triangle.
    pub triangles: Vec<[u32; 3]>,
}

/// The six tetrahedra of a cell: corner `c` is at offset `(c & 1, (c >> 1) & 1, (c >> 2) & 1)`; each
/// tetrahedron walks from corner 0 to corner 7 along one permutation of the axes.
const TETRAHEDRA: [[usize; 4]; 6] = [
    [0, 1, 3, 7], // x, y, z
    [0, 1, 5, 7], // x, z, y
    [0, 2, 3, 7], // y, x, z
    [0, 2, 6, 7], // y, z, x
    [0, 4, 5, 7], // z, x, y
    [0, 4, 6, 7], // z, y, x
];

/// The iso-surface of `grid` at `iso` (marching tetrahedra; see the module header). A grid smaller than
/// 2 samples along an axis, or values that never cross `iso`, give an empty mesh.
pub fn marching_tetrahedra(grid: &SampledGrid, iso: f32) -> Mesh {
    let [nx, ny, nz] = grid.dims;
    let mut mesh = Mesh::default();
    if nx < 2 || ny < 2 || nz < 2 || grid.values.len() != nx * ny * nz || !iso.is_finite() {
        return mesh;
    }
    let index = |i: usize, j: usize, k: usize| i + nx * (j + ny * k);
    let mut edge_vertex: HashMap<(usize, usize), u32> = HashMap::new();
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let corner = |c: usize| (i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
                let corners: [usize; 8] = std::array::from_fn(|c| {
                    let (a, b, d) = corner(c);
                    index(a, b, d)
                });
                let inside = corners.map(|g| grid.values[g] >= iso);
                if inside.iter().all(|&x| x) || inside.iter().all(|&x| !x) {
                    continue;
                }
                for tet in TETRAHEDRA {
                    let ids = tet.map(|c| corners[c]);
                    let ins: Vec<usize> = (0..4).filter(|&t| inside[tet[t]]).collect();
                    if ins.is_empty() || ins.len() == 4 {
                        continue;
                    }
                    let outs: Vec<usize> = (0..4).filter(|&t| !inside[tet[t]]).collect();
                    let mut vertex = |a: usize, b: usize| -> u32 {
                        let (ga, gb) = (ids[a], ids[b]);
                        let key = (ga.min(gb), ga.max(gb));
                        *edge_vertex.entry(key).or_insert_with(|| {
                            let (va, vb) = (grid.values[ga], grid.values[gb]);
                            let t = if (vb - va).abs() > f32::EPSILON {
                                f64::from(((iso - va) / (vb - va)).clamp(0.0, 1.0))
                            } else {
                                0.5
                            };
                            let pa = {
                                let (x, y, z) = corner(tet[a]);
                                grid.position(x, y, z)
                            };
                            let pb = {
                                let (x, y, z) = corner(tet[b]);
                                grid.position(x, y, z)
                            };
                            mesh.vertices.push(pa + (pb - pa) * t);
                            (mesh.vertices.len() - 1) as u32
                        })
                    };
                    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(2);
                    match ins.len() {
                        1 => triangles.push([
                            vertex(ins[0], outs[0]),
                            vertex(ins[0], outs[1]),
                            vertex(ins[0], outs[2]),
                        ]),
                        3 => triangles.push([
                            vertex(outs[0], ins[0]),
                            vertex(outs[0], ins[1]),
                            vertex(outs[0], ins[2]),
                        ]),
                        _ => {
                            // Two inside (a, b), two outside (c, d): the quad a-c, a-d, b-d, b-c.
                            let ac = vertex(ins[0], outs[0]);
                            let ad = vertex(ins[0], outs[1]);
                            let bd = vertex(ins[1], outs[1]);
                            let bc = vertex(ins[1], outs[0]);
                            triangles.push([ac, ad, bd]);
                            triangles.push([ac, bd, bc]);
                        }
                    }
                    // Wind each triangle so its normal points from the inside corners to the outside ones.
                    let centre = |set: &[usize]| {
                        set.iter()
                            .map(|&t| {
                                let (x, y, z) = corner(tet[t]);
                                grid.position(x, y, z)
                            })
                            .sum::<DVec3>()
                            / set.len() as f64
                    };
                    let outward = centre(&outs) - centre(&ins);
                    for mut triangle in triangles {
                        let [a, b, c] = triangle.map(|v| mesh.vertices[v as usize]);
                        let normal = (b - a).cross(c - a);
                        if normal.length_squared() == 0.0 {
                            continue;
                        }
                        if normal.dot(outward) < 0.0 {
                            triangle.swap(1, 2);
                        }
                        mesh.triangles.push(triangle);
                    }
                }
            }
        }
    }
    mesh
}

/// Samples with `sample(n)` (an `n`³ grid over the volume's box) at `start_samples` per axis, and lower
/// resolutions, until the iso-surface has at most `max_triangles`; returns the mesh and the `n` used.
/// Errors of `sample` are passed on. Below 4 samples per axis the mesh is returned as it is.
pub fn bounded_isosurface<E>(
    iso: f32,
    start_samples: usize,
    max_triangles: usize,
    mut sample: impl FnMut(usize) -> Result<SampledGrid, E>,
) -> Result<(Mesh, usize), E> {
    let mut n = start_samples.max(4);
    loop {
        let grid = sample(n)?;
        let mesh = marching_tetrahedra(&grid, iso);
        if mesh.triangles.len() <= max_triangles || n <= 4 {
            return Ok((mesh, n));
        }
        n = ((n as f64) * 0.75) as usize;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ball(n: usize, radius_m: f64) -> SampledGrid {
        let half = DVec3::splat(0.02);
        SampledGrid::from_fn(-half, half, [n, n, n], |p| (radius_m - p.length()) as f32)
    }

    /// Each undirected edge of a closed, consistently wound surface is used by exactly two triangles, once
    /// in each direction.
    #[test]
    fn a_ball_gives_a_closed_consistently_wound_surface_at_the_right_radius() {
        let mesh = marching_tetrahedra(&ball(24, 0.012), 0.0);
        assert!(mesh.triangles.len() > 500, "{}", mesh.triangles.len());
        let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
        for t in &mesh.triangles {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *directed.entry((a, b)).or_default() += 1;
            }
        }
        for (&(a, b), &count) in &directed {
            assert_eq!(count, 1, "edge {a}-{b} used {count} times in one direction");
            assert_eq!(directed.get(&(b, a)), Some(&1), "edge {a}-{b} has no twin");
        }
        for v in &mesh.vertices {
            assert!(
                (v.length() - 0.012).abs() < 0.0005,
                "vertex at radius {}",
                v.length()
            );
        }
        // Normals point out of the ball (towards lower values).
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
            let normal = (b - a).cross(c - a);
            assert!(normal.dot(a + b + c) > 0.0);
        }
    }

    #[test]
    fn no_crossing_gives_no_mesh_and_the_bound_lowers_the_resolution() {
        assert!(marching_tetrahedra(&ball(8, 0.1), 0.0).triangles.is_empty());
        assert!(marching_tetrahedra(&ball(8, 0.01), f32::NAN)
            .triangles
            .is_empty());
        let (full, n) =
            bounded_isosurface(0.0, 32, usize::MAX, |n| Ok::<_, ()>(ball(n, 0.012))).unwrap();
        assert_eq!(n, 32);
        let (small, n) = bounded_isosurface(0.0, 32, full.triangles.len() / 3, |n| {
            Ok::<_, ()>(ball(n, 0.012))
        })
        .unwrap();
        assert!(n < 32);
        assert!(small.triangles.len() <= full.triangles.len() / 3);
        assert!(!small.triangles.is_empty());
    }
}
