//! `voxhap sweep SCENARIO --set KEY=V1,V2,... [--set ...] --out-dir DIR`: run a scenario for every
//! combination of the listed values (the Cartesian product of the `--set` lists), as independent sims in
//! parallel on the available cores, one trace per point, then print a summary table (also written to
//! `DIR/sweep.csv`).
//!
//! Each point is `voxhap sim` with its `--set` overrides ([`super::sim::load_scenario`]); its trace is
//! `DIR/point-NNN.EXT` with its sidecar, whose scenario records the values used; with `--format parquet`
//! the traces form one partitioned dataset under `DIR/points` plus a `DIR/points.parquet` table
//! ([`dataset`]). A progress bar over all
//! points' ticks shows on a terminal. `--fail-on` applies to every point; the sweep exits with code 3 when
//! any point met a condition (all traces are still written).

use super::sim::{fail_on_exit, fail_on_findings, load_scenario, solver_label, FailOn};
use crate::haptics::tick::SolverKind;
use crate::record::{
    create_trace_writer_with, error_chain, estimate_trace_bytes, OutputPolicy, TraceFormat,
    TraceMeta, TraceWriter,
};
use crate::sim::overrides::{split_override, split_values};
use crate::sim::{self, LoadedScenario, SimSummary};
use anyhow::Context;
use clap::Args;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

pub mod dataset;

#[derive(Debug, Args)]
pub struct SweepArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// KEY=V1,V2,...: the values of one scenario key to sweep (dotted path with indices, as `sim --set`;
    /// commas inside [...] do not split). Repeat for more keys: every combination runs.
    #[arg(long = "set", value_name = "KEY=V1,V2,...", required = true)]
    pub set: Vec<String>,
    /// Directory for the traces (created if missing).
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Trace format of every point.
    #[arg(long, value_parser = super::common::trace_format_parser(), default_value_t = TraceFormat::Csv)]
    pub format: TraceFormat,
    /// Override the scenario's duration_s (s) for every point.
    #[arg(long)]
    pub duration: Option<f64>,
    /// Override the scenario's rate_hz (Hz) for every point.
    #[arg(long)]
    pub rate: Option<f64>,
    /// Proxy solver; default: the scenario's.
    #[arg(long, value_parser = super::common::solver_kind_parser())]
    pub solver: Option<SolverKind>,
    /// Sims run at once; default: the available cores.
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Replace existing point traces.
    #[arg(long)]
    pub force: bool,
    /// Refuse to start when all traces together are estimated to take more bytes than this.
    #[arg(long, default_value_t = super::sim::DEFAULT_MAX_TRACE_BYTES)]
    pub max_trace_bytes: u64,
    /// As `sim --fail-on`, for every point.
    #[arg(long, value_enum, value_delimiter = ',')]
    pub fail_on: Vec<FailOn>,
}

/// The most points one sweep runs.
pub const MAX_POINTS: usize = 10_000;

/// Every combination of the `--set` lists, as lists of `KEY=VALUE` overrides.
pub fn sweep_points(sets: &[String]) -> anyhow::Result<Vec<Vec<String>>> {
    let mut points: Vec<Vec<String>> = vec![Vec::new()];
    for set in sets {
        let (key, list) = split_override(set)?;
        let values = split_values(list);
        if values.iter().any(|v| v.is_empty()) {
            anyhow::bail!("--set {set:?}: an empty value in the list");
        }
        if points.len().saturating_mul(values.len()) > MAX_POINTS {
            anyhow::bail!("the sweep has more than {MAX_POINTS} points");
        }
        points = points
            .iter()
            .flat_map(|point| {
                values.iter().map(move |value| {
                    let mut next = point.clone();
                    next.push(format!("{key}={value}"));
                    next
                })
            })
            .collect();
    }
    Ok(points)
}

struct Point {
    overrides: Vec<String>,
    loaded: LoadedScenario,
    out: PathBuf,
}

