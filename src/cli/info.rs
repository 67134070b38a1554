//! `voxhap info VOLUME [--json]`: prints what the loader read from a volume file (or a built-in
//! procedural volume, `builtin:NAME`): dimensions, spacing, the index-to-world affine, the stored
//! type, the value range, and the figures that help choose a surface level (percentiles, a histogram,
//! Otsu's threshold; definitions in [`crate::volume::levels`]). A thin reporting layer over
//! [`crate::volume::io::load`] and [`crate::volume::procedural::builtin`].

use crate::volume::io::{self, FileFormat, LoadedVolume, ScalarType};
use crate::volume::levels::{ValueLevels, OTSU_BINS};
use crate::volume::{procedural, AnyVolume};
use anyhow::Context;
use serde::Serialize;
use std::path::Path;

/// Arguments of `voxhap info`.
#[derive(Debug, clap::Args)]
pub struct InfoArgs {
    /// Volume file (.nii, .nii.gz, .nrrd, .nhdr, .mha, .mhd, .toml) or builtin:NAME
    /// (sphere, torus, shells, rankine, burgers, density-flow).
    pub volume: String,
    /// Print one JSON object per volume instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub limits: super::common::VolumeLimitArgs,
}

/// What `info` prints for one volume; also the `--json` schema.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VolumeReport {
    /// The argument as given (a file path or `builtin:NAME`).
    pub path: String,
    /// `nifti`, `nrrd`, `metaimage`, `raw` or `builtin`.
    pub format: String,
    /// `scalar` or `vector`.
    pub kind: String,
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    /// Voxel spacing along i, j, k, metres.
    pub spacing: [f64; 3],
    /// Index-to-world affine, RAS metres, row-major 4x4.
    pub affine: [[f64; 4]; 4],
    /// Element type in the file (`u8` ... `f64`; `f32` for built-ins).
    #[serde(rename = "type")]
    pub scalar_type: String,
    /// Smallest value (smallest vector magnitude for a vector volume).
    pub min: f32,
    /// Largest value (largest vector magnitude for a vector volume).
    pub max: f32,
    /// Non-finite values in the file that were replaced by 0.
    pub non_finite_replaced: usize,
    /// Values that f32 could not hold exactly and were rounded.
    pub rounded_values: usize,
    /// Nearest-rank percentiles of the values (magnitudes for a vector volume): `[p, value]` pairs.
    pub percentiles: Vec<(f64, f32)>,
    /// A histogram of the values over `min..max` in equal bins.
    pub histogram: HistogramReport,
    /// Otsu's threshold over 256 bins: the suggested surface level (`null` for a constant volume).
    pub otsu_level: Option<f64>,
}

/// The histogram in a [`VolumeReport`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HistogramReport {
    /// Bin edges, one more than the bins.
    pub edges: Vec<f64>,
    /// Values per bin.
    pub counts: Vec<u64>,
}

/// Bins of the histogram `info` prints.
pub const DISPLAY_BINS: usize = 16;

impl VolumeReport {
    fn new(
        path: &str,
        format: &str,
        volume: &AnyVolume,
        scalar_type: ScalarType,
        counts: (usize, usize),
    ) -> VolumeReport {
        let grid = volume.grid();
        let (min, max) = volume.value_range();
        // glam stores columns; the report wants rows.
        let affine = grid.affine().transpose().to_cols_array_2d();
        let levels = ValueLevels::of(volume, DISPLAY_BINS);
        VolumeReport {
            path: path.to_owned(),
            format: format.to_owned(),
            kind: volume.kind().to_owned(),
            dims: grid.dims(),
            spacing: grid.spacing_m().to_array(),
            affine,
            scalar_type: scalar_type.name().to_owned(),
            min,
            max,
            non_finite_replaced: counts.0,
            rounded_values: counts.1,
            percentiles: levels.percentiles,
            histogram: HistogramReport {
                edges: levels.histogram.edges,
                counts: levels.histogram.counts,
            },
            otsu_level: levels.otsu,
        }
    }

    fn from_loaded(path: &str, loaded: &LoadedVolume) -> VolumeReport {
        VolumeReport::new(
            path,
            loaded.format.name(),
            &loaded.volume,
            loaded.source_type,
            (loaded.non_finite_replaced, loaded.rounded_values),
        )
    }

    /// The human-readable form.
    pub fn to_text(&self) -> String {
        let mut text = format!(
            "path:     {}\nformat:   {}\nkind:     {}\ndims:     {} x {} x {}\nspacing:  {} x {} x {} m\n\
             affine (index -> world, RAS, metres):\n",
            self.path,
            self.format,
            self.kind,
            self.dims[0],
            self.dims[1],
            self.dims[2],
            self.spacing[0],
            self.spacing[1],
            self.spacing[2],
        );
        for row in &self.affine {
            text += &format!(
                "  [{:>12.6} {:>12.6} {:>12.6} {:>12.6} ]\n",
                row[0], row[1], row[2], row[3]
            );
        }
        let range_label = if self.kind == "vector" {
            "|v|:"
        } else {
            "range:"
        };
        text += &format!(
            "type:     {}\n{range_label:<10}{} .. {}\n",
            self.scalar_type, self.min, self.max
        );
        text += &self.levels_text();
        if self.non_finite_replaced > 0 {
            text += &format!(
                "warning:  {} non-finite values were replaced by 0\n",
                self.non_finite_replaced
            );
        }
        if self.rounded_values > 0 {
            text += &format!(
                "note:     {} values were rounded to the nearest f32\n",
                self.rounded_values
            );
        }
        text
    }
}

