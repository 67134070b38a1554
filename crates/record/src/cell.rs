//! The vocabulary of the trace's columns: a column's documentation ([`ColumnDoc`], [`ColumnType`]) and one
//! value of a row ([`Cell`], [`CellError`]). The column lists themselves are in `columns` and
//! `truth_columns`, which both build on this.

use serde::{Deserialize, Serialize};
use std::borrow::Cow;

/// The value type of a column.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ColumnType {
    /// Unsigned 64-bit integer.
    U64,
    /// Signed 64-bit integer.
    I64,
    /// 64-bit float (NaN and infinities allowed where the column says so).
    F64,
    /// `true` or `false`.
    Bool,
    /// Short text from a fixed set (the solver status, the force-off cause).
    Text,
    /// Unsigned 64-bit integer that may be missing (empty in CSV, null in Parquet and MCAP).
    OptionalU64,
}

/// One column of a trace (CSV and Parquet), as documented in the sidecar.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ColumnDoc {
    /// Header name.
    pub name: Cow<'static, str>,
    /// Unit (`m`, `N`, `s`, `ns`, `us`, `m/s`, `count`, `bits`, `-`).
    pub unit: Cow<'static, str>,
    /// What it holds.
    pub meaning: Cow<'static, str>,
    /// Its value type.
    #[serde(rename = "type")]
    pub column_type: ColumnType,
}

/// One cell of a row.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Cell {
    U64(u64),
    I64(i64),
    F64(f64),
    Bool(bool),
    Text(&'static str),
    Missing,
}

pub(crate) fn col(
    name: &'static str,
    unit: &'static str,
    meaning: &'static str,
    t: ColumnType,
) -> ColumnDoc {
    ColumnDoc {
        name: Cow::Borrowed(name),
        unit: Cow::Borrowed(unit),
        meaning: Cow::Borrowed(meaning),
        column_type: t,
    }
}

/// Why a row of cells is not a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CellError {
    /// 0-based column.
    pub index: usize,
    /// What is wrong.
    pub problem: &'static str,
}