pub fn run(args: &SweepArgs) -> anyhow::Result<()> {
    let overrides = sweep_points(&args.set)?;
    let parquet = args.format == TraceFormat::Parquet;
    std::fs::create_dir_all(&args.out_dir)
        .with_context(|| format!("cannot create {}", args.out_dir.display()))?;
    // Load and check every point before running any.
    let mut points = Vec::with_capacity(overrides.len());
    let mut total_bytes = 0u64;
    let mut total_ticks = 0u64;
    let mut partitions = Vec::new();
    for (index, overrides) in overrides.into_iter().enumerate() {
        let loaded = load_scenario(&args.scenario, &overrides, args.duration, args.rate)
            .with_context(|| format!("point {index} ({})", overrides.join(" ")))?;
        let ticks = loaded.scenario.tick_count();
        total_ticks += ticks;
        total_bytes = total_bytes.saturating_add(estimate_trace_bytes(
            args.format,
            loaded.scene.mode_names().len(),
            ticks,
            loaded.scenario.rate_hz,
        ));
        if parquet && index == 0 {
            let trace_columns: Vec<String> = crate::record::columns(loaded.scene.mode_names())
                .into_iter()
                .map(|c| c.name.into_owned())
                .collect();
            partitions = dataset::partition_columns(&args.set, &trace_columns)?;
        }
        let out = if parquet {
            dataset::point_path(&args.out_dir, &partitions, &overrides, index)
        } else {
            args.out_dir
                .join(format!("point-{index:03}.{}", args.format))
        };
        points.push(Point {
            overrides,
            loaded,
            out,
        });
    }
    if total_bytes > args.max_trace_bytes {
        anyhow::bail!(
            "the {} traces would take about {} together, more than --max-trace-bytes {}",
            points.len(),
            super::sim::human_bytes(total_bytes),
            args.max_trace_bytes
        );
    }
    let inputs = points
        .first()
        .map(|p| super::sim::scenario_inputs(&args.scenario, &p.loaded))
        .unwrap_or_default();
    let policy = OutputPolicy {
        overwrite: args.force,
        inputs,
    };
    for point in &points {
        if let Some(parent) = point.out.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("cannot create {}", parent.display()))?;
        }
        crate::record::check_output_path(&point.out, &policy)
            .map_err(|e| anyhow::anyhow!("{}", error_chain(&e)))?;
    }

    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .clamp(1, points.len().max(1));
    let bar = if std::io::stderr().is_terminal() {
        let bar = indicatif::ProgressBar::new(total_ticks);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "sweep {msg} [{bar:40}] {pos}/{len} ticks ({eta} left)",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let finished = AtomicUsize::new(0);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<anyhow::Result<SimSummary>>>> =
        Mutex::new((0..points.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            scope.spawn(|| loop {
                let index = next.fetch_add(1, Ordering::Relaxed);
                let Some(point) = points.get(index) else {
                    break;
                };
                let result = run_point(point, args, &policy, &bar);
                let done = finished.fetch_add(1, Ordering::Relaxed) + 1;
                bar.set_message(format!("{done}/{} points", points.len()));
                if let Ok(mut slots) = results.lock() {
                    slots[index] = Some(result);
                }
            });
        }
    });
    bar.finish_and_clear();

    let results = results.into_inner().unwrap_or_default();
    let mut table = String::from(
        "point,settings,ticks,certified,max_force_n,max_sweeps,max_error_bound_m,trace\n",
    );
    let mut failures = Vec::new();
    let mut errors = Vec::new();
    let mut rows = Vec::with_capacity(points.len());
    for (index, (point, result)) in points.iter().zip(&results).enumerate() {
        let settings = point.overrides.join(" ");
        match result {
            Some(Ok(summary)) => {
                table += &format!(
                    "{index},{settings:?},{},{},{:.6},{},{:e},{}\n",
                    summary.ticks,
                    summary.certified_ticks,
                    summary.max_force_n,
                    summary.max_sweeps,
                    summary.max_error_bound_m,
                    point.out.display()
                );
                for finding in fail_on_findings(&args.fail_on, summary) {
                    failures.push(format!("point {index} ({settings}): {finding}"));
                }
            }
            Some(Err(error)) => errors.push(format!("point {index} ({settings}): {error:#}")),
            None => errors.push(format!("point {index} ({settings}): did not run")),
        }
        rows.push(dataset::PointRow {
            overrides: &point.overrides,
            trace: &point.out,
            result: match result {
                Some(Ok(summary)) => Ok(summary),
                Some(Err(error)) => Err(format!("{error:#}")),
                None => Err("did not run".to_owned()),
            },
        });
    }
    let points_table = args.out_dir.join(dataset::POINTS_TABLE);
    if parquet {
        dataset::write_points_table(&points_table, &args.out_dir, &partitions, &rows)
            .with_context(|| format!("cannot write {}", points_table.display()))?;
    }
    let summary_path = args.out_dir.join("sweep.csv");
    {
        use std::io::Write;
        crate::record::create_or_replace_file(&summary_path)
            .map_err(anyhow::Error::from)
            .and_then(|mut file| Ok(file.write_all(table.as_bytes())?))
            .with_context(|| format!("cannot write {}", summary_path.display()))?;
    }
    super::common::print_out(&format_table(&table))?;
    let dataset_note = if parquet {
        format!(
            "; dataset {}, points {}",
            args.out_dir.join(dataset::DATASET_DIR).display(),
            points_table.display()
        )
    } else {
        String::new()
    };
    super::common::print_out(&format!(
        "{} points ({} jobs) -> {} (summary {}{dataset_note})",
        points.len(),
        jobs,
        args.out_dir.display(),
        summary_path.display()
    ))?;
    if !errors.is_empty() {
        anyhow::bail!("{}", errors.join("\n"));
    }
    if !failures.is_empty() {
        return Err(fail_on_exit(format!("--fail-on:\n{}", failures.join("\n"))));
    }
    Ok(())
}

