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

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::TraceReadError;
use crate::sample::TraceSample;
use crate::trace::Trace;

const FONT: &str = "sans-serif";
const PROBE_COLOR: RGBColor = RGBColor(31, 119, 180);
const PROXY_COLOR: RGBColor = RGBColor(255, 127, 14);
const X_COLOR: RGBColor = RGBColor(214, 39, 40);
const Y_COLOR: RGBColor = RGBColor(44, 160, 44);
const Z_COLOR: RGBColor = RGBColor(31, 119, 180);
const BOUND_COLOR: RGBColor = RGBColor(148, 103, 189);
const OUTLIER_COLOR: RGBColor = RGBColor(220, 0, 0);
/// Shading of periods with the force held back by safety (ramp-in, engage, slew).
const SAFETY_SHADE: RGBColor = RGBColor(255, 200, 120);
/// Shading of periods with the device away (disconnected, not enabled, faulted, stale).
const DEVICE_SHADE: RGBColor = RGBColor(200, 200, 200);
/// Height of each panel's legend strip (px).
const LEGEND_PX: u32 = 22;
/// Most shaded periods drawn per kind (closer ones are merged).
const MAX_SHADED_PERIODS: usize = 500;

/// The flag bits whose periods are shaded, with the legend text and colour.
const SHADED_FLAGS: [(u32, &str, RGBColor); 2] = [
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

/// A panel's pixel rectangle in the output image: `x0..x1`, `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PanelRect {
    /// Left edge (inclusive).
    pub x0: u32,
    /// Top edge (inclusive).
    pub y0: u32,
    /// Right edge (exclusive).
    pub x1: u32,
    /// Bottom edge (exclusive).
    pub y1: u32,
}

/// Height of the title strip (px).
const TITLE_PX: u32 = 36;

/// The four panels' rectangles for an image of this size: force, solver effort, top view, side view.
pub fn panel_layout(width_px: u32, height_px: u32) -> [PanelRect; 4] {
    let body = height_px - TITLE_PX;
    let row1 = TITLE_PX + body * 3 / 10;
    let row2 = row1 + body * 3 / 10;
    let half = width_px / 2;
    [
        PanelRect {
            x0: 0,
            y0: TITLE_PX,
            x1: width_px,
            y1: row1,
        },
        PanelRect {
            x0: 0,
            y0: row1,
            x1: width_px,
            y1: row2,
        },
        PanelRect {
            x0: 0,
            y0: row2,
            x1: half,
            y1: height_px,
        },
        PanelRect {
            x0: half,
            y0: row2,
            x1: width_px,
            y1: height_px,
        },
    ]
}

fn register_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
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
    plot_data(&data, trace, title, out, width_px, height_px)
}

/// Reads the trace at `path` in batches (Parquet pages, CSV lines) into a [`PlotData`] for a plot `width_px`
/// wide, so that memory does not grow with the trace's length; returns the trace without its samples (mode
/// names, sidecar, warnings) and the reduction. An MCAP trace, and a Parquet file cut off before its footer,
/// are read whole first.
pub fn read_plot_data(path: &Path, width_px: u32) -> Result<(Trace, PlotData), TraceReadError> {
    let mut data = PlotData::new(width_px);
    let mut sink = |sample: &TraceSample| data.push(sample);
    let (trace, _) = match sniff_format(path)? {
        voxhap_api::TraceFormat::Parquet => {
            crate::parquet_trace::for_each_parquet_sample(path, &mut sink)?
        }
        voxhap_api::TraceFormat::Csv => crate::csv::for_each_csv_sample(path, &mut sink)?,
        voxhap_api::TraceFormat::Mcap => {
            let mut trace = crate::formats::read_trace(path)?;
            let samples = std::mem::take(&mut trace.samples);
            samples.iter().for_each(&mut sink);
            (trace, samples.len() as u64)
        }
    };
    Ok((trace, data))
}

