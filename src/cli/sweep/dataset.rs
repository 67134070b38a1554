//! A Parquet sweep as one partitioned dataset: every point's trace goes to
//! `DIR/points/COLUMN=VALUE/.../point-NNN.parquet` (Hive-style directories, one level per `--set` key, so
//! DuckDB, polars, pyarrow and Spark read `DIR/points` as one table with the swept values as partition
//! columns), and `DIR/points.parquet` holds one row per point: its settings as typed columns, its summary
//! (the figures of `sweep.csv`) and its trace's path relative to `DIR`.
//!
//! A key's column name is the key with every run of characters other than ASCII letters, digits and `_`
//! replaced by one `_` (`modes[1].mu` -> `modes_1_mu`); a value is written in its directory name with every
//! byte other than ASCII letters, digits, `.`, `-` and `_` percent-encoded (as Hive does), so `/` or `=`
//! in a value cannot make another directory level.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::builder::{Float64Builder, Int64Builder, StringBuilder, UInt64Builder};
use arrow_array::{ArrayRef, RecordBatch};
use arrow_schema::{DataType, Field, Schema};
use parquet::arrow::ArrowWriter;

use crate::sim::overrides::split_override;
use crate::sim::SimSummary;

/// The dataset's directory inside the sweep's `--out-dir`.
pub const DATASET_DIR: &str = "points";
/// The per-point table inside the sweep's `--out-dir`.
pub const POINTS_TABLE: &str = "points.parquet";

/// The columns of `points.parquet` besides the partition columns (a swept key may not take their names).
const SUMMARY_COLUMNS: [&str; 9] = [
    "point",
    "settings",
    "ticks",
    "certified_ticks",
    "max_force_n",
    "max_sweeps",
    "max_error_bound_m",
    "trace",
    "error",
];

/// A swept key and its partition column's name.
#[derive(Debug, Clone, PartialEq)]
pub struct PartitionColumn {
    pub key: String,
    pub name: String,
}

/// The partition column of every `--set KEY=...`, in order. Fails when two keys give the same column name
/// or a key's name is taken by a `points.parquet` column or a trace column (`trace_columns`).
pub fn partition_columns(
    sets: &[String],
    trace_columns: &[String],
) -> anyhow::Result<Vec<PartitionColumn>> {
    let mut columns: Vec<PartitionColumn> = Vec::new();
    for set in sets {
        let (key, _) = split_override(set)?;
        let name = column_name(key);
        if name.is_empty() {
            anyhow::bail!("--set {set:?}: the key {key:?} has no letter or digit to name a column");
        }
        if let Some(other) = columns.iter().find(|c| c.name == name) {
            anyhow::bail!(
                "--set keys {:?} and {key:?} give the same partition column {name:?}",
                other.key
            );
        }
        if SUMMARY_COLUMNS.contains(&name.as_str()) || trace_columns.contains(&name) {
            anyhow::bail!(
                "--set {set:?}: the partition column {name:?} would have the name of a trace or points.parquet column"
            );
        }
        columns.push(PartitionColumn {
            key: key.to_owned(),
            name,
        });
    }
    Ok(columns)
}

/// `key` as a column name: runs of characters other than ASCII letters, digits and `_` become one `_`,
/// none at either end.
pub fn column_name(key: &str) -> String {
    let mut name = String::with_capacity(key.len());
    for c in key.chars() {
        if c.is_ascii_alphanumeric() || c == '_' {
            name.push(c);
        } else if !name.ends_with('_') {
            name.push('_');
        }
    }
    name.trim_matches('_').to_owned()
}

/// `value` for a directory name: bytes other than ASCII letters, digits, `.`, `-` and `_` as `%XX`.
pub fn encode_value(value: &str) -> String {
    let mut encoded = String::with_capacity(value.len());
    for byte in value.bytes() {
        if byte.is_ascii_alphanumeric() || matches!(byte, b'.' | b'-' | b'_') {
            encoded.push(byte as char);
        } else {
            encoded.push_str(&format!("%{byte:02X}"));
        }
    }
    // "." and ".." are not directory names a reader walks into.
    if encoded.chars().all(|c| c == '.') {
        encoded = encoded.replace('.', "%2E");
    }
    encoded
}

/// The value each override of a point gives, in `columns`' order.
fn point_values(overrides: &[String]) -> Vec<&str> {
    overrides
        .iter()
        .map(|o| split_override(o).map_or("", |(_, value)| value))
        .collect()
}

/// The trace path of point `index` with these overrides: `DIR/points/C1=V1/C2=V2/point-NNN.parquet`.
pub fn point_path(
    out_dir: &Path,
    columns: &[PartitionColumn],
    overrides: &[String],
    index: usize,
) -> PathBuf {
    let mut path = out_dir.join(DATASET_DIR);
    for (column, value) in columns.iter().zip(point_values(overrides)) {
        path.push(format!("{}={}", column.name, encode_value(value)));
    }
    path.join(format!("point-{index:03}.parquet"))
}

/// One point's row of `points.parquet`.
pub struct PointRow<'a> {
    pub overrides: &'a [String],
    pub trace: &'a Path,
    pub result: Result<&'a SimSummary, String>,
}

/// How a partition column's values are typed in `points.parquet`: integers when every value is one, else
/// floats when every value is one, else text (what DuckDB and polars infer from the directory names).
#[derive(Debug, Clone, Copy, PartialEq)]
enum ValueType {
    Int,
    Float,
    Text,
}

fn value_type<'a>(values: impl Iterator<Item = &'a str> + Clone) -> ValueType {
    if values.clone().all(|v| v.parse::<i64>().is_ok()) {
        ValueType::Int
    } else if values.clone().all(|v| v.parse::<f64>().is_ok()) {
        ValueType::Float
    } else {
        ValueType::Text
    }
}

