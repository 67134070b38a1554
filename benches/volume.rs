//! Volume sampling benchmarks on 256³ grids: the per-tick cost of a scalar sample, a gradient,
//! both together, and the vector Jacobian / curl / divergence.
//!
//! Two access patterns: `path` follows a proxy-like trajectory (a 2 cm circle with a wobble, about
//! 0.05 mm between consecutive samples, like a 50 mm/s stroke at 1 kHz), which is what the servo loop
//! does; `random` jumps between 4096 random points across the whole 64 MB (scalar) / 200 MB (vector)
//! volume, so nearly every sample misses the caches: a worst case, not the servo pattern.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use std::hint::black_box;
use voxhap::volume::{procedural, Grid};

const DIMS: [usize; 3] = [256; 3];
const HALF_EXTENT_M: f64 = 0.05;

/// Deterministic points in the inner 90% of the cube (xorshift, no rand dependency).
fn positions() -> Vec<DVec3> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut unit = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..4096)
        .map(|_| {
            DVec3::new(unit(), unit(), unit()) * (1.8 * HALF_EXTENT_M)
                - DVec3::splat(0.9 * HALF_EXTENT_M)
        })
        .collect()
}

/// A closed proxy-like path: 4096 points on a wobbling 2 cm circle, ~0.05 mm apart.
fn path() -> Vec<DVec3> {
    (0..4096)
        .map(|n| {
            let t = n as f64 / 4096.0 * std::f64::consts::TAU;
            DVec3::new(0.02 * t.cos(), 0.02 * t.sin(), 0.003 * (5.0 * t).sin())
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    for (pattern, points) in [("path", path()), ("random", positions())] {
        bench_pattern(c, pattern, &points);
    }
}

fn bench_pattern(c: &mut Criterion, pattern: &str, points: &[DVec3]) {
    let grid = || Grid::centred_cube(DIMS, HALF_EXTENT_M).expect("grid");
    let scalar = procedural::sphere(0.03, grid()).expect("sphere");
    let mut group = c.benchmark_group(format!("scalar_256_{pattern}"));
    let mut n = 0;
    let mut next = || {
        n = (n + 1) & 4095;
        points[n]
    };
    group.bench_function("sample", |b| b.iter(|| scalar.sample(black_box(next()))));
    group.bench_function("gradient", |b| {
        b.iter(|| scalar.gradient(black_box(next())))
    });
    group.bench_function("sample_with_gradient", |b| {
        b.iter(|| scalar.sample_with_gradient(black_box(next())))
    });
    group.finish();
    drop(scalar);

    let vector = procedural::rankine_vortex(0.01, 0.01, grid()).expect("rankine");
    let mut group = c.benchmark_group(format!("vector_256_{pattern}"));
    group.bench_function("sample", |b| b.iter(|| vector.sample(black_box(next()))));
    group.bench_function("jacobian", |b| {
        b.iter(|| vector.jacobian(black_box(next())))
    });
    group.bench_function("curl", |b| b.iter(|| vector.curl(black_box(next()))));
    group.bench_function("divergence", |b| {
        b.iter(|| vector.divergence(black_box(next())))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