/// The trace's format from its first bytes (the MCAP magic, `PAR1`, else CSV), as [`crate::formats::read_trace`]
/// chooses.
fn sniff_format(path: &Path) -> Result<voxhap_api::TraceFormat, TraceReadError> {
    use std::io::Read;
    let (file, _) = crate::trace::open_trace_file(path)?;
    let mut magic = Vec::with_capacity(8);
    file.take(8)
        .read_to_end(&mut magic)
        .map_err(|source| TraceReadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(if magic[..] == *mcap::MAGIC {
        voxhap_api::TraceFormat::Mcap
    } else if magic.starts_with(b"PAR1") {
        voxhap_api::TraceFormat::Parquet
    } else {
        voxhap_api::TraceFormat::Csv
    })
}

/// Draws a reduced trace into `out` (`.png` or `.svg`, chosen by the extension) at the given size; `trace`
/// gives the sidecar (its samples are not used).
pub fn plot_data(
    data: &PlotData,
    trace: &Trace,
    title: &str,
    out: &Path,
    width_px: u32,
    height_px: u32,
) -> Result<(), PlotError> {
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
    let effort = effort_name(trace);
    match extension {
        "png" => {
            let root = BitMapBackend::new(out, (width_px, height_px)).into_drawing_area();
            draw(&root, data, effort, title).map_err(drawing_error)?;
            root.present().map_err(|e| drawing_error(e.to_string()))
        }
        _ => {
            let root = SVGBackend::new(out, (width_px, height_px)).into_drawing_area();
            draw(&root, data, effort, title).map_err(drawing_error)?;
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

type DrawResult = Result<(), String>;
/// A polyline in chart coordinates.
type Points = Vec<(f64, f64)>;

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    data: &PlotData,
    effort: &str,
    title: &str,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let (width_px, height_px) = root.dim_in_pixel();
    let [force, solver, top, side] = panel_layout(width_px, height_px);
    root.draw(&Text::new(
        title.to_string(),
        (12, 8),
        (FONT, 20).into_font().color(&BLACK),
    ))
    .map_err(err)?;
    let area = |r: PanelRect| {
        root.clone()
            .shrink((r.x0, r.y0), (r.x1 - r.x0, r.y1 - r.y0))
    };
    let shaded: Vec<ShadedPeriods> = SHADED_FLAGS
        .iter()
        .map(|&(mask, name, color)| ShadedPeriods {
            name,
            color,
            periods: data.flag_periods(mask),
        })
        .filter(|s| !s.periods.is_empty())
        .collect();
    draw_force(&area(force), data, &shaded)?;
    draw_solver(&area(solver), data, effort, &shaded)?;
    draw_path(&area(top), data, VIEW_TOP, "Top view (x-y)", "y (mm)")?;
    draw_path(&area(side), data, VIEW_SIDE, "Side view (x-z)", "z (mm)")?;
    Ok(())
}

/// Periods (start, end time in s) of a flag kind, for shading.
struct ShadedPeriods {
    name: &'static str,
    color: RGBColor,
    periods: Vec<(f64, f64)>,
}

fn push_period(periods: &mut Vec<(f64, f64)>, period: (f64, f64), merge_gap_s: f64) {
    match periods.last_mut() {
        Some(last) if period.0 - last.1 <= merge_gap_s => last.1 = period.1,
        _ => periods.push(period),
    }
}

/// What the solver panel counts: the exact solver's block sweeps, or the baselines' iterations.
fn effort_name(trace: &Trace) -> &'static str {
    match trace.sidecar.as_ref().map(|s| s.meta.solver.as_str()) {
        // `exact`, `exact-dual`; `euler-baseline`, `constraint-baseline` (and their short names).
        Some(solver) if solver.starts_with("exact") => "sweeps",
        Some(solver) if solver.starts_with("euler") || solver.starts_with("constraint") => {
            "iterations"
        }
        _ => "sweeps or iterations",
    }
}

/// An axis range for `values` that a few far-off values cannot squash: the full range padded 5 % when
/// the 0.5 %..99.5 % quantiles span at least a third of it, else those quantiles padded 5 % (the values
/// beyond are drawn on the edge, see [`clamp_outliers`]).
fn robust_range(values: impl Iterator<Item = f64>) -> Range<f64> {
    let mut finite: Vec<f64> = values.filter(|v| v.is_finite()).collect();
    if finite.len() < 20 {
        return padded_range(finite.into_iter());
    }
    finite.sort_by(f64::total_cmp);
    let n = finite.len();
    let (low, high) = (finite[0], finite[n - 1]);
    let q_low = finite[n / 200];
    let q_high = finite[n - 1 - n / 200];
    if q_high - q_low >= (high - low) / 3.0 {
        padded_range([low, high].into_iter())
    } else {
        padded_range([q_low, q_high].into_iter())
    }
}

/// `points` with y clamped into `range`, and the points that were outside (at the edge they were drawn at).
fn clamp_outliers(points: Points, range: &Range<f64>) -> (Points, Points) {
    let mut outside = Vec::new();
    let clamped = points
        .into_iter()
        .map(|(x, y)| {
            if y < range.start || y > range.end {
                let edge = y.clamp(range.start, range.end);
                outside.push((x, edge));
                (x, edge)
            } else {
                (x, y)
            }
        })
        .collect();
    (clamped, outside)
}

/// One legend entry: text, colour, and whether it is a filled box (shading, markers) or a line.
struct LegendEntry {
    text: String,
    color: RGBColor,
    filled: bool,
}

impl LegendEntry {
    fn line(text: impl Into<String>, color: RGBColor) -> Self {
        LegendEntry {
            text: text.into(),
            color,
            filled: false,
        }
    }

    fn filled(text: impl Into<String>, color: RGBColor) -> Self {
        LegendEntry {
            text: text.into(),
            color,
            filled: true,
        }
    }
}

/// Splits a panel into its legend strip (caption, then the entries, left to right) and the chart area
/// below, so no legend covers data.
fn legend_strip<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    caption: &str,
    entries: &[LegendEntry],
) -> Result<DrawingArea<DB, Shift>, String>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let (strip, chart) = area.split_vertically(LEGEND_PX);
    let caption_font = (FONT, 16).into_font().color(&BLACK);
    strip
        .draw(&Text::new(
            caption.to_string(),
            (10, 3),
            caption_font.clone(),
        ))
        .map_err(err)?;
    let (width, _) = strip.dim_in_pixel();
    let text_width = |text: &str, size: f64| {
        strip
            .estimate_text_size(text, &TextStyle::from((FONT, size).into_font()))
            .map_or(text.len() as i32 * 7, |(w, _)| w as i32)
    };
    let mut x = 10 + text_width(caption, 16.0) + 24;
    let label_font = (FONT, 12).into_font().color(&BLACK);
    for entry in entries {
        let needed = 24 + text_width(&entry.text, 12.0) + 16;
        if x + needed > width as i32 {
            break; // no room: the strip never draws over the chart
        }
        let y = (LEGEND_PX / 2) as i32;
        if entry.filled {
            strip
                .draw(&Rectangle::new(
                    [(x, y - 6), (x + 18, y + 6)],
                    entry.color.filled(),
                ))
                .map_err(err)?;
        } else {
            strip
                .draw(&PathElement::new(
                    vec![(x, y), (x + 18, y)],
                    entry.color.stroke_width(2),
                ))
                .map_err(err)?;
        }
        strip
            .draw(&Text::new(
                entry.text.clone(),
                (x + 24, y - 7),
                label_font.clone(),
            ))
            .map_err(err)?;
        x += needed;
    }
    Ok(chart)
}

