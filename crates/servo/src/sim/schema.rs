//! The scene file schema as a table: every key of a scene (scenario) file with its unit, default, accepted
//! values and meaning, for the generated reference page docs/reference/scene.md.
//!
//! Where it sits: documentation of [`super::scenario::Scenario`], the one type and validator of scene files
//! (`voxhap sim`, `voxhap serve --scene`). Nothing reads scene files through this table; instead the unit tests
//! below hold it against the real parser and validator, so the page cannot drift from the code:
//!
//! - the keys of each table are exactly the fields serde accepts there (read from the parser's own "unknown
//!   field, expected one of ..." message);
//! - writing a key's default explicitly gives the same scenario as leaving the key out;
//! - every accepted range holds at its edges: the bounds are accepted, values just outside, NaN and infinity are
//!   refused with a message naming the key.
//!
//! The numeric limits are the validator's own constants ([`MAX_DURATION_S`], [`RATE_HZ_RANGE`],
//! [`TOLERANCE_RANGE_M`], [`MAX_SWEEPS_LIMIT`], [`SUBSTEPS_PER_TICK_RANGE`]); the simulated arm's, path's and
//! force profile's units and ranges are the ones the device crate checks them with
//! (`voxhap_device::sim::keys`). The page is rendered by tests/docs_reference.rs.

use super::scenario::{
    MAX_DURATION_S, MAX_SWEEPS_LIMIT, RATE_HZ_RANGE, STIFFNESS_RANGE_N_PER_M,
    SUBSTEPS_PER_TICK_RANGE, TOLERANCE_RANGE_M,
};
use crate::passivity::settings::{
    MAX_CONTROLLER_DAMPING_N_S_PER_M, MAX_OBSERVER_LATENCY_S, MAX_THRESHOLD_J,
};
use voxhap_core::haptics::modes::{
    MAX_COORDINATE_M, MAX_FRICTION_MU, MAX_POWER_BUDGET_W, MAX_STRENGTH_N, MAX_TRANSFER_VALUE,
};
use voxhap_core::volume::procedural::BUILTIN_NAMES;
use voxhap_device::sim::effects::{
    MAX_FORCE_RESOLUTION_N, MAX_LATENCY_S, MAX_POSITION_RESOLUTION_M, MAX_VELOCITY_WINDOW_TICKS,
};
use voxhap_device::sim::keys::{
    NumberRange, VectorRange, ARM_MASS, FREQUENCY, HAND_FORCE, PATH_SPEED, PATH_TIME, POSITION,
    RADIUS, RASTER_LINES, WAYPOINTS,
};
use voxhap_device::sim::{ArmPreset, MAX_LOCAL_RATE_HZ};

/// What a key's value may be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Accepts {
    /// Any string.
    Text,
    /// One of these strings.
    OneOf(&'static [&'static str]),
    /// `true` or `false`.
    Bool,
    /// A finite number > 0.
    Positive,
    /// A finite number > 0 and at most this.
    PositiveAtMost(f64),
    /// A finite number >= 0.
    NonNegative,
    /// A finite number >= 0 and at most this.
    NonNegativeAtMost(f64),
    /// A finite number from `.0` to `.1`, both included.
    Between(f64, f64),
    /// A whole number from `.0` to `.1`, both included.
    Count(u64, u64),
    /// Three finite numbers.
    Vector,
    /// Three finite numbers, each from `-.0` to `.0`.
    VectorWithin(f64),
    /// Three finite numbers, not all zero.
    Direction,
    /// A list of at least one vector of three finite numbers.
    Points,
    /// A list of 1 to `.1` vectors of three finite numbers, each from `-.0` to `.0`.
    PointsWithin(f64, u64),
    /// A transfer function: `[[value, newtons], ...]`, values strictly increasing within
    /// `MAX_TRANSFER_VALUE` of 0, newtons from 0 to `MAX_STRENGTH_N`.
    Transfer,
    /// A table, described in the section with this title.
    Table(&'static str),
}

