//! The plot's look: font, colours, the shaded flag kinds and the legend strip's height.

use plotters::style::RGBColor;

pub(super) const FONT: &str = "sans-serif";
pub(super) const PROBE_COLOR: RGBColor = RGBColor(31, 119, 180);
pub(super) const PROXY_COLOR: RGBColor = RGBColor(255, 127, 14);
pub(super) const X_COLOR: RGBColor = RGBColor(214, 39, 40);
pub(super) const Y_COLOR: RGBColor = RGBColor(44, 160, 44);
pub(super) const Z_COLOR: RGBColor = RGBColor(31, 119, 180);
pub(super) const BOUND_COLOR: RGBColor = RGBColor(148, 103, 189);
pub(super) const OUTLIER_COLOR: RGBColor = RGBColor(220, 0, 0);
/// Shading of periods with the force held back by safety (ramp-in, engage, slew).
pub(super) const SAFETY_SHADE: RGBColor = RGBColor(255, 200, 120);
/// Shading of periods with the device away (disconnected, not enabled, faulted, stale).
pub(super) const DEVICE_SHADE: RGBColor = RGBColor(200, 200, 200);
/// Height of each panel's legend strip (px).
pub(super) const LEGEND_PX: u32 = 22;
/// Most shaded periods drawn per kind (closer ones are merged).
pub(super) const MAX_SHADED_PERIODS: usize = 500;

/// The flag bits whose periods are shaded, with the legend text and colour.
pub(super) const SHADED_FLAGS: [(u32, &str, RGBColor); 2] = [
    (
        crate::flags::FLAG_FORCE_LIMITED_BY_SAFETY,
        "force held back (ramp-in, engage, slew)",
        SAFETY_SHADE,
    ),
    (
        crate::flags::FLAG_DEVICE_DISCONNECTED
            | crate::flags::FLAG_DEVICE_NOT_ENABLED
            | crate::flags::FLAG_DEVICE_FAULTED
            | crate::flags::FLAG_STALE_STATE,
        "device away (disconnected, not enabled, faulted)",
        DEVICE_SHADE,
    ),
];
