//! What `voxhap serve` renders: the scene file (`--scene`), the volume override (`--volume`), and building
//! them into the ready-to-tick [`SceneBundle`] the servo thread swaps in.
//!
//! Off the real-time path: everything here reads files, allocates and validates; the servo thread only
//! ever receives a finished `SceneBundle` (scene plus a tick workspace sized for it).
//!
//! A scene file is a sim scenario ([`crate::sim::scenario::Scenario`], one type and one validator): `k_n_per_m`,
//! optional `damping_n_s_per_m`, `[solver]`, `[[volumes]]`, `[[modes]]`, and for the simulated arm `start_m`,
//! `[arm]`, `[hand]`, `[path]`. Any `voxhap sim` scenario file is also a valid scene (its `duration_s` is
//! ignored). Without `--scene`, the built-in sims/scenes/explore.toml is used; `--volume` alone renders a surface of
//! that volume at `--iso` or else at Otsu's threshold of its values (voxhap_core::volume::levels), with the arm
//! circling through its centre; a vector volume alone is followed (vector_follow). `--scene X --volume V` renders X
//! with V in place of X's first volume, which is then never loaded.

use crate::passivity::PassivitySettings;
use crate::sim::scenario::{Purpose, Scenario, ScenarioError, SolverSettings};
use glam::DVec3;
use std::path::{Path, PathBuf};
use voxhap_core::haptics::modes::{ModeConfig, ModeError, ModeKind, RenderScene, TransferFunction};
use voxhap_core::haptics::tick::{SolverKind, TickWorkspace};
use voxhap_core::haptics::SolverConfig;
use voxhap_core::volume::levels::ValueLevels;
use voxhap_core::volume::{procedural, AnyVolume};
use voxhap_device::mock::default_arm_config;
use voxhap_device::sim::{HandPath, SimArmConfig};
use voxhap_io as io;

/// The built-in scene (sims/scenes/explore.toml).
pub const BUILTIN_SCENE: &str = include_str!("../../../sims/scenes/explore.toml");

/// A scene file as written: the same type, and the same validator, as a `voxhap sim` scenario.
pub type SceneFile = Scenario;

pub use voxhap_api::NamedVolume;

/// A loaded, validated scene: what the control side keeps and edits, and rebuilds bundles from.
#[derive(Debug, Clone)]
pub struct SceneSetup {
    pub label: String,
    pub stiffness_n_per_m: f64,
    pub damping_n_s_per_m: f64,
    pub solver: SolverSettings,
    pub volumes: Vec<NamedVolume>,
    pub modes: Vec<ModeConfig>,
    /// The simulated arm (used when the device is `sim`) and where it starts.
    pub arm: SimArmConfig,
    pub start_m: DVec3,
    pub rate_hz: Option<f64>,
    /// `[passivity]` (crate::passivity): the mode left out is decided by the device.
    pub passivity: PassivitySettings,
}

/// A scene ready for the servo thread: built off the real-time thread, swapped in at a tick boundary.
#[derive(Debug)]
pub struct SceneBundle {
    pub scene: RenderScene,
    pub workspace: TickWorkspace,
    pub damping_n_s_per_m: f64,
    pub generation: u64,
}

/// Why a scene could not be loaded or built.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error("{origin}: {source}")]
    Read {
        origin: String,
        source: std::io::Error,
    },
    #[error(transparent)]
    Volume(#[from] ScenarioError),
    #[error("--volume {given}: {source}")]
    VolumeArg {
        given: String,
        source: VolumeArgError,
    },
    #[error("--volume {given}: {source}")]
    ReplaceVolume {
        given: String,
        source: ReplaceVolumeError,
    },
    #[error("{origin}: {source}")]
    Modes { origin: String, source: ModeError },
    #[error("{origin}: {message}")]
    Invalid { origin: String, message: String },
    /// `--iso` cannot place a surface in this volume.
    #[error("--iso {level}: {reason}")]
    Iso { level: f64, reason: String },
}

