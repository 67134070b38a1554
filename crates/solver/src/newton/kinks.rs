//! The exact line search over the kinks a step crosses, and the set W of kinks the proxy is held on: the
//! multipliers, screening, entering and leaving (module header of `newton`, steps 3 to 5).

use super::*;

impl<S: Storage> Workspace<S> {
    /// Minimises the piecewise model along `d` over `t in [0, 1]` (module header, step 3).
    /// `slope` is the derivative along `d` on the face (the reduced gradient's, free of the kinks' part).
    // Inlined by hand (the compiler moves it out of line); inlined or called measure the same on 1 000 random
    // primitives.
    #[inline(always)]
    pub(super) fn line_search(
        &mut self,
        items: &[Item],
        x: DVec3,
        d: DVec3,
        slope: f64,
        model: &Model,
    ) -> Step {
        let curvature = d.dot(model.hessian * d).max(f64::MIN_POSITIVE);
        // `min(1, -slope / curvature)`, with the division (about 1 to rounding for a Newton step) off the
        // iteration's critical path: a comparison decides the common case. A NaN slope gives 1, as `min` did.
        let smooth_t = if -slope < curvature {
            -slope / curvature
        } else {
            1.0
        };
        if d.length_squared() < model.clearance_m * model.clearance_m {
            // No kink within reach of the step.
            return Step {
                t: smooth_t.max(0.0),
                kink: None,
            };
        }
        self.breakpoints.clear();
        // A plane crosses at t <= 1 only if |q.r| <= |q.d| <= |d|; a point or line turns round only if
        // rho^2 <= -r.step <= rho |d|. So items farther than |d| from their kink (measured by the pass at this same
        // x) are skipped unread; the margin covers the rounding of those comparisons.
        let reach_m = d.length() * (1.0 + 1e-9);
        for &index in self.active.iter() {
            let i = index as usize;
            if self.kink_distance_m[i] > reach_m {
                continue;
            }
            let item = &items[i];
            let state = self.state[i];
            let r = x - item.position_m;
            match (item.kind, state) {
                (PrimitiveKind::Plane, State::Off | State::Full) => {
                    let q = item.direction;
                    let qd = q.dot(d);
                    let crosses = if state == State::Off {
                        qd < 0.0
                    } else {
                        qd > 0.0
                    };
                    if !crosses {
                        continue;
                    }
                    let t = (-q.dot(r) / qd).max(0.0) + 0.0;
                    if t <= 1.0 {
                        self.breakpoints.push((t.to_bits(), index));
                    }
                }
                (PrimitiveKind::Point | PrimitiveKind::Line, State::Smooth) => {
                    // A step that turns the offset round and comes within a tenth of the starting distance
                    // passes close to the kink; whether it should stop there is decided in the walk below.
                    let line = item.kind == PrimitiveKind::Line;
                    let q = item.direction;
                    let before = if line { r - q * q.dot(r) } else { r };
                    let step = if line { d - q * q.dot(d) } else { d };
                    if before.dot(before + step) > 0.0 {
                        continue;
                    }
                    let tau = (-before.dot(step) / step.length_squared()).clamp(0.0, 1.0) + 0.0;
                    if (before + tau * step).length() > 0.1 * before.length() {
                        continue;
                    }
                    // A point or line marks a near pass rather than a slope change.
                    self.breakpoints.push((tau.to_bits(), index));
                }
                _ => {}
            }
        }
        // Every step fraction is >= +0.0 (pushed as `max(0.0) + 0.0`, which turns -0.0 into +0.0), and the bits of
        // non-negative floats order as the floats do: an integer key is cheaper to compare than `total_cmp`.
        self.breakpoints.sort_unstable_by_key(|b| b.0);
        let mut jumps = 0.0;
        // The planes crossed so far, as the change they make to the gradient (for the near-pass test).
        let mut jump_gradient = DVec3::ZERO;
        for &(t_bits, index) in self.breakpoints.iter() {
            let t = f64::from_bits(t_bits);
            let unconstrained = -(slope + jumps) / curvature;
            if unconstrained < t {
                return Step {
                    t: unconstrained.max(0.0),
                    kink: None,
                };
            }
            let item = &items[index as usize];
            if item.kind != PrimitiveKind::Plane {
                // A near pass of a point or line: stop on it if, along the step, the other terms' slope there
                // is within what the primitive can hold (`s |step|` either way): the minimum along the line
                // is at the kink. The model's slope there is corrected for the primitive's own share, which the
                // quadratic model spreads over the whole step.
                let line = item.kind == PrimitiveKind::Line;
                let q = item.direction;
                let r = x - item.position_m;
                let before = if line { r - q * q.dot(r) } else { r };
                let step = if line { d - q * q.dot(d) } else { d };
                let rho = before.length();
                let normal = before / rho;
                let s = item.strength_n;
                let own_slope = s * normal.dot(step);
                let along = normal.dot(step);
                let own_curvature = s / rho * (step.length_squared() - along * along);
                let others = slope - own_slope + t * (curvature - own_curvature) + jumps;
                if others.abs() <= s * step.length()
                    && (self.kink_count > 0
                        || self.could_hold(item, model, d, t, normal, step, rho, jump_gradient))
                {
                    return Step {
                        t,
                        kink: Some(index as usize),
                    };
                }
                continue;
            }
            let plane = item;
            jumps += plane.strength_n * plane.direction.dot(d).abs();
            jump_gradient += if self.state[index as usize] == State::Off {
                -plane.strength_n * plane.direction
            } else {
                plane.strength_n * plane.direction
            };
            if slope + t * curvature + jumps >= 0.0 {
                return Step {
                    t,
                    kink: Some(index as usize),
                };
            }
        }
        Step {
            t: (-(slope + jumps) / curvature).clamp(0.0, 1.0),
            kink: None,
        }
    }