/// `entries` followed by the count of samples drawn on the axis edge (when there are any) and the shaded
/// flag kinds: the legend of a time panel.
fn with_marks(
    mut entries: Vec<LegendEntry>,
    off_axis: usize,
    shaded: &[ShadedPeriods],
) -> Vec<LegendEntry> {
    if off_axis > 0 {
        entries.push(LegendEntry::filled(
            format!("{off_axis} off the axis"),
            OUTLIER_COLOR,
        ));
    }
    entries.extend(shaded.iter().map(|s| LegendEntry::filled(s.name, s.color)));
    entries
}

/// A range covering `values` with 5 % padding; a unit-wide range around a constant.
fn padded_range(values: impl Iterator<Item = f64>) -> Range<f64> {
    let (low, high) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !low.is_finite() {
        return 0.0..1.0;
    }
    let span = high - low;
    if span <= f64::EPSILON * high.abs().max(1.0) {
        let half = (high.abs() * 0.1).max(1e-3);
        return (low - half)..(high + half);
    }
    (low - 0.05 * span)..(high + 0.05 * span)
}

/// A thick polyline as separate two-point segments: plotters joins thick polylines with mitres that
/// shoot far outside the chart at sharp reversals (min/max envelopes, raster turns).
fn thick_segments(
    points: Vec<(f64, f64)>,
    style: ShapeStyle,
) -> impl Iterator<Item = PathElement<(f64, f64)>> {
    let single = (points.len() == 1).then(|| PathElement::new(vec![points[0], points[0]], style));
    let pairs: Vec<_> = points.windows(2).map(|w| (w[0], w[1])).collect();
    pairs
        .into_iter()
        .map(move |(a, b)| PathElement::new(vec![a, b], style))
        .chain(single)
}

