//! The modes of a scene and what they emit each tick (module header of `modes` has the table).

use super::config::{ModeConfig, ModeKind};
use super::mode::{Mode, ModeError, SurfaceSide, MAX_MODES, MIN_DIRECTION_MAGNITUDE};
use super::transfer::TransferFunction;
use crate::haptics::Primitive;
use crate::volume::{AnyVolume, ScalarVolume, VectorVolume};
use glam::DVec3;

/// What the tick renders: the volumes, the modes over them, and the coupling stiffness. Built off the
/// servo thread; read-only during ticks.
#[derive(Debug, Clone)]
pub struct RenderScene {
    stiffness_n_per_m: f64,
    volumes: Vec<(String, AnyVolume)>,
    modes: Vec<Mode>,
    mode_names: Vec<String>,
}

/// What a mode remembers from the previous tick, kept in the tick state (fixed size, `Copy`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModeMemory {
    /// The normal of the plane each mode emitted last tick (surface modes only), zero when none.
    pub plane_normals: [DVec3; MAX_MODES],
    /// The device force of the previous tick (N).
    pub previous_force_n: DVec3,
    /// The probe position of the previous tick (m), `None` on the first tick of a scene (then the hand's
    /// velocity is taken as zero).
    pub previous_probe_m: Option<DVec3>,
}

impl Default for ModeMemory {
    fn default() -> Self {
        Self {
            plane_normals: [DVec3::ZERO; MAX_MODES],
            previous_force_n: DVec3::ZERO,
            previous_probe_m: None,
        }
    }
}

/// Where a tick's modes sample: the proxy (passive modes) and the hand (active modes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModeInput {
    /// The proxy at the start of the tick (m): where the last tick left it.
    pub proxy_m: DVec3,
    /// Where the hand is expected half-way through the period this tick's force is held for (m): the probe
    /// plus half its last displacement. Active modes sample their field here (module docs of `modes`).
    pub hand_m: DVec3,
    /// The hand's velocity over the last tick (m/s): zero on the first tick.
    pub hand_velocity_m_per_s: DVec3,
}

impl ModeInput {
    /// The input for a tick with the proxy at `proxy_m`, the probe at `probe_m` and the previous probe at
    /// `previous_probe_m`, `dt_s` apart. Without a previous probe (or a usable `dt_s`) the hand is taken at
    /// rest at the probe.
    pub fn new(proxy_m: DVec3, probe_m: DVec3, previous_probe_m: Option<DVec3>, dt_s: f64) -> Self {
        let step_m = match previous_probe_m {
            Some(previous) if dt_s.is_finite() && dt_s > 0.0 && previous.is_finite() => {
                probe_m - previous
            }
            _ => DVec3::ZERO,
        };
        let velocity = step_m / dt_s;
        let (step_m, velocity) = if velocity.is_finite() {
            (step_m, velocity)
        } else {
            (DVec3::ZERO, DVec3::ZERO)
        };
        Self {
            proxy_m,
            hand_m: probe_m + 0.5 * step_m,
            hand_velocity_m_per_s: velocity,
        }
    }

    /// A tick with the hand at rest at the proxy (tests, warm-up).
    pub fn at_rest(proxy_m: DVec3) -> Self {
        Self {
            proxy_m,
            hand_m: proxy_m,
            hand_velocity_m_per_s: DVec3::ZERO,
        }
    }
}

