//! One pass of the primal Newton method over the items: the gradient, the kinks' model and the dual values at
//! a point (module header of `newton`, step 2), and the third-order term of the step.

use super::*;

/// Adds `w v v^T` to the symmetric matrix `b` (xx, xy, xz, yy, yz, zz).
#[inline(always)]
fn add_outer(b: &mut [f64; 6], w: f64, v: DVec3) {
    b[0] += w * v.x * v.x;
    b[1] += w * v.x * v.y;
    b[2] += w * v.x * v.z;
    b[3] += w * v.y * v.y;
    b[4] += w * v.y * v.z;
    b[5] += w * v.z * v.z;
}

impl<S: Storage> Workspace<S> {
    /// [`Self::pass`] as a call, for scenes of more than [`INLINE_PASS_MAX_ITEMS`] primitives. Out of line, the
    /// pass's `Model` comes back through memory, and the iteration read parts of it with loads that span two of
    /// the pass's stores (its 3x3 Hessian's columns are 24 bytes), which the processor cannot forward from the
    /// stores and waits out: on ten primitives, three passes, the inlined pass was about 4 % faster in time
    /// (more instructions, fewer waits). On large scenes the loop's own code is what counts, and inlined it
    /// took more instructions (9 % on 100 random primitives, which were 4 % slower), so they call it.
    #[inline(never)]
    pub(super) fn pass_out_of_line<G: GradientSum>(
        &mut self,
        attempt: &Attempt,
        x: DVec3,
        dual: &mut [DVec3],
    ) -> Model {
        self.pass::<G>(attempt, x, dual)
    }

    /// One O(N) pass: the smooth model at `x`, and every item's subgradient written to `dual` (W members are
    /// left to [`Self::multipliers`]). Inlined into the iteration for small scenes; see
    /// [`Self::pass_out_of_line`].
    /// `G` is how the gradient is summed: [`CompensatedSum`] near the answer, where the gradient is the small
    /// difference of many forces and a plain sum's rounding (about sqrt(N) eps of their magnitudes) would be
    /// what Newton converges to; [`PlainSum`] before that, where only the step's direction matters.
    #[inline(always)]
    pub(super) fn pass<G: GradientSum>(
        &mut self,
        attempt: &Attempt,
        x: DVec3,
        dual: &mut [DVec3],
    ) -> Model {
        let items = attempt.items;
        let Frame { y, k, .. } = *attempt.frame;
        let offset = x - y;
        let mut gradient = G::default();
        gradient.add(k * offset);
        gradient.add(self.fixed_gradient_n);
        let mut energy =
            0.5 * k * offset.length_squared() + self.fixed_gradient_n.dot(x) + self.fixed_energy_j;
        let mut energy_scale = energy.abs();
        // Hessian of the distance terms: a I - B, with B symmetric (xx, xy, xz, yy, yz, zz).
        let mut a = 0.0;
        let mut b = [0.0f64; 6];
        let mut clearance = f64::INFINITY;
        let mut on_unlisted_kink = None;
        for &index in self.active.iter() {
            let i = index as usize;
            let item = &items[i];
            let state = self.state[i];
            if state == State::Kink {
                continue;
            }
            let s = item.strength_n;
            let r = x - item.position_m;
            match item.kind {
                PrimitiveKind::Plane => {
                    let q = item.direction;
                    let sigma = q.dot(r);
                    let full = sigma < 0.0 || (sigma == 0.0 && state == State::Full);
                    if full {
                        gradient.add(-s * q);
                        energy -= s * sigma;
                        energy_scale -= s * sigma;
                        dual[i] = -s * q;
                        self.state[i] = State::Full;
                    } else {
                        dual[i] = DVec3::ZERO;
                        self.state[i] = State::Off;
                    }
                    let distance = sigma.abs();
                    self.kink_distance_m[i] = distance;
                    // A comparison, not `f64::min` (whose NaN rule costs a few instructions per item): a NaN
                    // distance is skipped either way.
                    if distance < clearance {
                        clearance = distance;
                    }
                }
                PrimitiveKind::Point | PrimitiveKind::Line => {
                    let line = item.kind == PrimitiveKind::Line;
                    let q = item.direction;
                    let perpendicular = if line { r - q * q.dot(r) } else { r };
                    let rho_squared = perpendicular.length_squared();
                    if rho_squared == 0.0 {
                        on_unlisted_kink = Some(i);
                        dual[i] = DVec3::ZERO;
                        self.kink_distance_m[i] = 0.0;
                        clearance = 0.0;
                        continue;
                    }
                    let rho = sqrt(rho_squared);
                    self.kink_distance_m[i] = rho;
                    let inverse = 1.0 / rho;
                    let normal = perpendicular * inverse;
                    let force = s * normal;
                    gradient.add(force);
                    dual[i] = force;
                    energy += s * rho;
                    energy_scale += s * rho;
                    let w = s * inverse;
                    a += w;
                    add_outer(&mut b, w, normal);
                    if line {
                        add_outer(&mut b, w, q);
                    }
                    if rho < clearance {
                        clearance = rho;
                    }
                }
                PrimitiveKind::Directed => {}
            }
        }
        let diagonal = k + a;
        let hessian = DMat3::from_cols(
            DVec3::new(diagonal - b[0], -b[1], -b[2]),
            DVec3::new(-b[1], diagonal - b[3], -b[4]),
            DVec3::new(-b[2], -b[4], diagonal - b[5]),
        );
        Model {
            gradient: gradient.value(),
            hessian,
            energy_j: energy,
            energy_scale_j: energy_scale,
            clearance_m: clearance,
            on_unlisted_kink,
        }
    }

    /// `T[d, d]`, the third derivative of the smooth terms at `x` applied twice to `d` (W empty): for a point at
    /// distance `rho` in direction `n` (for a line, `n` normal to it and `d` replaced by its part `d'` across the
    /// line), `D^3 (s |r|)[d, d] = -(s / rho^2) (2 a d' + (|d'|^2 - 3 a^2) n)` with `a = n.d'`; planes are
    /// linear. Read from the last pass at `x`: its force `f = s n` (`dual`) and `rho` (`kink_distance_m`), with
    /// `b = f.d'` that is `-(1 / rho^2) (2 b d' + |d'|^2 f) + 3 b^2 / (rho^2 s^2) f`, one division per item.
    pub(super) fn third_order(&self, items: &[Item], dual: &[DVec3], d: DVec3) -> DVec3 {
        let mut sum = DVec3::ZERO;
        for &index in self.active.iter() {
            let i = index as usize;
            if self.state[i] != State::Smooth {
                continue;
            }
            let item = &items[i];
            let along = if item.kind == PrimitiveKind::Line {
                let q = item.direction;
                d - q * q.dot(d)
            } else {
                d
            };
            let f = dual[i];
            let b = f.dot(along);
            let rho = self.kink_distance_m[i];
            let s_squared = item.strength_n * item.strength_n;
            // 1 / (rho^2 s^2); times s^2 it is 1 / rho^2.
            let inverse = 1.0 / (rho * rho * s_squared);
            sum += (3.0 * b * b * inverse) * f
                - (s_squared * inverse) * (2.0 * b * along + along.length_squared() * f);
        }
        sum
    }
}
