//! The exact boundary against truths computed here by other routes: the one-period matrix of the loop taken
//! from a matrix exponential (a Taylor series of the continuous system, not the module's closed forms) and
//! its eigenvalues (Jury's second-order conditions without latency, the spectral radius from repeated
//! squaring with it); Gillespie and Cutkosky's closed form; Colgate and Schenkel's asymptote `2 b / T`; and
//! the transfer-function analysis of `super::super::zoh_exact` (whole periods only).

use super::super::bisect::geometric_bisection;
use super::*;

/// `exp(A h)` of a small square matrix by scaling and squaring a Taylor series.
fn expm(a: &[Vec<f64>], h: f64) -> Vec<Vec<f64>> {
    let n = a.len();
    let norm = a
        .iter()
        .map(|r| r.iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max)
        * h;
    let squarings = (norm.max(1e-300).log2().ceil().max(0.0) as u32) + 4;
    let step = h / f64::from(1u32 << squarings);
    let mut result = identity(n);
    let mut term = identity(n);
    for k in 1..30 {
        term = mul(&term, &scale(a, step / k as f64));
        for i in 0..n {
            for j in 0..n {
                result[i][j] += term[i][j];
            }
        }
    }
    for _ in 0..squarings {
        result = mul(&result, &result);
    }
    result
}

fn identity(n: usize) -> Vec<Vec<f64>> {
    (0..n)
        .map(|i| (0..n).map(|j| f64::from(u8::from(i == j))).collect())
        .collect()
}

fn scale(a: &[Vec<f64>], s: f64) -> Vec<Vec<f64>> {
    a.iter()
        .map(|r| r.iter().map(|v| v * s).collect())
        .collect()
}

fn mul(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = a.len();
    let m = b[0].len();
    (0..n)
        .map(|i| {
            (0..m)
                .map(|j| (0..b.len()).map(|k| a[i][k] * b[k][j]).sum())
                .collect()
        })
        .collect()
}

/// Position, velocity and the held force after a span `h` from `(x, v)` under force `f`: the exponential of
/// the continuous system `[x' v' f'] = [v, (f - b v) / m, 0]`.
fn span(m: f64, b: f64, h: f64) -> Vec<Vec<f64>> {
    let a = vec![
        vec![0.0, 1.0, 0.0],
        vec![0.0, -b / m, 1.0 / m],
        vec![0.0, 0.0, 0.0],
    ];
    expm(&a, h)
}

/// The closed loop's one-period matrix with latency `(d + theta) T`: the state is `[x, v, F_{n-d-1}, ...,
/// F_{n-1}]` (the forces sampled but not yet fully acted); over the period the arm feels the oldest for
/// `theta T`, then the next for the rest; the new sample is `-K x_n`.
fn one_period_matrix(m: f64, b: f64, t: f64, d: usize, theta: f64, k: f64) -> Vec<Vec<f64>> {
    let queue = d + 1;
    let n = 2 + queue;
    // Columns of the state the forces come from: index 2 is F_{n-d-1}, index 2 + d is F_{n-1}; with d = 0
    // the newer force is the one sampled now, -K x_n.
    let early = span(m, b, theta * t);
    let late = span(m, b, (1.0 - theta) * t);
    let mut out = vec![vec![0.0; n]; n];
    // Row vectors (over the state) of the force acting in each part of the period.
    let mut older = vec![0.0; n];
    older[2] = 1.0;
    let mut newer = vec![0.0; n];
    if d == 0 {
        newer[0] = -k;
    } else {
        newer[3] = 1.0;
    }
    // After the early part: (x, v) as linear functions of the state.
    let mut xv_early = vec![vec![0.0; n]; 2];
    for r in 0..2 {
        xv_early[r][0] = early[r][0];
        xv_early[r][1] = early[r][1];
        for c in 0..n {
            xv_early[r][c] += early[r][2] * older[c];
        }
    }
    for r in 0..2 {
        for c in 0..n {
            out[r][c] =
                late[r][0] * xv_early[0][c] + late[r][1] * xv_early[1][c] + late[r][2] * newer[c];
        }
    }
    // The queue shifts: F_{n-d} .. F_{n-1} move down one, and -K x_n enters last.
    for i in 0..queue - 1 {
        out[2 + i][3 + i] = 1.0;
    }
    out[2 + queue - 1][0] = -k;
    out
}