/// Writes `points.parquet` (replacing it) at `path`: one row per point, `point`, `settings`, a column per
/// swept key, the summary figures (null for a point that failed, whose `error` says why) and `trace`,
/// the point's trace path relative to `out_dir`.
pub fn write_points_table(
    path: &Path,
    out_dir: &Path,
    columns: &[PartitionColumn],
    rows: &[PointRow],
) -> anyhow::Result<()> {
    let values: Vec<Vec<&str>> = rows.iter().map(|r| point_values(r.overrides)).collect();
    let mut fields = vec![
        Field::new("point", DataType::UInt64, false),
        Field::new("settings", DataType::Utf8, false),
    ];
    let mut arrays: Vec<ArrayRef> = Vec::new();
    let mut point = UInt64Builder::new();
    let mut settings = StringBuilder::new();
    for (index, row) in rows.iter().enumerate() {
        point.append_value(index as u64);
        settings.append_value(row.overrides.join(" "));
    }
    arrays.push(Arc::new(point.finish()));
    arrays.push(Arc::new(settings.finish()));
    for (c, column) in columns.iter().enumerate() {
        let of_column = values.iter().map(move |v| v.get(c).copied().unwrap_or(""));
        let (data_type, array): (DataType, ArrayRef) = match value_type(of_column.clone()) {
            ValueType::Int => {
                let mut b = Int64Builder::new();
                of_column.for_each(|v| b.append_option(v.parse().ok()));
                (DataType::Int64, Arc::new(b.finish()))
            }
            ValueType::Float => {
                let mut b = Float64Builder::new();
                of_column.for_each(|v| b.append_option(v.parse().ok()));
                (DataType::Float64, Arc::new(b.finish()))
            }
            ValueType::Text => {
                let mut b = StringBuilder::new();
                of_column.for_each(|v| b.append_value(v));
                (DataType::Utf8, Arc::new(b.finish()))
            }
        };
        fields.push(Field::new(&column.name, data_type, false));
        arrays.push(array);
    }
    let summaries: Vec<Option<&SimSummary>> = rows
        .iter()
        .map(|r| r.result.as_ref().ok().copied())
        .collect();
    let u64_column = |value: fn(&SimSummary) -> u64| -> ArrayRef {
        let mut b = UInt64Builder::new();
        summaries.iter().for_each(|s| b.append_option(s.map(value)));
        Arc::new(b.finish())
    };
    let f64_column = |value: fn(&SimSummary) -> f64| -> ArrayRef {
        let mut b = Float64Builder::new();
        summaries.iter().for_each(|s| b.append_option(s.map(value)));
        Arc::new(b.finish())
    };
    let mut trace = StringBuilder::new();
    let mut error = StringBuilder::new();
    for row in rows {
        let relative = row.trace.strip_prefix(out_dir).unwrap_or(row.trace);
        trace.append_value(relative.to_string_lossy());
        error.append_option(row.result.as_ref().err());
    }
    for (name, array) in [
        ("ticks", u64_column(|s| s.ticks)),
        ("certified_ticks", u64_column(|s| s.certified_ticks)),
        ("max_force_n", f64_column(|s| s.max_force_n)),
        ("max_sweeps", u64_column(|s| u64::from(s.max_sweeps))),
        ("max_error_bound_m", f64_column(|s| s.max_error_bound_m)),
    ] {
        fields.push(Field::new(name, array.data_type().clone(), true));
        arrays.push(array);
    }
    fields.push(Field::new("trace", DataType::Utf8, false));
    arrays.push(Arc::new(trace.finish()));
    fields.push(Field::new("error", DataType::Utf8, true));
    arrays.push(Arc::new(error.finish()));
    let schema = Arc::new(Schema::new(fields));
    let batch = RecordBatch::try_new(schema.clone(), arrays)?;
    let file = crate::record::create_or_replace_file(path)?;
    let mut writer = ArrowWriter::try_new(file, schema, None)?;
    writer.write(&batch)?;
    writer.close()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_become_column_names() {
        assert_eq!(column_name("modes[1].mu"), "modes_1_mu");
        assert_eq!(column_name("k_n_per_m"), "k_n_per_m");
        assert_eq!(
            column_name("arm.workspace.radius_m"),
            "arm_workspace_radius_m"
        );
        let sets = ["modes[1].mu=0.3".to_owned(), "modes.1.mu=0.5".to_owned()];
        let error = partition_columns(&sets, &[]).unwrap_err().to_string();
        assert!(error.contains("modes_1_mu"), "{error}");
        let error = partition_columns(&["t_s=1,2".to_owned()], &["t_s".to_owned()])
            .unwrap_err()
            .to_string();
        assert!(error.contains("\"t_s\""), "{error}");
    }

    #[test]
    fn values_cannot_make_directories() {
        // The Hive escaping: '/' is %2F, '=' is %3D, ' ' is %20 (Apache Hive FileUtils.escapePathName).
        assert_eq!(encode_value("0.3"), "0.3");
        assert_eq!(encode_value("a/b=c d"), "a%2Fb%3Dc%20d");
        assert_eq!(encode_value(".."), "%2E%2E");
        let columns = partition_columns(&["solver.kind=x".to_owned()], &[]).unwrap();
        let path = point_path(
            Path::new("sw"),
            &columns,
            &["solver.kind=../x".to_owned()],
            7,
        );
        assert_eq!(
            path,
            Path::new("sw/points/solver_kind=..%2Fx/point-007.parquet")
        );
    }
}
