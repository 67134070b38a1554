//! The exact discretisation of the arm's linear part over one substep: `m x'' = -k x - c v + u(t)` with the
//! input `u` a straight line in time over the substep (`u(t) = u0 + s (t - t0)`), per axis.
//!
//! Where it sits: [`super::SimArm::step`] advances the arm by this map, so a force held constant over a tick
//! (zero-order hold, as a device's amplifier holds it) moves the arm exactly as the continuous equations do,
//! whatever the substep: the sampled loop's stability boundary is then the exact zero-order-hold one, and not
//! shifted by the integrator (semi-implicit Euler with 10 substeps put it 11 % too high, with 1 substep far
//! higher still). The hand's target moves along a straight line within a substep, which the ramp term `s`
//! integrates exactly too.
//!
//! Maths: with the state `z = (x, v, u, s)`, `z' = M z` where `M = [[0, 1, 0, 0], [-k/m, -c/m, 1/m, 0],
//! [0, 0, 0, 1], [0, 0, 0, 0]]`, so `z(t0 + h) = exp(M h) z(t0)` (Van Loan, "Computing integrals involving the
//! matrix exponential", IEEE TAC 23(3), 1978). The exponential is computed by scaling and squaring with a
//! Taylor series (Moler and Van Loan, "Nineteen dubious ways to compute the exponential of a matrix", SIAM
//! Review 20(4), 1978): `M h` is scaled by `2^-j` until its norm is below 1/2, 18 terms are summed (their
//! truncation error is below 1e-20 there), and the result squared `j` times. Nothing allocates.

/// The first two rows of `exp(M h)`: how one substep maps `(x, v, u0, s)` to the new `(x, v)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SubstepMap {
    /// `[row][column]` for rows x and v, columns x, v, u0, s.
    rows: [[f64; 4]; 2],
}

impl SubstepMap {
    /// The map for mass `mass_kg`, spring `stiffness_n_per_m` to the origin, damping `damping_n_s_per_m` and
    /// substep `h_s`.
    pub fn new(mass_kg: f64, stiffness_n_per_m: f64, damping_n_s_per_m: f64, h_s: f64) -> Self {
        let mut m = [[0.0; 4]; 4];
        m[0][1] = h_s;
        m[1][0] = -stiffness_n_per_m / mass_kg * h_s;
        m[1][1] = -damping_n_s_per_m / mass_kg * h_s;
        m[1][2] = h_s / mass_kg;
        m[2][3] = h_s;
        let norm = m
            .iter()
            .map(|row| row.iter().map(|x| x.abs()).sum::<f64>())
            .fold(0.0, f64::max);
        let mut squarings = 0u32;
        let mut scale = 1.0;
        while norm * scale > 0.5 && squarings < 200 {
            scale *= 0.5;
            squarings += 1;
        }
        for row in m.iter_mut() {
            for x in row.iter_mut() {
                *x *= scale;
            }
        }
        // Taylor series: term_n = M^n / n!.
        let mut sum = identity();
        let mut term = identity();
        for n in 1..=18 {
            term = multiply(&term, &m);
            let inverse = 1.0 / f64::from(n);
            for row in term.iter_mut() {
                for x in row.iter_mut() {
                    *x *= inverse;
                }
            }
            add_into(&mut sum, &term);
        }
        for _ in 0..squarings {
            sum = multiply(&sum, &sum);
        }
        SubstepMap {
            rows: [sum[0], sum[1]],
        }
    }

    /// The new `(x, v)` from `(x, v)` and the input's value `u0` at the substep's start and its slope `s`.
    #[inline]
    pub fn apply(&self, x: f64, v: f64, u0: f64, s: f64) -> (f64, f64) {
        let [a, b] = &self.rows;
        (
            a[0] * x + a[1] * v + a[2] * u0 + a[3] * s,
            b[0] * x + b[1] * v + b[2] * u0 + b[3] * s,
        )
    }
}

type Mat4 = [[f64; 4]; 4];

fn identity() -> Mat4 {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

fn multiply(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut c = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn add_into(a: &mut Mat4, b: &Mat4) {
    for (ra, rb) in a.iter_mut().zip(b) {
        for (x, y) in ra.iter_mut().zip(rb) {
            *x += y;
        }
    }
}

/// A few maps kept by their parameters, so a run with a constant tick computes each once.
#[derive(Clone, Debug, Default)]
pub struct SubstepMapCache {
    entries: [Option<([f64; 4], SubstepMap)>; 4],
    next: usize,
}

impl SubstepMapCache {
    /// The map for these parameters, computed on a miss (no allocation).
    pub fn get(&mut self, mass_kg: f64, stiffness: f64, damping: f64, h_s: f64) -> SubstepMap {
        let key = [mass_kg, stiffness, damping, h_s];
        for (k, map) in self.entries.iter().flatten() {
            if *k == key {
                return *map;
            }
        }
        let map = SubstepMap::new(mass_kg, stiffness, damping, h_s);
        self.entries[self.next] = Some((key, map));
        self.next = (self.next + 1) % self.entries.len();
        map
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A free mass under a constant force: x = x0 + v0 h + u h^2 / (2 m), v = v0 + u h / m (Newton).
    #[test]
    fn a_free_mass_under_a_constant_force_moves_as_newton_says() {
        let map = SubstepMap::new(0.5, 0.0, 0.0, 0.01);
        let (x, v) = map.apply(0.1, 2.0, 3.0, 0.0);
        assert!((x - (0.1 + 2.0 * 0.01 + 3.0 * 1e-4 / 1.0)).abs() < 1e-15);
        assert!((v - (2.0 + 3.0 * 0.01 / 0.5)).abs() < 1e-14);
    }

    /// An undamped spring released at rest: x = x0 cos(w h), v = -x0 w sin(w h), w = sqrt(k / m).
    #[test]
    fn an_undamped_spring_follows_its_cosine() {
        let (m, k, h): (f64, f64, f64) = (0.1, 2000.0, 0.0137);
        let w = (k / m).sqrt();
        let (x, v) = SubstepMap::new(m, k, 0.0, h).apply(0.01, 0.0, 0.0, 0.0);
        assert!((x - 0.01 * (w * h).cos()).abs() < 1e-13, "{x}");
        assert!((v + 0.01 * w * (w * h).sin()).abs() < 1e-11, "{v}");
    }

    /// A damper under a ramp force from rest, c v' ... checked against the closed form for k = 0:
    /// m v' = -c v + s t gives v(h) = (s/c) (h - tau (1 - e^{-h/tau})), tau = m / c.
    #[test]
    fn a_damped_mass_under_a_ramp_matches_the_closed_form() {
        let (m, c, s, h) = (0.2, 1.5, 4.0, 0.3);
        let tau = m / c;
        let (_, v) = SubstepMap::new(m, 0.0, c, h).apply(0.0, 0.0, 0.0, s);
        let expected = s / c * (h - tau * (1.0 - (-h / tau).exp()));
        assert!((v - expected).abs() < 1e-13, "{v} vs {expected}");
    }
}
