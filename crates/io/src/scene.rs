//! Scene files for `voxhap solve`: one proxy problem in JSON.
//!
//! ```json
//! {
//!   "k": 500.0,
//!   "probe": [0.003, 0.0, -0.002],
//!   "previous_proxy": [0.0, 0.0, 0.0],
//!   "primitives": [
//!     {"type": "plane", "position": [0, 0, 0], "direction": [0, 0, 1], "strength": 2.0},
//!     {"type": "point", "position": [0, 0, 0], "strength": 0.5}
//!   ]
//! }
//! ```
//!
//! `k` in N/m, positions in metres, strengths in newtons. `previous_proxy` is optional. A point takes no
//! `direction` and a directed force no `position`; giving one is an error rather than silently ignored.
//! Every error names the field, e.g. `primitives[1].strength: strength must be a finite number >= 0 N, got -1`.
//! Finite values far outside physical sense are refused too, with the range ([`STIFFNESS_RANGE_N_PER_M`],
//! [`MAX_SCENE_COORDINATE_M`], [`MAX_SCENE_STRENGTH_N`]): beyond them the energy and the force overflow.

use glam::DVec3;
use serde::Deserialize;
use std::path::Path;
use voxhap_core::haptics::modes::limits::readable;
use voxhap_solver::primitive::{Primitive, PrimitiveError};

/// Coupling stiffness a scene or scenario may ask for (N/m): below a millinewton per metre the directed forces
/// over `k` put the proxy kilometres away; above 10 MN/m (a thousand times the stiffest haptic device) the
/// coupling force of a millimetre is 10 kN.
pub const STIFFNESS_RANGE_N_PER_M: (f64, f64) = (1e-3, 1e7);
/// Largest size of a coordinate of a scene's positions (probe, previous proxy, primitives) (m): the limit a
/// support plane's point has too.
pub const MAX_SCENE_COORDINATE_M: f64 = voxhap_core::haptics::modes::MAX_COORDINATE_M;
/// Largest strength of a scene's primitive (N): the limit of a mode's strengths too.
pub const MAX_SCENE_STRENGTH_N: f64 = voxhap_core::haptics::modes::MAX_STRENGTH_N;

/// A parsed, validated scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub stiffness_n_per_m: f64,
    pub probe_m: DVec3,
    pub previous_proxy_m: Option<DVec3>,
    pub primitives: Vec<Primitive>,
}

/// Why a scene could not be read. The message always names the file (when there is one) and the field.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("cannot read scene file {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{origin}: {field}: {message}")]
    Invalid {
        origin: String,
        field: String,
        message: String,
    },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    k: f64,
    probe: [f64; 3],
    #[serde(default)]
    previous_proxy: Option<[f64; 3]>,
    primitives: Vec<PrimitiveSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, rename_all = "lowercase")]
enum SpecKind {
    Point,
    Line,
    Plane,
    Directed,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PrimitiveSpec {
    #[serde(rename = "type")]
    kind: SpecKind,
    #[serde(default)]
    position: Option<[f64; 3]>,
    #[serde(default)]
    direction: Option<[f64; 3]>,
    strength: f64,
}

impl Scene {
    /// Reads and validates a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = crate::source::read_text_file(path).map_err(|source| SceneError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and validates scene JSON; `origin` names the source in error messages.
    pub fn parse(text: &str, origin: &str) -> Result<Scene, SceneError> {
        let invalid = |field: String, message: String| SceneError::Invalid {
            origin: origin.to_string(),
            field,
            message,
        };
        let deserializer = &mut serde_json::Deserializer::from_str(text);
        let file: SceneFile = serde_path_to_error::deserialize(deserializer).map_err(|err| {
            let path = err.path().to_string();
            let field = if path == "." {
                "scene".to_string()
            } else {
                path
            };
            invalid(field, err.into_inner().to_string())
        })?;
        if !(file.k.is_finite() && file.k > 0.0) {
            return Err(invalid(
                "k".into(),
                format!("stiffness must be a finite number > 0 N/m, got {}", file.k),
            ));
        }
        let (k_min, k_max) = STIFFNESS_RANGE_N_PER_M;
        if !(k_min..=k_max).contains(&file.k) {
            return Err(invalid(
                "k".into(),
                format!(
                    "{} N/m is out of range: give a number from {k_min} to {k_max:.0} N/m",
                    readable(file.k)
                ),
            ));
        }
        // Finite but far out, positions and strengths overflow the energy and the force (a probe at 1e300 m).
        let position = |field: String, value: [f64; 3]| {
            if value.iter().all(|c| c.abs() <= MAX_SCENE_COORDINATE_M) {
                Ok(DVec3::from_array(value))
            } else {
                Err(invalid(
                    field,
                    format!(
                        "{value:?} is out of range: each of x, y, z must be from -{MAX_SCENE_COORDINATE_M} to {MAX_SCENE_COORDINATE_M} m"
                    ),
                ))
            }
        };
        let probe = position("probe".into(), file.probe)?;
        let previous_proxy = file
            .previous_proxy
            .map(|p| position("previous_proxy".into(), p))
            .transpose()?;
        let mut primitives = Vec::with_capacity(file.primitives.len());
        for (i, spec) in file.primitives.iter().enumerate() {
            let field = |name: &str| format!("primitives[{i}].{name}");
            let require = |value: Option<[f64; 3]>, name: &str, kind: &str| {
                value
                    .map(DVec3::from_array)
                    .ok_or_else(|| invalid(field(name), format!("required for a {kind}")))
            };
            let forbid = |value: Option<[f64; 3]>, name: &str, kind: &str| match value {
                Some(_) => Err(invalid(
                    field(name),
                    format!("a {kind} has no {name}; remove it"),
                )),
                None => Ok(()),
            };
            let built = match spec.kind {
                SpecKind::Point => {
                    forbid(spec.direction, "direction", "point")?;
                    Primitive::point(require(spec.position, "position", "point")?, spec.strength)
                }
                SpecKind::Line => Primitive::line(
                    require(spec.position, "position", "line")?,
                    require(spec.direction, "direction", "line")?,
                    spec.strength,
                ),
                SpecKind::Plane => Primitive::plane(
                    require(spec.position, "position", "plane")?,
                    require(spec.direction, "direction", "plane")?,
                    spec.strength,
                ),
                SpecKind::Directed => {
                    forbid(spec.position, "position", "directed force")?;
                    Primitive::directed(
                        require(spec.direction, "direction", "directed force")?,
                        spec.strength,
                    )
                }
            };
            let primitive = built.map_err(|err| {
                let name = match err {
                    PrimitiveError::BadStrength(_) => "strength",
                    PrimitiveError::BadPosition(_) => "position",
                    PrimitiveError::BadDirection(_) | PrimitiveError::ZeroDirection(_) => {
                        "direction"
                    }
                };
                invalid(field(name), err.to_string())
            })?;
            if primitive.strength_n() > MAX_SCENE_STRENGTH_N {
                return Err(invalid(
                    field("strength"),
                    format!(
                        "{} N is out of range: give a number from 0 to {MAX_SCENE_STRENGTH_N:.0} N",
                        readable(primitive.strength_n())
                    ),
                ));
            }
            if let Some(p) = spec.position {
                position(field("position"), p)?;
            }
            primitives.push(primitive);
        }
        Ok(Scene {
            stiffness_n_per_m: file.k,
            probe_m: probe,
            previous_proxy_m: previous_proxy,
            primitives,
        })
    }

