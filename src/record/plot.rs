//! Plots of a force trace (`voxhap plot`): what the user felt, where the probe and proxy went, and how
//! hard the solver worked.
//!
//! Downstream of the recorder in the data flow: it reads a finished trace ([`Trace`]) and draws four
//! panels with `plotters` into a PNG or SVG file:
//!
//! 1. force over time: magnitude and x, y, z components (N);
//! 2. solver effort over time: sweeps per tick (left axis, linear) and the certificate bound (right axis,
//!    log scale, m), as in the paper's Figure 7; ticks without a certificate (`inf`) are left out and a
//!    bound of exactly 0 is drawn at the bottom of the axis;
//! 3. top view (x-y) and 4. side view (x-z) of the probe and proxy paths (mm), with equal scales on both
//!    axes so shapes are not distorted.
//!
//! Long traces are thinned for drawing: time series keep the minimum and maximum of each of at most
//! [`MAX_BUCKETS`] time buckets (so spikes survive), paths keep every n-th point and drop sub-pixel
//! steps. Text uses DejaVu Sans embedded in the binary (the `dejavu` crate; licence in
//! `assets/fonts/DejaVu-LICENSE.txt`), so no system font library is needed.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

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
    draw_force(&area(force), &trace.samples)?;
    draw_solver(&area(solver), &trace.samples)?;
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

fn legend_line(color: RGBColor) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
}

fn draw_force<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    samples: &[TraceSample],
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
    let y_range = padded_range(series.iter().flat_map(|(_, _, p)| p.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(area)
        .caption("Force on the device", (FONT, 16))
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(64)
        .build_cartesian_2d(time_range(samples), y_range)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("t (s)")
        .y_desc("force (N)")
        .label_style((FONT, 12))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(err)?;
    for (name, color, points) in series {
        let drawn = if name == "|F|" {
            chart.draw_series(thick_segments(points, color.stroke_width(2)))
        } else {
            chart.draw_series(LineSeries::new(points, color.stroke_width(1)))
        };
        drawn.map_err(err)?.label(name).legend(legend_line(color));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, 12))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()
        .map_err(err)
}

fn draw_solver<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    samples: &[TraceSample],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let sweeps = envelope(samples, |s| f64::from(s.sweeps));
    let max_sweeps = sweeps.iter().map(|p| p.1).fold(0.0, f64::max).max(1.0);
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

    let mut chart = ChartBuilder::on(area)
        .caption("Solver effort", (FONT, 16))
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(64)
        .right_y_label_area_size(72)
        .build_cartesian_2d(time_range(samples), 0.0..max_sweeps * 1.1)
        .map_err(err)?
        .set_secondary_coord(time_range(samples), log_low..log_high);
    chart
        .configure_mesh()
        .x_desc("t (s)")
        .y_desc("sweeps per tick")
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
    // The bound first, so the sweeps stay visible on top of a dense bound band.
    chart
        .draw_secondary_series(LineSeries::new(bounds, BOUND_COLOR.stroke_width(1)))
        .map_err(err)?
        .label("error bound (right)")
        .legend(legend_line(BOUND_COLOR));
    chart
        .draw_series(LineSeries::new(sweeps, BLACK.stroke_width(1)))
        .map_err(err)?
        .label("sweeps")
        .legend(legend_line(BLACK));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, 12))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()
        .map_err(err)
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
    let x = padded_range(probe.iter().chain(&proxy).map(|p| p.0));
    let y = padded_range(probe.iter().chain(&proxy).map(|p| p.1));
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
    let probe = thin_path(probe, min_step_mm);
    let proxy = thin_path(proxy, min_step_mm);
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, 16))
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
        .map_err(err)?
        .label("probe")
        .legend(legend_line(PROBE_COLOR));
    chart
        .draw_series(LineSeries::new(proxy, PROXY_COLOR.stroke_width(1)))
        .map_err(err)?
        .label("proxy")
        .legend(legend_line(PROXY_COLOR));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, 12))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()
        .map_err(err)
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
    fn equal_aspect_gives_equal_scales() {
        let (x, y) = equal_aspect(0.0..10.0, 0.0..1.0, 400.0, 200.0);
        let x_scale = (x.end - x.start) / 400.0;
        let y_scale = (y.end - y.start) / 200.0;
        assert!((x_scale - y_scale).abs() < 1e-12);
        assert!(x.start <= 0.0 && x.end >= 10.0 && y.start <= 0.0 && y.end >= 1.0);
    }
}