/// Why a `--volume` / `load_volume` argument gave no volume.
#[derive(Debug, thiserror::Error)]
pub enum VolumeArgError {
    /// `builtin:NAME` names no built-in volume.
    #[error(transparent)]
    Builtin(#[from] voxhap_core::volume::VolumeError),
    /// The built-in has neither a scalar nor a vector field.
    #[error("the built-in is empty")]
    EmptyBuiltin,
    /// The volume file could not be loaded (boxed: the error is large).
    #[error(transparent)]
    Load(Box<io::LoadError>),
}

/// Why a scene's volume could not be replaced (the scene is left as it was).
#[derive(Debug, thiserror::Error)]
pub enum ReplaceVolumeError {
    /// No volume has the name asked for.
    #[error("no volume named {name:?}")]
    NoSuchVolume { name: String },
    /// The scene has no volume to replace.
    #[error("the scene has no volume")]
    NoVolume,
    /// The scene's modes do not accept the new volume.
    #[error(transparent)]
    Modes(#[from] ModeError),
}

/// Loads `spec` (`builtin:NAME` or a file path) as a volume for `--volume` and `load_volume`; a built-in
/// with two fields gives its scalar one.
pub fn load_volume_arg(spec: &str) -> Result<(AnyVolume, String), SetupError> {
    let error = |source: VolumeArgError| SetupError::VolumeArg {
        given: spec.to_owned(),
        source,
    };
    if let Some(name) = spec.strip_prefix("builtin:") {
        let built = procedural::builtin(name).map_err(|e| error(e.into()))?;
        let volume = match (built.scalar, built.vector) {
            (Some(s), _) => AnyVolume::Scalar(s),
            (None, Some(v)) => AnyVolume::Vector(v),
            (None, None) => return Err(error(VolumeArgError::EmptyBuiltin)),
        };
        return Ok((volume, spec.to_owned()));
    }
    let loaded = io::load(Path::new(spec)).map_err(|e| error(VolumeArgError::Load(Box::new(e))))?;
    Ok((loaded.volume, spec.to_owned()))
}

impl SceneSetup {
    /// Parses and loads a scene file's text (`origin` names it in errors; volume files relative to
    /// `base_dir`).
    pub fn parse(text: &str, origin: &str, base_dir: &Path) -> Result<SceneSetup, SetupError> {
        Self::parse_with(text, origin, base_dir, None)
    }

    /// [`SceneSetup::parse`], with `first` (a volume and its source) in place of the file's first volume,
    /// which is then not loaded at all.
    fn parse_with(
        text: &str,
        origin: &str,
        base_dir: &Path,
        mut first: Option<(AnyVolume, String)>,
    ) -> Result<SceneSetup, SetupError> {
        let file = Scenario::parse_for(text, origin, Purpose::Serve)?;
        let mut volumes = Vec::with_capacity(file.volumes.len());
        for (index, spec) in file.volumes.iter().enumerate() {
            let (volume, source) = match first.take() {
                Some(replacement) if index == 0 => replacement,
                _ => spec.load(index, base_dir, origin)?,
            };
            volumes.push(NamedVolume {
                name: spec.name.clone(),
                source,
                volume,
            });
        }
        if let Some((_, given)) = first {
            return Err(SetupError::ReplaceVolume {
                given,
                source: ReplaceVolumeError::NoVolume,
            });
        }
        let arm = SimArmConfig {
            arm: file.arm,
            hand: file.hand,
            path: file.path,
            local_model: file.local_model,
        };
        let start_m = file
            .start_m
            .or_else(|| arm.path.target_at(0.0))
            .unwrap_or(DVec3::ZERO);
        let setup = SceneSetup {
            label: file.name.unwrap_or_else(|| origin.to_owned()),
            stiffness_n_per_m: file.k_n_per_m,
            damping_n_s_per_m: file.damping_n_s_per_m,
            solver: file.solver,
            volumes,
            modes: file.modes,
            arm,
            start_m,
            rate_hz: Some(file.rate_hz),
            passivity: file.passivity,
        };
        setup.build_scene().map_err(|source| SetupError::Modes {
            origin: origin.to_owned(),
            source,
        })?;
        Ok(setup)
    }

