//! Drawing the four panels with plotters: force and solver effort over time (with shaded flag periods and
//! legends in a strip above each chart), and the top and side views of the probe and proxy paths.

use std::ops::Range;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::axes::{
    clamp_outliers, decade_label, equal_aspect, path_data_limits, robust_range, thin_path, Points,
};
use super::data::{PlotData, SERIES_BOUND, SERIES_SWEEPS, VIEW_SIDE, VIEW_TOP};
use super::layout::{panel_layout, PanelRect};
use super::style::*;
use crate::trace::Trace;

/// What drawing a panel returns: plotters' error for the backend, kept typed until [`super::plot_data`]
/// names the output file.
pub(super) type DrawResult<DB> =
    Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

pub(super) fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    data: &PlotData,
    effort: &str,
    title: &str,
) -> DrawResult<DB>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (width_px, height_px) = root.dim_in_pixel();
    let [force, solver, top, side] = panel_layout(width_px, height_px);
    root.draw(&Text::new(
        title.to_string(),
        (12, 8),
        (FONT, 20).into_font().color(&BLACK),
    ))?;
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

/// What the solver panel counts: the exact solver's block sweeps, or the baselines' iterations.
pub(super) fn effort_name(trace: &Trace) -> &'static str {
    match trace.sidecar.as_ref().map(|s| s.meta.solver.as_str()) {
        // `exact`, `exact-dual`; `euler-baseline`, `constraint-baseline` (and their short names).
        Some(solver) if solver.starts_with("exact") => "sweeps",
        Some(solver) if solver.starts_with("euler") || solver.starts_with("constraint") => {
            "iterations"
        }
        _ => "sweeps or iterations",
    }
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
) -> Result<DrawingArea<DB, Shift>, DrawingAreaErrorKind<DB::ErrorType>>
where
    DB::ErrorType: 'static,
{
    let (strip, chart) = area.split_vertically(LEGEND_PX);
    let caption_font = (FONT, 16).into_font().color(&BLACK);
    strip.draw(&Text::new(
        caption.to_string(),
        (10, 3),
        caption_font.clone(),
    ))?;
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
            strip.draw(&Rectangle::new(
                [(x, y - 6), (x + 18, y + 6)],
                entry.color.filled(),
            ))?;
        } else {
            strip.draw(&PathElement::new(
                vec![(x, y), (x + 18, y)],
                entry.color.stroke_width(2),
            ))?;
        }
        strip.draw(&Text::new(
            entry.text.clone(),
            (x + 24, y - 7),
            label_font.clone(),
        ))?;
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
) -> DrawResult<DB>
where
    DB::ErrorType: 'static,
{
    for kind in shaded {
        let style = kind.color.mix(0.45).filled();
        chart.draw_series(
            kind.periods
                .iter()
                .map(|&(t0, t1)| Rectangle::new([(t0, y.start), (t1, y.end)], style)),
        )?;
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
) -> DrawResult<DB>
where
    DB::ErrorType: 'static,
{
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
    let mut chart = chart_on(&area).build_cartesian_2d(data.time_range(), y_range.clone())?;
    draw_mesh(&mut chart, "t (s)", "force (N)")?;
    shade_periods(&mut chart, shaded, &y_range)?;
    for (name, color, points) in series {
        if name == "|F|" {
            chart.draw_series(thick_segments(points, color.stroke_width(2)))
        } else {
            chart.draw_series(LineSeries::new(points, color.stroke_width(1)))
        }?;
    }
    chart.draw_series(outlier_markers(outliers))?;
    Ok(())
}

fn draw_solver<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PlotData,
    effort: &str,
    shaded: &[ShadedPeriods],
) -> DrawResult<DB>
where
    DB::ErrorType: 'static,
{
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
    let mut chart = chart_on(&area)
        .right_y_label_area_size(72)
        .build_cartesian_2d(data.time_range(), sweep_range.clone())?
        .set_secondary_coord(data.time_range(), log_low..log_high);
    draw_mesh(&mut chart, "t (s)", &format!("{effort} per tick"))?;
    chart
        .configure_secondary_axes()
        .y_desc("certificate bound (m, log)")
        .label_style((FONT, 12))
        .y_labels(((log_high - log_low) as usize + 1).min(20))
        .y_label_formatter(&decade_label)
        .draw()?;
    shade_periods(&mut chart, shaded, &sweep_range)?;
    // The bound first, so the sweeps stay visible on top of a dense bound band.
    chart.draw_secondary_series(LineSeries::new(bounds, BOUND_COLOR.stroke_width(1)))?;
    chart.draw_series(LineSeries::new(sweeps, BLACK.stroke_width(1)))?;
    chart.draw_series(outlier_markers(outliers))?;
    Ok(())
}

fn draw_path<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PlotData,
    view: usize,
    caption: &str,
    vertical_label: &str,
) -> DrawResult<DB>
where
    DB::ErrorType: 'static,
{
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
    let mut chart = chart_on(area).build_cartesian_2d(x, y)?;
    draw_mesh(&mut chart, "x (mm)", vertical_label)?;
    chart.draw_series(thick_segments(probe, PROBE_COLOR.stroke_width(3)))?;
    chart.draw_series(LineSeries::new(proxy, PROXY_COLOR.stroke_width(1)))?;
    chart.draw_series(outlier_markers(outliers))?;
    Ok(())
}

/// A chart builder on `area` with the panels' margin and room for the axis labels.
fn chart_on<'a, 'b, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
) -> ChartBuilder<'a, 'b, DB> {
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(64);
    builder
}

/// Draws `chart`'s axes, labelled `x_desc` and `y_desc`, in the panels' style (no light grid lines).
fn draw_mesh<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    x_desc: &str,
    y_desc: &str,
) -> DrawResult<DB>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 12))
        .light_line_style(WHITE.mix(0.0))
        .draw()
}
