//! Value statistics for choosing a surface level in a scan: exact percentiles, an equal-width histogram, and
//! Otsu's threshold, the level that best separates a volume's values into two classes (background and tissue).
//!
//! Definitions, so figures can be checked against other tools:
//! - **Percentiles** are nearest-rank: the value at index `round(p / 100 · (n − 1))` of the sorted values, ties
//!   rounded to even (NumPy's `np.percentile(x, p, method="nearest")`).
//! - **Histogram** bins split `[min, max]` into equal widths; a value on an inner edge belongs to the bin above,
//!   the maximum to the last bin (NumPy's `np.histogram(x, bins, range=(min, max))`).
//! - **Otsu's threshold** (N. Otsu, "A threshold selection method from gray-level histograms", IEEE Trans.
//!   SMC 9 (1979) 62-66) over [`OTSU_BINS`] bins: the bin centre `t` that maximises the between-class variance
//!   `w0 w1 (m0 − m1)²` of the classes `value ≤ t` and `value > t`, each class's mean taken over bin centres
//!   (scikit-image's `skimage.filters.threshold_otsu` with its default 256 bins).
//!
//! For a vector volume every figure is of the vectors' magnitudes. Computing the levels copies the values once
//! (percentiles need them sorted); nothing here runs on the servo thread.

use super::AnyVolume;

/// The percentiles `voxhap info` reports.
pub const PERCENTILES: [f64; 7] = [1.0, 5.0, 25.0, 50.0, 75.0, 95.0, 99.0];

/// Bins of the histogram Otsu's threshold is computed on.
pub const OTSU_BINS: usize = 256;

/// An equal-width histogram of values over `[edges[0], edges[bins]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Histogram {
    /// `bins + 1` edges, from the smallest value to the largest.
    pub edges: Vec<f64>,
    /// Values per bin.
    pub counts: Vec<u64>,
}

impl Histogram {
    /// Counts `values` into `bins` equal bins over `[min, max]` (all in one bin when `min == max`). Values
    /// outside `[min, max]` and non-finite values are not counted.
    pub fn new(
        values: impl IntoIterator<Item = f32>,
        min: f32,
        max: f32,
        bins: usize,
    ) -> Histogram {
        let (min, max) = (f64::from(min), f64::from(max));
        let bins = bins.max(1);
        let width = max - min;
        let edges: Vec<f64> = (0..=bins)
            .map(|k| {
                if k == bins {
                    max
                } else {
                    min + width * k as f64 / bins as f64
                }
            })
            .collect();
        let mut counts = vec![0u64; bins];
        for value in values {
            let x = f64::from(value);
            if !(min..=max).contains(&x) {
                continue;
            }
            counts[bin_of(x, &edges)] += 1;
        }
        Histogram { edges, counts }
    }

    /// The number of bins.
    pub fn bins(&self) -> usize {
        self.counts.len()
    }

    /// The centre of bin `i`.
    pub fn centre(&self, i: usize) -> f64 {
        0.5 * (self.edges[i] + self.edges[i + 1])
    }
}

/// The bin of `x` (within `[edges[0], edges[last]]`): the first estimate from the bin width, corrected
/// against the edges themselves so rounding never puts a value on the wrong side of an edge.
fn bin_of(x: f64, edges: &[f64]) -> usize {
    let bins = edges.len() - 1;
    let (min, max) = (edges[0], edges[bins]);
    if max <= min {
        return 0;
    }
    let mut i = (((x - min) / (max - min)) * bins as f64) as usize;
    i = i.min(bins - 1);
    if x < edges[i] && i > 0 {
        i -= 1;
    } else if i + 1 < bins && x >= edges[i + 1] {
        i += 1;
    }
    i
}

/// Otsu's threshold of a histogram: the centre of the bin that ends the lower class. `None` when the
/// histogram has fewer than two bins or fewer than two occupied bins (a constant volume has no threshold).
pub fn otsu_threshold(histogram: &Histogram) -> Option<f64> {
    let bins = histogram.bins();
    if bins < 2 || histogram.counts.iter().filter(|&&c| c > 0).count() < 2 {
        return None;
    }
    let total: f64 = histogram.counts.iter().map(|&c| c as f64).sum();
    let weighted_total: f64 = (0..bins)
        .map(|i| histogram.counts[i] as f64 * histogram.centre(i))
        .sum();
    let (mut w0, mut s0) = (0.0f64, 0.0f64);
    let mut best: Option<(f64, usize)> = None;
    for i in 0..bins - 1 {
        w0 += histogram.counts[i] as f64;
        s0 += histogram.counts[i] as f64 * histogram.centre(i);
        let w1 = total - w0;
        if w0 <= 0.0 || w1 <= 0.0 {
            continue;
        }
        let m0 = s0 / w0;
        let m1 = (weighted_total - s0) / w1;
        let between = w0 * w1 * (m0 - m1) * (m0 - m1);
        // Strictly greater: the first maximum wins, as NumPy's argmax does.
        if best.is_none_or(|(b, _)| between > b) {
            best = Some((between, i));
        }
    }
    best.map(|(_, i)| histogram.centre(i))
}