    /// Reads a scene file.
    pub fn read(path: &Path) -> Result<SceneSetup, SetupError> {
        Self::read_with(path, None)
    }

    /// Reads a scene file, with `first` in place of its first volume (see [`SceneSetup::parse_with`]).
    fn read_with(
        path: &Path,
        first: Option<(AnyVolume, String)>,
    ) -> Result<SceneSetup, SetupError> {
        let origin = path.display().to_string();
        let text = voxhap_io::read_text_file(path).map_err(|source| SetupError::Read {
            origin: origin.clone(),
            source,
        })?;
        Self::parse_with(
            &text,
            &origin,
            path.parent().unwrap_or(Path::new("")),
            first,
        )
    }

    /// The built-in scene (sims/scenes/explore.toml).
    pub fn builtin() -> Result<SceneSetup, SetupError> {
        Self::parse(
            BUILTIN_SCENE,
            "built-in scene sims/scenes/explore.toml",
            Path::new("."),
        )
    }

    /// A scene for a lone `--volume`: a surface that starts at `iso` (or, without it, at Otsu's threshold of the
    /// values; the middle of the range for a constant volume) with 0 N and stiffens to 2 N over 5 % of the
    /// value range above it, k = 500 N/m, the arm circling through the volume's centre with a radius of a
    /// third of its smallest half-extent. A vector volume gets a vector-follow mode instead (and refuses
    /// `iso`).
    pub fn for_volume(
        volume: AnyVolume,
        source: String,
        iso: Option<f64>,
    ) -> Result<SceneSetup, SetupError> {
        let (min_m, max_m) = volume.grid().bounds_world();
        let centre = (min_m + max_m) * 0.5;
        let half = ((max_m - min_m) * 0.5).min_element().max(1e-3);
        let (lo, hi) = volume.value_range();
        let (lo, hi) = (f64::from(lo), f64::from(hi));
        let span = if hi > lo { hi - lo } else { 1.0 };
        let (level, label) = match (&volume, iso) {
            (AnyVolume::Vector(_), Some(level)) => {
                return Err(SetupError::Iso {
                    level,
                    reason: format!(
                        "{source} is a vector volume, which is followed (vector_follow), not given a surface: \
                         --iso applies to a scalar volume"
                    ),
                })
            }
            (AnyVolume::Vector(_), None) => (0.0, format!("vector_follow along {source}")),
            (AnyVolume::Scalar(_), Some(level)) => {
                if !(level.is_finite() && lo <= level && level < hi) {
                    return Err(SetupError::Iso {
                        level,
                        reason: format!(
                            "outside {source}'s values {lo} .. {hi}: give a level at least {lo} and below {hi} \
                             (`voxhap info` suggests one)"
                        ),
                    });
                }
                (level, format!("surface of {source} at level {level} (--iso)"))
            }
            (AnyVolume::Scalar(_), None) => match ValueLevels::of(&volume, 1).otsu {
                Some(level) => (
                    level,
                    format!("surface of {source} at level {level} (Otsu's threshold)"),
                ),
                None => (
                    lo + 0.5 * span,
                    format!("surface of {source} (a constant volume: no surface to feel)"),
                ),
            },
        };
        let transfer = |points: Vec<[f64; 2]>| {
            TransferFunction::new(points).map_err(|e| SetupError::Invalid {
                origin: source.clone(),
                message: e.to_string(),
            })
        };
        let mode = match volume {
            AnyVolume::Scalar(_) => ModeConfig {
                kind: ModeKind::Surface,
                transfer: Some(transfer(vec![[level, 0.0], [level + 0.05 * span, 2.0]])?),
                ..ModeConfig::new(ModeKind::Surface)
            },
            AnyVolume::Vector(_) => ModeConfig {
                kind: ModeKind::VectorFollow,
                transfer: Some(transfer(vec![[0.0, 0.0], [hi.max(1e-9), 0.4]])?),
                ..ModeConfig::new(ModeKind::VectorFollow)
            },
        };
        let mode = ModeConfig {
            volume: Some("volume".to_owned()),
            ..mode
        };
        let mut arm = default_arm_config();
        arm.path = HandPath::Circle {
            center_m: centre,
            radius_m: half / 3.0,
            normal: DVec3::Z,
            period_s: 4.0,
        };
        let start_m = arm.path.target_at(0.0).unwrap_or(centre);
        let setup = SceneSetup {
            label,
            stiffness_n_per_m: 500.0,
            damping_n_s_per_m: 0.0,
            solver: SolverSettings::default(),
            volumes: vec![NamedVolume {
                name: "volume".to_owned(),
                source: source.clone(),
                volume,
            }],
            modes: vec![mode],
            arm,
            start_m,
            rate_hz: None,
            passivity: PassivitySettings::default(),
        };
        setup
            .build_scene()
            .map_err(|source_error| SetupError::Modes {
                origin: source,
                source: source_error,
            })?;
        Ok(setup)
    }