    /// The scene as a solver problem.
    pub fn problem(&self) -> voxhap_solver::Problem<'_> {
        voxhap_solver::Problem {
            stiffness_n_per_m: self.stiffness_n_per_m,
            probe_m: self.probe_m,
            previous_proxy_m: self.previous_proxy_m,
            primitives: &self.primitives,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn error_of(text: &str) -> String {
        Scene::parse(text, "test.json").unwrap_err().to_string()
    }

    #[test]
    fn reads_the_readme_example() {
        let scene = Scene::parse(
            include_str!("../../../sims/scenes/plane_point.json"),
            "example",
        )
        .unwrap();
        assert_eq!(scene.stiffness_n_per_m, 500.0);
        assert_eq!(scene.primitives.len(), 2);
        assert_eq!(scene.previous_proxy_m, Some(DVec3::ZERO));
    }

    #[test]
    fn errors_name_the_field() {
        assert!(error_of(r#"{"probe":[0,0,0],"primitives":[]}"#).contains("missing field `k`"));
        assert!(error_of(r#"{"k":-5,"probe":[0,0,0],"primitives":[]}"#)
            .contains("test.json: k: stiffness"));
        assert!(error_of(r#"{"k":"a","probe":[0,0,0],"primitives":[]}"#)
            .starts_with("test.json: k: invalid type"));
        assert!(error_of(r#"{"k":1,"probe":[0,0],"primitives":[]}"#).contains("probe"));
        let e = error_of(
            r#"{"k":1,"probe":[0,0,0],"primitives":[{"type":"point","position":[0,0,0],"strength":1},
                {"type":"plane","position":[0,0,0],"direction":[0,0,1],"strength":-1}]}"#,
        );
        assert!(e.contains("primitives[1].strength"), "{e}");
        let e = error_of(
            r#"{"k":1,"probe":[0,0,0],"primitives":[{"type":"plane","position":[0,0,0],"strength":1}]}"#,
        );
        assert!(
            e.contains("primitives[0].direction: required for a plane"),
            "{e}"
        );
        let e = error_of(
            r#"{"k":1,"probe":[0,0,0],"primitives":[{"type":"line","position":[0,0,0],"direction":[0,0,0],"strength":1}]}"#,
        );
        assert!(
            e.contains("primitives[0].direction: direction must not be zero"),
            "{e}"
        );
        let e = error_of(r#"{"k":1,"probe":[0,0,0],"primitives":[{"type":"cube","strength":1}]}"#);
        assert!(
            e.contains("primitives[0].type") && e.contains("unknown variant `cube`"),
            "{e}"
        );
        let e = error_of(r#"{"k":1,"probe":[0,0,0],"primitives":[],"extra":1}"#);
        assert!(e.contains("unknown field `extra`"), "{e}");
        let e = error_of(
            r#"{"k":1,"probe":[0,0,0],"primitives":[{"type":"point","position":[0,0,0],"direction":[1,0,0],"strength":1}]}"#,
        );
        assert!(
            e.contains("primitives[0].direction: a point has no direction"),
            "{e}"
        );
        let e = error_of(r#"{"k":1e999,"probe":[0,0,0],"primitives":[]}"#);
        assert!(e.contains("k"), "{e}");
    }
}
