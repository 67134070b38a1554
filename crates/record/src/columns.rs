//! The trace's columns, one list for every format: names, units, meanings, value types, and the cells of
//! one sample in column order.
//!
//! Where it sits: the CSV writer and reader, the Parquet writer and reader and the sidecar all take their
//! columns from [`columns`], so a column added here appears in every tabular format and in the sidecar's
//! documentation at once. The MCAP messages carry the same values grouped by message (see
//! `mcap_trace.rs`). Names are safe for pandas: no name collides with a `DataFrame` attribute (the flag bit
//! set is `flag_bits`, not `flags`), and every flag also gets a boolean column `flag_<name>`.

pub(crate) use crate::cell::{col, Cell, CellError};
pub use crate::cell::{ColumnDoc, ColumnType};
use crate::flags::FLAG_DOCS;
use crate::sample::{SolverStatus, TraceSample};
use glam::DVec3;
use std::borrow::Cow;
use voxhap_core::haptics::modes::MAX_MODES;

fn vector_columns(
    columns: &mut Vec<ColumnDoc>,
    names: [&'static str; 3],
    unit: &'static str,
    meaning: &'static str,
) {
    for (name, axis) in names.into_iter().zip(["x", "y", "z"]) {
        columns.push(ColumnDoc {
            name: Cow::Borrowed(name),
            unit: Cow::Borrowed(unit),
            meaning: Cow::Owned(format!("{meaning} {axis}")),
            column_type: ColumnType::F64,
        });
    }
}

/// Prefix of the per-mode primitive count columns.
pub(crate) const PRIMITIVES_PREFIX: &str = "primitives_";
/// Prefix of the per-mode force columns (`mode_force_<mode>_x_n`).
pub(crate) const MODE_FORCE_PREFIX: &str = "mode_force_";
/// Prefix of the per-flag boolean columns.
pub(crate) const FLAG_PREFIX: &str = "flag_";

/// The columns for these modes, in file order.
pub fn columns(mode_names: &[String]) -> Vec<ColumnDoc> {
    use ColumnType::*;
    let mut c = vec![
        col("tick", "-", "servo tick number since the run started", U64),
        col(
            "t_s",
            "s",
            "tick time since the run started (monotonic schedule time)",
            F64,
        ),
        col(
            "utc_ns",
            "ns",
            "wall-clock UTC of the tick, ns since 1970 (the run's start_utc_ns + t_s)",
            I64,
        ),
    ];
    vector_columns(
        &mut c,
        ["probe_x_m", "probe_y_m", "probe_z_m"],
        "m",
        "probe (device) position",
    );
    vector_columns(
        &mut c,
        ["probe_vx_m_per_s", "probe_vy_m_per_s", "probe_vz_m_per_s"],
        "m/s",
        "probe velocity (reported, or estimated: flag_velocity_estimated)",
    );
    vector_columns(
        &mut c,
        ["proxy_x_m", "proxy_y_m", "proxy_z_m"],
        "m",
        "proxy position",
    );
    vector_columns(
        &mut c,
        [
            "rendered_force_x_n",
            "rendered_force_y_n",
            "rendered_force_z_n",
        ],
        "N",
        "force rendered, before the safety pipeline",
    );
    vector_columns(
        &mut c,
        ["force_x_n", "force_y_n", "force_z_n"],
        "N",
        "force sent to the device, after the safety pipeline",
    );
    for name in mode_names {
        c.push(ColumnDoc {
            name: Cow::Owned(format!("{PRIMITIVES_PREFIX}{name}")),
            unit: Cow::Borrowed("count"),
            meaning: Cow::Owned(format!("primitives the {name} mode emitted")),
            column_type: U64,
        });
        for axis in ["x", "y", "z"] {
            c.push(ColumnDoc {
                name: Cow::Owned(format!("{MODE_FORCE_PREFIX}{name}_{axis}_n")),
                unit: Cow::Borrowed("N"),
                meaning: Cow::Owned(format!(
                    "force the {name} mode's primitives exert on the proxy, {axis}"
                )),
                column_type: F64,
            });
        }
    }
    c.extend([
        col(
            "solver_status",
            "-",
            "certified, budget_exhausted, stalled, uncertified (baseline solver), input_rejected or unknown",
            Text,
        ),
        col("sweeps", "count", "solver sweeps", U64),
        col(
            "error_bound_m",
            "m",
            "certificate bound on the proxy's distance from the exact equilibrium; inf = none",
            F64,
        ),
        col("device_sequence", "-", "the device's sequence number of the state used; empty if it has none", OptionalU64),
        col("device_time_us", "us", "the device's clock at that state; empty if it has none", OptionalU64),
        col("flag_bits", "bits", "bit set of the flags, see the sidecar's flag_bits", U64),
    ]);
    for doc in FLAG_DOCS.iter() {
        c.push(ColumnDoc {
            name: Cow::Owned(format!("{FLAG_PREFIX}{}", doc.name)),
            unit: Cow::Borrowed("-"),
            meaning: doc.meaning.clone(),
            column_type: Bool,
        });
    }
    crate::truth_columns::truth_columns(&mut c);
    c
}

fn push_vector(out: &mut Vec<Cell>, v: DVec3) {
    out.extend([Cell::F64(v.x), Cell::F64(v.y), Cell::F64(v.z)]);
}

/// `row` emptied and filled with the cells of `sample` in column order ([`cells`]); returns them.
pub(crate) fn refill<'a>(
    row: &'a mut Vec<Cell>,
    sample: &TraceSample,
    mode_count: usize,
    start_utc_ns: i64,
) -> &'a [Cell] {
    row.clear();
    cells(sample, mode_count, start_utc_ns, row);
    row
}

