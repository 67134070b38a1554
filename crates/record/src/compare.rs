//! Comparing two traces within tolerances, for `voxhap compare A B --tol force=1e-6,...` in CI: a new run
//! against a reference trace.
//!
//! Where it sits: after two traces were read ([`crate::formats::read_trace`]), [`compare_traces`] pairs their samples
//! by position, checks that they cover the same ticks with the same modes, and reports, for every quantity,
//! the largest difference and the tick where it occurs. Floating-point quantities pass within an absolute
//! tolerance (default 0: identical); counts, flags and solver status must be equal. NaN equals NaN and
//! +inf equals +inf (a missing certificate on both sides is no difference).

use crate::sample::TraceSample;
use crate::trace::Trace;
use glam::DVec3;
use std::fmt::Write;

/// The quantities with a tolerance, with their names on the command line and units.
pub const QUANTITIES: [(&str, &str); 8] = [
    ("time", "s"),
    ("probe", "m"),
    ("velocity", "m/s"),
    ("proxy", "m"),
    ("rendered_force", "N"),
    ("force", "N"),
    ("mode_force", "N"),
    ("bound", "m"),
];

/// Absolute tolerances per quantity (index as [`QUANTITIES`]); default all 0.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Tolerances(pub [f64; QUANTITIES.len()]);

/// What is wrong with a `--tol` list.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ToleranceError {
    /// An item without `=`.
    #[error("{item:?}: expected NAME=TOLERANCE, e.g. force=1e-6")]
    MissingEquals { item: String },
    /// A tolerance that is not a finite number >= 0.
    #[error("{item:?}: the tolerance must be a number >= 0")]
    BadValue { item: String },
    /// A name that is not in [`QUANTITIES`] (nor `all`).
    #[error("{name:?} is not a quantity; use one of {} or all", quantity_names())]
    UnknownQuantity { name: String },
}

/// The quantity names, comma-separated, for messages.
fn quantity_names() -> String {
    let names: Vec<&str> = QUANTITIES.iter().map(|(q, _)| *q).collect();
    names.join(", ")
}

impl Tolerances {
    /// Parses `name=value,name=value` (names from [`QUANTITIES`]; `all=value` sets every one).
    pub fn parse(text: &str) -> Result<Tolerances, ToleranceError> {
        let mut tolerances = Tolerances::default();
        tolerances.apply(text)?;
        Ok(tolerances)
    }

    /// Applies `name=value,...` on top of these tolerances.
    pub fn apply(&mut self, text: &str) -> Result<(), ToleranceError> {
        for item in text.split(',').filter(|s| !s.trim().is_empty()) {
            let (name, value) =
                item.split_once('=')
                    .ok_or_else(|| ToleranceError::MissingEquals {
                        item: item.to_owned(),
                    })?;
            let value: f64 = value
                .trim()
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite() && *v >= 0.0)
                .ok_or_else(|| ToleranceError::BadValue {
                    item: item.to_owned(),
                })?;
            let name = name.trim();
            if name == "all" {
                self.0 = [value; QUANTITIES.len()];
                continue;
            }
            let index = QUANTITIES
                .iter()
                .position(|(q, _)| *q == name)
                .ok_or_else(|| ToleranceError::UnknownQuantity {
                    name: name.to_owned(),
                })?;
            self.0[index] = value;
        }
        Ok(())
    }
}

/// The largest difference of one quantity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Difference {
    /// Largest absolute difference (of any component).
    pub max: f64,
    /// Tick (of trace A) where it occurs.
    pub tick: u64,
}

/// What a comparison found.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// Largest differences per quantity (index as [`QUANTITIES`]).
    pub differences: [Difference; QUANTITIES.len()],
    /// The tolerances used.
    pub tolerances: Tolerances,
    /// Structural problems and exact-field mismatches (different ticks, modes, flags, ...).
    pub mismatches: Vec<String>,
    /// Samples compared.
    pub compared: usize,
}

impl Comparison {
    /// True when every quantity is within its tolerance and nothing else differs.
    pub fn passed(&self) -> bool {
        self.mismatches.is_empty()
            && self
                .differences
                .iter()
                .zip(self.tolerances.0)
                .all(|(d, tol)| d.max <= tol)
    }

    /// A readable report, one line per quantity and one per mismatch.
    pub fn report(&self) -> String {
        let mut text = format!("{} samples compared\n", self.compared);
        for (((name, unit), d), tol) in QUANTITIES
            .iter()
            .zip(&self.differences)
            .zip(self.tolerances.0)
        {
            let verdict = if d.max <= tol { "ok" } else { "DIFFERS" };
            let _ = writeln!(
                text,
                "{name:<15} max difference {:.3e} {unit} at tick {} (tolerance {tol:.1e}): {verdict}",
                d.max, d.tick
            );
        }
        for mismatch in &self.mismatches {
            let _ = writeln!(text, "DIFFERS: {mismatch}");
        }
        text
    }
}