    /// Replaces the volume named `name` (default: the first) and checks the scene still builds.
    pub fn replace_volume(
        &mut self,
        name: Option<&str>,
        volume: AnyVolume,
        source: String,
    ) -> Result<(), ReplaceVolumeError> {
        let index = match name {
            Some(name) => self
                .volumes
                .iter()
                .position(|v| v.name == name)
                .ok_or_else(|| ReplaceVolumeError::NoSuchVolume {
                    name: name.to_owned(),
                })?,
            None if self.volumes.is_empty() => return Err(ReplaceVolumeError::NoVolume),
            None => 0,
        };
        let name = self.volumes[index].name.clone();
        let previous = std::mem::replace(
            &mut self.volumes[index],
            NamedVolume {
                name,
                source,
                volume,
            },
        );
        if let Err(error) = self.build_scene() {
            self.volumes[index] = previous;
            return Err(error.into());
        }
        Ok(())
    }

    /// Builds the render scene (volumes are shared, not copied).
    pub fn build_scene(&self) -> Result<RenderScene, ModeError> {
        let volumes = self
            .volumes
            .iter()
            .map(|v| (v.name.clone(), v.volume.clone()))
            .collect();
        RenderScene::new(self.stiffness_n_per_m, volumes, &self.modes)
    }

    /// The solver settings for a servo at `period_ns`: the file's tolerance and sweeps, and a time budget of
    /// `budget_fraction` of the period.
    pub fn solver_config(&self, period_ns: u64, budget_fraction: f64) -> SolverConfig {
        SolverConfig {
            max_time_ns: (period_ns as f64 * budget_fraction) as u64,
            ..self.solver.solver_config()
        }
    }

    pub fn solver_kind(&self) -> SolverKind {
        self.solver.kind
    }