impl RenderScene {
    /// Builds a scene from named volumes and mode settings. Errors name the offending key.
    pub fn new(
        stiffness_n_per_m: f64,
        volumes: Vec<(String, AnyVolume)>,
        modes: &[ModeConfig],
    ) -> Result<Self, ModeError> {
        if !(stiffness_n_per_m.is_finite() && stiffness_n_per_m > 0.0) {
            return Err(ModeError::BadStiffness(stiffness_n_per_m));
        }
        if modes.len() > MAX_MODES {
            return Err(ModeError::TooManyModes(modes.len()));
        }
        for (i, (name, _)) in volumes.iter().enumerate() {
            if volumes[..i].iter().any(|(n, _)| n == name) {
                return Err(ModeError::DuplicateVolumeName(name.clone()));
            }
        }
        let names: Vec<&str> = modes.iter().map(ModeConfig::display_name).collect();
        let kinds: Vec<ModeKind> = modes.iter().map(|m| m.kind).collect();
        for (index, name) in names.iter().enumerate() {
            let valid = !name.is_empty()
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
            if !valid {
                return Err(ModeError::BadModeName {
                    index,
                    name: (*name).to_owned(),
                });
            }
            if names[..index].contains(name) {
                return Err(ModeError::DuplicateModeName {
                    index,
                    name: (*name).to_owned(),
                });
            }
        }
        let built = modes
            .iter()
            .enumerate()
            .map(|(index, m)| m.build(index, &volumes, &names, &kinds))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            stiffness_n_per_m,
            volumes,
            modes: built,
            mode_names: names.into_iter().map(str::to_owned).collect(),
        })
    }

    /// Coupling stiffness `k` (N/m).
    pub fn stiffness_n_per_m(&self) -> f64 {
        self.stiffness_n_per_m
    }

    /// Changes the coupling stiffness `k` (N/m) in place (no allocation; the servo thread applies stiffness
    /// commands this way). Refuses a non-finite or non-positive value and keeps the old one.
    pub fn set_stiffness_n_per_m(&mut self, stiffness_n_per_m: f64) -> Result<(), ModeError> {
        if !(stiffness_n_per_m.is_finite() && stiffness_n_per_m > 0.0) {
            return Err(ModeError::BadStiffness(stiffness_n_per_m));
        }
        self.stiffness_n_per_m = stiffness_n_per_m;
        Ok(())
    }

    pub fn volumes(&self) -> &[(String, AnyVolume)] {
        &self.volumes
    }

    pub fn modes(&self) -> &[Mode] {
        &self.modes
    }

    /// The modes' names, in order (trace columns).
    pub fn mode_names(&self) -> &[String] {
        &self.mode_names
    }

    /// The most primitives one tick can emit (each mode emits at most one).
    pub fn max_primitives(&self) -> usize {
        self.modes.len()
    }

    fn scalar(&self, index: usize) -> Option<&ScalarVolume> {
        match &self.volumes[index].1 {
            AnyVolume::Scalar(v) => Some(v),
            AnyVolume::Vector(_) => None,
        }
    }

    fn vector(&self, index: usize) -> Option<&VectorVolume> {
        match &self.volumes[index].1 {
            AnyVolume::Vector(v) => Some(v),
            AnyVolume::Scalar(_) => None,
        }
    }

    /// What an active mode pushes along at `p`: the gradient of a scalar volume (`gradient_force`), the value
    /// of a vector volume (`vector_force`). The scene's build gives each mode the kind of volume it reads.
    fn active_field(&self, index: usize, p: DVec3) -> DVec3 {
        match &self.volumes[index].1 {
            AnyVolume::Scalar(v) => v.gradient(p),
            AnyVolume::Vector(v) => v.sample(p),
        }
    }

    /// Reads every volume around `proxy_m` (value, gradient or Jacobian) and returns a number made from the
    /// reads only so they cannot be optimised away. The servo thread calls this a few microseconds before a
    /// tick's deadline: after a millisecond asleep, the voxels the tick is about to sample have left the
    /// caches, and fetching them again is most of a tick's compute time. No allocation.
    pub fn warm_caches(&self, proxy_m: DVec3) -> f64 {
        self.volumes
            .iter()
            .map(|(_, volume)| match volume {
                AnyVolume::Scalar(v) => v.sample_with_gradient(proxy_m).0,
                AnyVolume::Vector(v) => v.jacobian(proxy_m).x_axis.x,
            })
            .sum()
    }

    /// The viscous damping (N s/m) mode `index` puts on the proxy at `proxy_m`: `TF(V)` for a viscosity
    /// mode, 0 for every other kind. The tick renders it implicitly (its module docs).
    pub fn damping_n_s_per_m(&self, index: usize, proxy_m: DVec3) -> f64 {
        match &self.modes[index] {
            Mode::Viscosity { volume, transfer } => self
                .scalar(*volume)
                .map_or(0.0, |v| transfer.eval(v.sample(proxy_m))),
            _ => 0.0,
        }
    }

    /// Runs mode `index` for a tick at `at` (passive modes sample at the proxy, active ones at the hand),
    /// with `memory` from the previous tick: pushes at most one primitive onto `out` and returns how many it
    /// pushed, and the normal of the plane it emitted (surface modes), or zero. No allocation while `out`
    /// has capacity. Viscosity emits no primitive (see [`Self::damping_n_s_per_m`]).
    pub fn emit(
        &self,
        index: usize,
        at: &ModeInput,
        memory: &ModeMemory,
        out: &mut Vec<Primitive>,
    ) -> (u16, DVec3) {
        let proxy_m = at.proxy_m;
        let mut normal_out = DVec3::ZERO;
        let primitive = match &self.modes[index] {
            Mode::Surface {
                volume,
                transfer,
                side,
            } => self.scalar(*volume).and_then(|v| {
                let (value, gradient) = v.sample_with_gradient(proxy_m);
                let strength = transfer.eval(value);
                let normal = match side {
                    SurfaceSide::Outward => -gradient,
                    SurfaceSide::Inward => gradient,
                };
                let plane = direction_of(normal)
                    .and_then(|n| nonzero(strength).map(|s| (n, s)))
                    .and_then(|(n, s)| Primitive::plane(proxy_m, n, s).ok());
                if let Some(p) = &plane {
                    normal_out = p.direction();
                }
                plane
            }),
            Mode::Friction { surface_mode, mu } => {
                let normal = memory.plane_normals[*surface_mode];
                let normal_force_n = normal.dot(memory.previous_force_n).max(0.0);
                nonzero(mu * normal_force_n).and_then(|s| Primitive::point(proxy_m, s).ok())
            }
            Mode::Viscosity { .. } => None,
            Mode::CoulombDrag { volume, transfer } => self.scalar(*volume).and_then(|v| {
                nonzero(transfer.eval(v.sample(proxy_m)))
                    .and_then(|s| Primitive::point(proxy_m, s).ok())
            }),
            Mode::VectorFollow { volume, transfer } => self.vector(*volume).and_then(|v| {
                let velocity = v.sample(proxy_m);
                direction_of(velocity)
                    .and_then(|_| nonzero(transfer.eval(velocity.length())))
                    .and_then(|s| Primitive::line(proxy_m, velocity, s).ok())
            }),
            Mode::GradientForce {
                volume,
                transfer,
                power_budget_w,
            }
            | Mode::VectorForce {
                volume,
                transfer,
                power_budget_w,
            } => active_push(
                self.active_field(*volume, at.hand_m),
                transfer,
                at,
                *power_budget_w,
            ),
            Mode::Vortex { volume, transfer } => self.vector(*volume).and_then(|v| {
                let jacobian = v.jacobian(proxy_m);
                let curl = crate::volume::vector::curl_of(&jacobian);
                let axis = direction_of(curl)?;
                let strength = nonzero(transfer.eval(curl.length()))?;
                let core = vortex_core_m(proxy_m, v.sample(proxy_m), &jacobian, axis);
                Primitive::line(core, axis, strength).ok()
            }),
            Mode::SupportPlane { plane } => Some(*plane),
        };
        match primitive {
            Some(p) => {
                out.push(p);
                (1, normal_out)
            }
            None => (0, DVec3::ZERO),
        }
    }
}

