//! The plots of `voxhap stability --plots DIR`: grouped bars on a logarithmic axis, as a small hand-written SVG
//! (no fonts embedded, no scripts; text in the viewer's sans-serif), so the files are deterministic and
//! diff well.

use std::fmt::Write as _;

/// One bar series: its name in the legend and its colour.
pub struct Series {
    pub name: &'static str,
    pub colour: &'static str,
}

impl Series {
    /// The series `name`, drawn in `colour` (`#rrggbb`).
    pub const fn new(name: &'static str, colour: &'static str) -> Self {
        Series { name, colour }
    }
}

/// One group of bars: its label, one value per series (`None`: no bar), a marker per series (a short
/// black line across the bar, e.g. the analytic bound; `None`: no marker) and a dot per series (a small open
/// circle on the bar's centre line, e.g. the exact boundary; `None` or missing: no dot).
pub struct Group {
    pub label: String,
    pub values: Vec<Option<f64>>,
    pub markers: Vec<Option<f64>>,
    pub dots: Vec<Option<f64>>,
}

/// What the markers and the dots stand for, in the legend (`dots: None`: no dots drawn, no legend entry).
pub struct Notes {
    pub markers: &'static str,
    pub dots: Option<&'static str>,
}

const WIDTH: f64 = 960.0;
const LEFT: f64 = 90.0;
const RIGHT: f64 = 20.0;
const TOP: f64 = 70.0;
const PLOT_HEIGHT: f64 = 320.0;
const BOTTOM: f64 = 110.0;

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// A number for an axis label: whole numbers grouped by thin spaces, small ones in plain decimals.
fn axis_label(value: f64) -> String {
    if value >= 1.0 {
        group_digits(value)
    } else {
        let text = format!("{value:.6}");
        text.trim_end_matches('0').to_owned()
    }
}

