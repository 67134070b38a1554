//! The tick's truth in the tabular formats (CSV, Parquet; the sidecar's column list): the energy ledger's
//! totals, the force-off cause, the device's latched faults, the age of the rendered sample, what the
//! passivity controller dissipated, the force the device itself reports and the external force added to the
//! rendered force. One place for every column added after the flag columns, so a new one appears in every
//! tabular format at once; MCAP carries the same values in the solver message's `truth` object
//! (`mcap_trace.rs`).
//!
//! These columns come last (after `flag_<name>`), so the columns before them keep their places; format 4's
//! (`passivity_dissipated_j`, `device_force_<axis>_n`, `external_force_<axis>_n`) come after format 3's, and
//! format 5's (a local-model device's own proxy, its bound and the model's sequence and age) after those.

use crate::cell::{col, Cell, CellError, ColumnDoc, ColumnType};
use crate::sample::TraceSample;
use glam::DVec3;
use voxhap_api::{DeviceLocal, ForceOffCause, TickEnergy, TickTruth};

/// The energy columns: name, meaning, and the field they hold.
type EnergyColumn = (&'static str, &'static str, fn(&mut TickEnergy) -> &mut f64);

const ENERGY_COLUMNS: [EnergyColumn; 6] = [
    (
        "work_on_probe_j",
        "work the sent force did on the probe since the run started (zero-order hold)",
        |e| &mut e.work_on_probe_j,
    ),
    (
        "coupling_energy_j",
        "energy the coupling spring holds at this tick that the sent force can give back, \
         s^2 k/2 |proxy - probe|^2 with s the share of the rendered force that was sent (1 in a sim)",
        |e| &mut e.coupling_energy_j,
    ),
    (
        "generated_energy_j",
        "energy the renderer generated: work on the probe plus the change of the coupling energy",
        |e| &mut e.generated_j,
    ),
    (
        "active_work_j",
        "work of the directed-force modes (vector_force, gradient_force) and of the external force on the probe",
        |e| &mut e.active_work_j,
    ),
    (
        "device_dissipation_j",
        "the least the device's own damping dissipated",
        |e| &mut e.device_dissipation_j,
    ),
    (
        "net_generated_j",
        "generated energy less active work and device dissipation",
        |e| &mut e.net_generated_j,
    ),
];

/// The column of what the passivity controller dissipated (format 4).
pub(crate) const PASSIVITY_COLUMN: EnergyColumn = (
    "passivity_dissipated_j",
    "work the passivity controller's damping took from the probe since the run started; 0 with the \
     controller off or observing",
    |e| &mut e.passivity_dissipated_j,
);

/// The columns of the force the device reports reached the arm (format 4), x, y, z.
const DEVICE_FORCE_COLUMNS: [&str; 3] =
    ["device_force_x_n", "device_force_y_n", "device_force_z_n"];

/// What the device-force columns hold.
const DEVICE_FORCE_MEANING: &str = "force the device itself reports reached the arm with this tick's state \
     (the Haply Inverse3's current_cursor_force, after the Inverse Service's filters), scene frame; NaN where \
     the device reports none";

/// The cells of the device's reported force: its components, or NaN for none.
fn device_force_cells(force: Option<DVec3>) -> [f64; 3] {
    force.map_or([f64::NAN; 3], |f| f.to_array())
}

/// The device's reported force from its cells: none when a component is not a number.
fn device_force_from_cells(cells: [f64; 3]) -> Option<DVec3> {
    let force = DVec3::from_array(cells);
    (!force.is_nan()).then_some(force)
}

/// Name of the force-off cause column.
pub(crate) const FORCE_OFF_CAUSE: &str = "force_off_cause";

/// Names of the external force columns.
pub(crate) const EXTERNAL_FORCE: [&str; 3] = [
    "external_force_x_n",
    "external_force_y_n",
    "external_force_z_n",
];

/// What the external force columns hold.
const EXTERNAL_FORCE_MEANING: &str =
    "external force added to the rendered force before the safety pipeline (serve --external-force); 0 when \
     off, none was sent, the last one is older than the staleness timeout, or the tick had no device state";

/// The columns of a local-model device's own loop (format 5): its proxy x, y, z and the proxy's bound.
const DEVICE_PROXY_COLUMNS: [&str; 4] = [
    "device_proxy_x_m",
    "device_proxy_y_m",
    "device_proxy_z_m",
    "device_proxy_bound_m",
];

/// The column of the model's sequence number (format 5).
pub(crate) const LOCAL_MODEL_SEQUENCE: &str = "local_model_sequence";

/// The column of the model's age (format 5).
const LOCAL_MODEL_AGE: &str = "local_model_age_s";