/// The unit vector along `v`, or `None` when `v` is too short (or not finite) to define a direction.
fn direction_of(v: DVec3) -> Option<DVec3> {
    let length = v.length();
    (length.is_finite() && length > MIN_DIRECTION_MAGNITUDE).then(|| v / length)
}

/// An active mode's push along `field` (sampled at the hand): the transfer of its length, held to the power
/// budget; `None` where the field has no direction or the strength is 0.
fn active_push(
    field: DVec3,
    transfer: &TransferFunction,
    at: &ModeInput,
    budget_w: f64,
) -> Option<Primitive> {
    let direction = direction_of(field)?;
    let strength = within_budget(transfer.eval(field.length()), direction, at, budget_w);
    nonzero(strength).and_then(|s| Primitive::directed(direction, s).ok())
}

/// An active mode's strength held to its power budget: a force `s q` on a hand moving at `v` delivers
/// `s q.v`; where that exceeds `budget_w` the strength is cut to `budget_w / q.v`. A hand moving against the
/// force (or at rest) takes the full strength: the mode then does no positive work.
fn within_budget(strength_n: f64, direction: DVec3, at: &ModeInput, budget_w: f64) -> f64 {
    let along_m_per_s = direction.dot(at.hand_velocity_m_per_s);
    if along_m_per_s > 0.0 && strength_n * along_m_per_s > budget_w {
        budget_w / along_m_per_s
    } else {
        strength_n
    }
}

fn nonzero(strength_n: f64) -> Option<f64> {
    (strength_n.is_finite() && strength_n > 0.0).then_some(strength_n)
}

/// The vortex core nearest `x` from the linearisation `v(x + d) = v + J d` (module docs): `d` in the
/// plane across `axis` zeroing the in-plane velocity; `x` itself when that 2x2 system is singular.
fn vortex_core_m(x: DVec3, velocity: DVec3, jacobian: &glam::DMat3, axis: DVec3) -> DVec3 {
    let (a, b) = axis.any_orthonormal_pair();
    let ja = *jacobian * a;
    let jb = *jacobian * b;
    // M = [[a.Ja, a.Jb], [b.Ja, b.Jb]], rhs = -(a.v, b.v)
    let m00 = a.dot(ja);
    let m01 = a.dot(jb);
    let m10 = b.dot(ja);
    let m11 = b.dot(jb);
    let det = m00 * m11 - m01 * m10;
    let scale = m00.abs().max(m01.abs()).max(m10.abs()).max(m11.abs());
    if !(det.is_finite() && det.abs() > 1e-12 * scale * scale) || scale == 0.0 {
        return x;
    }
    let (r0, r1) = (-a.dot(velocity), -b.dot(velocity));
    let c0 = (m11 * r0 - m01 * r1) / det;
    let c1 = (m00 * r1 - m10 * r0) / det;
    let core = x + c0 * a + c1 * b;
    if core.is_finite() {
        core
    } else {
        x
    }
}