    /// A bundle for the servo thread.
    pub fn bundle(
        &self,
        period_ns: u64,
        budget_fraction: f64,
        generation: u64,
    ) -> Result<SceneBundle, ModeError> {
        let scene = self.build_scene()?;
        let workspace = TickWorkspace::new(
            &scene,
            self.solver.kind,
            self.solver_config(period_ns, budget_fraction),
        );
        Ok(SceneBundle {
            scene,
            workspace,
            damping_n_s_per_m: self.damping_n_s_per_m,
            generation,
        })
    }
}

/// Where `serve` gets its scene from: `--scene` and `--volume`.
/// `iso` (`serve --iso`) places a lone `--volume`'s surface; the command line lets it only with `--volume`
/// and without `--scene`.
pub fn resolve(
    scene: Option<&PathBuf>,
    volume: Option<&str>,
    iso: Option<f64>,
) -> Result<SceneSetup, SetupError> {
    match (scene, volume) {
        (Some(path), None) => SceneSetup::read(path),
        (None, None) => SceneSetup::builtin(),
        (None, Some(volume)) => {
            let (volume, source) = load_volume_arg(volume)?;
            SceneSetup::for_volume(volume, source, iso)
        }
        (Some(path), Some(spec)) => {
            let (volume, source) = load_volume_arg(spec)?;
            // The scene's own first volume is never loaded (it may not even exist here): V takes its place
            // before the modes are built, so a shipped sim is a template for one's own scan.
            let replaced = SceneSetup::read_with(path, Some((volume, source)));
            match replaced {
                Err(SetupError::Modes { source, .. }) => Err(SetupError::ReplaceVolume {
                    given: spec.to_owned(),
                    source: ReplaceVolumeError::Modes(source),
                }),
                other => other,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_scene_has_three_modes_and_builds() {
        let setup = SceneSetup::builtin().unwrap();
        assert_eq!(setup.modes.len(), 3);
        assert_eq!(setup.volumes.len(), 2);
        let bundle = setup.bundle(1_000_000, 0.25, 1).unwrap();
        assert_eq!(bundle.scene.modes().len(), 3);
        assert_eq!(bundle.generation, 1);
    }

    /// A 4 x 4 x 4 volume, half 0 and half 100 (split along k).
    fn two_valued() -> AnyVolume {
        use voxhap_core::volume::{Grid, ScalarVolume};
        let grid = Grid::new(
            [4, 4, 4],
            DVec3::splat(0.01),
            glam::DMat3::IDENTITY,
            DVec3::ZERO,
        )
        .unwrap();
        let data = (0..64).map(|n| if n < 32 { 0.0 } else { 100.0 }).collect();
        AnyVolume::Scalar(ScalarVolume::new(grid, data).unwrap())
    }

    fn first_transfer(setup: &SceneSetup) -> Vec<[f64; 2]> {
        setup.modes[0].transfer.as_ref().unwrap().points().to_vec()
    }

    #[test]
    fn a_lone_volume_gets_its_surface_at_otsus_level_or_at_iso() {
        // Otsu on two values 0 and 100 in 256 bins: every split between them is perfect, the first wins, so the
        // level is the centre of bin 0, 100 / 512 (Otsu 1979; scikit-image's threshold_otsu gives the same).
        let setup = SceneSetup::for_volume(two_valued(), "two.nii".into(), None).unwrap();
        assert_eq!(
            first_transfer(&setup),
            vec![[100.0 / 512.0, 0.0], [100.0 / 512.0 + 5.0, 2.0]]
        );
        assert!(setup.label.contains("Otsu"), "{}", setup.label);
        let setup = SceneSetup::for_volume(two_valued(), "two.nii".into(), Some(40.0)).unwrap();
        assert_eq!(first_transfer(&setup), vec![[40.0, 0.0], [45.0, 2.0]]);
        for bad in [100.0, -1.0, f64::NAN] {
            let err =
                SceneSetup::for_volume(two_valued(), "two.nii".into(), Some(bad)).unwrap_err();
            let text = err.to_string();
            assert!(
                text.contains("--iso") && text.contains("0 .. 100"),
                "{text}"
            );
        }
    }

    #[test]
    fn a_lone_vector_volume_says_it_is_followed_and_refuses_iso() {
        let (volume, source) = load_volume_arg("builtin:rankine").unwrap();
        let setup = SceneSetup::for_volume(volume.clone(), source.clone(), None).unwrap();
        assert!(setup.label.contains("vector_follow"), "{}", setup.label);
        let err = SceneSetup::for_volume(volume, source, Some(1.0)).unwrap_err();
        assert!(err.to_string().contains("vector volume"), "{err}");
    }

    #[test]
    fn a_scene_with_a_volume_argument_never_loads_its_own_first_volume() {
        // The scene names a file that does not exist: with --volume in its place it must still load.
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene.toml");
        std::fs::write(
            &scene,
            "k_n_per_m = 300\n[[volumes]]\nname = \"t1\"\nfile = \"absent.nii.gz\"\n[[modes]]\nkind = \"surface\"\n\
             volume = \"t1\"\ntransfer = [[0.2, 0.0], [0.6, 2.0]]\n",
        )
        .unwrap();
        assert!(
            resolve(Some(&scene), None, None).is_err(),
            "the file is absent"
        );
        let setup = resolve(Some(&scene), Some("builtin:sphere"), None).unwrap();
        assert_eq!(setup.volumes[0].source, "builtin:sphere");
        assert_eq!(setup.volumes[0].name, "t1");
        assert_eq!(setup.stiffness_n_per_m, 300.0);
        // A scene without a volume has nothing to replace.
        std::fs::write(&scene, "k_n_per_m = 300\nvolumes = []\n").unwrap();
        let err = resolve(Some(&scene), Some("builtin:sphere"), None).unwrap_err();
        assert!(err.to_string().contains("has no volume"), "{err}");
    }

    #[test]
    fn sim_scenarios_are_scenes() {
        let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("sims");
        let setup = SceneSetup::read(&dir.join("multimodal.toml")).unwrap();
        assert_eq!(setup.modes.len(), 3);
        assert_eq!(setup.stiffness_n_per_m, 500.0);
    }

    #[test]
    fn bad_scene_files_name_the_problem() {
        let base = Path::new(".");
        let err = SceneSetup::parse("k_n_per_m = -1\nvolumes = []", "s.toml", base).unwrap_err();
        assert!(
            err.to_string().contains("s.toml: k_n_per_m: must be"),
            "{err}"
        );
        // The solver settings are validated for serve as for sim, naming the key.
        let err = SceneSetup::parse(
            "k_n_per_m = 1\nvolumes = []\n[solver]\nmax_sweeps = 0",
            "s.toml",
            base,
        )
        .unwrap_err();
        assert!(
            err.to_string()
                .contains("s.toml: solver.max_sweeps: must be from 1"),
            "{err}"
        );
        let err = SceneSetup::parse(
            "k_n_per_m = 1\nvolumes = []\n[solver]\ntolerance_m = 0.0",
            "s.toml",
            base,
        )
        .unwrap_err();
        assert!(
            err.to_string()
                .contains("s.toml: solver.tolerance_m: must be"),
            "{err}"
        );
        let err = SceneSetup::parse("k_n_per_m = 1\nvolumes = []\nbogus = 1", "s.toml", base)
            .unwrap_err();
        assert!(err.to_string().contains("bogus"), "{err}");
        let text = "k_n_per_m = 100\n[[volumes]]\nname = \"v\"\nbuiltin = \"sphere\"\n[[modes]]\nkind = \"surface\"\nvolume = \"nope\"\ntransfer = [[0.0, 0.0], [1.0, 1.0]]\n";
        let err = SceneSetup::parse(text, "s.toml", base).unwrap_err();
        assert!(err.to_string().contains("s.toml: modes[0]"), "{err}");
    }

    #[test]
    fn a_lone_volume_gets_one_surface_mode() {
        let setup = resolve(None, Some("builtin:sphere"), None).unwrap();
        assert_eq!(setup.modes.len(), 1);
        assert_eq!(setup.modes[0].kind, ModeKind::Surface);
        assert!(setup.build_scene().is_ok());
        // The shipped MNI T1 template: Otsu's level over 256 bins of 0..255 is the centre of bin 89,
        // 89.5 * 255 / 256 (scikit-image 0.26.0's threshold_otsu on the same file gives 89.15039).
        let t1 = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../data/mni152_t1_1mm.nii.gz"
        );
        let setup = resolve(None, Some(t1), None).unwrap();
        assert_eq!(
            setup.label,
            format!("surface of {t1} at level 89.150390625 (Otsu's threshold)")
        );
        let err = resolve(None, Some("builtin:nonesuch"), None).unwrap_err();
        assert!(
            err.to_string().starts_with("--volume builtin:nonesuch"),
            "{err}"
        );
    }

    #[test]
    fn replacing_a_volume_with_the_wrong_kind_changes_nothing() {
        let mut setup = SceneSetup::builtin().unwrap();
        let (vector, source) = load_volume_arg("builtin:burgers").unwrap();
        let before = setup.volumes[0].source.clone();
        assert!(setup
            .replace_volume(Some("density"), vector, source)
            .is_err());
        assert_eq!(setup.volumes[0].source, before);
        assert!(matches!(setup
            .replace_volume(
                Some("nope"),
                load_volume_arg("builtin:sphere").unwrap().0,
                String::new()
            )
            .unwrap_err(),
            ReplaceVolumeError::NoSuchVolume { name } if name == "nope"));
    }
}