/// The cells of a local-model device's report: proxy x, y, z, bound, age (NaN for none), and the sequence
/// (0 for none).
fn device_local_cells(local: Option<DeviceLocal>) -> ([f64; 4], u64, f64) {
    match local {
        Some(l) => (
            [l.proxy_m.x, l.proxy_m.y, l.proxy_m.z, l.proxy_bound_m],
            u64::from(l.model_sequence),
            l.model_age_s,
        ),
        None => ([f64::NAN; 4], 0, f64::NAN),
    }
}

/// A local-model device's report from its cells: none when the proxy is not a number.
fn device_local_from_cells(proxy: [f64; 4], sequence: u32, age_s: f64) -> Option<DeviceLocal> {
    let proxy_m = DVec3::new(proxy[0], proxy[1], proxy[2]);
    (!proxy_m.is_nan()).then_some(DeviceLocal {
        proxy_m,
        proxy_bound_m: proxy[3],
        model_sequence: sequence,
        model_age_s: age_s,
    })
}

/// Appends the truth columns.
pub(crate) fn truth_columns(c: &mut Vec<ColumnDoc>) {
    use ColumnType::*;
    for (name, meaning, _) in ENERGY_COLUMNS {
        c.push(col(name, "J", meaning, F64));
    }
    c.extend([
        col(
            FORCE_OFF_CAUSE,
            "-",
            "why the force is off: none, disconnected, not_enabled, not_engaged, device_fault, enable_refused, \
             device_watchdog, device_dropped_out, monitor_stop, watchdog, stale_link, implausible_input or \
             invalid_force",
            Text,
        ),
        col(
            "device_fault_bits",
            "bits",
            "the device's latched faults (bit n = fault code n); 0 when none or unknown",
            U64,
        ),
        col(
            "sample_age_ticks",
            "count",
            "age of the device state the tick rendered from, in servo periods from the force it answers; \
             0 for drivers that cannot tell",
            U64,
        ),
    ]);
    let (name, meaning, _) = PASSIVITY_COLUMN;
    c.push(col(name, "J", meaning, F64));
    for name in DEVICE_FORCE_COLUMNS {
        c.push(col(name, "N", DEVICE_FORCE_MEANING, F64));
    }
    for name in EXTERNAL_FORCE {
        c.push(col(name, "N", EXTERNAL_FORCE_MEANING, F64));
    }
    for name in &DEVICE_PROXY_COLUMNS[..3] {
        c.push(col(
            name,
            "m",
            "proxy a device with the local-model capability solved itself, as it reported it with this tick's \
             state (protocol SPEC 10.4), scene frame; NaN on ticks that sent no local model",
            F64,
        ));
    }
    c.extend([
        col(
            DEVICE_PROXY_COLUMNS[3],
            "m",
            "certified error bound of that proxy, as the device reported it; NaN where no local model",
            F64,
        ),
        col(
            LOCAL_MODEL_SEQUENCE,
            "count",
            "sequence number of the local model the device rendered; 0 where no local model",
            U64,
        ),
        col(
            LOCAL_MODEL_AGE,
            "s",
            "device time since that model arrived, as the device reported it; NaN where no local model",
            F64,
        ),
    ]);
}

/// Appends the truth cells of `sample`.
pub(crate) fn truth_cells(sample: &TraceSample, out: &mut Vec<Cell>) {
    let mut energy = sample.truth.energy;
    for (_, _, field) in ENERGY_COLUMNS {
        out.push(Cell::F64(*field(&mut energy)));
    }
    out.push(Cell::Text(sample.truth.force_off_cause.name()));
    out.push(Cell::U64(u64::from(sample.truth.device_fault_bits)));
    out.push(Cell::U64(u64::from(sample.truth.sample_age_ticks)));
    out.push(Cell::F64(*(PASSIVITY_COLUMN.2)(&mut energy)));
    out.extend(device_force_cells(sample.truth.device_force_n).map(Cell::F64));
    for value in sample.truth.external_force_n.to_array() {
        out.push(Cell::F64(value));
    }
    let (proxy, sequence, age_s) = device_local_cells(sample.truth.device_local);
    out.extend(proxy.map(Cell::F64));
    out.push(Cell::U64(sequence));
    out.push(Cell::F64(age_s));
}

