//! Plots of a force trace (`voxhap plot`): what the user felt, where the probe and proxy went, and how
//! hard the solver worked.
//!
//! Downstream of the recorder in the data flow: it reads a finished trace ([`Trace`]) and draws four
//! panels with `plotters` into a PNG or SVG file:
//!
//! 1. force over time: magnitude and x, y, z components (N);
//! 2. solver effort over time: sweeps (exact solver) or iterations (Euler, constraint) per tick, named
//!    from the trace's sidecar (left axis, linear), and the certificate bound (right axis, log scale, m),
//!    as in the paper's Figure 7; ticks without a certificate (`inf`) are left out and a bound of exactly 0
//!    is drawn at the bottom of the axis;
//! 3. top view (x-y) and 4. side view (x-z) of the probe and proxy paths (mm), with equal scales on both
//!    axes so shapes are not distorted, and each axis at least [`MIN_PATH_SPAN_MM`] wide, centred on the
//!    data, so a sub-millimetre motion stays readable.
//!
//! The two time panels shade the periods when the trace's flags say the force was held back (ramp-in,
//! waiting to engage, slew limit: `force_limited_by_safety`) or the device was away (disconnected, not
//! enabled, faulted, stale state). Each panel's legend sits in a strip above its chart, never on the data.
//! Axis limits are robust: when a few samples lie far outside the rest (a spike), the axis covers the
//! 0.5 %..99.5 % quantiles and the samples beyond it are drawn on the axis edge as red triangles, counted in
//! the legend, instead of squashing everything else into a line.
//!
//! Long traces are thinned for drawing: time series keep the minimum and maximum of each of at most
//! [`MAX_BUCKETS`] time buckets (so spikes survive), paths keep every n-th point and drop sub-pixel
//! steps. Text uses DejaVu Sans embedded in the binary (the `dejavu` crate; licence in
//! `assets/fonts/DejaVu-LICENSE.txt`), so no system font library is needed.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::prelude::*;

use crate::error::TraceReadError;
use crate::sample::TraceSample;
use crate::trace::Trace;

mod axes;
mod data;
mod draw;
mod layout;
mod style;

pub use self::axes::MIN_PATH_SPAN_MM;
pub use self::data::{PlotData, PATH_BUCKETS};
pub use self::layout::{panel_layout, PanelRect};
#[cfg(test)]
use self::{axes::*, data::*, draw::effort_name};

/// Why a plot could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The output name does not end in `.png` or `.svg`.
    #[error("plot output {0}: the file name must end in .png or .svg")]
    UnsupportedFormat(PathBuf),
    /// The output path is a symbolic link (dangling or not): a plot is never written through one.
    #[error("plot output {0} is a symbolic link; voxhap never writes a plot through one (remove it or pick another --out)")]
    Symlink(PathBuf),
    /// Width or height outside [`PLOT_WIDTH_PX`] x [`PLOT_HEIGHT_PX`].
    #[error(
        "plot size {width_px}x{height_px} px is out of range: width 400..=8192, height 300..=8192"
    )]
    TooSmall {
        /// Width asked for.
        width_px: u32,
        /// Height asked for.
        height_px: u32,
    },
    /// The trace has no samples.
    #[error("the trace has no samples to plot")]
    EmptyTrace,
    /// The embedded font could not be loaded.
    #[error("the embedded font could not be loaded")]
    Font,
    /// plotters failed (drawing or writing the file).
    #[error("drawing the plot {path}: {message}")]
    Drawing {
        /// The output file.
        path: PathBuf,
        /// plotters' message.
        message: String,
    },
}

fn register_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(style::FONT, FontStyle::Normal, dejavu::sans::regular())
            .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// Plot widths accepted (px): at least room for the axes, at most a 8192-px image (an 8192 x 8192 PNG