/// Nearest-rank percentiles of `values` (reordered in place), for each `p` in `ps` (0 to 100). Empty when
/// `values` is empty.
pub fn percentiles(values: &mut [f32], ps: &[f64]) -> Vec<(f64, f32)> {
    if values.is_empty() {
        return Vec::new();
    }
    let last = (values.len() - 1) as f64;
    ps.iter()
        .map(|&p| {
            let rank = (p.clamp(0.0, 100.0) / 100.0 * last).round_ties_even() as usize;
            let (_, value, _) = values.select_nth_unstable_by(rank, f32::total_cmp);
            (p, *value)
        })
        .collect()
}

/// What a volume's values look like: the figures `voxhap info` prints and `serve --volume` uses to place a
/// surface.
#[derive(Debug, Clone, PartialEq)]
pub struct ValueLevels {
    /// Values (or vector magnitudes) counted.
    pub count: usize,
    /// [`PERCENTILES`] with their values.
    pub percentiles: Vec<(f64, f32)>,
    /// A histogram of `display_bins` bins over the value range.
    pub histogram: Histogram,
    /// Otsu's threshold over [`OTSU_BINS`] bins; `None` for a constant volume.
    pub otsu: Option<f64>,
}

impl ValueLevels {
    /// The levels of `volume`'s values (magnitudes for a vector volume), with a `display_bins` histogram.
    pub fn of(volume: &AnyVolume, display_bins: usize) -> ValueLevels {
        let mut values: Vec<f32> = match volume {
            AnyVolume::Scalar(v) => v.data().to_vec(),
            AnyVolume::Vector(v) => v
                .data()
                .iter()
                .map(|&[x, y, z]| (x * x + y * y + z * z).sqrt())
                .collect(),
        };
        let (min, max) = volume.value_range();
        let histogram = Histogram::new(values.iter().copied(), min, max, display_bins);
        let otsu = otsu_threshold(&Histogram::new(values.iter().copied(), min, max, OTSU_BINS));
        let percentiles = percentiles(&mut values, &PERCENTILES);
        ValueLevels {
            count: values.len(),
            percentiles,
            histogram,
            otsu,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_values_are_split_between_them() {
        // Analytic: a volume of two values a < b has every threshold in [a, b) separating them perfectly; Otsu's
        // maximum is the first bin centre whose class holds exactly the a's, i.e. the centre of bin 0.
        let mut values = vec![10.0f32; 300];
        values.extend(std::iter::repeat_n(50.0f32, 100));
        let histogram = Histogram::new(values.iter().copied(), 10.0, 50.0, 256);
        let level = otsu_threshold(&histogram).unwrap();
        assert!((10.0..50.0).contains(&level), "{level}");
        assert_eq!(level, 10.0 + 0.5 * 40.0 / 256.0);
    }

    #[test]
    fn a_constant_volume_has_no_threshold() {
        let histogram = Histogram::new([3.0f32; 8], 3.0, 3.0, 256);
        assert_eq!(histogram.counts.iter().sum::<u64>(), 8);
        assert_eq!(otsu_threshold(&histogram), None);
    }

    #[test]
    fn histogram_edges_follow_numpy() {
        // np.histogram([0, 1, 2, 3, 4], bins=4, range=(0, 4)) -> counts [1, 1, 1, 2]: inner edges go up, the
        // maximum stays in the last bin.
        let histogram = Histogram::new([0.0f32, 1.0, 2.0, 3.0, 4.0], 0.0, 4.0, 4);
        assert_eq!(histogram.counts, vec![1, 1, 1, 2]);
        assert_eq!(histogram.edges, vec![0.0, 1.0, 2.0, 3.0, 4.0]);
    }

    #[test]
    fn percentiles_are_nearest_rank() {
        // np.percentile(np.arange(11), [0, 10, 25, 50, 99, 100], method="nearest") -> 0, 1, 2, 5, 10, 10
        // (25 % of 10 is 2.5, rounded to even: 2).
        let mut values: Vec<f32> = (0..11).rev().map(|v| v as f32).collect();
        let got = percentiles(&mut values, &[0.0, 10.0, 25.0, 50.0, 99.0, 100.0]);
        let values: Vec<f32> = got.iter().map(|&(_, v)| v).collect();
        assert_eq!(values, vec![0.0, 1.0, 2.0, 5.0, 10.0, 10.0]);
        assert!(percentiles(&mut [], &[50.0]).is_empty());
    }
}
