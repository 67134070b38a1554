//! `voxhap compare A B [--tol force=1e-6,proxy=1e-9,...]`: compare trace B with reference trace A (see
//! [`crate::record::compare`]). Prints a report; exits 0 when they agree within the tolerances, 1 when they
//! differ (with the report on stderr), 2 for bad arguments.

use crate::record::compare::{compare_traces, Tolerances};
use crate::record::read_trace;
use anyhow::Context;
use clap::Args;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct CompareArgs {
    /// The reference trace (CSV or MCAP).
    pub reference: PathBuf,
    /// The trace to check against it.
    pub candidate: PathBuf,
    /// Absolute tolerances, NAME=VALUE comma-separated: time (s), probe (m), velocity (m/s), proxy (m),
    /// rendered_force (N), force (N), mode_force (N), bound (m), or all. Default 0 (identical).
    #[arg(long, default_value = "")]
    pub tol: String,
}

pub fn run(args: &CompareArgs) -> anyhow::Result<()> {
    let tolerances = Tolerances::parse(&args.tol).map_err(|e| anyhow::anyhow!("--tol: {e}"))?;
    let a = read_trace(&args.reference)
        .with_context(|| format!("cannot read {}", args.reference.display()))?;
    let b = read_trace(&args.candidate)
        .with_context(|| format!("cannot read {}", args.candidate.display()))?;
    for warning in a.warnings.iter().chain(&b.warnings) {
        eprintln!("warning: {warning}");
    }
    let comparison = compare_traces(&a, &b, tolerances);
    if comparison.passed() {
        super::common::print_out(comparison.report().trim_end())?;
        super::common::print_out(&format!(
            "{} matches {} within the tolerances",
            args.candidate.display(),
            args.reference.display()
        ))
    } else {
        Err(super::common::ExitWith {
            code: 1,
            message: format!(
                "{}{} differs from {} beyond the tolerances",
                comparison.report(),
                args.candidate.display(),
                args.reference.display()
            ),
        }
        .into())
    }
}