/// is 200 MB of pixels while drawn).
pub const PLOT_WIDTH_PX: std::ops::RangeInclusive<u32> = 400..=8192;
/// Plot heights accepted (px).
pub const PLOT_HEIGHT_PX: std::ops::RangeInclusive<u32> = 300..=8192;

/// Draws `trace` into `out` (`.png` or `.svg`, chosen by the extension) at the given size.
pub fn plot_trace(
    trace: &Trace,
    title: &str,
    out: &Path,
    width_px: u32,
    height_px: u32,
) -> Result<(), PlotError> {
    let mut data = PlotData::new(width_px);
    trace.samples.iter().for_each(|sample| data.push(sample));
    plot_data(&data, trace, title, out, height_px)
}

/// Reads the trace at `path` in batches (Parquet pages, CSV lines, MCAP messages) into a [`PlotData`] for a
/// plot `width_px` wide, so that memory does not grow with the number of samples; returns the trace without
/// its samples (mode names, sidecar, warnings) and the reduction. An MCAP trace's file is held in memory while
/// it is read (its samples are not).
pub fn read_plot_data(path: &Path, width_px: u32) -> Result<(Trace, PlotData), TraceReadError> {
    let mut data = PlotData::new(width_px);
    let mut sink = |sample: &TraceSample| data.push(sample);
    let (trace, _) = match crate::formats::sniff_format(path)? {
        voxhap_api::TraceFormat::Parquet => {
            crate::parquet_read::for_each_parquet_sample(path, &mut sink)?
        }
        voxhap_api::TraceFormat::Csv => crate::csv::for_each_csv_sample(path, &mut sink)?,
        voxhap_api::TraceFormat::Mcap => crate::mcap_stream::stream_mcap_samples(path, &mut sink)?,
    };
    Ok((trace, data))
}

/// Draws a reduced trace into `out` (`.png` or `.svg`, chosen by the extension), as wide as the plot `data`
/// was reduced for ([`PlotData::width_px`]) and `height_px` high; `trace` gives the sidecar (its samples are
/// not used).
pub fn plot_data(
    data: &PlotData,
    trace: &Trace,
    title: &str,
    out: &Path,
    height_px: u32,
) -> Result<(), PlotError> {
    let width_px = data.width_px();
    if !PLOT_WIDTH_PX.contains(&width_px) || !PLOT_HEIGHT_PX.contains(&height_px) {
        return Err(PlotError::TooSmall {
            width_px,
            height_px,
        });
    }
    if data.time_span_s().is_none() {
        return Err(PlotError::EmptyTrace);
    }
    register_font()?;
    let extension = check_output_name(out)?;
    let drawing_error = |message: String| PlotError::Drawing {
        path: out.to_path_buf(),
        message,
    };
    let effort = draw::effort_name(trace);
    match extension {
        "png" => {
            let root = BitMapBackend::new(out, (width_px, height_px)).into_drawing_area();
            draw::draw(&root, data, effort, title).map_err(|e| drawing_error(e.to_string()))?;
            root.present().map_err(|e| drawing_error(e.to_string()))
        }
        _ => {
            let root = SVGBackend::new(out, (width_px, height_px)).into_drawing_area();
            draw::draw(&root, data, effort, title).map_err(|e| drawing_error(e.to_string()))?;
            root.present().map_err(|e| drawing_error(e.to_string()))
        }
    }
}

/// The output format, `"png"` or `"svg"`, from the file name (checked before a trace is read, and again
/// just before drawing); a symbolic link at `out` is refused.
pub fn check_output_name(out: &Path) -> Result<&'static str, PlotError> {
    if std::fs::symlink_metadata(out).is_ok_and(|m| m.file_type().is_symlink()) {
        return Err(PlotError::Symlink(out.to_path_buf()));
    }
    match out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => Ok("png"),
        Some("svg") => Ok("svg"),
        _ => Err(PlotError::UnsupportedFormat(out.to_path_buf())),
    }
}

#[cfg(test)]
#[path = "plot_tests.rs"]
mod tests;