impl Accepts {
    /// The accepted values in words, for the reference page.
    pub fn describe(&self) -> String {
        match self {
            Accepts::Text => "text".to_owned(),
            Accepts::OneOf(names) => names
                .iter()
                .map(|n| format!("`{n}`"))
                .collect::<Vec<_>>()
                .join(", "),
            Accepts::Bool => "`true`, `false`".to_owned(),
            Accepts::Positive => "> 0".to_owned(),
            Accepts::PositiveAtMost(hi) => format!("> 0, at most {hi}"),
            Accepts::NonNegative => ">= 0".to_owned(),
            Accepts::NonNegativeAtMost(hi) => format!(">= 0, at most {}", plain(*hi)),
            Accepts::Between(lo, hi) => format!("{} to {}", plain(*lo), plain(*hi)),
            Accepts::Count(lo, hi) => format!("whole number, {lo} to {hi}"),
            Accepts::Vector => "`[x, y, z]`".to_owned(),
            Accepts::VectorWithin(limit) => {
                format!(
                    "`[x, y, z]`, each from -{} to {}",
                    plain(*limit),
                    plain(*limit)
                )
            }
            Accepts::Direction => "`[x, y, z]`, not zero".to_owned(),
            Accepts::Points => "`[[x, y, z], ...]`, at least one".to_owned(),
            Accepts::PointsWithin(limit, most) => format!(
                "`[[x, y, z], ...]`, 1 to {most}, each coordinate from -{} to {}",
                plain(*limit),
                plain(*limit)
            ),
            Accepts::Transfer => format!(
                "`[[value, N], ...]`: values strictly increasing, each from -{} to {}; N from 0 to {}",
                plain(MAX_TRANSFER_VALUE),
                plain(MAX_TRANSFER_VALUE),
                plain(MAX_STRENGTH_N)
            ),
            Accepts::Table(title) => format!("a table: see {title}"),
        }
    }
}

/// A limit as a reader writes it: whole numbers in full (`100000`), others in exponent form (`1e-12`).
fn plain(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e7 {
        format!("{x:.0}")
    } else {
        format!("{x:e}")
    }
}

/// A key's default.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum KeyDefault {
    /// The key must be given.
    Required,
    /// Left out, the key has this value (TOML syntax).
    Value(&'static str),
    /// Left out, this happens (words).
    Otherwise(&'static str),
}

/// One key of a scene file table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SchemaKey {
    pub name: &'static str,
    /// SI unit, or "" for none.
    pub unit: &'static str,
    pub default: KeyDefault,
    pub accepts: Accepts,
    /// A valid value in TOML syntax (the tests write it).
    pub example: &'static str,
    pub meaning: &'static str,
}

/// One table of a scene file (or one variant of a table chosen by its `kind`/`shape` key).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SchemaSection {
    /// The heading on the reference page.
    pub title: &'static str,
    /// What the table is for (Markdown).
    pub intro: &'static str,
    /// The TOML header the keys go under ("" for the top level).
    pub header: &'static str,
    /// Valid lines always written under the header (the table's required keys), each `key = value`.
    pub base: &'static str,
    /// Which serde type the keys belong to: sections with the same group together list its fields.
    pub group: &'static str,
    pub keys: &'static [SchemaKey],
}

const fn key(
    name: &'static str,
    unit: &'static str,
    default: KeyDefault,
    accepts: Accepts,
    example: &'static str,
    meaning: &'static str,
) -> SchemaKey {
    SchemaKey {
        name,
        unit,
        default,
        accepts,
        example,
        meaning,
    }
}

/// A vector key whose unit and range are the device crate's (`voxhap_device::sim::keys`), the ones its
/// validator checks with.
const fn vector_key(
    name: &'static str,
    range: VectorRange,
    default: KeyDefault,
    example: &'static str,
    meaning: &'static str,
) -> SchemaKey {
    key(
        name,
        range.unit,
        default,
        VectorWithin(range.bounds),
        example,
        meaning,
    )
}

/// A number key whose unit and range are the device crate's (`voxhap_device::sim::keys`): a range from 0
/// excludes 0.
const fn number_key(
    name: &'static str,
    range: NumberRange,
    default: KeyDefault,
    example: &'static str,
    meaning: &'static str,
) -> SchemaKey {
    let (min, max) = range.bounds;
    let accepts = if min == 0.0 {
        PositiveAtMost(max)
    } else {
        Between(min, max)
    };
    key(name, range.unit, default, accepts, example, meaning)
}