/// The cells of `sample` in column order (as [`columns`] for `mode_count` modes), appended to `out`.
pub(crate) fn cells(
    sample: &TraceSample,
    mode_count: usize,
    start_utc_ns: i64,
    out: &mut Vec<Cell>,
) {
    out.push(Cell::U64(sample.tick));
    out.push(Cell::F64(sample.t_s));
    out.push(utc_cell(start_utc_ns, sample.t_s));
    push_vector(out, sample.probe_m);
    push_vector(out, sample.probe_velocity_m_per_s);
    push_vector(out, sample.proxy_m);
    push_vector(out, sample.rendered_force_n);
    push_vector(out, sample.sent_force_n);
    for mode in 0..mode_count.min(MAX_MODES) {
        let (primitives, force_n) = sample.modes.slot(mode);
        out.push(Cell::U64(u64::from(primitives)));
        push_vector(out, force_n);
    }
    out.push(Cell::Text(sample.solver_status.name()));
    out.push(Cell::U64(u64::from(sample.sweeps)));
    out.push(Cell::F64(sample.error_bound_m));
    for value in [sample.device_sequence, sample.device_time_us] {
        out.push(value.map_or(Cell::Missing, Cell::U64));
    }
    out.push(Cell::U64(u64::from(sample.flags)));
    for doc in FLAG_DOCS.iter() {
        out.push(Cell::Bool(sample.flags & (1 << doc.bit) != 0));
    }
    crate::truth_columns::truth_cells(sample, out);
}

/// The UTC cell: `start_utc_ns + round(t_s * 1e9)`, saturating; missing when `t_s` is not finite.
pub(crate) fn utc_cell(start_utc_ns: i64, t_s: f64) -> Cell {
    if t_s.is_finite() {
        Cell::I64(start_utc_ns.saturating_add((t_s * 1e9).round() as i64))
    } else {
        Cell::Missing
    }
}