/// Reads the truth cells (the inverse of [`truth_cells`]); `next` hands out the row's cells in order.
pub(crate) fn truth_from_cells(
    next: &mut dyn FnMut() -> (usize, Cell),
) -> Result<TickTruth, CellError> {
    let err = |index, problem| CellError { index, problem };
    let mut truth = TickTruth::default();
    for (_, _, field) in ENERGY_COLUMNS {
        *field(&mut truth.energy) = match next() {
            (_, Cell::F64(v)) => v,
            (i, _) => return Err(err(i, "not a number")),
        };
    }
    truth.force_off_cause = match next() {
        (i, Cell::Text(text)) => {
            ForceOffCause::from_name(text).ok_or(err(i, "not a force-off cause"))?
        }
        (i, _) => return Err(err(i, "not a force-off cause")),
    };
    truth.device_fault_bits = match next() {
        (i, Cell::U64(v)) => {
            u16::try_from(v).map_err(|_| err(i, "not an integer from 0 to 65535"))?
        }
        (i, _) => return Err(err(i, "not an integer from 0 to 65535")),
    };
    truth.sample_age_ticks = match next() {
        (i, Cell::U64(v)) => {
            u32::try_from(v).map_err(|_| err(i, "not an unsigned 32-bit integer"))?
        }
        (i, _) => return Err(err(i, "not an unsigned 32-bit integer")),
    };
    let mut number = || match next() {
        (_, Cell::F64(v)) => Ok(v),
        (i, _) => Err(err(i, "not a number")),
    };
    *(PASSIVITY_COLUMN.2)(&mut truth.energy) = number()?;
    truth.device_force_n = device_force_from_cells([number()?, number()?, number()?]);
    truth.external_force_n = DVec3::new(number()?, number()?, number()?);
    let proxy = [number()?, number()?, number()?, number()?];
    let sequence = match next() {
        (i, Cell::U64(v)) => {
            u32::try_from(v).map_err(|_| err(i, "not an unsigned 32-bit integer"))?
        }
        (i, _) => return Err(err(i, "not an unsigned 32-bit integer")),
    };
    let age_s = match next() {
        (_, Cell::F64(v)) => v,
        (i, _) => return Err(err(i, "not a number")),
    };
    truth.device_local = device_local_from_cells(proxy, sequence, age_s);
    Ok(truth)
}

/// The text of a text cell as one of the fixed names (solver statuses, force-off causes), so a cell can
/// hold a `&'static str`.
pub(crate) fn static_text(text: &str) -> Option<&'static str> {
    crate::sample::SolverStatus::from_name(text)
        .map(|s| s.name())
        .or_else(|| ForceOffCause::from_name(text).map(|c| c.name()))
}

/// The truth in an MCAP trace: the solver message's `truth` object (same names as the columns).
#[derive(serde::Serialize)]
pub(crate) struct TruthMessage {
    work_on_probe_j: f64,
    coupling_energy_j: f64,
    generated_energy_j: f64,
    active_work_j: f64,
    device_dissipation_j: f64,
    net_generated_j: f64,
    force_off_cause: &'static str,
    device_fault_bits: u16,
    sample_age_ticks: u32,
    passivity_dissipated_j: f64,
    /// Omitted where the device reports none.
    #[serde(skip_serializing_if = "Option::is_none")]
    device_force_n: Option<[f64; 3]>,
    external_force_n: [f64; 3],
    /// A local-model device's own proxy, bound and model; omitted on ticks that sent no local model.
    #[serde(skip_serializing_if = "Option::is_none")]
    device_proxy_m: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    device_proxy_bound_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    local_model_sequence: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    local_model_age_s: Option<f64>,
}

impl TruthMessage {
    pub(crate) fn new(truth: &TickTruth) -> Self {
        let e = &truth.energy;
        TruthMessage {
            work_on_probe_j: e.work_on_probe_j,
            coupling_energy_j: e.coupling_energy_j,
            generated_energy_j: e.generated_j,
            active_work_j: e.active_work_j,
            device_dissipation_j: e.device_dissipation_j,
            net_generated_j: e.net_generated_j,
            force_off_cause: truth.force_off_cause.name(),
            device_fault_bits: truth.device_fault_bits,
            sample_age_ticks: truth.sample_age_ticks,
            passivity_dissipated_j: e.passivity_dissipated_j,
            device_force_n: truth.device_force_n.map(|f| f.to_array()),
            external_force_n: truth.external_force_n.to_array(),
            device_proxy_m: truth.device_local.map(|l| l.proxy_m.to_array()),
            device_proxy_bound_m: truth.device_local.map(|l| l.proxy_bound_m),
            local_model_sequence: truth.device_local.map(|l| l.model_sequence),
            local_model_age_s: truth.device_local.map(|l| l.model_age_s),
        }
    }
}

/// The solver message's `truth` object as read back: `null` (a non-finite value) becomes NaN.
#[derive(serde::Deserialize)]
pub(crate) struct TruthMessageOwned {
    work_on_probe_j: Option<f64>,
    coupling_energy_j: Option<f64>,
    generated_energy_j: Option<f64>,
    active_work_j: Option<f64>,
    device_dissipation_j: Option<f64>,
    net_generated_j: Option<f64>,
    force_off_cause: String,
    device_fault_bits: u16,
    sample_age_ticks: u32,
    passivity_dissipated_j: Option<f64>,
    /// Absent where the device reports none; a non-finite component is `null`.
    #[serde(default)]
    device_force_n: Option<[Option<f64>; 3]>,
    external_force_n: [Option<f64>; 3],
    /// Absent on ticks that sent no local model.
    #[serde(default)]
    device_proxy_m: Option<[Option<f64>; 3]>,
    #[serde(default)]
    device_proxy_bound_m: Option<f64>,
    #[serde(default)]
    local_model_sequence: Option<u32>,
    #[serde(default)]
    local_model_age_s: Option<f64>,
}

