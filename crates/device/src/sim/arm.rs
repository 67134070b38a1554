//! The arm's parameters, its state and the fixed-step integrator (see the module header in `sim` for the
//! model and the maths). `SimArm::step` runs on the servo thread: it does not allocate, lock or do I/O.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::effects::{DeviceEffects, EffectsState};
use super::keys::{check_positive, KeyCheck, ARM_MASS, POSITION, RADIUS};
use super::preset::{ArmPreset, PresetFigures};
use super::tagged::tagged_table;
use super::zoh::SubstepMapCache;
use super::{HandDrive, HandPath, SimError};
use crate::mapping::WorkspaceMapping;

/// What an `[arm]` table that leaves `substeps_per_tick` out gets.
pub(crate) const DEFAULT_SUBSTEPS_PER_TICK: u32 = 10;
/// What an `[arm]` table that leaves `wall_stiffness_n_per_m` out gets (N/m).
pub(crate) const DEFAULT_WALL_STIFFNESS_N_PER_M: f64 = 5000.0;
/// What an `[arm]` table that leaves `wall_damping_n_s_per_m` out gets (N s/m).
pub(crate) const DEFAULT_WALL_DAMPING_N_S_PER_M: f64 = 10.0;

fn default_substeps_per_tick() -> u32 {
    DEFAULT_SUBSTEPS_PER_TICK
}

fn default_wall_stiffness_n_per_m() -> f64 {
    DEFAULT_WALL_STIFFNESS_N_PER_M
}

fn default_wall_damping_n_s_per_m() -> f64 {
    DEFAULT_WALL_DAMPING_N_S_PER_M
}

/// Where the arm can go. A table with a `shape` key, e.g. `{ shape = "sphere", center_m = [0, 0, 0],
/// radius_m = 0.1 }`, read through `WorkspaceTable` so that every error names its key (super::tagged).
/// Outside it a stiff one-sided wall spring pushes the arm back (see [`ArmParams`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "snake_case", try_from = "WorkspaceTable")]
pub enum Workspace {
    /// An axis-aligned box.
    Box {
        /// Lower corner (m).
        min_m: DVec3,
        /// Upper corner (m), >= `min_m` on every axis.
        max_m: DVec3,
    },
    /// A ball.
    Sphere {
        /// Centre (m).
        center_m: DVec3,
        /// Radius (m), > 0.
        radius_m: f64,
    },
    /// No limit.
    Unbounded,
}

tagged_table! {
    Workspace by shape at "arm.workspace",
    /// The `shape` of a [`Workspace`] table.
    kinds WorkspaceShape {
        Box = "box" { min_m: POSITION, max_m: POSITION },
        Sphere = "sphere" { center_m: POSITION, radius_m: RADIUS },
        Unbounded = "unbounded" {},
    }
    /// An `[arm.workspace]` table as written: every key of every shape, checked against its `shape` by
    /// `Workspace::try_from` (super::tagged says why).
    table WorkspaceTable {
        min_m: DVec3,
        max_m: DVec3,
        center_m: DVec3,
        radius_m: f64,
    }
}

impl Workspace {
    /// Checks every key ([`super::keys`], each key's in the `tagged_table!` above), then that a box's
    /// corners are in order.
    fn validate(&self) -> Result<(), SimError> {
        self.check_keys()?;
        match self {
            Workspace::Box { min_m, max_m } if min_m.cmpgt(*max_m).any() => {
                Err(SimError::InvertedBox)
            }
            _ => Ok(()),
        }
    }

    /// The point of the workspace closest to `position_m` (the point itself when inside).
    pub fn closest_point_m(&self, position_m: DVec3) -> DVec3 {
        match self {
            Workspace::Box { min_m, max_m } => position_m.clamp(*min_m, *max_m),
            Workspace::Sphere { center_m, radius_m } => {
                let offset = position_m - *center_m;
                let distance_m = offset.length();
                if distance_m > *radius_m {
                    *center_m + offset * (*radius_m / distance_m)
                } else {
                    position_m
                }
            }
            Workspace::Unbounded => position_m,
        }
    }

    /// Whether `position_m` is inside the workspace or at most `tolerance_m` outside it.
    pub fn contains_m(&self, position_m: DVec3, tolerance_m: f64) -> bool {
        (position_m - self.closest_point_m(position_m)).length() <= tolerance_m
    }
}