fn float_difference(a: f64, b: f64) -> f64 {
    if a == b || (a.is_nan() && b.is_nan()) {
        0.0
    } else {
        (a - b).abs()
    }
}

fn vector_difference(a: DVec3, b: DVec3) -> f64 {
    float_difference(a.x, b.x)
        .max(float_difference(a.y, b.y))
        .max(float_difference(a.z, b.z))
}

fn quantities(a: &TraceSample, b: &TraceSample) -> [f64; QUANTITIES.len()] {
    let mode_force = a
        .modes
        .forces_n()
        .iter()
        .zip(b.modes.forces_n())
        .map(|(x, y)| vector_difference(*x, *y))
        .fold(0.0, f64::max);
    [
        float_difference(a.t_s, b.t_s),
        vector_difference(a.probe_m, b.probe_m),
        vector_difference(a.probe_velocity_m_per_s, b.probe_velocity_m_per_s),
        vector_difference(a.proxy_m, b.proxy_m),
        vector_difference(a.rendered_force_n, b.rendered_force_n),
        vector_difference(a.sent_force_n, b.sent_force_n),
        mode_force,
        float_difference(a.error_bound_m, b.error_bound_m),
    ]
}

/// Compares trace `b` against trace `a` with `tolerances`.
pub fn compare_traces(a: &Trace, b: &Trace, tolerances: Tolerances) -> Comparison {
    let mut comparison = Comparison {
        differences: [Difference { max: 0.0, tick: 0 }; QUANTITIES.len()],
        tolerances,
        mismatches: Vec::new(),
        compared: 0,
    };
    if a.mode_names != b.mode_names {
        comparison
            .mismatches
            .push(format!("modes {:?} vs {:?}", a.mode_names, b.mode_names));
    }
    if a.samples.len() != b.samples.len() {
        comparison.mismatches.push(format!(
            "{} samples vs {}",
            a.samples.len(),
            b.samples.len()
        ));
    }
    let mut exact: Vec<(&'static str, u64, usize)> = Vec::new();
    let mut note = |field: &'static str, tick: u64| match exact.iter_mut().find(|e| e.0 == field) {
        Some(entry) => entry.2 += 1,
        None => exact.push((field, tick, 1)),
    };
    for (sa, sb) in a.samples.iter().zip(&b.samples) {
        comparison.compared += 1;
        if sa.tick != sb.tick {
            note("tick", sa.tick);
        }
        if sa.modes.primitives() != sb.modes.primitives() {
            note("primitive counts", sa.tick);
        }
        if sa.flags != sb.flags {
            note("flags", sa.tick);
        }
        if sa.solver_status != sb.solver_status {
            note("solver status", sa.tick);
        }
        for (slot, value) in comparison.differences.iter_mut().zip(quantities(sa, sb)) {
            if value > slot.max || value.is_nan() {
                *slot = Difference {
                    max: if value.is_nan() { f64::INFINITY } else { value },
                    tick: sa.tick,
                };
            }
        }
    }
    for (field, tick, count) in exact {
        comparison.mismatches.push(format!(
            "{field} differ first at tick {tick} ({count} samples)"
        ));
    }
    comparison
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::samples;

    fn trace(data: Vec<TraceSample>) -> Trace {
        Trace {
            mode_names: vec!["surface".into(), "friction".into()],
            samples: data,
            sidecar: None,
            warnings: Vec::new(),
        }
    }

    #[test]
    fn identical_traces_pass_and_differences_are_located() {
        let a = trace(samples(100, 2));
        assert!(compare_traces(&a, &a.clone(), Tolerances::default()).passed());
        let mut b = a.clone();
        b.samples[40].sent_force_n.y += 2e-6;
        let strict = compare_traces(&a, &b, Tolerances::parse("force=1e-6").unwrap());
        assert!(!strict.passed());
        let force = strict.differences[5];
        assert_eq!(force.tick, a.samples[40].tick);
        assert!(strict.report().contains("force"), "{}", strict.report());
        assert!(strict.report().contains("DIFFERS"));
        assert!(compare_traces(&a, &b, Tolerances::parse("force=1e-5").unwrap()).passed());
        // Exact fields.
        let mut c = a.clone();
        c.samples[7].flags ^= 1;
        let report = compare_traces(&a, &c, Tolerances::parse("all=1").unwrap());
        assert!(!report.passed());
        assert!(
            report.mismatches[0].contains("flags differ first at tick 14"),
            "{:?}",
            report.mismatches
        );
        // Lengths.
        let mut d = a.clone();
        d.samples.pop();
        assert!(!compare_traces(&a, &d, Tolerances::parse("all=1").unwrap()).passed());
    }

    #[test]
    fn bad_tolerances_are_refused_with_the_names() {
        assert!(Tolerances::parse("forse=1")
            .unwrap_err()
            .to_string()
            .contains("force"));
        assert!(Tolerances::parse("force=-1").is_err());
        assert!(Tolerances::parse("force").is_err());
    }
}