/// Shades `periods` over the full height of a chart whose y axis spans `y`.
fn shade_periods<DB: DrawingBackend, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, Y>>,
    shaded: &[ShadedPeriods],
    y: &Range<f64>,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    for kind in shaded {
        let style = kind.color.mix(0.45).filled();
        chart
            .draw_series(
                kind.periods
                    .iter()
                    .map(|&(t0, t1)| Rectangle::new([(t0, y.start), (t1, y.end)], style)),
            )
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// Red triangles at the axis edge where samples lay beyond it.
fn outlier_markers(points: Points) -> impl Iterator<Item = TriangleMarker<(f64, f64), i32>> {
    points
        .into_iter()
        .map(|p| TriangleMarker::new(p, 5, OUTLIER_COLOR.filled()))
}

fn draw_force<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PlotData,
    shaded: &[ShadedPeriods],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let components: [(&str, RGBColor); 4] = [
        ("|F|", BLACK),
        ("Fx", X_COLOR),
        ("Fy", Y_COLOR),
        ("Fz", Z_COLOR),
    ];
    let series: Vec<_> = components
        .iter()
        .enumerate()
        .map(|(index, (name, color))| (*name, *color, data.series_points(index, |v| v)))
        .collect();
    let y_range = robust_range(series.iter().flat_map(|(_, _, p)| p.iter().map(|p| p.1)));
    let mut outliers = Vec::new();
    let series: Vec<_> = series
        .into_iter()
        .map(|(name, color, points)| {
            let (points, outside) = clamp_outliers(points, &y_range);
            outliers.extend(outside);
            (name, color, points)
        })
        .collect();
    let entries = with_marks(
        series
            .iter()
            .map(|(name, color, _)| LegendEntry::line(*name, *color))
            .collect(),
        outliers.len(),
        shaded,
    );
    let area = legend_strip(area, "Force on the device", &entries)?;
    let mut chart = ChartBuilder::on(&area)
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(64)
        .build_cartesian_2d(data.time_range(), y_range.clone())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("t (s)")
        .y_desc("force (N)")
        .label_style((FONT, 12))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    shade_periods(&mut chart, shaded, &y_range)?;
    for (name, color, points) in series {
        if name == "|F|" {
            chart.draw_series(thick_segments(points, color.stroke_width(2)))
        } else {
            chart.draw_series(LineSeries::new(points, color.stroke_width(1)))
        }
        .map_err(err)?;
    }
    chart.draw_series(outlier_markers(outliers)).map_err(err)?;
    Ok(())
}

fn draw_solver<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PlotData,
    effort: &str,
    shaded: &[ShadedPeriods],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let sweeps = data.series_points(SERIES_SWEEPS, |v| v);
    let sweep_range = robust_range(sweeps.iter().map(|p| p.1).chain([0.0]));
    let sweep_range = 0.0..sweep_range.end.max(1.0);
    let (sweeps, outliers) = clamp_outliers(sweeps, &sweep_range);
    let (low, high) = (data.bound_low, data.bound_high);
    // The bound axis is linear in log10(bound) with whole decades labelled; plotters' own log axis
    // labels too few decades to read.
    let (log_low, log_high) = if low.is_finite() {
        (
            (low.log10() - 0.3).floor(),
            (high.log10() + 0.3).ceil().max(low.log10() + 1.0),
        )
    } else {
        (-18.0, -15.0)
    };
    // Finite bounds only (ticks without a certificate are left out); 0 drawn at the bottom of the axis. The
    // logarithm keeps the order, so each bucket's minimum and maximum stay its extremes.
    let bounds = data.series_points(SERIES_BOUND, |bound| {
        if bound > 0.0 {
            bound.log10().max(log_low)
        } else {
            log_low
        }
    });

    let entries = with_marks(
        vec![
            LegendEntry::line(format!("{effort} (left)"), BLACK),
            LegendEntry::line("certificate bound (right)", BOUND_COLOR),
        ],
        outliers.len(),
        shaded,
    );
    let area = legend_strip(area, "Solver effort", &entries)?;
    let mut chart = ChartBuilder::on(&area)
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(64)
        .right_y_label_area_size(72)
        .build_cartesian_2d(data.time_range(), sweep_range.clone())
        .map_err(err)?
        .set_secondary_coord(data.time_range(), log_low..log_high);
    chart
        .configure_mesh()
        .x_desc("t (s)")
        .y_desc(format!("{effort} per tick"))
        .label_style((FONT, 12))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    chart
        .configure_secondary_axes()
        .y_desc("certificate bound (m, log)")
        .label_style((FONT, 12))
        .y_labels(((log_high - log_low) as usize + 1).min(20))
        .y_label_formatter(&decade_label)
        .draw()
        .map_err(err)?;
    shade_periods(&mut chart, shaded, &sweep_range)?;
    // The bound first, so the sweeps stay visible on top of a dense bound band.
    chart
        .draw_secondary_series(LineSeries::new(bounds, BOUND_COLOR.stroke_width(1)))
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new(sweeps, BLACK.stroke_width(1)))
        .map_err(err)?;
    chart.draw_series(outlier_markers(outliers)).map_err(err)?;
    Ok(())
}