/// The arm's own dynamics. Missing optional keys take the defaults noted; `preset` fills the keys it has a
/// sourced figure for (super::preset), and a key written beside it wins.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "ArmTable")]
pub struct ArmParams {
    /// Moving mass at the end effector (kg), > 0.
    pub mass_kg: f64,
    /// Viscous damping to ground (N s/m), >= 0.
    pub damping_n_s_per_m: f64,
    /// Where the arm can go.
    pub workspace: Workspace,
    /// Physics substeps per servo tick, >= 1 (default 10).
    pub substeps_per_tick: u32,
    /// Stiffness of the workspace wall (N/m), >= 0 (default 5000).
    pub wall_stiffness_n_per_m: f64,
    /// Damping of the workspace wall along its normal while outside (N s/m), >= 0 (default 10).
    pub wall_damping_n_s_per_m: f64,
    /// Latency, quantisation, jitter, velocity estimation and the preset (all off by default;
    /// super::effects).
    #[serde(flatten)]
    pub effects: DeviceEffects,
}

/// An `[arm]` table as written: the preset's figures fill what is left out.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArmTable {
    preset: Option<ArmPreset>,
    mass_kg: Option<f64>,
    damping_n_s_per_m: Option<f64>,
    workspace: Workspace,
    #[serde(default = "default_substeps_per_tick")]
    substeps_per_tick: u32,
    #[serde(default = "default_wall_stiffness_n_per_m")]
    wall_stiffness_n_per_m: f64,
    #[serde(default = "default_wall_damping_n_s_per_m")]
    wall_damping_n_s_per_m: f64,
    latency_s: Option<f64>,
    position_resolution_m: Option<f64>,
    #[serde(default)]
    force_resolution_n: f64,
    #[serde(default)]
    period_jitter_s: f64,
    #[serde(default)]
    jitter_seed: u32,
    #[serde(default)]
    velocity_window_ticks: u32,
}

/// An `[arm]` table that leaves out a key no preset gives.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("missing field `{key}`{}", preset_note(*.preset))]
pub struct MissingArmKey {
    /// The key.
    pub key: &'static str,
    /// The preset named, if any.
    pub preset: Option<ArmPreset>,
}

fn preset_note(preset: Option<ArmPreset>) -> String {
    match preset {
        Some(p) => format!(
            " (preset \"{}\" has no sourced figure for it: {}; give it)",
            p.name(),
            p.figures().source
        ),
        None => String::new(),
    }
}

impl TryFrom<ArmTable> for ArmParams {
    type Error = MissingArmKey;

    fn try_from(table: ArmTable) -> Result<Self, MissingArmKey> {
        let figures = table.preset.map(ArmPreset::figures);
        let pick = |given: Option<f64>,
                    from_preset: fn(&PresetFigures) -> Option<f64>,
                    key: &'static str| {
            given
                .or_else(|| figures.as_ref().and_then(from_preset))
                .ok_or(MissingArmKey {
                    key,
                    preset: table.preset,
                })
        };
        let optional = |given: Option<f64>, from_preset: fn(&PresetFigures) -> Option<f64>| {
            given
                .or_else(|| figures.as_ref().and_then(from_preset))
                .unwrap_or(0.0)
        };
        Ok(ArmParams {
            mass_kg: pick(table.mass_kg, |f| f.mass_kg, "mass_kg")?,
            damping_n_s_per_m: pick(
                table.damping_n_s_per_m,
                |f| f.damping_n_s_per_m,
                "damping_n_s_per_m",
            )?,
            workspace: table.workspace,
            substeps_per_tick: table.substeps_per_tick,
            wall_stiffness_n_per_m: table.wall_stiffness_n_per_m,
            wall_damping_n_s_per_m: table.wall_damping_n_s_per_m,
            effects: DeviceEffects {
                preset: table.preset,
                latency_s: optional(table.latency_s, |f| f.latency_s),
                position_resolution_m: optional(table.position_resolution_m, |f| {
                    f.position_resolution_m
                }),
                force_resolution_n: table.force_resolution_n,
                period_jitter_s: table.period_jitter_s,
                jitter_seed: table.jitter_seed,
                velocity_window_ticks: table.velocity_window_ticks,
            },
        })
    }
}

/// The virtual hand's grip: a spring-damper between the hand target and the arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandParams {
    /// Spring stiffness (N/m), > 0.
    pub stiffness_n_per_m: f64,
    /// Damping on the velocity error (N s/m), >= 0.
    pub damping_n_s_per_m: f64,
}