impl VolumeReport {
    /// Percentiles, the histogram as bars, and the suggested surface level.
    fn levels_text(&self) -> String {
        let what = if self.kind == "vector" { "|v| " } else { "" };
        let mut text = format!("{what}percentiles:");
        for (p, value) in &self.percentiles {
            text += &format!(" p{p} {value}");
        }
        text += "\n";
        let widest = self
            .histogram
            .counts
            .iter()
            .copied()
            .max()
            .unwrap_or(0)
            .max(1);
        text += &format!(
            "histogram ({} bins, voxels per bin):\n",
            self.histogram.counts.len()
        );
        for (i, &count) in self.histogram.counts.iter().enumerate() {
            // Bars are 40 characters at the fullest bin; any non-empty bin shows at least one.
            let bar = if count == 0 {
                0
            } else {
                ((count as f64 / widest as f64) * 40.0).ceil() as usize
            };
            text += &format!(
                "  {:>12} .. {:<12} {:<40} {count}\n",
                short(self.histogram.edges[i]),
                short(self.histogram.edges[i + 1]),
                "#".repeat(bar)
            );
        }
        match self.otsu_level {
            Some(level) => {
                text += &format!(
                    "surface level: {} (Otsu's threshold, {OTSU_BINS} bins: where `serve --volume` puts the \
                     surface)\n",
                    short(level)
                )
            }
            None => text += "surface level: none (every value is the same)\n",
        }
        text
    }
}

/// A bin edge or level with at most four decimals and no trailing zeros.
fn short(value: f64) -> String {
    let text = format!("{value:.4}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".to_owned()
    } else {
        text.to_owned()
    }
}

/// Loads the volume(s) named by `volume` and reports them.
pub fn reports(volume: &str) -> anyhow::Result<Vec<VolumeReport>> {
    if let Some(name) = volume.strip_prefix("builtin:") {
        let volumes = procedural::builtin(name)?.into_volumes();
        return Ok(volumes
            .iter()
            .map(|v| VolumeReport::new(volume, "builtin", v, ScalarType::F32, (0, 0)))
            .collect());
    }
    let loaded = io::load(Path::new(volume)).with_context(|| {
        match FileFormat::from_path(Path::new(volume)) {
            Some(format) => format!("cannot load {} volume", format.name()),
            None => "cannot load volume".to_owned(),
        }
    })?;
    Ok(vec![VolumeReport::from_loaded(volume, &loaded)])
}

/// Runs `voxhap info`.
pub fn run(args: &InfoArgs) -> anyhow::Result<()> {
    args.limits.apply();
    let reports = reports(&args.volume)?;
    if args.json {
        // One object for one volume; an array for a built-in that holds two (density-flow).
        let text = match reports.as_slice() {
            [one] => serde_json::to_string(one)?,
            many => serde_json::to_string(many)?,
        };
        return super::common::print_out(&text);
    }
    let text: String = reports.iter().map(|report| report.to_text()).collect();
    super::common::print_out(text.trim_end())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_reports_match_the_volume() {
        let reports = reports("builtin:density-flow").unwrap();
        assert_eq!(reports.len(), 2);
        assert_eq!(reports[0].kind, "scalar");
        assert_eq!(reports[1].kind, "vector");
        let sphere = &reports[0];
        assert_eq!(sphere.dims, procedural::BUILTIN_DIMS);
        // Row-major: the translation is the last column of the first three rows.
        assert_eq!(sphere.affine[0][3], -procedural::BUILTIN_HALF_EXTENT_M);
        assert_eq!(sphere.affine[3], [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(sphere.affine[0][0], sphere.spacing[0]);
        let json: serde_json::Value = serde_json::to_value(sphere).unwrap();
        for key in [
            "dims",
            "spacing",
            "affine",
            "type",
            "min",
            "max",
            "format",
            "kind",
            "path",
            "percentiles",
            "histogram",
            "otsu_level",
        ] {
            assert!(json.get(key).is_some(), "missing {key}");
        }
        assert!(sphere.to_text().contains("64 x 64 x 64"));
    }

    #[test]
    fn unknown_builtins_and_extensions_are_errors() {
        let message = format!("{:#}", reports("builtin:cube").unwrap_err());
        assert!(message.contains("sphere"), "{message}");
        let message = format!("{:#}", reports("volume.png").unwrap_err());
        assert!(
            message.contains("volume.png") && message.contains("extension"),
            "{message}"
        );
    }
}