use Accepts::*;
use KeyDefault::*;

/// The kinds of `[[modes]]`.
pub const MODE_KINDS: &[&str] = &[
    "surface",
    "friction",
    "viscosity",
    "coulomb_drag",
    "vector_follow",
    "vortex",
    "vector_force",
    "gradient_force",
    "support_plane",
];

const SERVE_ARM: KeyDefault =
    Otherwise("the simulated arm of `voxhap serve` (sims/scenes/explore.toml)");

/// Every table of a scene file, in the order of the reference page.
pub const SCENE_SCHEMA: &[SchemaSection] = &[
    SchemaSection {
        title: "Top level",
        intro: "Keys before the first table. A scene file for `voxhap serve --scene` and a scenario for \
                `voxhap sim` are the same file; `sim` needs `duration_s`, `serve` ignores it.",
        header: "",
        base: "k_n_per_m = 500.0\nduration_s = 1.0",
        group: "scenario",
        keys: &[
            key("name", "", Otherwise("no label"), Text, "\"demo\"", "a label for traces and plot titles"),
            key("description", "", Otherwise("none"), Text, "\"a ball\"", "what the scene shows (free text)"),
            key("duration_s", "s", Otherwise("needed by `voxhap sim`; ignored by `serve`"), PositiveAtMost(MAX_DURATION_S), "2.0", "simulated time of a `voxhap sim` run"),
            key("rate_hz", "Hz", Value("1000.0"), Between(*RATE_HZ_RANGE.start(), *RATE_HZ_RANGE.end()), "500.0", "servo rate"),
            key("k_n_per_m", "N/m", Required, Between(STIFFNESS_RANGE_N_PER_M.0, STIFFNESS_RANGE_N_PER_M.1), "400.0", "coupling stiffness k between probe and proxy"),
            key("damping_n_s_per_m", "N s/m", Value("0.0"), NonNegative, "0.5", "coupling damping B (v_proxy - v_probe); rendered by `serve` and `sim`"),
            vector_key("start_m", POSITION, Otherwise("the hand path's target at t = 0 (needed for a force path)"), "[0.0, 0.0, 0.04]", "where the simulated arm starts, at rest (a scene position)"),
            key("solver", "", Otherwise("all of `[solver]`'s defaults"), Table("`[solver]`"), "", "which solver, and the exact solver's budget"),
            key("volumes", "", Required, Table("`[[volumes]]`"), "", "the volumes, by name (may be empty: `volumes = []`)"),
            key("modes", "", Otherwise("no modes"), Table("`[[modes]]`"), "", "the haptic modes, at most 8, in trace column order"),
            key("arm", "", SERVE_ARM, Table("`[arm]`"), "", "the simulated arm's dynamics"),
            key("hand", "", SERVE_ARM, Table("`[hand]`"), "", "the virtual hand's grip"),
            key("path", "", SERVE_ARM, Table("`[path]`"), "", "what the virtual hand does over time (scene positions and forces)"),
            key("device", "", Otherwise("no profile"), Table("[device profiles](../workspace.md)"), "", "a device profile for `serve` (`--device-profile` replaces it)"),
            key("passivity", "", Otherwise("all of `[passivity]`'s defaults"), Table("`[passivity]`"), "", "the passivity observer and controller ([Stability](../stability.md))"),
            key("local_model", "", Otherwise("a set-force arm"), Table("`[local_model]`"), "", "the simulated arm renders local models with its own loop ([Local models](../local-model.md))"),
            key("events", "", Otherwise("no events"), Table("[Scenario files](../scenarios.md)"), "", "`voxhap sim` only: control commands at given times, `t_s` beside the command as the control API spells it"),
        ],
    },
    SchemaSection {
        title: "`[passivity]`",
        intro: "The passivity observer and controller on the coupling, and the passive introduction of changes \
                made in contact ([Stability](../stability.md)).",
        header: "[passivity]",
        base: "",
        group: "passivity",
        keys: &[
            key("mode", "", Otherwise("`control` for every real device, `observe` for the simulated arm (`voxhap sim`, and `serve` on the simulated arm)"), OneOf(&["off", "observe", "control"]), "\"control\"", "`off`: nothing, changes apply at once; `observe`: the observer books, changes in contact are introduced passively; `control`: the controller also dissipates what the coupling generates"),
            key("max_damping_n_s_per_m", "N s/m", Value("20.0"), PositiveAtMost(MAX_CONTROLLER_DAMPING_N_S_PER_M), "10.0", "the most damping the controller adds in a tick"),
            key("threshold_j", "J", Value("1e-6"), Between(0.0, MAX_THRESHOLD_J), "1e-5", "energy generated beyond the reference that the controller lets pass before it acts"),
            key("latency_s", "s", Otherwise("the driver's declared worst-case link latency, or the simulated arm's `[arm] latency_s`, else 0"), Between(0.0, MAX_OBSERVER_LATENCY_S), "0.003", "the delay after which a sent force acts on the arm, as the observer pairs force with motion (a fraction of a tick counts as a whole tick)"),
        ],
    },
    SchemaSection {
        title: "`[local_model]`",
        intro: "The simulated arm as a device with the local-model capability: `serve` and `voxhap sim` send it \
                the tick's primitives and its own loop renders them at `rate_hz`; with it `k_n_per_m` is at most \
                65535 N/m and `damping_n_s_per_m` at most 65.535 N s/m ([Local models](../local-model.md)).",
        header: "[local_model]",
        base: "rate_hz = 10000.0",
        group: "local_model",
        keys: &[
            key("rate_hz", "Hz", Required, PositiveAtMost(MAX_LOCAL_RATE_HZ), "10000.0", "the device's control rate: a whole multiple of `rate_hz` with a whole number of microseconds per cycle"),
        ],
    },
    SchemaSection {
        title: "`[solver]`",
        intro: "Which solver ticks, and the exact solver's budget ([The exact solver](../solver.md)).",
        header: "[solver]",
        base: "",
        group: "solver",
        keys: &[
            key("kind", "", Value("\"exact\""), OneOf(&["exact", "euler", "constraint"]), "\"euler\"", "the certified exact solver, or a baseline of the paper (uncertified); `voxhap sim --solver` overrides it"),
            key("tolerance_m", "m", Value("1e-12"), Between(TOLERANCE_RANGE_M.0, TOLERANCE_RANGE_M.1), "1e-9", "stop when the certified error bound is at most this"),
            key("max_sweeps", "", Value("10000"), Count(1, MAX_SWEEPS_LIMIT as u64), "50", "most solver passes per tick (a tick over budget sets flag bit 0)"),
        ],
    },
    SchemaSection {
        title: "`[[volumes]]`",
        intro: "One table per volume. Give `builtin` or `file`, not both. More in [Volumes](../volumes.md).",
        header: "[[volumes]]",
        base: "name = \"extra\"\nbuiltin = \"sphere\"",
        group: "volume",
        keys: &[
            key("name", "", Required, Text, "\"ball\"", "the name modes use"),
            key("builtin", "", Otherwise("give `file`"), OneOf(&BUILTIN_NAMES), "\"torus\"", "a built-in procedural volume (`voxhap info builtin:NAME`)"),
            key("file", "", Otherwise("give `builtin`"), Text, "", "a volume file (.nii, .nii.gz, .nrrd, .nhdr, .mha, .mhd, raw .toml), relative to the scene file"),
            key("part", "", Otherwise("the only field; needed for `density-flow`"), OneOf(&["scalar", "vector"]), "\"scalar\"", "which field of a two-field built-in"),
        ],
    },
    SchemaSection {
        title: "`[[modes]]`: every kind",
        intro: "One table per haptic mode ([Haptic modes](../modes.md)). Every mode takes these keys; the \
                others depend on its `kind` (below), and a key the kind does not use is an error.",
        header: "[[modes]]",
        base: "kind = \"surface\"\nvolume = \"density\"\ntransfer = [[0.45, 0.0], [0.5, 2.0]]",
        group: "mode",
        keys: &[
            key("kind", "", Required, OneOf(MODE_KINDS), "\"surface\"", "what the mode does"),
            key("name", "", Otherwise("its kind"), Text, "\"skin\"", "unique in the scene; names the mode's trace column"),
            key("enabled", "", Value("true"), Bool, "false", "`false` keeps the settings and the trace column but renders no force"),
        ],
    },
    SchemaSection {
        title: "`[[modes]]` `kind = \"surface\"`",
        intro: "A plane through the proxy, facing along the volume's gradient.",
        header: "[[modes]]",
        base: "kind = \"surface\"\nvolume = \"density\"\ntransfer = [[0.45, 0.0], [0.5, 2.0]]",
        group: "mode",
        keys: &[
            key("volume", "", Required, Text, "\"density\"", "a scalar volume's name"),
            key("transfer", "value -> N", Required, Transfer, "[[0.4, 0.0], [0.5, 3.0]]", "data value to strength"),
            key("side", "", Value("\"outward\""), OneOf(&["outward", "inward"]), "\"inward\"", "`outward` pushes towards lower values (out of a density), `inward` towards higher"),
        ],
    },
    SchemaSection {
        title: "`[[modes]]` `kind = \"friction\"`",
        intro: "A point at the proxy, as strong as `mu` times a surface mode's normal force.",
        header: "[[modes]]\nkind = \"surface\"\nvolume = \"density\"\ntransfer = [[0.45, 0.0], [0.5, 2.0]]\n[[modes]]",
        base: "kind = \"friction\"\nsurface = \"surface\"\nmu = 0.5",
        group: "mode",
        keys: &[
            key("surface", "", Required, Text, "\"surface\"", "the name of a surface mode"),
            key("mu", "", Required, Between(0.0, MAX_FRICTION_MU), "0.3", "friction coefficient"),
        ],
    },
    SchemaSection {
        title: "`[[modes]]` `kind = \"viscosity\"`",
        intro: "Viscous drag `b v` on the proxy's motion, with the damping `b` read from a scalar volume.",
        header: "[[modes]]",
        base: "kind = \"viscosity\"\nvolume = \"density\"\ntransfer = [[0.0, 0.0], [1.0, 3.0]]",
        group: "mode",
        keys: &[
            key("volume", "", Required, Text, "\"density\"", "a scalar volume's name"),
            key("transfer", "value -> N s/m", Required, Transfer, "[[0.0, 0.0], [1.0, 5.0]]", "data value to damping b"),
        ],
    },
    SchemaSection {
        title: "`[[modes]]` `kind = \"coulomb_drag\"`, `\"vector_follow\"`, `\"vortex\"`",
        intro: "A primitive sampled from a volume: Coulomb drag (a constant-magnitude drag) reads a scalar volume, \
                the others a vector volume.",
        header: "[[modes]]",
        base: "kind = \"coulomb_drag\"\nvolume = \"density\"\ntransfer = [[0.0, 0.0], [1.0, 0.3]]",
        group: "mode",
        keys: &[
            key("volume", "", Required, Text, "\"density\"", "the volume's name"),
            key("transfer", "value -> N", Required, Transfer, "[[0.0, 0.0], [1.0, 0.5]]", "data value (or its magnitude or curl) to strength"),
        ],
    },
    SchemaSection {
        title: "`[[modes]]` `kind = \"vector_force\"`, `\"gradient_force\"`",
        intro: "An active mode: a force along a vector volume's vectors or a scalar volume's gradient, sampled at \
                the hand, with the power it may put into the hand bounded.",
        header: "[[modes]]",
        base: "kind = \"gradient_force\"\nvolume = \"density\"\ntransfer = [[0.0, 0.0], [500.0, 1.0]]",
        group: "mode",
        keys: &[
            key("volume", "", Required, Text, "\"density\"", "the volume's name"),
            key("transfer", "value -> N", Required, Transfer, "[[0.0, 0.0], [100.0, 0.5]]", "vector magnitude or gradient magnitude to strength"),
            key("power_budget_w", "W", Value("0.05"), Between(0.0, MAX_POWER_BUDGET_W), "0.2", "the most power the mode puts into a hand moving with its force"),
        ],
    },
    SchemaSection {
        title: "`[[modes]]` `kind = \"support_plane\"`",
        intro: "A fixed plane, placed by the user (a table to rest on).",
        header: "[[modes]]",
        base: "kind = \"support_plane\"\npoint_m = [0.0, 0.0, -0.04]\nnormal = [0.0, 0.0, 1.0]\nstrength_n = 3.0",
        group: "mode",
        keys: &[
            key("point_m", "m", Required, VectorWithin(MAX_COORDINATE_M), "[0.0, 0.0, -0.03]", "a point on the plane"),
            key("normal", "", Required, Direction, "[0.0, 1.0, 1.0]", "the side the plane pushes towards (any length)"),
            key("strength_n", "N", Required, Between(0.0, MAX_STRENGTH_N), "2.0", "the plane's strength"),
        ],
    },
    SchemaSection {
        title: "`[arm]`",
        intro: "The simulated arm: a damped point mass ([The simulated arm](../sim-arm.md)). Left out, the \
                whole table is `voxhap serve`'s arm.",
        header: "[arm]",
        base: "mass_kg = 0.1\ndamping_n_s_per_m = 1.0\nworkspace = { shape = \"unbounded\" }",
        group: "arm",
        keys: &[
            number_key("mass_kg", ARM_MASS, Required, "0.2", "moving mass at the end effector"),
            key("damping_n_s_per_m", "N s/m", Required, NonNegative, "2.0", "viscous damping to ground"),
            key("workspace", "", Required, Table("`[arm.workspace]`"), "", "where the arm can go"),
            key("substeps_per_tick", "", Value("10"), Count(*SUBSTEPS_PER_TICK_RANGE.start() as u64, *SUBSTEPS_PER_TICK_RANGE.end() as u64), "20", "physics steps per servo tick"),
            key("wall_stiffness_n_per_m", "N/m", Value("5000.0"), NonNegative, "2000.0", "stiffness of the workspace wall"),
            key("wall_damping_n_s_per_m", "N s/m", Value("10.0"), NonNegative, "5.0", "damping of the workspace wall, outside it"),
            key("preset", "", Otherwise("none"), OneOf(&ArmPreset::NAMES), "\"touch\"", "a device's sourced figures for the keys left out ([The simulated arm](../sim-arm.md))"),
            key("latency_s", "s", Value("0.0"), NonNegativeAtMost(MAX_LATENCY_S), "0.002", "time from a force being sent to it acting"),
            key("position_resolution_m", "m", Value("0.0"), NonNegativeAtMost(MAX_POSITION_RESOLUTION_M), "1e-5", "reported positions are rounded to this"),
            key("force_resolution_n", "N", Value("0.0"), NonNegativeAtMost(MAX_FORCE_RESOLUTION_N), "0.01", "applied forces are rounded to this"),
            key("period_jitter_s", "s", Value("0.0"), NonNegativeAtMost(MAX_LATENCY_S), "1e-5", "sample instants vary by up to this (below half a tick)"),
            key("jitter_seed", "", Value("0"), Count(0, u32::MAX as u64), "7", "seed of the jitter"),
            key("velocity_window_ticks", "", Value("0"), Count(0, MAX_VELOCITY_WINDOW_TICKS as u64), "5", "0: exact velocity; n: estimated from positions n ticks apart"),
        ],
    },
    SchemaSection {
        title: "`[arm.workspace]`",
        intro: "Where the arm can go; outside it a one-sided wall spring pushes back. `shape = \"unbounded\"` \
                takes no other key.",
        header: "[arm]\nmass_kg = 0.1\ndamping_n_s_per_m = 1.0\n[arm.workspace]",
        base: "shape = \"box\"\nmin_m = [-0.1, -0.1, -0.1]\nmax_m = [0.1, 0.1, 0.1]",
        group: "workspace",
        keys: &[
            key("shape", "", Required, OneOf(&["box", "sphere", "unbounded"]), "\"box\"", "the workspace's shape"),
            vector_key("min_m", POSITION, Required, "[-0.2, -0.1, -0.1]", "`box`: lower corner"),
            vector_key("max_m", POSITION, Required, "[0.2, 0.1, 0.1]", "`box`: upper corner, >= `min_m` on every axis"),
        ],
    },
    SchemaSection {
        title: "`[arm.workspace]` `shape = \"sphere\"`",
        intro: "A ball.",
        header: "[arm]\nmass_kg = 0.1\ndamping_n_s_per_m = 1.0\n[arm.workspace]",
        base: "shape = \"sphere\"\ncenter_m = [0.0, 0.0, 0.0]\nradius_m = 0.1",
        group: "workspace",
        keys: &[
            vector_key("center_m", POSITION, Required, "[0.0, 0.0, 0.01]", "centre"),
            number_key("radius_m", RADIUS, Required, "0.2", "radius"),
        ],
    },
    SchemaSection {
        title: "`[hand]`",
        intro: "The virtual hand's grip: a spring-damper pulling the arm towards the path's target.",
        header: "[hand]",
        base: "stiffness_n_per_m = 300.0\ndamping_n_s_per_m = 3.0",
        group: "hand",
        keys: &[
            key("stiffness_n_per_m", "N/m", Required, Positive, "200.0", "spring stiffness"),
            key("damping_n_s_per_m", "N s/m", Required, NonNegative, "1.0", "damping on the velocity error"),
        ],
    },
    SchemaSection {
        title: "`[path]` `kind = \"hold\"`",
        intro: "What the virtual hand does over time: a table with a `kind` key. `hold`: stay at one point.",
        header: "[path]",
        base: "kind = \"hold\"\nat_m = [0.0, 0.0, 0.04]",
        group: "path",
        keys: &[
            key("kind", "", Required, OneOf(&["hold", "line", "waypoints", "circle", "raster", "force"]), "\"hold\"", "the kind of path"),
            vector_key("at_m", POSITION, Required, "[0.01, 0.0, 0.04]", "the point"),
        ],
    },
    SchemaSection {
        title: "`[path]` `kind = \"line\"`",
        intro: "From `from_m` to `to_m` at constant speed, then hold.",
        header: "[path]",
        base: "kind = \"line\"\nfrom_m = [0.0, 0.0, 0.04]\nto_m = [0.0, 0.0, 0.0]\nduration_s = 2.0",
        group: "path",
        keys: &[
            vector_key("from_m", POSITION, Required, "[0.01, 0.0, 0.04]", "start point"),
            vector_key("to_m", POSITION, Required, "[0.01, 0.0, 0.0]", "end point"),
            number_key("duration_s", PATH_TIME, Required, "1.0", "travel time"),
        ],
    },
    SchemaSection {
        title: "`[path]` `kind = \"waypoints\"`",
        intro: "Visit the points in order at constant speed, then hold at the last.",
        header: "[path]",
        base: "kind = \"waypoints\"\npoints_m = [[0.0, 0.0, 0.04], [0.0, 0.0, 0.0]]\nspeed_m_per_s = 0.02",
        group: "path",
        keys: &[
            key("points_m", WAYPOINTS.each.unit, Required, PointsWithin(WAYPOINTS.each.bounds, WAYPOINTS.most as u64), "[[0.0, 0.0, 0.04]]", "the points"),
            number_key("speed_m_per_s", PATH_SPEED, Required, "0.05", "speed along the polyline"),
        ],
    },
    SchemaSection {
        title: "`[path]` `kind = \"circle\"`",
        intro: "Go round a circle forever.",
        header: "[path]",
        base: "kind = \"circle\"\ncenter_m = [0.0, 0.0, 0.02]\nradius_m = 0.02\nnormal = [0.0, 0.0, 1.0]\nperiod_s = 3.0",
        group: "path",
        keys: &[
            vector_key("center_m", POSITION, Required, "[0.0, 0.0, 0.01]", "centre"),
            number_key("radius_m", RADIUS, Required, "0.01", "radius"),
            key("normal", "", Required, Direction, "[0.0, 1.0, 0.0]", "the circle's axis (any length)"),
            number_key("period_s", PATH_TIME, Required, "4.0", "time for one turn"),
        ],
    },
    SchemaSection {
        title: "`[path]` `kind = \"raster\"`",
        intro: "A lawn-mower sweep: `lines` passes along `sweep_m`, stepping across by `step_m / (lines - 1)`, \
                then hold.",
        header: "[path]",
        base: "kind = \"raster\"\norigin_m = [-0.02, -0.02, 0.0]\nsweep_m = [0.04, 0.0, 0.0]\nstep_m = [0.0, 0.04, 0.0]\nlines = 5\nspeed_m_per_s = 0.05",
        group: "path",
        keys: &[
            vector_key("origin_m", POSITION, Required, "[-0.01, -0.02, 0.0]", "start corner"),
            vector_key("sweep_m", POSITION, Required, "[0.02, 0.0, 0.0]", "one pass: direction and length"),
            vector_key("step_m", POSITION, Required, "[0.0, 0.02, 0.0]", "offset from the first pass to the last"),
            key("lines", "", Required, Count(1, RASTER_LINES.most as u64), "3", "number of passes"),
            number_key("speed_m_per_s", PATH_SPEED, Required, "0.02", "speed along the path"),
        ],
    },
    SchemaSection {
        title: "`[path]` `kind = \"force\"`",
        intro: "Push the arm with a force profile instead of a target (needs `start_m`).",
        header: "[path]",
        base: "kind = \"force\"\nprofile = { shape = \"constant\", force_n = [0.0, 0.0, -1.0] }",
        group: "path",
        keys: &[key("profile", "", Required, Table("`[path.profile]`"), "", "the force over time")],
    },
    SchemaSection {
        title: "`[path.profile]` `shape = \"constant\"`",
        intro: "The force of a `force` path: a table with a `shape` key. `constant`: the same force always.",
        header: "[path]\nkind = \"force\"\n[path.profile]",
        base: "shape = \"constant\"\nforce_n = [0.0, 0.0, -1.0]",
        group: "profile",
        keys: &[
            key("shape", "", Required, OneOf(&["constant", "ramp", "sine"]), "\"constant\"", "the kind of profile"),
            vector_key("force_n", HAND_FORCE, Required, "[0.0, 0.5, -1.0]", "the force"),
        ],
    },
    SchemaSection {
        title: "`[path.profile]` `shape = \"ramp\"`",
        intro: "Linear from `from_n` at t = 0 to `to_n` at `duration_s`, then constant.",
        header: "[path]\nkind = \"force\"\n[path.profile]",
        base: "shape = \"ramp\"\nfrom_n = [0.0, 0.0, 0.0]\nto_n = [0.0, 0.0, -2.0]\nduration_s = 2.0",
        group: "profile",
        keys: &[
            vector_key("from_n", HAND_FORCE, Required, "[0.0, 0.0, -0.5]", "force at t = 0"),
            vector_key("to_n", HAND_FORCE, Required, "[0.0, 0.0, -1.0]", "force from `duration_s` on"),
            number_key("duration_s", PATH_TIME, Required, "1.0", "ramp time"),
        ],
    },
    SchemaSection {
        title: "`[path.profile]` `shape = \"sine\"`",
        intro: "`offset_n + amplitude_n sin(2 pi frequency_hz t)`, per axis.",
        header: "[path]\nkind = \"force\"\n[path.profile]",
        base: "shape = \"sine\"\noffset_n = [0.0, 0.0, -1.0]\namplitude_n = [0.0, 0.0, 0.5]\nfrequency_hz = 2.0",
        group: "profile",
        keys: &[
            vector_key("offset_n", HAND_FORCE, Required, "[0.0, 0.0, -0.5]", "mean force"),
            vector_key("amplitude_n", HAND_FORCE, Required, "[0.1, 0.0, 0.5]", "amplitude"),
            number_key("frequency_hz", FREQUENCY, Required, "1.0", "frequency"),
        ],
    },
];

#[cfg(test)]
#[path = "schema_tests.rs"]
mod tests;