/// Everything that defines a simulated arm; deserialises from a scenario TOML table with `[arm]`,
/// `[hand]` and `[path]` sub-tables.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimArmConfig {
    /// The arm's dynamics and workspace.
    pub arm: ArmParams,
    /// The hand's grip.
    pub hand: HandParams,
    /// What the hand does over time.
    pub path: HandPath,
    /// `[local_model]`: the arm simulates a device with the local-model capability (protocol/SPEC.md section
    /// 10) whose own control loop runs at this rate; `None`: a set-force device.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local_model: Option<LocalModelSim>,
}

/// `[local_model]` of a scene file: the simulated arm renders the host's local models with the reference device
/// loop at `rate_hz` (a whole multiple of the servo rate, at most 100 kHz).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LocalModelSim {
    /// The device's control rate, Hz.
    pub rate_hz: f64,
}

/// The fastest simulated local loop, Hz.
pub const MAX_LOCAL_RATE_HZ: f64 = 100_000.0;

impl LocalModelSim {
    /// How many control cycles of whole microseconds fit one servo period at `servo_hz`: `None` unless
    /// `rate_hz` is a whole multiple of `servo_hz`, at most [`MAX_LOCAL_RATE_HZ`], with a cycle of whole
    /// microseconds (the device loop's clock).
    pub fn cycles_per_period(&self, servo_hz: f64) -> Option<u32> {
        let rate_hz = self.rate_hz;
        let in_range = rate_hz.is_finite()
            && servo_hz.is_finite()
            && servo_hz > 0.0
            && (servo_hz..=MAX_LOCAL_RATE_HZ).contains(&rate_hz);
        if !in_range {
            return None;
        }
        let cycles = (rate_hz / servo_hz).round();
        let cycle_us = 1e6 / rate_hz;
        let whole = (cycles * servo_hz - rate_hz).abs() <= 1e-9 * rate_hz
            && (cycle_us - cycle_us.round()).abs() <= 1e-9 * cycle_us;
        whole.then_some(cycles as u32)
    }
}

impl SimArmConfig {
    /// The arm's physics as the coupling caps see it (crate::physics): the arm's own damping (the hand
    /// may let go, so its damping does not count), its latency and resolution; no Coulomb friction.
    pub fn physics(&self) -> crate::physics::DevicePhysics {
        crate::physics::DevicePhysics {
            damping_n_s_per_m: self.arm.damping_n_s_per_m,
            latency_s: self.arm.effects.latency_s,
            position_resolution_m: self.arm.effects.position_resolution_m,
            coulomb_friction_n: 0.0,
            source: "the simulated arm's [arm] table",
        }
    }
}

/// What happened during one [`SimArm::step`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepOutcome {
    /// The arm was outside the workspace (the wall pushed) during at least one substep.
    pub workspace_limit_hit: bool,
    /// The rendered force had a non-finite component and was replaced by zero.
    pub force_rejected: bool,
}

/// A simulated haptic arm: a damped point mass driven by a virtual hand. See the `sim` module header.
#[derive(Clone, Debug)]
pub struct SimArm {
    config: SimArmConfig,
    max_substep_s: f64,
    /// The true state: position (m) and velocity (m/s).
    x_m: DVec3,
    v_m_per_s: DVec3,
    /// The position as the device reports it (rounded to `position_resolution_m`).
    position_m: DVec3,
    /// The velocity as the device reports it (exact, or estimated from reported positions).
    v_reported_m_per_s: DVec3,
    /// How far this tick's sample instant is off its nominal time (s): the period jitter.
    jitter_offset_s: f64,
    effects: EffectsState,
    maps: SubstepMapCache,
    hand_force_n: DVec3,
    wall_force_n: DVec3,
    rejected_force_count: u64,
    /// When set, the hand pulls towards this point (at rest) instead of following its path: a user dragging
    /// the hand with the mouse in the visualiser.
    hand_target_override_m: Option<DVec3>,
    /// When set, the scripted path is in the scene frame and this maps the arm's (device) frame into it
    /// ([`SimArm::use_scene_frame`]); `None` for the identity, so such arms compute exactly as unmapped ones.
    path_mapping: Option<WorkspaceMapping>,
}

fn non_negative(name: &'static str, value: f64) -> Result<(), SimError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SimError::InvalidParameter {
            name,
            value,
            requirement: "finite and >= 0",
        })
    }
}