/// The summary CSV as aligned columns for the terminal.
fn format_table(csv: &str) -> String {
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| split_csv_row(l)).collect();
    let columns = rows.iter().map(Vec::len).max().unwrap_or(0);
    let widths: Vec<usize> = (0..columns)
        .map(|c| {
            rows.iter()
                .filter_map(|r| r.get(c))
                .map(|f| f.len())
                .max()
                .unwrap_or(0)
        })
        .collect();
    rows.iter()
        .map(|row| {
            row.iter()
                .zip(&widths)
                .map(|(field, width)| format!("{field:<width$}"))
                .collect::<Vec<_>>()
                .join("  ")
                .trim_end()
                .to_owned()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Splits a summary row at commas outside double quotes.
fn split_csv_row(line: &str) -> Vec<&str> {
    let mut fields = Vec::new();
    let (mut start, mut quoted) = (0, false);
    for (i, c) in line.char_indices() {
        match c {
            '"' => quoted = !quoted,
            ',' if !quoted => {
                fields.push(&line[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    fields.push(&line[start..]);
    fields
}

fn run_point(
    point: &Point,
    args: &SweepArgs,
    policy: &OutputPolicy,
    bar: &indicatif::ProgressBar,
) -> anyhow::Result<SimSummary> {
    let loaded = &point.loaded;
    let solver = args.solver.unwrap_or(loaded.scenario.solver.kind);
    let meta = TraceMeta::new(
        loaded.scene.mode_names().to_vec(),
        loaded.scenario.rate_hz,
        serde_json::to_value(&loaded.scenario)?,
        loaded.volume_description.clone(),
        solver_label(solver),
    );
    let mut writer = create_trace_writer_with(&point.out, args.format, &meta, policy)
        .map_err(|e| anyhow::anyhow!("{}", error_chain(&e)))?;
    let mut reported = 0;
    let result = sim::run(loaded, solver, writer.as_mut(), |done| {
        bar.inc(done - reported);
        reported = done;
    });
    end_point(writer.as_mut(), result)
}

/// Ends a point's trace: finished when its run succeeded; otherwise, or when finishing fails (a full disk),
/// marked failed in its sidecar with the error (`complete: false`, the samples that reached the file), so no
/// point's sidecar claims a trace it does not have.
fn end_point<T, E>(writer: &mut dyn TraceWriter, result: Result<T, E>) -> anyhow::Result<T>
where
    E: std::error::Error + Send + Sync + 'static,
{
    let (message, error) = match result {
        Ok(value) => match writer.finish() {
            Ok(_) => return Ok(value),
            Err(error) => (error_chain(&error), anyhow::Error::from(error)),
        },
        Err(error) => (error_chain(&error), anyhow::Error::from(error)),
    };
    let _ = writer.fail(&message);
    Err(error)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::TraceError;

    #[test]
    fn points_are_the_cartesian_product() {
        let points =
            sweep_points(&["k_n_per_m=200,500".into(), "modes[1].mu=0.3,0.5,0.7".into()]).unwrap();
        assert_eq!(points.len(), 6);
        assert_eq!(points[0], ["k_n_per_m=200", "modes[1].mu=0.3"]);
        assert_eq!(points[5], ["k_n_per_m=500", "modes[1].mu=0.7"]);
        assert!(sweep_points(&["k=1,,2".into()]).is_err());
    }

    /// A writer whose `finish` fails as on a full disk, recording what it is told.
    #[derive(Default)]
    struct FullDisk {
        failed_with: Option<String>,
    }

    impl TraceWriter for FullDisk {
        fn write_sample(&mut self, _: &crate::record::TraceSample) -> Result<(), TraceError> {
            Ok(())
        }
        fn flush(&mut self) -> Result<(), TraceError> {
            Ok(())
        }
        fn finish(&mut self) -> Result<crate::record::TraceSummary, TraceError> {
            Err(TraceError::Io {
                path: "point-000.csv".into(),
                source: std::io::Error::from_raw_os_error(28), // ENOSPC
            })
        }
        fn fail(&mut self, error: &str) -> Result<(), TraceError> {
            self.failed_with = Some(error.to_owned());
            Ok(())
        }
        fn sample_count(&self) -> u64 {
            0
        }
    }

    #[test]
    fn a_point_whose_finish_fails_is_marked_failed() {
        let mut writer = FullDisk::default();
        let result = end_point(&mut writer, Ok::<_, std::io::Error>(7));
        let error = format!("{:#}", result.unwrap_err());
        assert!(error.contains("point-000.csv"), "{error}");
        let failed_with = writer.failed_with.expect("the sidecar is marked failed");
        assert!(
            failed_with.contains("No space left on device"),
            "{failed_with}"
        );
    }

    #[test]
    fn the_table_is_aligned() {
        let table = format_table("a,bb\n\"x,y\",2\n");
        assert_eq!(table, "a      bb\n\"x,y\"  2");
    }
}