/// The spectral radius from `||M^(2^j)||^(1/2^j)`, squaring with rescaling, for 60 squarings.
fn spectral_radius(m: &[Vec<f64>]) -> f64 {
    let mut m = m.to_vec();
    let mut log = 0.0;
    let mut weight = 1.0;
    for _ in 0..60 {
        let s = m
            .iter()
            .flat_map(|r| r.iter())
            .fold(0.0f64, |a, v| a.max(v.abs()));
        if s == 0.0 {
            return 0.0;
        }
        log += weight * s.ln();
        m = scale(&m, 1.0 / s);
        m = mul(&m, &m);
        weight /= 2.0;
    }
    let s = m
        .iter()
        .flat_map(|r| r.iter())
        .fold(0.0f64, |a, v| a.max(v.abs()));
    (log + weight * s.max(1e-300).ln()).exp()
}

fn split(latency_s: f64, t: f64) -> (usize, f64) {
    let r = latency_s / t;
    let d = (r + 1e-9).floor();
    (d as usize, (r - d).max(0.0))
}

/// 0.1 kg, 1 N s/m at 1 kHz without latency: the one-period matrix from the matrix exponential, closed by
/// `-K x`, has both eigenvalues inside the unit circle just below 2 003 N/m and not just above (Jury's
/// conditions for `z^2 - tr z + det`: `|det| < 1`, `|tr| < 1 + det`); Gillespie and Cutkosky's closed form
/// agrees; and the library's figure is that value.
#[test]
fn the_default_arm_at_1_khz_is_2003_n_per_m_by_eigenvalues_and_closed_form() {
    let (m, b, t) = (0.1, 1.0, 1e-3);
    let e = span(m, b, t);
    let jury_stable = |k: f64| {
        let (m11, m12, m21, m22) = (
            e[0][0] - k * e[0][2],
            e[0][1],
            e[1][0] - k * e[1][2],
            e[1][1],
        );
        let (tr, det) = (m11 + m22, m11 * m22 - m12 * m21);
        det.abs() < 1.0 && tr.abs() < 1.0 + det
    };
    let by_eigenvalues = geometric_bisection(100.0, 1e5, 0.0, jury_stable);
    // Gillespie and Cutkosky: K* = b (1 - a) / (tau_m (1 - a) - a T), a = exp(-T b / m), tau_m = m / b.
    let a = (-t * b / m).exp();
    let closed = b * (1.0 - a) / (m / b * (1.0 - a) - a * t);
    let library = zoh_boundary(m, b, t, 0.0).unwrap();
    assert!((by_eigenvalues - 2003.3).abs() < 0.1, "{by_eigenvalues}");
    assert!((closed / by_eigenvalues - 1.0).abs() < 1e-6, "{closed}");
    assert!((library / by_eigenvalues - 1.0).abs() < 1e-6, "{library}");
}

/// With whole and fractional latency, at several rates and arms, the one-period matrix's spectral radius is
/// below 1 at 0.995 of the library's boundary and above 1 at 1.005 of it.
#[test]
fn the_boundary_with_any_latency_matches_the_spectral_radius_of_the_one_period_matrix() {
    let cases = [
        // (m, b, rate, latency)
        (0.1, 1.0, 1000.0, 0.0),
        (0.1, 1.0, 1000.0, 0.001),
        (0.1, 1.0, 1000.0, 0.002),
        (0.1, 1.0, 1000.0, 0.0005),
        (0.1, 1.0, 1000.0, 0.0013),
        (0.1, 1.0, 4000.0, 0.001),
        (0.1, 1.0, 4000.0, 0.0006),
        (0.045, 0.5, 1000.0, 0.00025),
        (0.01, 20.0, 1000.0, 0.0007),
        (2.0, 0.2, 250.0, 0.0031),
    ];
    for (m, b, rate, latency_s) in cases {
        let t = 1.0 / rate;
        let (d, theta) = split(latency_s, t);
        let boundary = zoh_boundary(m, b, t, latency_s).unwrap();
        let below = spectral_radius(&one_period_matrix(m, b, t, d, theta, 0.995 * boundary));
        let above = spectral_radius(&one_period_matrix(m, b, t, d, theta, 1.005 * boundary));
        assert!(
            below < 1.0 && above > 1.0,
            "m {m}, b {b}, {rate} Hz, latency {latency_s}: boundary {boundary:.2} N/m, spectral radius \
             {below} below, {above} above"
        );
    }
}