/// Builds a sample from cells in column order (the reader's inverse of [`cells`]). The `utc_ns` cell and
/// the boolean flag cells are checked against the values they derive from.
pub(crate) fn sample_from_cells(
    row: &[Cell],
    mode_count: usize,
    start_utc_ns: Option<i64>,
) -> Result<TraceSample, CellError> {
    let mut index = 0usize;
    let mut next = || {
        let i = index;
        index += 1;
        (i, row.get(i).copied().unwrap_or(Cell::Missing))
    };
    let err = |index, problem| CellError { index, problem };
    let u64_cell = |next: &mut dyn FnMut() -> (usize, Cell)| match next() {
        (_, Cell::U64(v)) => Ok(v),
        (i, _) => Err(err(i, "not an unsigned integer")),
    };
    let f64_cell = |next: &mut dyn FnMut() -> (usize, Cell)| match next() {
        (_, Cell::F64(v)) => Ok(v),
        (i, _) => Err(err(i, "not a number")),
    };
    let tick = u64_cell(&mut next)?;
    let t_s = f64_cell(&mut next)?;
    let (utc_index, utc) = next();
    let vector = |next: &mut dyn FnMut() -> (usize, Cell)| -> Result<DVec3, CellError> {
        Ok(DVec3::new(
            f64_cell(next)?,
            f64_cell(next)?,
            f64_cell(next)?,
        ))
    };
    let mut sample = TraceSample::zeroed(mode_count as u8);
    sample.tick = tick;
    sample.t_s = t_s;
    sample.probe_m = vector(&mut next)?;
    sample.probe_velocity_m_per_s = vector(&mut next)?;
    sample.proxy_m = vector(&mut next)?;
    sample.rendered_force_n = vector(&mut next)?;
    sample.sent_force_n = vector(&mut next)?;
    for (primitives, force_n) in sample.modes.slots_mut() {
        let (i, count) = next();
        *primitives = match count {
            Cell::U64(v) => {
                u16::try_from(v).map_err(|_| err(i, "not an integer from 0 to 65535"))?
            }
            _ => return Err(err(i, "not an integer from 0 to 65535")),
        };
        *force_n = vector(&mut next)?;
    }
    sample.solver_status = match next() {
        (i, Cell::Text(text)) => {
            SolverStatus::from_name(text).ok_or(err(i, "not a solver status"))?
        }
        (i, _) => return Err(err(i, "not a solver status")),
    };
    let (i, sweeps) = next();
    sample.sweeps = match sweeps {
        Cell::U64(v) => u32::try_from(v).map_err(|_| err(i, "not an unsigned 32-bit integer"))?,
        _ => return Err(err(i, "not an unsigned 32-bit integer")),
    };
    sample.error_bound_m = f64_cell(&mut next)?;
    for slot in [&mut sample.device_sequence, &mut sample.device_time_us] {
        *slot = match next() {
            (_, Cell::U64(v)) => Some(v),
            (_, Cell::Missing) => None,
            (i, _) => return Err(err(i, "not an unsigned integer or empty")),
        };
    }
    let (i, bits) = next();
    sample.flags = match bits {
        Cell::U64(v) => u32::try_from(v).map_err(|_| err(i, "not an unsigned 32-bit integer"))?,
        _ => return Err(err(i, "not an unsigned 32-bit integer")),
    };
    for doc in FLAG_DOCS.iter() {
        match next() {
            (_, Cell::Bool(set)) if set == (sample.flags & (1 << doc.bit) != 0) => {}
            (i, Cell::Bool(_)) => return Err(err(i, "disagrees with flag_bits")),
            (i, _) => return Err(err(i, "not true or false")),
        }
    }
    sample.truth = crate::truth_columns::truth_from_cells(&mut next)?;
    if let Some(start) = start_utc_ns {
        if utc != utc_cell(start, t_s) {
            return Err(err(utc_index, "disagrees with start_utc_ns + t_s"));
        }
    } else if !matches!(utc, Cell::I64(_) | Cell::Missing) {
        return Err(err(utc_index, "not an integer"));
    }
    Ok(sample)
}

#[cfg(test)]
mod tests {
    use super::*;
    use voxhap_core::haptics::tick::ModeBreakdown;