/// Grouped vertical bars on a log-10 axis from the decade below the smallest value (at least `floor`) to the
/// decade above the largest; a value below the axis gets no bar. `notes` name the markers and dots in the
/// legend.
pub fn grouped_bars(
    title: &str,
    axis: &str,
    notes: &Notes,
    floor: f64,
    series: &[Series],
    groups: &[Group],
) -> String {
    let all = groups
        .iter()
        .flat_map(|g| g.values.iter().chain(&g.markers).chain(&g.dots))
        .flatten()
        .copied()
        .filter(|v| v.is_finite() && *v >= floor && *v > 0.0);
    let (lo, hi) = all.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let (lo_exp, hi_exp) = if hi > 0.0 {
        (
            lo.log10().floor() as i32,
            (hi.log10().ceil() as i32).max(lo.log10().floor() as i32 + 1),
        )
    } else {
        (0, 1)
    };
    let y = |v: f64| {
        let f = (v.log10() - f64::from(lo_exp)) / f64::from(hi_exp - lo_exp);
        TOP + PLOT_HEIGHT * (1.0 - f.clamp(0.0, 1.0))
    };
    let height = TOP + PLOT_HEIGHT + BOTTOM;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{WIDTH}\" height=\"{height}\" viewBox=\"0 0 {WIDTH} {height}\" font-family=\"sans-serif\" font-size=\"12\">"
    );
    let _ = writeln!(
        out,
        "<rect width=\"{WIDTH}\" height=\"{height}\" fill=\"white\"/>"
    );
    let _ = writeln!(
        out,
        "<text x=\"{}\" y=\"22\" font-size=\"15\" text-anchor=\"middle\">{}</text>",
        WIDTH / 2.0,
        escape(title)
    );
    // Legend.
    let mut x = LEFT;
    for s in series {
        let _ = writeln!(
            out,
            "<rect x=\"{x:.1}\" y=\"34\" width=\"12\" height=\"12\" fill=\"{}\"/><text x=\"{:.1}\" y=\"45\">{}</text>",
            s.colour,
            x + 16.0,
            escape(s.name)
        );
        x += 24.0 + 7.0 * s.name.len() as f64;
    }
    let _ = writeln!(
        out,
        "<line x1=\"{x:.1}\" y1=\"40\" x2=\"{:.1}\" y2=\"40\" stroke=\"black\" stroke-width=\"2\"/><text x=\"{:.1}\" y=\"45\">{}</text>",
        x + 14.0,
        x + 18.0,
        escape(notes.markers)
    );
    if let Some(dots) = notes.dots {
        let x = x + 30.0 + 7.0 * notes.markers.chars().count() as f64;
        let _ = writeln!(
            out,
            "<circle cx=\"{:.1}\" cy=\"40\" r=\"3.5\" fill=\"white\" stroke=\"black\" stroke-width=\"1.5\"/><text x=\"{:.1}\" y=\"45\">{}</text>",
            x + 7.0,
            x + 14.0,
            escape(dots)
        );
    }
    // Axis and decade grid.
    let _ = writeln!(
        out,
        "<text x=\"18\" y=\"{:.1}\" transform=\"rotate(-90 18 {:.1})\" text-anchor=\"middle\">{}</text>",
        TOP + PLOT_HEIGHT / 2.0,
        TOP + PLOT_HEIGHT / 2.0,
        escape(axis)
    );
    for exp in lo_exp..=hi_exp {
        let v = 10f64.powi(exp);
        let yy = y(v);
        let _ = writeln!(
            out,
            "<line x1=\"{LEFT}\" y1=\"{yy:.1}\" x2=\"{:.1}\" y2=\"{yy:.1}\" stroke=\"#ccc\"/><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
            WIDTH - RIGHT,
            LEFT - 6.0,
            yy + 4.0,
            axis_label(v)
        );
    }
    let _ = writeln!(
        out,
        "<line x1=\"{LEFT}\" y1=\"{TOP}\" x2=\"{LEFT}\" y2=\"{:.1}\" stroke=\"black\"/>",
        TOP + PLOT_HEIGHT
    );
    // Bars.
    let slot = (WIDTH - LEFT - RIGHT) / groups.len().max(1) as f64;
    let bar = (slot * 0.8) / series.len().max(1) as f64;
    for (g, group) in groups.iter().enumerate() {
        let x0 = LEFT + slot * g as f64 + slot * 0.1;
        for (i, s) in series.iter().enumerate() {
            let bx = x0 + bar * i as f64;
            let visible = |v: &f64| *v > 0.0 && v.log10() >= f64::from(lo_exp);
            if let Some(v) = group.values.get(i).copied().flatten().filter(visible) {
                let top = y(v);
                let _ = writeln!(
                    out,
                    "<rect x=\"{bx:.1}\" y=\"{top:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{}\"><title>{}: {}</title></rect>",
                    bar * 0.9,
                    TOP + PLOT_HEIGHT - top,
                    s.colour,
                    escape(s.name),
                    axis_label(v)
                );
            }
            if let Some(m) = group.markers.get(i).copied().flatten().filter(visible) {
                let my = y(m);
                let _ = writeln!(
                    out,
                    "<line x1=\"{:.1}\" y1=\"{my:.1}\" x2=\"{:.1}\" y2=\"{my:.1}\" stroke=\"black\" stroke-width=\"2\"/>",
                    bx - 1.0,
                    bx + bar * 0.9 + 1.0
                );
            }
            if let Some(d) = group.dots.get(i).copied().flatten().filter(visible) {
                let _ = writeln!(
                    out,
                    "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"3.5\" fill=\"white\" stroke=\"black\" stroke-width=\"1.5\"><title>{}</title></circle>",
                    bx + bar * 0.45,
                    y(d),
                    axis_label(d)
                );
            }
        }
        let cx = x0 + slot * 0.4;
        let ly = TOP + PLOT_HEIGHT + 14.0;
        let _ = writeln!(
            out,
            "<text x=\"{cx:.1}\" y=\"{ly:.1}\" text-anchor=\"end\" transform=\"rotate(-35 {cx:.1} {ly:.1})\">{}</text>",
            escape(&group.label)
        );
    }
    out.push_str("</svg>\n");
    out
}

/// `1234.6` as `1 235`: whole numbers with thin-space thousands, as the docs write them.
pub fn group_digits(value: f64) -> String {
    let digits = (value.round() as i64).to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(' ');
        }
        out.push(c);
    }
    out
}
