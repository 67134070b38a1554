//! Volume sampling benchmarks on 256³ grids: the per-tick cost of a scalar sample, a gradient,
//! both together, and the vector Jacobian / curl / divergence. Positions cycle through 4096
//! pseudo-random points inside the volume so caches see a realistic (not single-point) pattern.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use std::hint::black_box;
use voxhap::volume::procedural;

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

fn bench(c: &mut Criterion) {
    let points = positions();
    let scalar = procedural::sphere(0.03, DIMS, HALF_EXTENT_M).expect("sphere");
    let mut group = c.benchmark_group("scalar_256");
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

    let vector = procedural::rankine_vortex(0.01, 0.01, DIMS, HALF_EXTENT_M).expect("rankine");
    let mut group = c.benchmark_group("vector_256");
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
