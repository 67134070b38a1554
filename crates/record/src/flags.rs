//! The flag bits of a trace sample: the bit constants (defined in `voxhap_core`, where the tick sets
//! them) and [`FLAG_DOCS`], their names and meanings as written into the sidecar and the `flag_<name>`
//! columns.

use serde::{Deserialize, Serialize};
use std::borrow::Cow;

pub use voxhap_core::status::flags::*;

/// One flag bit.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FlagDoc {
    /// Bit index (value `1 << bit`).
    pub bit: u32,
    /// Short name.
    pub name: Cow<'static, str>,
    /// What it means when set.
    pub meaning: Cow<'static, str>,
}

const fn flag(bit: u32, name: &'static str, meaning: &'static str) -> FlagDoc {
    FlagDoc {
        bit,
        name: Cow::Borrowed(name),
        meaning: Cow::Borrowed(meaning),
    }
}

/// How many flag bits are defined.
pub const FLAG_COUNT: usize = 17;

/// Every flag bit with its name and meaning, lowest bit first; written into the sidecar and, one boolean
/// column `flag_<name>` each, into the trace.
pub const FLAG_DOCS: [FlagDoc; FLAG_COUNT] = [
    flag(
        0,
        "solver_budget_hit",
        "solver stopped on its sweep or time budget before the certificate met its tolerance",
    ),
    flag(1, "force_clamped", "force clamped to the device maximum, direction kept"),
    flag(2, "workspace_limit", "probe at or beyond the device workspace limit"),
    flag(3, "overrun", "tick started late; missed ticks were skipped, not caught up"),
    flag(4, "non_finite_replaced", "a non-finite probe position or force was replaced by zero"),
    flag(5, "samples_dropped", "recorder ring was full; samples before this one were lost"),
    flag(
        6,
        "force_limited_by_safety",
        "force below what was rendered: ramping in, waiting to engage, slew-limited, or held at zero (watchdog, disconnect, device not enabled, stale state)",
    ),
    flag(7, "compute_over_budget", "tick compute exceeded its budget; the last safe force was sent again"),
    flag(
        8,
        "device_not_enabled",
        "device not accepting force (starting, recovering, faulted, or Enable refused): zero commanded",
    ),
    flag(9, "device_disconnected", "the device was disconnected this tick"),
    flag(10, "velocity_estimated", "probe velocity estimated by the host from positions, not reported by the device"),
    flag(
        11,
        "invalid_values",
        "the sample broke a trace rule (non-finite or negative value, wrong mode count) and was recorded as it came",
    ),
    flag(
        12,
        "position_rejected",
        "implausible device position (speed, workspace, non-finite); the last accepted one was held",
    ),
    flag(
        13,
        "velocity_replaced",
        "reported velocity disagreed with the positions; the estimate from positions was used",
    ),
    flag(14, "force_slew_limited", "the force's rise was limited by the slew rate"),
    flag(15, "stale_state", "no fresh device state for several periods: zero commanded"),
    flag(16, "device_faulted", "a device fault that needs a person is active"),
];