impl TruthMessageOwned {
    /// The truth, or the unknown force-off cause's name.
    pub(crate) fn truth(&self) -> Result<TickTruth, String> {
        let v = |x: Option<f64>| x.unwrap_or(f64::NAN);
        Ok(TickTruth {
            energy: TickEnergy {
                work_on_probe_j: v(self.work_on_probe_j),
                coupling_energy_j: v(self.coupling_energy_j),
                generated_j: v(self.generated_energy_j),
                active_work_j: v(self.active_work_j),
                device_dissipation_j: v(self.device_dissipation_j),
                net_generated_j: v(self.net_generated_j),
                passivity_dissipated_j: v(self.passivity_dissipated_j),
            },
            force_off_cause: ForceOffCause::from_name(&self.force_off_cause)
                .ok_or_else(|| self.force_off_cause.clone())?,
            device_fault_bits: self.device_fault_bits,
            sample_age_ticks: self.sample_age_ticks,
            device_force_n: self
                .device_force_n
                .and_then(|f| device_force_from_cells(f.map(v))),
            external_force_n: self.external_force_n.map(v).into(),
            device_local: self.device_proxy_m.and_then(|p| {
                let p = p.map(v);
                device_local_from_cells(
                    [p[0], p[1], p[2], v(self.device_proxy_bound_m)],
                    self.local_model_sequence.unwrap_or(0),
                    v(self.local_model_age_s),
                )
            }),
        })
    }
}

/// The JSON schema of the `truth` object (plain types only: Foxglove and Lichtblick refuse `null` unions).
pub(crate) fn truth_schema() -> serde_json::Value {
    let mut properties = serde_json::Map::new();
    for (name, meaning, _) in ENERGY_COLUMNS {
        properties.insert(
            name.to_owned(),
            serde_json::json!({"type": "number", "description": format!("{meaning} (J)")}),
        );
    }
    let causes: Vec<&str> = ForceOffCause::ALL.iter().map(|c| c.name()).collect();
    properties.insert(
        FORCE_OFF_CAUSE.to_owned(),
        serde_json::json!({"type": "string", "enum": causes, "description": "why the force is off"}),
    );
    properties.insert(
        "device_fault_bits".to_owned(),
        serde_json::json!({"type": "integer", "minimum": 0, "maximum": 65535, "description": "the device's latched faults (bit n = fault code n)"}),
    );
    properties.insert(
        "sample_age_ticks".to_owned(),
        serde_json::json!({"type": "integer", "minimum": 0, "description": "age of the rendered device state (servo periods)"}),
    );
    let (name, meaning, _) = PASSIVITY_COLUMN;
    properties.insert(
        name.to_owned(),
        serde_json::json!({"type": "number", "description": format!("{meaning} (J)")}),
    );
    properties.insert(
        "external_force_n".to_owned(),
        serde_json::json!({"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": format!("{EXTERNAL_FORCE_MEANING} (N, x y z)")}),
    );
    let required: Vec<String> = properties.keys().cloned().collect();
    properties.insert(
        "device_force_n".to_owned(),
        serde_json::json!({
            "type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3,
            "description": "force the device itself reports reached the arm [x, y, z] (N, scene frame; the Haply \
                            Inverse3's current_cursor_force); omitted = the device reports none"
        }),
    );
    // A local-model device's own loop: omitted on ticks that sent no local model.
    properties.insert(
        "device_proxy_m".to_owned(),
        serde_json::json!({
            "type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3,
            "description": "proxy a local-model device solved itself [x, y, z] (m, scene frame, as reported)"
        }),
    );
    properties.insert(
        DEVICE_PROXY_COLUMNS[3].to_owned(),
        serde_json::json!({"type": "number", "description": "certified error bound of the device's proxy (m)"}),
    );
    properties.insert(
        LOCAL_MODEL_SEQUENCE.to_owned(),
        serde_json::json!({"type": "integer", "minimum": 0, "description": "sequence of the local model the device rendered"}),
    );
    properties.insert(
        LOCAL_MODEL_AGE.to_owned(),
        serde_json::json!({"type": "number", "description": "device time since that model arrived (s)"}),
    );
    serde_json::json!({
        "type": "object",
        "description": "the tick's truth: energy ledger, force-off cause, device faults, sample age, passivity \
                        controller, the device's own force, the external force, a local-model device's own loop",
        "properties": properties,
        "required": required,
    })
}