impl SimArm {
    /// Checks the configuration and places the arm at rest at `start_m`.
    pub fn new(config: SimArmConfig, start_m: DVec3) -> Result<Self, SimError> {
        let arm = &config.arm;
        ARM_MASS.check("arm.mass_kg", &arm.mass_kg)?;
        non_negative("arm.damping_n_s_per_m", arm.damping_n_s_per_m)?;
        check_positive("arm.substeps_per_tick", f64::from(arm.substeps_per_tick))?;
        non_negative("arm.wall_stiffness_n_per_m", arm.wall_stiffness_n_per_m)?;
        non_negative("arm.wall_damping_n_s_per_m", arm.wall_damping_n_s_per_m)?;
        arm.workspace.validate()?;
        arm.effects.validate()?;
        check_positive("hand.stiffness_n_per_m", config.hand.stiffness_n_per_m)?;
        non_negative("hand.damping_n_s_per_m", config.hand.damping_n_s_per_m)?;
        config.path.validate()?;
        POSITION.check("start_m", &start_m)?;

        // The mass, its damping and the hand are integrated exactly (super::zoh); only the workspace wall,
        // a one-sided spring held over each substep, limits the substep.
        let max_substep_s = if matches!(arm.workspace, Workspace::Unbounded) {
            f64::INFINITY
        } else {
            let spring_limit_s = if arm.wall_stiffness_n_per_m > 0.0 {
                (arm.mass_kg / arm.wall_stiffness_n_per_m).sqrt()
            } else {
                f64::INFINITY
            };
            let damping_limit_s = if arm.wall_damping_n_s_per_m > 0.0 {
                arm.mass_kg / arm.wall_damping_n_s_per_m
            } else {
                f64::INFINITY
            };
            spring_limit_s.min(damping_limit_s)
        };
        let reported_position_m =
            DeviceEffects::quantise(start_m, arm.effects.position_resolution_m);
        let effects = EffectsState::new(&arm.effects);
        Ok(SimArm {
            max_substep_s,
            config,
            x_m: start_m,
            v_m_per_s: DVec3::ZERO,
            position_m: reported_position_m,
            v_reported_m_per_s: DVec3::ZERO,
            jitter_offset_s: 0.0,
            effects,
            maps: SubstepMapCache::default(),
            hand_force_n: DVec3::ZERO,
            wall_force_n: DVec3::ZERO,
            rejected_force_count: 0,
            hand_target_override_m: None,
            path_mapping: None,
        })
    }

    /// Advances the arm by one servo tick `[t_s, t_s + dt_s)` under the rendered force `rendered_force_n`
    /// (the force the haptic loop sends to the device), in `substeps_per_tick` substeps integrated exactly
    /// (super::zoh).
    ///
    /// The force is rounded to `force_resolution_n` and acts from `latency_s` after this tick's sample
    /// instant until the next force takes over (zero-order hold); with `period_jitter_s` the tick runs
    /// between two jittered sample instants. A rendered force with a non-finite component is replaced by
    /// zero, counted ([`SimArm::rejected_force_count`]) and reported in the outcome. No allocation.
    pub fn step(
        &mut self,
        t_s: f64,
        dt_s: f64,
        rendered_force_n: DVec3,
    ) -> Result<StepOutcome, SimError> {
        if !t_s.is_finite() || !dt_s.is_finite() || dt_s <= 0.0 {
            return Err(SimError::InvalidTime { t_s, dt_s });
        }
        let arm = self.config.arm;
        let effects = arm.effects;
        if effects.period_jitter_s > 0.0 && effects.period_jitter_s * 2.0 >= dt_s {
            return Err(SimError::JitterTooLarge {
                jitter_s: effects.period_jitter_s,
                dt_s,
            });
        }
        let substeps = arm.substeps_per_tick;
        let start_s = t_s + self.jitter_offset_s;
        let next_offset_s = self.effects.next_jitter_s(effects.period_jitter_s);
        let end_s = t_s + dt_s + next_offset_s;
        let substep_s = (end_s - start_s) / f64::from(substeps);
        if substep_s > self.max_substep_s {
            return Err(SimError::SubstepTooLong {
                substep_s,
                max_substep_s: self.max_substep_s,
            });
        }
        let mut outcome = StepOutcome::default();
        let rendered_n = if rendered_force_n.is_finite() {
            rendered_force_n
        } else {
            self.rejected_force_count += 1;
            outcome.force_rejected = true;
            DVec3::ZERO
        };
        self.effects.send(
            start_s + effects.latency_s,
            DeviceEffects::quantise(rendered_n, effects.force_resolution_n),
        );

        for i in 0..substeps {
            let mut a_s = start_s + f64::from(i) * substep_s;
            let b_s = if i + 1 == substeps {
                end_s
            } else {
                a_s + substep_s
            };
            // A substep is cut where a delayed force takes over, so each piece sees one held force.
            while a_s < b_s {
                let (acting_n, next_s) = self.effects.acting_at(a_s);
                let piece_end_s = if next_s < b_s { next_s } else { b_s };
                if piece_end_s > a_s {
                    self.advance_piece(a_s, piece_end_s - a_s, acting_n, &mut outcome);
                }
                a_s = piece_end_s;
            }
        }
        self.jitter_offset_s = next_offset_s;
        self.position_m = DeviceEffects::quantise(self.x_m, effects.position_resolution_m);
        self.v_reported_m_per_s = if effects.velocity_window_ticks == 0 {
            self.v_m_per_s
        } else {
            self.effects
                .record(end_s, self.position_m)
                .unwrap_or(DVec3::ZERO)
        };
        Ok(outcome)
    }

