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

use super::{Trace, TraceSample};

/// Most time buckets (each drawn as its min and max) per time series.
pub const MAX_BUCKETS: usize = 2000;
/// Most points per drawn path.
pub const MAX_PATH_POINTS: usize = 4000;

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
        super::FLAG_FORCE_LIMITED_BY_SAFETY,
        "force held back (ramp-in, engage, slew)",
        SAFETY_SHADE,
    ),
    (
        super::FLAG_DEVICE_DISCONNECTED
            | super::FLAG_DEVICE_NOT_ENABLED
            | super::FLAG_DEVICE_FAULTED
            | super::FLAG_STALE_STATE,
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
    if !PLOT_WIDTH_PX.contains(&width_px) || !PLOT_HEIGHT_PX.contains(&height_px) {
        return Err(PlotError::TooSmall {
            width_px,
            height_px,
        });
    }
    if trace.samples.is_empty() {
        return Err(PlotError::EmptyTrace);
    }
    register_font()?;
    let extension = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let drawing_error = |message: String| PlotError::Drawing {
        path: out.to_path_buf(),
        message,
    };
    match extension.as_deref() {
        Some("png") => {
            let root = BitMapBackend::new(out, (width_px, height_px)).into_drawing_area();
            draw(&root, trace, title).map_err(drawing_error)?;
            root.present().map_err(|e| drawing_error(e.to_string()))
        }
        Some("svg") => {
            let root = SVGBackend::new(out, (width_px, height_px)).into_drawing_area();
            draw(&root, trace, title).map_err(drawing_error)?;
            root.present().map_err(|e| drawing_error(e.to_string()))
        }
        _ => Err(PlotError::UnsupportedFormat(out.to_path_buf())),
    }
}

type DrawResult = Result<(), String>;
/// A polyline in chart coordinates.
type Points = Vec<(f64, f64)>;
/// A force series: legend name, colour and the value it plots.
type ForceSeries = (&'static str, RGBColor, fn(&TraceSample) -> f64);

fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, trace: &Trace, title: &str) -> DrawResult
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
            periods: flag_periods(&trace.samples, mask),
        })
        .filter(|s| !s.periods.is_empty())
        .collect();
    draw_force(&area(force), &trace.samples, &shaded)?;
    draw_solver(&area(solver), &trace.samples, effort_name(trace), &shaded)?;
    draw_path(
        &area(top),
        &trace.samples,
        "Top view (x-y)",
        "y (mm)",
        |v| v.y,
    )?;
    draw_path(
        &area(side),
        &trace.samples,
        "Side view (x-z)",
        "z (mm)",
        |v| v.z,
    )?;
    Ok(())
}

/// Min and max of `value` in each of at most `MAX_BUCKETS` equal-count buckets, in time order.
fn envelope(samples: &[TraceSample], value: impl Fn(&TraceSample) -> f64) -> Vec<(f64, f64)> {
    let bucket = samples.len().div_ceil(MAX_BUCKETS).max(1);
    let mut points = Vec::with_capacity(2 * samples.len().min(MAX_BUCKETS) + 2);
    for chunk in samples.chunks(bucket) {
        if bucket == 1 {
            points.push((chunk[0].t_s, value(&chunk[0])));
            continue;
        }
        let (mut low, mut high) = (&chunk[0], &chunk[0]);
        for s in chunk {
            if value(s) < value(low) {
                low = s;
            }
            if value(s) > value(high) {
                high = s;
            }
        }
        let (first, second) = if low.t_s <= high.t_s {
            (low, high)
        } else {
            (high, low)
        };
        points.push((first.t_s, value(first)));
        points.push((second.t_s, value(second)));
    }
    points
}

/// Periods (start, end time in s) of a flag kind, for shading.
struct ShadedPeriods {
    name: &'static str,
    color: RGBColor,
    periods: Vec<(f64, f64)>,
}