/// Labels a log10 axis at whole decades (`-12` -> `1e-12`), leaving other ticks unlabelled.
fn decade_label(log10_value: &f64) -> String {
    let exponent = log10_value.round();
    if (log10_value - exponent).abs() < 1e-9 {
        format!("1e{exponent}")
    } else {
        String::new()
    }
}

/// Drops points closer than `min_step` to the last kept one (sub-pixel segments draw badly), keeping
/// the last point.
fn thin_path(points: Vec<(f64, f64)>, min_step: f64) -> Vec<(f64, f64)> {
    let mut kept: Vec<(f64, f64)> = Vec::with_capacity(points.len());
    let last = points.last().copied();
    for p in points {
        match kept.last() {
            Some(k) if (p.0 - k.0).hypot(p.1 - k.1) < min_step => {}
            _ => kept.push(p),
        }
    }
    if let (Some(last), Some(k)) = (last, kept.last()) {
        if *k != last {
            kept.push(last);
        }
    }
    kept
}

/// Smallest span of each path view's axes (mm): a sub-millimetre wobble is drawn as the small motion it is,
/// on readable millimetre ticks, instead of being blown up to fill the panel, where it is unreadable.
pub const MIN_PATH_SPAN_MM: f64 = 5.0;

/// `range` widened, about its centre, to at least `min_span` (a wider range is returned as it is).
fn with_min_span(range: Range<f64>, min_span: f64) -> Range<f64> {
    let span = range.end - range.start;
    if span >= min_span {
        return range;
    }
    let centre = 0.5 * (range.start + range.end);
    (centre - 0.5 * min_span)..(centre + 0.5 * min_span)
}

/// The data limits of a path view (mm), before the equal-aspect widening: robust on each axis (a far-off
/// point does not squash the rest, see [`robust_range`]) and at least [`MIN_PATH_SPAN_MM`] wide, centred on
/// the data.
fn path_data_limits(probe: &[(f64, f64)], proxy: &[(f64, f64)]) -> (Range<f64>, Range<f64>) {
    let x = robust_range(probe.iter().chain(proxy).map(|p| p.0));
    let y = robust_range(probe.iter().chain(proxy).map(|p| p.1));
    (
        with_min_span(x, MIN_PATH_SPAN_MM),
        with_min_span(y, MIN_PATH_SPAN_MM),
    )
}

/// Widens one of the ranges so that a millimetre has the same length on both axes of a plot area of
/// `width_px` by `height_px`.
fn equal_aspect(
    x: Range<f64>,
    y: Range<f64>,
    width_px: f64,
    height_px: f64,
) -> (Range<f64>, Range<f64>) {
    let mm_per_px = ((x.end - x.start) / width_px).max((y.end - y.start) / height_px);
    let grow = |r: Range<f64>, px: f64| {
        let centre = 0.5 * (r.start + r.end);
        let half = 0.5 * mm_per_px * px;
        (centre - half)..(centre + half)
    };
    (grow(x, width_px), grow(y, height_px))
}

fn draw_path<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PlotData,
    view: usize,
    caption: &str,
    vertical_label: &str,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let (probe, proxy) = data.path_points(view);
    let (x, y) = path_data_limits(&probe, &proxy);
    let off_axis = probe
        .iter()
        .chain(&proxy)
        .filter(|p| !x.contains(&p.0) || !y.contains(&p.1))
        .count();
    let entries = with_marks(
        vec![
            LegendEntry::line("probe", PROBE_COLOR),
            LegendEntry::line("proxy", PROXY_COLOR),
        ],
        off_axis,
        &[],
    );
    let area = &legend_strip(area, caption, &entries)?;
    let (width_px, height_px) = area.dim_in_pixel();
    // Plot area: the panel less the label areas and margins used below.
    let (x, y) = equal_aspect(
        x,
        y,
        f64::from(width_px.saturating_sub(64 + 16)).max(1.0),
        f64::from(height_px.saturating_sub(32 + 16 + 24)).max(1.0),
    );
    let min_step_mm =
        1.5 * (x.end - x.start) / f64::from(width_px.saturating_sub(64 + 16)).max(1.0);
    // Points off the axes are drawn on the edge (red triangles), not outside the chart.
    let clamp = |points: Points| -> (Points, Points) {
        let mut outside = Vec::new();
        let kept = points
            .into_iter()
            .map(|(a, b)| {
                let edge = (a.clamp(x.start, x.end), b.clamp(y.start, y.end));
                if edge != (a, b) {
                    outside.push(edge);
                }
                edge
            })
            .collect();
        (kept, outside)
    };
    let (probe, mut outliers) = clamp(thin_path(probe, min_step_mm));
    let (proxy, more) = clamp(thin_path(proxy, min_step_mm));
    outliers.extend(more);
    let mut chart = ChartBuilder::on(area)
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(64)
        .build_cartesian_2d(x, y)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("x (mm)")
        .y_desc(vertical_label)
        .label_style((FONT, 12))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(thick_segments(probe, PROBE_COLOR.stroke_width(3)))
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new(proxy, PROXY_COLOR.stroke_width(1)))
        .map_err(err)?;
    chart.draw_series(outlier_markers(outliers)).map_err(err)?;
    Ok(())
}