    /// Integrates `[time_s, time_s + h_s)` exactly under the held force `acting_n`, the hand (its target
    /// moving along a straight line) and the wall (held at its value at the piece's start).
    fn advance_piece(&mut self, time_s: f64, h_s: f64, acting_n: DVec3, outcome: &mut StepOutcome) {
        let arm = self.config.arm;
        let hand = self.config.hand;
        let x = self.x_m;
        let v = self.v_m_per_s;
        let drive = match self.hand_target_override_m {
            Some(position_m) => HandDrive::Target {
                position_m,
                velocity_m_per_s: DVec3::ZERO,
            },
            None => self.scripted_drive_at(time_s),
        };
        self.wall_force_n = wall_force_n(&arm, x, v);
        if self.wall_force_n != DVec3::ZERO || !arm.workspace.contains_m(x, 0.0) {
            outcome.workspace_limit_hit = true;
        }
        // m x'' = -k x - c x' + u0 + s (t - time_s), per axis.
        let (k, c, u0, slope) = match drive {
            HandDrive::Target {
                position_m,
                velocity_m_per_s,
            } => {
                self.hand_force_n = hand.stiffness_n_per_m * (position_m - x)
                    + hand.damping_n_s_per_m * (velocity_m_per_s - v);
                (
                    hand.stiffness_n_per_m,
                    arm.damping_n_s_per_m + hand.damping_n_s_per_m,
                    acting_n
                        + self.wall_force_n
                        + hand.stiffness_n_per_m * position_m
                        + hand.damping_n_s_per_m * velocity_m_per_s,
                    hand.stiffness_n_per_m * velocity_m_per_s,
                )
            }
            HandDrive::Force { force_n } => {
                self.hand_force_n = force_n;
                (
                    0.0,
                    arm.damping_n_s_per_m,
                    acting_n + self.wall_force_n + force_n,
                    DVec3::ZERO,
                )
            }
        };
        let map = self.maps.get(arm.mass_kg, k, c, h_s);
        let (x0, v0) = map.apply(x.x, v.x, u0.x, slope.x);
        let (x1, v1) = map.apply(x.y, v.y, u0.y, slope.y);
        let (x2, v2) = map.apply(x.z, v.z, u0.z, slope.z);
        self.x_m = DVec3::new(x0, x1, x2);
        self.v_m_per_s = DVec3::new(v0, v1, v2);
    }

    /// Reads the scripted path and the start point as scene positions under `mapping` (device frame to
    /// scene frame, `x_scene = s R x_device + t`): the arm is placed at rest at the device point that maps to
    /// `start_scene_m`, and from then on the hand follows the path's targets mapped into the device frame
    /// (`Rᵀ (p - t) / s`, velocities `Rᵀ v / s`) or pushes with its scripted force rotated back (`Rᵀ f`, not
    /// scaled, as every scene force). The workspace limit and a hand target set with
    /// [`SimArm::set_hand_target_m`] stay in the device frame. Meant to be called before the first step; the
    /// identity mapping leaves the path as it is. A start point that leaves f64's range in the device frame is refused
    /// (nothing changes).
    pub fn use_scene_frame(
        &mut self,
        mapping: WorkspaceMapping,
        start_scene_m: DVec3,
    ) -> Result<(), SimError> {
        let start_m = mapping.to_device_position_m(start_scene_m);
        if !start_m.is_finite() {
            return Err(SimError::NonFiniteVector {
                name: "start_m (mapped into the device frame)",
            });
        }
        self.path_mapping = (!mapping.is_identity()).then_some(mapping);
        self.x_m = start_m;
        self.v_m_per_s = DVec3::ZERO;
        self.position_m =
            DeviceEffects::quantise(start_m, self.config.arm.effects.position_resolution_m);
        self.v_reported_m_per_s = DVec3::ZERO;
        self.jitter_offset_s = 0.0;
        self.effects.reset();
        self.hand_force_n = DVec3::ZERO;
        self.wall_force_n = DVec3::ZERO;
        Ok(())
    }