/// Whole periods of latency: the state-space polynomial and the transfer-function analysis of `zoh_exact`
/// (Gillespie and Cutkosky's `G(z)` closed by `-K z^-d`) give the same boundary.
#[test]
fn whole_periods_agree_with_the_transfer_function_analysis() {
    use super::super::zoh_exact::exact_boundary;
    for (m, b, rate) in [(0.1, 1.0, 1000.0), (0.045, 0.5, 4000.0), (1.0, 3.0, 250.0)] {
        let t = 1.0 / rate;
        for d in 0..4usize {
            let here = zoh_boundary(m, b, t, d as f64 * t).unwrap();
            let there = exact_boundary(m, b, t, d);
            assert!(
                (here / there - 1.0).abs() < 1e-6,
                "{m} kg, {b} N s/m, {rate} Hz, {d} periods: {here} against {there}"
            );
        }
    }
}

/// As the period shrinks the boundary tends to Colgate and Schenkel's `2 b / T`: `K* T / (2 b) - 1` is
/// `O(T b / m)` (a third of it, from the closed form's series), so within 1e-4 at 1 MHz for the default arm.
#[test]
fn as_the_period_shrinks_the_boundary_tends_to_two_b_over_t() {
    let (m, b) = (0.1, 1.0);
    for (t, tolerance) in [(1e-3, 1e-2), (1e-4, 1e-3), (1e-6, 1e-5)] {
        let ratio = zoh_boundary(m, b, t, 0.0).unwrap() * t / (2.0 * b);
        assert!(ratio > 1.0 && ratio - 1.0 < tolerance, "T = {t}: {ratio}");
    }
}

/// A half period of latency lies between none and a whole one, and more latency never raises the boundary.
#[test]
fn the_boundary_falls_as_the_latency_grows() {
    let (m, b, t) = (0.1, 1.0, 1e-3);
    let mut last = f64::INFINITY;
    for i in 0..=40 {
        let k = zoh_boundary(m, b, t, f64::from(i) * 0.1 * t).unwrap();
        assert!(
            k < last,
            "latency {} periods: {k} after {last}",
            f64::from(i) * 0.1
        );
        last = k;
    }
}

#[test]
fn an_undamped_arm_has_no_stable_stiffness() {
    assert_eq!(zoh_boundary(0.1, 0.0, 1e-3, 0.0).unwrap(), 0.0);
}

#[test]
fn bad_figures_are_refused_by_name() {
    let err = zoh_boundary(f64::NAN, 1.0, 1e-3, 0.0).unwrap_err();
    assert!(err.to_string().contains("mass (kg) = NaN"), "{err}");
    let err = zoh_boundary(0.1, -1.0, 1e-3, 0.0).unwrap_err();
    assert!(err.to_string().contains("damping"), "{err}");
    let err = zoh_boundary(0.1, 1.0, 0.0, 0.0).unwrap_err();
    assert!(err.to_string().contains("period (s) = 0"), "{err}");
    let err = zoh_boundary(0.1, 1.0, 1e-3, f64::INFINITY).unwrap_err();
    assert!(err.to_string().contains("latency"), "{err}");
    let err = zoh_boundary(0.1, 1.0, 1e-5, 1.0).unwrap_err();
    assert!(matches!(err, ZohError::LatencyTooLong { .. }), "{err}");
}

/// What docs/stability.md says of the sweep's mass estimate: for the presets' damping (0.5 N s/m) at 1 and
/// 4 kHz with 0, 1 and 2 ms of latency, a heavier arm never has a higher boundary, and from 0.045 to 0.2 kg the
/// boundary is within 1 % of the 0.1 kg arm's.
#[test]
fn the_mass_moves_the_boundary_little_and_a_heavier_arm_never_raises_it() {
    let b = 0.5;
    for rate in [1000.0, 4000.0] {
        for latency_s in [0.0, 0.001, 0.002] {
            let at = |m: f64| zoh_boundary(m, b, 1.0 / rate, latency_s).unwrap();
            let reference = at(0.1);
            let mut last = f64::INFINITY;
            for m in [0.045, 0.07, 0.1, 0.1205, 0.15, 0.2] {
                let k = at(m);
                assert!(
                    k <= last,
                    "{rate} Hz, {latency_s} s: {m} kg gives {k} after {last}"
                );
                assert!(
                    (k / reference - 1.0).abs() < 0.01,
                    "{rate} Hz, {latency_s} s: {m} kg gives {k}, 0.1 kg {reference}"
                );
                last = k;
            }
        }
    }
}