    #[test]
    fn names_are_unique_and_pandas_safe() {
        let names: Vec<String> = columns(&["surface".into(), "friction".into()])
            .into_iter()
            .map(|c| c.name.into_owned())
            .collect();
        let mut sorted = names.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), names.len());
        // Attributes of a pandas DataFrame that a column must not shadow.
        for reserved in [
            "flags", "index", "columns", "values", "shape", "size", "T", "dtypes",
        ] {
            assert!(!names.iter().any(|n| n == reserved), "{reserved}");
        }
    }

    #[test]
    fn cells_round_trip_through_sample_from_cells() {
        let mut sample = TraceSample::zeroed(2);
        sample.tick = 7;
        sample.t_s = 0.007;
        let mut primitives = [0; MAX_MODES];
        primitives[1] = 3;
        let mut forces_n = [DVec3::ZERO; MAX_MODES];
        forces_n[1] = DVec3::new(1.0, -2.0, 3.5);
        sample.modes = ModeBreakdown::new(2, primitives, forces_n);
        sample.device_time_us = Some(99);
        sample.flags = 0b101;
        sample.solver_status = SolverStatus::Certified;
        sample.truth.energy.generated_j = 0.25;
        sample.truth.force_off_cause = voxhap_api::ForceOffCause::StaleLink;
        sample.truth.device_fault_bits = 0b100;
        sample.truth.sample_age_ticks = 4;
        sample.truth.energy.passivity_dissipated_j = 0.125;
        sample.truth.device_force_n = Some(DVec3::new(0.5, -1.25, 2.0));
        sample.truth.external_force_n = DVec3::new(-0.75, 0.0, 1.5);
        sample.truth.device_local = Some(voxhap_api::DeviceLocal {
            proxy_m: DVec3::new(0.01, -0.02, 0.03),
            proxy_bound_m: 1e-9,
            model_sequence: 42,
            model_age_s: 250e-6,
        });
        let mut row = Vec::new();
        cells(&sample, 2, 1_000, &mut row);
        assert_eq!(row.len(), columns(&["a".into(), "b".into()]).len());
        assert_eq!(sample_from_cells(&row, 2, Some(1_000)).unwrap(), sample);
        assert!(sample_from_cells(&row, 2, Some(5)).is_err());
        // After format 3's: what the controller dissipated, the device's own force, the external force
        // (format 4), then the local-model device's proxy, bound, model sequence and age (format 5).
        let last: Vec<Cell> = row[row.len() - 13..row.len() - 6].to_vec();
        assert_eq!(
            last,
            [
                Cell::F64(0.125),
                Cell::F64(0.5),
                Cell::F64(-1.25),
                Cell::F64(2.0),
                Cell::F64(-0.75),
                Cell::F64(0.0),
                Cell::F64(1.5)
            ]
        );
        assert_eq!(
            row[row.len() - 6..],
            [
                Cell::F64(0.01),
                Cell::F64(-0.02),
                Cell::F64(0.03),
                Cell::F64(1e-9),
                Cell::U64(42),
                Cell::F64(250e-6)
            ]
        );
        // A device that reports no force: NaN in each column, and none again when read back.
        sample.truth.device_force_n = None;
        row.clear();
        cells(&sample, 2, 1_000, &mut row);
        assert!(row[row.len() - 12..row.len() - 9]
            .iter()
            .all(|c| matches!(c, Cell::F64(v) if v.is_nan())));
        assert_eq!(sample_from_cells(&row, 2, Some(1_000)).unwrap(), sample);
        // A tick that sent no local model: NaN proxy, bound and age, sequence 0, and none again when read back.
        sample.truth.device_local = None;
        row.clear();
        cells(&sample, 2, 1_000, &mut row);
        assert!(row[row.len() - 6..row.len() - 2]
            .iter()
            .chain(&row[row.len() - 1..])
            .all(|c| matches!(c, Cell::F64(v) if v.is_nan())));
        assert_eq!(row[row.len() - 2], Cell::U64(0));
        assert_eq!(sample_from_cells(&row, 2, Some(1_000)).unwrap(), sample);
    }
}