/// The time series kept per time bucket, as their minimum and maximum: |F|, Fx, Fy, Fz, sweeps, and the
/// certificate bound (finite values only, m).
const SERIES: usize = 6;
const SERIES_SWEEPS: usize = 4;
const SERIES_BOUND: usize = 5;
/// The paths kept per time bucket: (top, side) x (probe, proxy), index `2 * view + which`.
const PATHS: usize = 4;
/// Path views: the vertical axis of the top view is y, of the side view z.
const VIEW_TOP: usize = 0;
const VIEW_SIDE: usize = 1;

/// The smallest and largest value seen, each with its time: `(t_s, value)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct MinMax {
    low: (f64, f64),
    high: (f64, f64),
}

impl MinMax {
    const EMPTY: MinMax = MinMax {
        low: (0.0, f64::INFINITY),
        high: (0.0, f64::NEG_INFINITY),
    };

    fn add(&mut self, t_s: f64, value: f64) {
        if value < self.low.1 {
            self.low = (t_s, value);
        }
        if value > self.high.1 {
            self.high = (t_s, value);
        }
    }

    fn merge(&mut self, other: &MinMax) {
        if other.low.1 < self.low.1 {
            self.low = other.low;
        }
        if other.high.1 > self.high.1 {
            self.high = other.high;
        }
    }

    /// The minimum and maximum in time order (one point when they are the same sample).
    fn push_points(&self, points: &mut Points, map: impl Fn(f64) -> f64) {
        if self.low.1 > self.high.1 {
            return;
        }
        let (first, second) = if self.low.0 <= self.high.0 {
            (self.low, self.high)
        } else {
            (self.high, self.low)
        };
        points.push((first.0, map(first.1)));
        if second != first {
            points.push((second.0, map(second.1)));
        }
    }
}

/// The points of a path (mm) that reach furthest in eight directions (along the horizontal and vertical
/// axes and the two diagonals, both ways), each with its time: `(t_s, horizontal, vertical)`. The path's
/// smallest and largest coordinates are among them, and on a curve they are spread along the stretch of path
/// the bucket covers.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PathExtremes {
    /// `None` until a point is added.
    points: Option<[(f64, f64, f64); 8]>,
}

impl PathExtremes {
    const EMPTY: PathExtremes = PathExtremes { points: None };

    /// How far `point` reaches in direction `k` (0..8).
    fn reach(point: &(f64, f64, f64), k: usize) -> f64 {
        let (a, b) = (point.1, point.2);
        match k {
            0 => -a,
            1 => a,
            2 => -b,
            3 => b,
            4 => -(a + b),
            5 => a + b,
            6 => b - a,
            _ => a - b,
        }
    }

    fn add(&mut self, point: (f64, f64, f64)) {
        match &mut self.points {
            None => self.points = Some([point; 8]),
            Some(points) => {
                for (k, kept) in points.iter_mut().enumerate() {
                    if Self::reach(&point, k) > Self::reach(kept, k) {
                        *kept = point;
                    }
                }
            }
        }
    }

    fn merge(&mut self, other: &PathExtremes) {
        if let Some(points) = other.points {
            points.into_iter().for_each(|p| self.add(p));
        }
    }

    /// The distinct extreme points in time order.
    fn push_points(&self, points: &mut Points) {
        let Some(mut sorted) = self.points else {
            return;
        };
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (i, p) in sorted.iter().enumerate() {
            if i == 0 || *p != sorted[i - 1] {
                points.push((p.1, p.2));
            }
        }
    }
}

/// Equal time buckets that merge in pairs (the width doubling) when a sample falls past the last one.
#[derive(Clone, Debug)]
struct Buckets<B> {
    slots: Vec<Option<B>>,
    width_s: f64,
}

impl<B: Copy> Buckets<B> {
    fn new(capacity: usize) -> Self {
        Buckets {
            slots: vec![None; capacity.max(2) & !1],
            width_s: FIRST_BUCKET_S,
        }
    }