/// The time periods in which some bit of `mask` is set: from the first flagged sample to the next
/// unflagged one (or the last sample). Periods closer than 1/`MAX_SHADED_PERIODS` of the trace are merged so
/// at most about `MAX_SHADED_PERIODS` are drawn.
fn flag_periods(samples: &[TraceSample], mask: u32) -> Vec<(f64, f64)> {
    let time = time_range(samples);
    let merge_gap_s = (time.end - time.start) / MAX_SHADED_PERIODS as f64;
    let mut periods: Vec<(f64, f64)> = Vec::new();
    let mut open: Option<f64> = None;
    for sample in samples {
        let flagged = sample.flags & mask != 0;
        match (open, flagged) {
            (None, true) => open = Some(sample.t_s),
            (Some(start), false) => {
                push_period(&mut periods, (start, sample.t_s), merge_gap_s);
                open = None;
            }
            _ => {}
        }
    }
    if let (Some(start), Some(last)) = (open, samples.last()) {
        push_period(&mut periods, (start, last.t_s), merge_gap_s);
    }
    periods
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

fn time_range(samples: &[TraceSample]) -> Range<f64> {
    let first = samples.first().map_or(0.0, |s| s.t_s);
    let last = samples.last().map_or(1.0, |s| s.t_s);
    if last > first {
        first..last
    } else {
        first..first + 1e-3
    }
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
    samples: &[TraceSample],
    shaded: &[ShadedPeriods],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let components: [ForceSeries; 4] = [
        ("|F|", BLACK, |s| s.force_n.length()),
        ("Fx", X_COLOR, |s| s.force_n.x),
        ("Fy", Y_COLOR, |s| s.force_n.y),
        ("Fz", Z_COLOR, |s| s.force_n.z),
    ];
    let series: Vec<_> = components
        .iter()
        .map(|(name, color, f)| (*name, *color, envelope(samples, f)))
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
        .build_cartesian_2d(time_range(samples), y_range.clone())
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
    samples: &[TraceSample],
    effort: &str,
    shaded: &[ShadedPeriods],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let sweeps = envelope(samples, |s| f64::from(s.sweeps));
    let sweep_range = robust_range(sweeps.iter().map(|p| p.1).chain([0.0]));
    let sweep_range = 0.0..sweep_range.end.max(1.0);
    let (sweeps, outliers) = clamp_outliers(sweeps, &sweep_range);
    let positive_bounds = samples
        .iter()
        .map(|s| s.error_bound_m)
        .filter(|b| b.is_finite() && *b > 0.0);
    let (low, high) = positive_bounds.fold((f64::INFINITY, 0.0f64), |(lo, hi), b| {
        (lo.min(b), hi.max(b))
    });
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
    // Finite bounds only; 0 drawn at the bottom of the axis.
    let finite: Vec<TraceSample> = samples
        .iter()
        .filter(|s| s.error_bound_m.is_finite())
        .copied()
        .collect();
    let bounds = envelope(&finite, |s| {
        if s.error_bound_m > 0.0 {
            s.error_bound_m.log10().max(log_low)
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
        .build_cartesian_2d(time_range(samples), sweep_range.clone())
        .map_err(err)?
        .set_secondary_coord(time_range(samples), log_low..log_high);
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

/// Every n-th point of the probe and proxy paths in mm, at most `MAX_PATH_POINTS` each.
fn path_points(samples: &[TraceSample], vertical: impl Fn(glam::DVec3) -> f64) -> (Points, Points) {
    let stride = samples.len().div_ceil(MAX_PATH_POINTS).max(1);
    let pick = |v: glam::DVec3| (v.x * 1e3, vertical(v) * 1e3);
    let mut probe: Vec<_> = samples
        .iter()
        .step_by(stride)
        .map(|s| pick(s.probe_m))
        .collect();
    let mut proxy: Vec<_> = samples
        .iter()
        .step_by(stride)
        .map(|s| pick(s.proxy_m))
        .collect();
    if let Some(last) = samples.last() {
        probe.push(pick(last.probe_m));
        proxy.push(pick(last.proxy_m));
    }
    (probe, proxy)
}

/// Smallest span of each path view's axes (mm): a sub-millimetre wobble is drawn as the small motion it is,
/// on readable millimetre ticks, instead of being blown up to fill the panel (issue 17: "the side view is
/// unreadable for small motions").
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
    samples: &[TraceSample],
    caption: &str,
    vertical_label: &str,
    vertical: impl Fn(glam::DVec3) -> f64,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let (probe, proxy) = path_points(samples, vertical);
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

#[cfg(test)]
mod tests {
    use super::super::test_support::samples;
    use super::*;

    fn trace(count: u64) -> Trace {
        Trace {
            mode_names: vec!["surface".into()],
            samples: samples(count, 1),
            sidecar: None,
            warnings: Vec::new(),
        }
    }

    #[test]
    fn png_has_the_right_size_and_ink_in_every_panel() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("plot.png");
        plot_trace(&trace(3000), "unit test", &out, 1000, 900).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()));
        let mut reader = decoder.read_info().expect("a valid PNG");
        let mut pixels = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut pixels).expect("a decodable PNG");
        assert_eq!((info.width, info.height), (1000, 900));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        let stride = info.line_size;
        for (i, panel) in panel_layout(1000, 900).iter().enumerate() {
            let mut coloured = 0;
            for y in panel.y0..panel.y1 {
                for x in panel.x0..panel.x1 {
                    let at = y as usize * stride + x as usize * 3;
                    let [r, g, b] = [pixels[at], pixels[at + 1], pixels[at + 2]];
                    // Series colours (not white, not grey axes and text).
                    if r.abs_diff(g) > 40 || g.abs_diff(b) > 40 || r.abs_diff(b) > 40 {
                        coloured += 1;
                    }
                }
            }
            assert!(
                coloured > 200,
                "panel {i} has only {coloured} coloured pixels"
            );
        }
    }

    #[test]
    fn svg_output_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("plot.svg");
        plot_trace(&trace(50), "svg", &out, 800, 600).unwrap();
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(text.starts_with("<svg") && text.contains("Solver effort"));
        let bad = dir.path().join("plot.jpg");
        assert!(matches!(
            plot_trace(&trace(5), "", &bad, 800, 600),
            Err(PlotError::UnsupportedFormat(_))
        ));
        assert!(matches!(
            plot_trace(&trace(0), "", &out, 800, 600),
            Err(PlotError::EmptyTrace)
        ));
        assert!(matches!(
            plot_trace(&trace(5), "", &out, 10, 10),
            Err(PlotError::TooSmall { .. })
        ));
    }

    #[test]
    fn degenerate_traces_still_plot() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("d.png");
        // One sample; all zero; no certificates at all; a huge jump.
        plot_trace(&trace(1), "one", &out, 640, 480).unwrap();
        let mut zeros = trace(20);
        for s in &mut zeros.samples {
            *s = TraceSample {
                tick: s.tick,
                t_s: s.t_s,
                ..TraceSample::zeroed(1)
            };
        }
        plot_trace(&zeros, "zeros", &out, 640, 480).unwrap();
        let mut no_bounds = trace(20);
        for s in &mut no_bounds.samples {
            s.error_bound_m = f64::INFINITY;
        }
        plot_trace(&no_bounds, "inf", &out, 640, 480).unwrap();
        let mut jump = trace(20);
        jump.samples[10].probe_m.x = 1e6;
        jump.samples[11].force_n.z = -1e9;
        plot_trace(&jump, "jump", &out, 640, 480).unwrap();
    }

    #[test]
    fn the_effort_is_named_by_solver() {
        let mut traced = trace(5);
        assert_eq!(effort_name(&traced), "sweeps or iterations");
        for (solver, name) in [
            ("exact", "sweeps"),
            ("exact-dual", "sweeps"),
            ("euler-baseline", "iterations"),
            ("constraint-baseline", "iterations"),
        ] {
            let meta = crate::record::TraceMeta::new(
                vec!["surface".into()],
                1000.0,
                serde_json::Value::Null,
                "v",
                solver,
            );
            let sidecar = crate::record::Sidecar::new(
                &meta,
                crate::record::TraceFormat::Csv,
                Path::new("t.csv"),
            );
            traced.sidecar = Some(sidecar);
            assert_eq!(effort_name(&traced), name, "{solver}");
        }
    }

    #[test]
    fn one_spike_does_not_squash_the_axis_and_is_marked() {
        let values: Vec<f64> = (0..1000).map(|i| f64::from(i % 10) * 0.1).collect();
        let mut spiked = values.clone();
        spiked[500] = 1e6;
        let range = robust_range(spiked.iter().copied());
        assert!(range.end < 2.0 && range.start < 0.0, "{range:?}");
        // Spread-out data keeps its full range.
        assert_eq!(
            robust_range(values.iter().copied()),
            padded_range(values.iter().copied())
        );
        let points: Points = spiked
            .iter()
            .enumerate()
            .map(|(i, &v)| (i as f64, v))
            .collect();
        let (clamped, outside) = clamp_outliers(points, &range);
        assert_eq!(outside, vec![(500.0, range.end)]);
        assert!(clamped
            .iter()
            .all(|p| range.contains(&p.1) || p.1 == range.end));
    }

    #[test]
    fn flagged_periods_are_found_and_merged() {
        let mut data = samples(1000, 1);
        for (i, s) in data.iter_mut().enumerate() {
            s.flags = 0;
            if (100..200).contains(&i) || (600..610).contains(&i) || i >= 990 {
                s.flags = crate::record::FLAG_FORCE_LIMITED_BY_SAFETY;
            }
        }
        let t = |i: usize| data[i].t_s;
        let periods = flag_periods(&data, crate::record::FLAG_FORCE_LIMITED_BY_SAFETY);
        assert_eq!(
            periods,
            vec![(t(100), t(200)), (t(600), t(610)), (t(990), t(999))]
        );
        assert!(flag_periods(&data, crate::record::FLAG_DEVICE_DISCONNECTED).is_empty());
        // Flicker every other tick merges into one period.
        for (i, s) in data.iter_mut().enumerate() {
            s.flags = if i % 2 == 0 {
                crate::record::FLAG_DEVICE_DISCONNECTED
            } else {
                0
            };
        }
        assert_eq!(
            flag_periods(&data, crate::record::FLAG_DEVICE_DISCONNECTED).len(),
            1
        );
    }

    #[test]
    fn svg_names_the_effort_shades_flags_and_counts_outliers() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("flags.svg");
        let mut spiky = trace(2000);
        for (i, s) in spiky.samples.iter_mut().enumerate() {
            s.flags = if i < 300 {
                crate::record::FLAG_FORCE_LIMITED_BY_SAFETY
            } else {
                0
            };
        }
        spiky.samples[1500].force_n.z = 1e4;
        plot_trace(&spiky, "flags", &out, 1200, 900).unwrap();
        let text = std::fs::read_to_string(&out).unwrap();
        for expected in [
            "sweeps or iterations per tick",
            "force held back (ramp-in, engage, slew)",
            "off the axis",
        ] {
            assert!(text.contains(expected), "the SVG lacks {expected:?}");
        }
        assert!(
            !text.contains("device away"),
            "no device flags in this trace"
        );
    }

    #[test]
    fn envelope_keeps_spikes_and_time_order() {
        let mut data = samples(10_000, 1);
        data[5_555].force_n.x = 99.0;
        let points = envelope(&data, |s| s.force_n.x);
        assert!(points.len() <= 2 * MAX_BUCKETS);
        assert!(points.iter().any(|p| p.1 == 99.0));
        assert!(points.windows(2).all(|w| w[0].0 <= w[1].0));
    }

    #[test]
    fn decade_labels_and_path_thinning() {
        assert_eq!(decade_label(&-12.0), "1e-12");
        assert_eq!(decade_label(&-11.5), "");
        let points: Vec<(f64, f64)> = (0..100).map(|i| (f64::from(i) * 0.1, 0.0)).collect();
        let thinned = thin_path(points, 1.0);
        assert!(thinned.len() <= 12, "{}", thinned.len());
        assert_eq!(thinned.last(), Some(&(9.9, 0.0)));
        assert!(thinned.windows(2).all(|w| w[1].0 > w[0].0));
    }

    #[test]
    fn sub_millimetre_motion_gets_readable_path_limits() {
        // The probe wobbles 0.2 mm round (12.3, -4.5, 30.0) mm, the proxy 0.05 mm above it: both views'
        // axes span MIN_PATH_SPAN_MM, centred on the data, instead of the 0.4 mm the data covers.
        let mut wobble = trace(2000);
        for (i, s) in wobble.samples.iter_mut().enumerate() {
            let a = i as f64 * 0.01;
            s.probe_m = glam::DVec3::new(
                12.3e-3 + 0.2e-3 * a.cos(),
                -4.5e-3 + 0.2e-3 * a.sin(),
                30.0e-3 + 0.1e-3 * (2.0 * a).sin(),
            );
            s.proxy_m = s.probe_m + glam::DVec3::new(0.0, 0.0, 0.05e-3);
        }
        let centre = |r: &Range<f64>| 0.5 * (r.start + r.end);
        let span = |r: &Range<f64>| r.end - r.start;
        for (name, vertical, expected_vertical_centre) in [
            (
                "top",
                (|v: glam::DVec3| v.y) as fn(glam::DVec3) -> f64,
                -4.5,
            ),
            ("side", |v: glam::DVec3| v.z, 30.025),
        ] {
            let (probe, proxy) = path_points(&wobble.samples, vertical);
            let (x, y) = path_data_limits(&probe, &proxy);
            assert!(
                (span(&x) - MIN_PATH_SPAN_MM).abs() < 1e-9,
                "{name}: x {x:?}"
            );
            assert!(
                (span(&y) - MIN_PATH_SPAN_MM).abs() < 1e-9,
                "{name}: y {y:?}"
            );
            assert!((centre(&x) - 12.3).abs() < 0.01, "{name}: x {x:?}");
            assert!(
                (centre(&y) - expected_vertical_centre).abs() < 0.01,
                "{name}: y {y:?}"
            );
            for p in probe.iter().chain(&proxy) {
                assert!(
                    x.contains(&p.0) && y.contains(&p.1),
                    "{name}: {p:?} off the axes"
                );
            }
        }
        // A path wider than the minimum keeps its own (robust, padded) limits.
        let wide = vec![(0.0, 0.0), (40.0, 20.0)];
        let (x, y) = path_data_limits(&wide, &wide);
        assert!(
            (x.start + 2.0).abs() < 1e-9 && (x.end - 42.0).abs() < 1e-9,
            "{x:?}"
        );
        assert!(
            (y.start + 1.0).abs() < 1e-9 && (y.end - 21.0).abs() < 1e-9,
            "{y:?}"
        );
        // Drawing the sub-millimetre trace works.
        let dir = tempfile::tempdir().unwrap();
        plot_trace(&wobble, "wobble", &dir.path().join("w.svg"), 800, 600).unwrap();
    }

    #[test]
    fn equal_aspect_gives_equal_scales() {
        let (x, y) = equal_aspect(0.0..10.0, 0.0..1.0, 400.0, 200.0);
        let x_scale = (x.end - x.start) / 400.0;
        let y_scale = (y.end - y.start) / 200.0;
        assert!((x_scale - y_scale).abs() < 1e-12);
        assert!(x.start <= 0.0 && x.end >= 10.0 && y.start <= 0.0 && y.end >= 1.0);
    }
}
