//! Axis limits and point thinning: robust ranges that a spike cannot squash, equal-aspect path views, and
//! the decade labels of the certificate bound's log axis.

use std::ops::Range;

/// A polyline in chart coordinates.
pub(super) type Points = Vec<(f64, f64)>;

/// An axis range for `values` that a few far-off values cannot squash: the full range padded 5 % when
/// the 0.5 %..99.5 % quantiles span at least a third of it, else those quantiles padded 5 % (the values
/// beyond are drawn on the edge, see [`clamp_outliers`]).
pub(super) fn robust_range(values: impl Iterator<Item = f64>) -> Range<f64> {
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
pub(super) fn clamp_outliers(points: Points, range: &Range<f64>) -> (Points, Points) {
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

/// A range covering `values` with 5 % padding; a unit-wide range around a constant.
pub(super) fn padded_range(values: impl Iterator<Item = f64>) -> Range<f64> {
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

/// Labels a log10 axis at whole decades (`-12` -> `1e-12`), leaving other ticks unlabelled.
pub(super) fn decade_label(log10_value: &f64) -> String {
    let exponent = log10_value.round();
    if (log10_value - exponent).abs() < 1e-9 {
        format!("1e{exponent}")
    } else {
        String::new()
    }
}

/// Drops points closer than `min_step` to the last kept one (sub-pixel segments draw badly), keeping
/// the last point.
pub(super) fn thin_path(points: Vec<(f64, f64)>, min_step: f64) -> Vec<(f64, f64)> {
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
pub(super) fn with_min_span(range: Range<f64>, min_span: f64) -> Range<f64> {
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
pub(super) fn path_data_limits(
    probe: &[(f64, f64)],
    proxy: &[(f64, f64)],
) -> (Range<f64>, Range<f64>) {
    let x = robust_range(probe.iter().chain(proxy).map(|p| p.0));
    let y = robust_range(probe.iter().chain(proxy).map(|p| p.1));
    (
        with_min_span(x, MIN_PATH_SPAN_MM),
        with_min_span(y, MIN_PATH_SPAN_MM),
    )
}

/// Widens one of the ranges so that a millimetre has the same length on both axes of a plot area of
/// `width_px` by `height_px`.
pub(super) fn equal_aspect(
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
