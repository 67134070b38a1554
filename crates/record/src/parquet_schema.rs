//! The layout a Parquet trace shares between its writer and its readers: the Arrow schema of the trace's
//! columns, the magic bytes, the metadata key of the embedded sidecar, and the check that a file's schema is
//! a voxhap trace's.

use std::sync::Arc;

use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::file::metadata::ParquetMetaData;

use crate::columns::{columns, ColumnType, PRIMITIVES_PREFIX};
use crate::error::ParquetProblem;
use crate::meta::{is_valid_mode_name, Sidecar};
use voxhap_core::haptics::modes::MAX_MODES;

/// The file-metadata key holding the sidecar's JSON (the final sidecar, in a finished file).
pub const SIDECAR_KEY: &str = "voxhap.sidecar";
/// `PAR1`, which starts a Parquet file and ends its footer.
pub(crate) const MAGIC: &[u8; 4] = b"PAR1";
/// Ends a row-group footer in place of `PAR1`, so a file cut off after a row-group footer is not taken
/// for a finished file holding only its last row group (pyarrow refuses it; `voxhap trace repair` reads
/// it).
pub(crate) const ROW_GROUP_FOOTER_MAGIC: &[u8; 4] = b"VXRG";

/// The Arrow type of a column type, and whether it may be null.
fn arrow_type(column_type: ColumnType) -> (DataType, bool) {
    match column_type {
        ColumnType::U64 => (DataType::UInt64, false),
        ColumnType::OptionalU64 => (DataType::UInt64, true),
        // utc_ns is null when t_s is not finite (only in a sample flagged invalid_values).
        ColumnType::I64 => (DataType::Int64, true),
        ColumnType::F64 => (DataType::Float64, false),
        ColumnType::Bool => (DataType::Boolean, false),
        ColumnType::Text => (DataType::Utf8, false),
    }
}

/// The Arrow schema of a trace with these modes.
pub(crate) fn arrow_schema(mode_names: &[String]) -> SchemaRef {
    let fields: Vec<Field> = columns(mode_names)
        .into_iter()
        .map(|c| {
            let (data_type, nullable) = arrow_type(c.column_type);
            Field::new(c.name.into_owned(), data_type, nullable)
        })
        .collect();
    Arc::new(Schema::new(fields))
}

/// The sidecar embedded in a finished file's metadata under [`SIDECAR_KEY`], when it is there and parses.
pub(crate) fn embedded_sidecar(metadata: &ParquetMetaData) -> Option<Sidecar> {
    metadata
        .file_metadata()
        .key_value_metadata()
        .and_then(|kv| kv.iter().find(|kv| kv.key == SIDECAR_KEY))
        .and_then(|kv| kv.value.as_deref())
        .and_then(|json| serde_json::from_str::<Sidecar>(json).ok())
}

/// Checks that `schema` is a voxhap trace's (every column named and typed as written); returns the mode names
/// and the expected schema.
pub(crate) fn trace_schema(schema: &SchemaRef) -> Result<(Vec<String>, SchemaRef), ParquetProblem> {
    let mode_names = mode_names_from_schema(schema)?;
    let expected = arrow_schema(&mode_names);
    for (index, want) in expected.fields().iter().enumerate() {
        match schema.fields().get(index) {
            Some(got) if got.name() == want.name() && got.data_type() == want.data_type() => {}
            Some(got) => {
                return Err(ParquetProblem::ColumnMismatch {
                    index: index + 1,
                    found: got.name().clone(),
                    found_type: got.data_type().clone(),
                    expected: want.name().clone(),
                    expected_type: want.data_type().clone(),
                })
            }
            None => {
                return Err(ParquetProblem::ColumnMissing {
                    index: index + 1,
                    expected: want.name().clone(),
                })
            }
        }
    }
    if schema.fields().len() != expected.fields().len() {
        return Err(ParquetProblem::ColumnCount {
            found: schema.fields().len(),
            expected: expected.fields().len(),
        });
    }
    Ok((mode_names, expected))
}

/// The mode names in a trace's schema (the `primitives_<mode>` columns, in order).
fn mode_names_from_schema(schema: &Schema) -> Result<Vec<String>, ParquetProblem> {
    let mut names: Vec<String> = Vec::new();
    for field in schema.fields() {
        if let Some(name) = field.name().strip_prefix(PRIMITIVES_PREFIX) {
            if !is_valid_mode_name(name) || names.iter().any(|n| n == name) {
                return Err(ParquetProblem::BadModeColumn(field.name().clone()));
            }
            names.push(name.to_owned());
        }
    }
    if names.len() > MAX_MODES {
        return Err(ParquetProblem::TooManyModes {
            count: names.len(),
            max: MAX_MODES,
        });
    }
    if schema.fields().first().map(|f| f.name().as_str()) != Some("tick") {
        return Err(ParquetProblem::NotVoxhap);
    }
    Ok(names)
}