    /// Whether a point or line passed near at step fraction `t` could hold the proxy there, W being empty: the
    /// whole force the other terms' model puts on it there (not only its part along the step) is within
    /// [`NEAR_PASS_HOLD`] times its strength. (Without this a point could join W with a multiplier a thousand
    /// times its strength, and leaving it again threw the proxy far off.) `normal`, `step` and `rho` are its
    /// offset's direction, the step's part across it and its distance, at `x`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn could_hold(
        &self,
        item: &Item,
        model: &Model,
        d: DVec3,
        t: f64,
        normal: DVec3,
        step: DVec3,
        rho: f64,
        jump_gradient: DVec3,
    ) -> bool {
        let s = item.strength_n;
        let own_gradient = s * normal;
        let own_hessian_d = s / rho * (step - normal * normal.dot(step));
        let mut others =
            model.gradient - own_gradient + t * (model.hessian * d - own_hessian_d) + jump_gradient;
        if item.kind == PrimitiveKind::Line {
            let q = item.direction;
            others -= q * q.dot(others);
        }
        others.length() <= NEAR_PASS_HOLD * s
    }

    /// Recovers the kink multipliers (module header, step 4) into `dual`, each in its set. On failure returns
    /// the worst violation: the item, its multiplier, and the label it leaves W with.
    pub(super) fn multipliers(
        &self,
        items: &[Item],
        face: &Face,
        gradient: DVec3,
        dual: &mut [DVec3],
    ) -> Result<(), (usize, DVec3, State)> {
        if self.kink_count == 0 {
            return Ok(());
        }
        let needed = -gradient;
        if face.point.is_none() {
            // The minimum-norm split.
            let w = face.pinv * needed;
            let mut worst: Option<(usize, f64, DVec3, State)> = None;
            for &index in &self.kinks[..self.kink_count] {
                let i = index as usize;
                let item = &items[i];
                let u = kink_projector(item) * w;
                dual[i] = project(item, u);
                if let Some((violation, label)) = violation(item, u) {
                    if worst.is_none_or(|(_, v, _, _)| violation > v) {
                        worst = Some((i, violation, u, label));
                    }
                }
            }
            match worst {
                None => return Ok(()),
                Some((i, _, u, label)) => {
                    if self.kink_count == 1 {
                        return Err((i, u, label));
                    }
                    // Dependent kinks can split the force another way: try the sweeps below.
                    let _ = (i, u, label);
                }
            }
        } else {
            for &index in &self.kinks[..self.kink_count] {
                dual[index as usize] = DVec3::ZERO;
            }
        }
        // Dependent kinks: look for a feasible split by projected block sweeps over W alone.
        let tolerance = 8.0 * EPS * needed.length().max(f64::MIN_POSITIVE);
        let mut sum = DVec3::ZERO;
        for &index in &self.kinks[..self.kink_count] {
            let i = index as usize;
            dual[i] = project(&items[i], dual[i]);
            sum += dual[i];
        }
        for _ in 0..MAX_SPLIT_SWEEPS {
            let sum_before = sum;
            let mut changed = false;
            for &index in &self.kinks[..self.kink_count] {
                let i = index as usize;
                let others = sum - dual[i];
                let u = project(&items[i], needed - others);
                changed |= u != dual[i];
                dual[i] = u;
                sum = others + u;
            }
            if (sum - needed).length() <= tolerance {
                return Ok(());
            }
            if !changed && sum == sum_before {
                // A fixed point (one kink reaches it in one sweep): further sweeps would repeat this one.
                break;
            }
        }
        // No feasible split found: the kink whose unconstrained share most exceeds its set leaves.
        let mut worst: Option<(usize, f64, DVec3, State)> = None;
        for &index in &self.kinks[..self.kink_count] {
            let i = index as usize;
            let others = sum - dual[i];
            let u = kink_projector(&items[i]) * (needed - others);
            if let Some((violation, label)) = violation(&items[i], u) {
                if worst.is_none_or(|(_, v, _, _)| violation > v) {
                    worst = Some((i, violation, u, label));
                }
            }
        }
        let (i, _, u, label) = worst.unwrap_or_else(|| {
            // Every share is feasible on its own yet they do not add up: drop the last kink added.
            let i = self.kinks[self.kink_count - 1] as usize;
            (i, 0.0, dual[i], leave_label(&items[i], dual[i]))
        });
        Err((i, u, label))
    }

    /// Gap-safe screening (module header): drops the planes that keep their side on the ball of radius
    /// `radius` around `x`, which is proven to hold the answer. Runs only when the radius has shrunk by 4
    /// since the last screening.
    pub(super) fn screen(
        &mut self,
        items: &[Item],
        x: DVec3,
        radius: f64,
        screened_radius_m: &mut f64,
        dual: &mut [DVec3],
    ) {
        // (A NaN radius screens nothing.)
        if radius.is_nan() || radius >= 0.25 * *screened_radius_m {
            return;
        }
        *screened_radius_m = radius;
        let scale = x.abs().max_element();
        let mut kept = 0;
        for slot in 0..self.active.len() {
            let index = self.active[slot];
            let i = index as usize;
            let item = &items[i];
            let state = self.state[i];
            if item.kind == PrimitiveKind::Plane && matches!(state, State::Off | State::Full) {
                let sigma = item.direction.dot(x - item.position_m);
                let rounding = 8.0 * EPS * (scale + item.position_m.abs().max_element());
                if sigma.abs() > radius + rounding {
                    if sigma < 0.0 {
                        self.state[i] = State::ScreenedFull;
                        self.fixed_gradient_n -= item.strength_n * item.direction;
                        self.fixed_energy_j +=
                            item.strength_n * item.direction.dot(item.position_m);
                        dual[i] = -item.strength_n * item.direction;
                    } else {
                        self.state[i] = State::ScreenedOff;
                        dual[i] = DVec3::ZERO;
                    }
                    continue;
                }
            }
            self.active[kept] = index;
            kept += 1;
        }
        self.active.truncate(kept);
    }

    /// The affine set of W.
    pub(super) fn face(&self, items: &[Item]) -> Face {
        let kinks = &self.kinks[..self.kink_count];
        if let Some(&p) = kinks
            .iter()
            .find(|&&i| items[i as usize].kind == PrimitiveKind::Point)
        {
            return Face {
                pinv: DMat3::ZERO,
                null: DMat3::ZERO,
                point: Some(p as usize),
            };
        }
        match kinks {
            [] => Face {
                pinv: DMat3::ZERO,
                null: DMat3::IDENTITY,
                point: None,
            },
            [only] => {
                let p = kink_projector(&items[*only as usize]);
                Face {
                    pinv: p,
                    null: DMat3::IDENTITY - p,
                    point: None,
                }
            }
            _ => {
                let m = kinks
                    .iter()
                    .map(|&i| kink_projector(&items[i as usize]))
                    .fold(DMat3::ZERO, |m, p| m + p);
                let (pinv, null, _) = psd_pseudo_inverse(m, RANK_TOLERANCE);
                Face {
                    pinv,
                    null,
                    point: None,
                }
            }
        }
    }

    /// Moves `x` onto the affine set of W (two rounds: the second removes the first's rounding). Returns whether
    /// every kink then holds it (the set is consistent).
    pub(super) fn project_onto_face(
        &self,
        items: &[Item],
        face: &Face,
        x: &mut DVec3,
        scale: f64,
    ) -> bool {
        if self.kink_count == 0 {
            return true;
        }
        if let Some(p) = face.point {
            *x = items[p].position_m;
        } else {
            for _ in 0..2 {
                let mut residual = DVec3::ZERO;
                for &index in &self.kinks[..self.kink_count] {
                    let item = &items[index as usize];
                    residual += kink_projector(item) * (item.position_m - *x);
                }
                *x += face.pinv * residual;
            }
        }
        let tolerance = 64.0 * EPS * scale;
        self.kinks[..self.kink_count]
            .iter()
            .all(|&i| kink_distance_squared(&items[i as usize], *x) <= tolerance * tolerance)
    }

    /// Adds item `i` to W if the enlarged set is consistent, moving `x` onto it, and returns the new face;
    /// otherwise leaves W and `x`.
    pub(super) fn try_add_kink(
        &mut self,
        items: &[Item],
        i: usize,
        x: &mut DVec3,
        scale: f64,
    ) -> Option<Face> {
        if self.kink_count == MAX_KINKS || self.state[i] == State::Kink {
            return None;
        }
        self.kinks[self.kink_count] = i as u32;
        self.kink_count += 1;
        let face = self.face(items);
        let mut moved = *x;
        if self.project_onto_face(items, &face, &mut moved, scale) {
            self.state[i] = State::Kink;
            *x = moved;
            Some(face)
        } else {
            self.kink_count -= 1;
            None
        }
    }

    /// Takes kink `i`, whose multiplier `u` lies outside its set, out of W with `label` (a point or line is
    /// moved off its kink the way the excess force pushes, by what the coupling alone would yield to it).
    /// Returns false when `i` has left W too often in this solve (the attempt is then abandoned as cycling).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn leave(
        &mut self,
        items: &[Item],
        i: usize,
        u: DVec3,
        label: State,
        x: &mut DVec3,
        k: f64,
        scale: f64,
    ) -> bool {
        self.drops[i] = self.drops[i].saturating_add(1);
        if self.drops[i] > MAX_DROPS_PER_PRIMITIVE {
            return false;
        }
        self.remove_kink(i, label);
        let item = &items[i];
        if item.kind != PrimitiveKind::Plane {
            let excess = u.length() - item.strength_n;
            *x += u.normalize_or_zero() * (excess / k).max(1e-9 * scale);
        }
        true
    }

    /// Step 4 ahead of time: with one kink in W (a plane or a line), its multiplier at the minimiser of the
    /// face's model, from the gradient the model predicts there (`g + H d`). If that lies far outside its set
    /// (by more than [`EARLY_LEAVE`] of the strength), converging on the face would only end in the kink
    /// leaving: returns it, its multiplier and its label, so that it leaves now.
    pub(super) fn early_leave(
        &self,
        items: &[Item],
        face: &Face,
        predicted: DVec3,
    ) -> Option<(usize, DVec3, State)> {
        if self.kink_count != 1 || face.point.is_some() {
            return None;
        }
        let i = self.kinks[0] as usize;
        let item = &items[i];
        let u = kink_projector(item) * -predicted;
        let (amount, label) = violation(item, u)?;
        (amount > EARLY_LEAVE).then_some((i, u, label))
    }

    /// Removes item `i` from W with the given label.
    pub(super) fn remove_kink(&mut self, i: usize, label: State) {
        if let Some(slot) = self.kinks[..self.kink_count]
            .iter()
            .position(|&k| k as usize == i)
        {
            self.kinks.copy_within(slot + 1..self.kink_count, slot);
            self.kink_count -= 1;
        }
        self.state[i] = label;
    }

    /// Puts W back as it was before a step that is being halved.
    pub(super) fn restore_kinks(
        &mut self,
        items: &[Item],
        kinks: [u32; MAX_KINKS],
        count: usize,
        x: DVec3,
    ) {
        for slot in 0..self.kink_count {
            let i = self.kinks[slot] as usize;
            if !kinks[..count].contains(&(i as u32)) {
                self.state[i] = start_state(&items[i], x);
            }
        }
        self.kinks = kinks;
        self.kink_count = count;
        for &i in &kinks[..count] {
            self.state[i as usize] = State::Kink;
        }
    }
}
