//! The trace reduced for drawing as it streams past ([`PlotData`]): min/max time buckets and path extremes,
//! in memory that does not grow with the trace's length.

use std::ops::Range;

use super::axes::Points;
use super::style::MAX_SHADED_PERIODS;
use crate::sample::TraceSample;

/// The time series kept per time bucket, as their minimum and maximum: |F|, Fx, Fy, Fz, sweeps, and the
/// certificate bound (finite values only, m).
pub(super) const SERIES: usize = 6;
pub(super) const SERIES_SWEEPS: usize = 4;
pub(super) const SERIES_BOUND: usize = 5;
/// The paths kept per time bucket: (top, side) x (probe, proxy), index `2 * view + which`.
const PATHS: usize = 4;
/// Path views: the vertical axis of the top view is y, of the side view z.
pub(super) const VIEW_TOP: usize = 0;
pub(super) const VIEW_SIDE: usize = 1;

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
pub(super) struct Buckets<B> {
    slots: Vec<Option<B>>,
    pub(super) width_s: f64,
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
pub(super) struct Bucket {
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
    pub(super) series: Buckets<Bucket>,
    paths: Buckets<PathBucket>,
    origin_s: f64,
    samples: u64,
    untimed: u64,
    first_s: f64,
    last_s: f64,
    /// Smallest and largest positive finite certificate bound (m).
    pub(super) bound_low: f64,
    pub(super) bound_high: f64,
    /// The width of the plot the series were reduced for (px), as asked; [`super::plot_data`] draws at it.
    width_px: u32,
}

/// Narrowest bucket a trace starts with (s); the width doubles as the trace grows.
const FIRST_BUCKET_S: f64 = 1e-9;
/// Most path buckets (each keeps 8 points of each of the 4 paths: about 13 MiB in all).
pub const PATH_BUCKETS: usize = 16 * 1024;

impl PlotData {
    /// An empty reduction for a plot `width_px` wide ([`super::plot_data`] draws it at this width).
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
            width_px,
        }
    }

    /// The width of the plot this reduction is for (px), as given to [`PlotData::new`].
    pub fn width_px(&self) -> u32 {
        self.width_px
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
            sample.sent_force_n.length(),
            sample.sent_force_n.x,
            sample.sent_force_n.y,
            sample.sent_force_n.z,
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

    pub(super) fn time_range(&self) -> Range<f64> {
        match self.time_span_s() {
            Some((first, last)) if last > first => first..last,
            Some((first, _)) => first..first + 1e-3,
            None => 0.0..1.0,
        }
    }

    /// The kept points of one series, in time order, through `map`.
    pub(super) fn series_points(&self, series: usize, map: impl Fn(f64) -> f64) -> Points {
        let mut points = Vec::new();
        for bucket in self.series.slots.iter().flatten() {
            bucket.series[series].push_points(&mut points, &map);
        }
        points
    }

    /// The kept points of the probe and proxy paths in one view (mm), in time order.
    pub(super) fn path_points(&self, view: usize) -> (Points, Points) {
        let (mut probe, mut proxy) = (Vec::new(), Vec::new());
        for bucket in self.paths.slots.iter().flatten() {
            bucket[2 * view].push_points(&mut probe);
            bucket[2 * view + 1].push_points(&mut proxy);
        }
        (probe, proxy)
    }

    /// The time periods in which some bit of `mask` is set, at the buckets' resolution; periods closer than
    /// 1/[`MAX_SHADED_PERIODS`] of the trace are merged.
    pub(super) fn flag_periods(&self, mask: u32) -> Vec<(f64, f64)> {
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

fn push_period(periods: &mut Vec<(f64, f64)>, period: (f64, f64), merge_gap_s: f64) {
    match periods.last_mut() {
        Some(last) if period.0 - last.1 <= merge_gap_s => last.1 = period.1,
        _ => periods.push(period),
    }
}