    /// The scripted path's drive at `time_s`, in the arm's (device) frame.
    fn scripted_drive_at(&self, time_s: f64) -> HandDrive {
        let drive = self.config.path.drive_at(time_s);
        let Some(mapping) = self.path_mapping else {
            return drive;
        };
        match drive {
            HandDrive::Target {
                position_m,
                velocity_m_per_s,
            } => HandDrive::Target {
                position_m: mapping.to_device_position_m(position_m),
                velocity_m_per_s: mapping.to_device_velocity_m_per_s(velocity_m_per_s),
            },
            HandDrive::Force { force_n } => HandDrive::Force {
                force_n: mapping.to_device_force_n(force_n),
            },
        }
    }

    /// Makes the hand pull towards `target_m` (held still) instead of following its path, or, with `None`,
    /// resume the path. A non-finite target is refused (returns false, nothing changes).
    pub fn set_hand_target_m(&mut self, target_m: Option<DVec3>) -> bool {
        if target_m.is_some_and(|t| !t.is_finite()) {
            return false;
        }
        self.hand_target_override_m = target_m;
        true
    }

    /// The hand target set by [`SimArm::set_hand_target_m`], if any.
    pub fn hand_target_m(&self) -> Option<DVec3> {
        self.hand_target_override_m
    }

    /// The end effector's position as the device reports it (m): the probe position the servo loop reads
    /// (the true position rounded to `position_resolution_m`).
    pub fn position_m(&self) -> DVec3 {
        self.position_m
    }

    /// The end effector's velocity as the device reports it (m/s): the true velocity, or with
    /// `velocity_window_ticks` an estimate from reported positions.
    pub fn velocity_m_per_s(&self) -> DVec3 {
        self.v_reported_m_per_s
    }

    /// The end effector's true position (m), before quantisation.
    pub fn true_position_m(&self) -> DVec3 {
        self.x_m
    }

    /// The end effector's true velocity (m/s).
    pub fn true_velocity_m_per_s(&self) -> DVec3 {
        self.v_m_per_s
    }

    /// The force the hand applied during the last substep (N).
    pub fn hand_force_n(&self) -> DVec3 {
        self.hand_force_n
    }

    /// The force the workspace wall applied during the last substep (N); zero inside the workspace.
    pub fn wall_force_n(&self) -> DVec3 {
        self.wall_force_n
    }

    /// How many rendered forces were rejected as non-finite since the arm was built.
    pub fn rejected_force_count(&self) -> u64 {
        self.rejected_force_count
    }

    /// The longest stable physics substep for this configuration (s): the workspace wall's limit (infinite for
    /// an unbounded workspace; the rest of the arm is integrated exactly).
    pub fn max_substep_s(&self) -> f64 {
        self.max_substep_s
    }

    /// The configuration the arm was built with.
    pub fn config(&self) -> &SimArmConfig {
        &self.config
    }
}

/// The one-sided wall force at `x` moving at `v`: `max(0, k_w d + b_w v.n)` along `-n` outside the
/// workspace (d the distance outside, n the outward normal), zero inside.
fn wall_force_n(arm: &ArmParams, x: DVec3, v: DVec3) -> DVec3 {
    let outside = x - arm.workspace.closest_point_m(x);
    let distance_m = outside.length();
    if distance_m <= 0.0 {
        return DVec3::ZERO;
    }
    let normal = outside / distance_m;
    let push_n = (arm.wall_stiffness_n_per_m * distance_m
        + arm.wall_damping_n_s_per_m * v.dot(normal))
    .max(0.0);
    -push_n * normal
}

#[cfg(test)]
#[path = "arm_tests.rs"]
mod tests;