    /// The bucket for a sample `offset_s` (finite) after the first, merging as needed.
    fn at(&mut self, offset_s: f64, empty: B, merge: impl Fn(&mut B, &B)) -> &mut B {
        let capacity = self.slots.len();
        while offset_s / self.width_s >= capacity as f64 {
            for k in 0..capacity / 2 {
                let (a, b) = (self.slots[2 * k], self.slots[2 * k + 1]);
                self.slots[k] = match (a, b) {
                    (Some(mut a), Some(b)) => {
                        merge(&mut a, &b);
                        Some(a)
                    }
                    (a, b) => a.or(b),
                };
            }
            for slot in &mut self.slots[capacity / 2..] {
                *slot = None;
            }
            self.width_s *= 2.0;
        }
        // Before the first sample (times are not required to increase): the first bucket.
        let index = ((offset_s / self.width_s).floor().max(0.0) as usize).min(capacity - 1);
        self.slots[index].get_or_insert(empty)
    }
}

/// What one time bucket keeps of the samples in it.
#[derive(Clone, Copy, Debug)]
struct Bucket {
    series: [MinMax; SERIES],
    /// The flags of all its samples, or'ed.
    flags: u32,
}

impl Bucket {
    const EMPTY: Bucket = Bucket {
        series: [MinMax::EMPTY; SERIES],
        flags: 0,
    };

    fn merge(&mut self, other: &Bucket) {
        for (mine, theirs) in self.series.iter_mut().zip(&other.series) {
            mine.merge(theirs);
        }
        self.flags |= other.flags;
    }
}

/// What one path bucket keeps: the extreme points of each path in each view, index `2 * view + which`.
type PathBucket = [PathExtremes; PATHS];

fn merge_paths(mine: &mut PathBucket, theirs: &PathBucket) {
    for (mine, theirs) in mine.iter_mut().zip(theirs) {
        mine.merge(theirs);
    }
}

/// A trace reduced for drawing as it streams past, in memory that does not grow with its length.
///
/// Time series: the time axis is cut into at most twice as many equal buckets as the image has pixel columns,
/// and each bucket keeps the minimum and maximum of every series, each with its time; when a sample falls past
/// the last bucket, neighbouring buckets merge in pairs and the width doubles. Drawn in time order, these keep
/// the envelope of a long trace: a spike survives, a fast oscillation stays a filled band.
///
/// Paths: [`PATH_BUCKETS`] finer buckets, each keeping the points of the probe and proxy paths that reach
/// furthest in eight directions. Drawn in time order, a path is a polygon whose corners lie on it, at most a
/// bucket's stretch of path apart: a circle stays round, where every n-th sample taken near its period draws a
/// star.
///
/// The smallest and largest value of every series and path coordinate are among the kept points, so the drawn
/// extent is the data's.
#[derive(Clone, Debug)]
pub struct PlotData {
    series: Buckets<Bucket>,
    paths: Buckets<PathBucket>,
    origin_s: f64,
    samples: u64,
    untimed: u64,
    first_s: f64,
    last_s: f64,
    /// Smallest and largest positive finite certificate bound (m).
    bound_low: f64,
    bound_high: f64,
}

/// Narrowest bucket a trace starts with (s); the width doubles as the trace grows.
const FIRST_BUCKET_S: f64 = 1e-9;
/// Most path buckets (each keeps 8 points of each of the 4 paths: about 13 MiB in all).
pub const PATH_BUCKETS: usize = 16 * 1024;

impl PlotData {
    /// An empty reduction for a plot `width_px` wide.
    pub fn new(width_px: u32) -> PlotData {
        let columns = usize::try_from(width_px.clamp(200, 8192)).unwrap_or(8192);
        PlotData {
            series: Buckets::new(2 * columns),
            paths: Buckets::new(PATH_BUCKETS),
            origin_s: f64::NAN,
            samples: 0,
            untimed: 0,
            first_s: f64::INFINITY,
            last_s: f64::NEG_INFINITY,
            bound_low: f64::INFINITY,
            bound_high: 0.0,
        }
    }

    /// Samples seen.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Samples seen whose time is not finite (counted, not drawn).
    pub fn untimed_samples(&self) -> u64 {
        self.untimed
    }

    /// The earliest and latest finite time seen (s), when any.
    pub fn time_span_s(&self) -> Option<(f64, f64)> {
        (self.first_s <= self.last_s).then_some((self.first_s, self.last_s))
    }

    /// Adds one sample. A sample whose time is not finite is counted but has no place on the time axis and
    /// is not drawn.
    pub fn push(&mut self, sample: &TraceSample) {
        self.samples += 1;
        let t = sample.t_s;
        if self.origin_s.is_nan() && t.is_finite() {
            self.origin_s = t;
        }
        let offset = t - self.origin_s;
        if !offset.is_finite() {
            self.untimed += 1;
            return;
        }
        self.first_s = self.first_s.min(t);
        self.last_s = self.last_s.max(t);
        let bucket = self.series.at(offset, Bucket::EMPTY, Bucket::merge);
        let values = [
            sample.force_n.length(),
            sample.force_n.x,
            sample.force_n.y,
            sample.force_n.z,
            f64::from(sample.sweeps),
        ];
        for (series, value) in bucket.series.iter_mut().zip(values) {
            if value.is_finite() {
                series.add(t, value);
            }
        }
        let bound = sample.error_bound_m;
        if bound.is_finite() && bound >= 0.0 {
            bucket.series[SERIES_BOUND].add(t, bound);
            if bound > 0.0 {
                self.bound_low = self.bound_low.min(bound);
                self.bound_high = self.bound_high.max(bound);
            }
        }
        bucket.flags |= sample.flags;
        let paths = self
            .paths
            .at(offset, [PathExtremes::EMPTY; PATHS], merge_paths);
        for (which, position) in [sample.probe_m, sample.proxy_m].into_iter().enumerate() {
            if !position.is_finite() {
                continue;
            }
            let mm = position * 1e3;
            paths[2 * VIEW_TOP + which].add((t, mm.x, mm.y));
            paths[2 * VIEW_SIDE + which].add((t, mm.x, mm.z));
        }
    }

    fn time_range(&self) -> Range<f64> {
        match self.time_span_s() {
            Some((first, last)) if last > first => first..last,
            Some((first, _)) => first..first + 1e-3,
            None => 0.0..1.0,
        }
    }

    /// The kept points of one series, in time order, through `map`.
    fn series_points(&self, series: usize, map: impl Fn(f64) -> f64) -> Points {
        let mut points = Vec::new();
        for bucket in self.series.slots.iter().flatten() {
            bucket.series[series].push_points(&mut points, &map);
        }
        points
    }

    /// The kept points of the probe and proxy paths in one view (mm), in time order.
    fn path_points(&self, view: usize) -> (Points, Points) {
        let (mut probe, mut proxy) = (Vec::new(), Vec::new());
        for bucket in self.paths.slots.iter().flatten() {
            bucket[2 * view].push_points(&mut probe);
            bucket[2 * view + 1].push_points(&mut proxy);
        }
        (probe, proxy)
    }

    /// The time periods in which some bit of `mask` is set, at the buckets' resolution; periods closer than
    /// 1/[`MAX_SHADED_PERIODS`] of the trace are merged.
    fn flag_periods(&self, mask: u32) -> Vec<(f64, f64)> {
        let time = self.time_range();
        let merge_gap_s = (time.end - time.start) / MAX_SHADED_PERIODS as f64;
        let mut periods: Vec<(f64, f64)> = Vec::new();
        let width_s = self.series.width_s;
        for (k, bucket) in self.series.slots.iter().enumerate() {
            let Some(bucket) = bucket else { continue };
            if bucket.flags & mask == 0 {
                continue;
            }
            let start = (self.origin_s + k as f64 * width_s).clamp(time.start, time.end);
            let end = (self.origin_s + (k + 1) as f64 * width_s).clamp(time.start, time.end);
            push_period(&mut periods, (start, end), merge_gap_s.max(width_s));
        }
        periods
    }

    /// The smallest and largest value of each drawn series and path coordinate, taken from the points that
    /// are drawn (before they are clamped to the axes): `(name, min, max)`, N for forces, mm for positions.
    pub fn drawn_extents(&self) -> Vec<(&'static str, f64, f64)> {
        let extent = |values: &mut dyn Iterator<Item = f64>| {
            values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            })
        };
        let mut extents = Vec::new();
        for (index, name) in ["|F|", "Fx", "Fy", "Fz"].into_iter().enumerate() {
            let points = self.series_points(index, |v| v);
            let (lo, hi) = extent(&mut points.iter().map(|p| p.1));
            extents.push((name, lo, hi));
        }
        let (top_probe, top_proxy) = self.path_points(VIEW_TOP);
        let (side_probe, side_proxy) = self.path_points(VIEW_SIDE);
        for (name, points, vertical) in [
            ("probe x", &top_probe, false),
            ("probe y", &top_probe, true),
            ("probe z", &side_probe, true),
            ("proxy x", &top_proxy, false),
            ("proxy y", &top_proxy, true),
            ("proxy z", &side_proxy, true),
        ] {
            let (lo, hi) = extent(&mut points.iter().map(|p| if vertical { p.1 } else { p.0 }));
            extents.push((name, lo, hi));
        }
        extents
    }
}

#[cfg(test)]
#[path = "plot_tests.rs"]
mod tests;
