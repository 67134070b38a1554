//! Tests of [`super`].

use super::*;
use crate::test_support::samples;
use std::ops::Range;

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
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()));
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

/// `plot_data` draws as wide as its reduction was made for (it takes no second width that could disagree),
/// and a reduction for a width outside [`PLOT_WIDTH_PX`] is refused when drawn.
#[test]
fn plot_data_draws_at_the_width_it_was_reduced_for() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("w.png");
    let traced = trace(100);
    let reduced = |width_px: u32| {
        let mut data = PlotData::new(width_px);
        traced.samples.iter().for_each(|sample| data.push(sample));
        data
    };
    for width_px in [640, 1500] {
        let data = reduced(width_px);
        assert_eq!(data.width_px(), width_px);
        plot_data(&data, &traced, "width", &out, 480).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()));
        let info = decoder.read_info().expect("a valid PNG").info().clone();
        assert_eq!((info.width, info.height), (width_px, 480));
    }
    assert!(matches!(
        plot_data(&reduced(100), &traced, "", &out, 480),
        Err(PlotError::TooSmall {
            width_px: 100,
            height_px: 480
        })
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
    jump.samples[11].sent_force_n.z = -1e9;
    plot_trace(&jump, "jump", &out, 640, 480).unwrap();
}

#[test]
fn the_effort_is_named_by_solver() {
    let mut traced = trace(5);
    assert_eq!(effort_name(&traced), "sweeps or iterations");
    for (solver, name) in [
        ("exact", "sweeps"),
        ("exact-dual", "sweeps"),
        ("euler-baseline", "iterations"),
        ("constraint-baseline", "iterations"),
    ] {
        let meta = crate::TraceMeta::new(
            vec!["surface".into()],
            1000.0,
            serde_json::Value::Null,
            "v",
            solver,
        );
        let sidecar = crate::Sidecar::new(&meta, crate::TraceFormat::Csv, Path::new("t.csv"));
        traced.sidecar = Some(sidecar);
        assert_eq!(effort_name(&traced), name, "{solver}");
    }
}

#[test]
fn one_spike_does_not_squash_the_axis_and_is_marked() {
    let values: Vec<f64> = (0..1000).map(|i| f64::from(i % 10) * 0.1).collect();
    let mut spiked = values.clone();
    spiked[500] = 1e6;
    let range = robust_range(spiked.iter().copied());
    assert!(range.end < 2.0 && range.start < 0.0, "{range:?}");
    // Spread-out data keeps its full range.
    assert_eq!(
        robust_range(values.iter().copied()),
        padded_range(values.iter().copied())
    );
    let points: Points = spiked
        .iter()
        .enumerate()
        .map(|(i, &v)| (i as f64, v))
        .collect();
    let (clamped, outside) = clamp_outliers(points, &range);
    assert_eq!(outside, vec![(500.0, range.end)]);
    assert!(clamped
        .iter()
        .all(|p| range.contains(&p.1) || p.1 == range.end));
}

fn reduce(samples: &[TraceSample]) -> PlotData {
    let mut data = PlotData::new(1000);
    samples.iter().for_each(|s| data.push(s));
    data
}

#[test]
fn flagged_periods_are_found_and_merged() {
    let mut data = samples(1000, 1);
    let flagged = [(100, 199), (600, 609), (990, 999)];
    for (i, s) in data.iter_mut().enumerate() {
        s.flags = 0;
        if flagged.iter().any(|&(a, b)| (a..=b).contains(&i)) {
            s.flags = crate::FLAG_FORCE_LIMITED_BY_SAFETY;
        }
    }
    let reduced = reduce(&data);
    let periods = reduced.flag_periods(crate::FLAG_FORCE_LIMITED_BY_SAFETY);
    // At the buckets' resolution: each period covers its flagged samples and reaches at most one bucket
    // past them (less than the 1 ms between samples here).
    let width = reduced.series.width_s;
    assert!(width < 1e-3, "{width}");
    assert_eq!(periods.len(), flagged.len(), "{periods:?}");
    for (&(start, end), &(a, b)) in periods.iter().zip(&flagged) {
        let (ta, tb) = (data[a].t_s, data[b].t_s);
        assert!(start <= ta && start > ta - width, "{start} vs {ta}");
        assert!(end >= tb && end < tb + width + 1e-12, "{end} vs {tb}");
    }
    assert!(reduced
        .flag_periods(crate::FLAG_DEVICE_DISCONNECTED)
        .is_empty());
    // Flicker every other tick merges into one period.
    for (i, s) in data.iter_mut().enumerate() {
        s.flags = if i % 2 == 0 {
            crate::FLAG_DEVICE_DISCONNECTED
        } else {
            0
        };
    }
    assert_eq!(
        reduce(&data)
            .flag_periods(crate::FLAG_DEVICE_DISCONNECTED)
            .len(),
        1
    );
}

#[test]
fn svg_names_the_effort_shades_flags_and_counts_outliers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("flags.svg");
    let mut spiky = trace(2000);
    for (i, s) in spiky.samples.iter_mut().enumerate() {
        s.flags = if i < 300 {
            crate::FLAG_FORCE_LIMITED_BY_SAFETY
        } else {
            0
        };
    }
    spiky.samples[1500].sent_force_n.z = 1e4;
    plot_trace(&spiky, "flags", &out, 1200, 900).unwrap();
    let text = std::fs::read_to_string(&out).unwrap();
    for expected in [
        "sweeps or iterations per tick",
        "force held back (ramp-in, engage, slew)",
        "off the axis",
    ] {
        assert!(text.contains(expected), "the SVG lacks {expected:?}");
    }
    assert!(
        !text.contains("device away"),
        "no device flags in this trace"
    );
}

#[test]
fn envelope_keeps_spikes_and_time_order() {
    let mut data = samples(100_000, 1);
    data[55_555].sent_force_n.x = 99.0;
    let reduced = reduce(&data);
    let points = reduced.series_points(1, |v| v);
    assert!(points.len() <= 2 * 2 * 1000);
    assert!(points.iter().any(|p| p.1 == 99.0));
    assert!(points.windows(2).all(|w| w[0].0 <= w[1].0));
}

/// An hour at 1 kHz of a 20 mm circle run every 3 s (Nyquist's worst case for drawing every n-th sample:
/// 3.6 million samples thinned to a few thousand would take them about 0.9 s apart, 108 degrees of the
/// circle, and draw a star). The kept path points all lie on the circle, no two consecutive ones are more
/// than a sixth of it apart (so the polygon drawn through them stays round), and the drawn extents are the
/// circle's, computed here from the samples.
#[test]
fn an_hour_of_a_3_s_circle_stays_round_and_keeps_its_extremes() {
    let radius_mm = 20.0;
    let mut data = PlotData::new(1200);
    let (mut x_low, mut x_high, mut y_low, mut y_high) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    let (mut f_low, mut f_high) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut sample = TraceSample::zeroed(1);
    for i in 0..3_600_000u64 {
        sample.tick = i;
        sample.t_s = i as f64 * 1e-3;
        let angle = std::f64::consts::TAU * sample.t_s / 3.0;
        sample.probe_m = glam::DVec3::new(angle.cos(), angle.sin(), 0.0) * radius_mm * 1e-3;
        sample.proxy_m = sample.probe_m;
        sample.sent_force_n = glam::DVec3::new(angle.sin(), 0.0, 0.0);
        let mm = sample.probe_m * 1e3;
        (x_low, x_high) = (x_low.min(mm.x), x_high.max(mm.x));
        (y_low, y_high) = (y_low.min(mm.y), y_high.max(mm.y));
        (f_low, f_high) = (
            f_low.min(sample.sent_force_n.x),
            f_high.max(sample.sent_force_n.x),
        );
        data.push(&sample);
    }
    let (probe, _) = data.path_points(VIEW_TOP);
    assert!(probe.len() < 16 * PATH_BUCKETS, "{}", probe.len());
    let mut widest = 0.0f64;
    for pair in probe.windows(2) {
        let [a, b] = [pair[0], pair[1]].map(|(x, y)| {
            assert!(((x * x + y * y).sqrt() - radius_mm).abs() < 1e-9);
            y.atan2(x)
        });
        let apart = (b - a).rem_euclid(std::f64::consts::TAU);
        widest = widest.max(apart.min(std::f64::consts::TAU - apart));
    }
    assert!(
        widest < std::f64::consts::TAU / 6.0,
        "consecutive path points {:.1} degrees apart",
        widest.to_degrees()
    );
    let extents = data.drawn_extents();
    let get = |name: &str| extents.iter().find(|e| e.0 == name).map(|e| (e.1, e.2));
    assert_eq!(get("probe x"), Some((x_low, x_high)));
    assert_eq!(get("probe y"), Some((y_low, y_high)));
    assert_eq!(get("Fx"), Some((f_low, f_high)));
    let dir = tempfile::tempdir().unwrap();
    let trace = Trace {
        mode_names: vec!["surface".into()],
        samples: Vec::new(),
        sidecar: None,
        warnings: Vec::new(),
    };
    plot_data(&data, &trace, "an hour", &dir.path().join("hour.png"), 1000).unwrap();
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
fn sub_millimetre_motion_gets_readable_path_limits() {
    // The probe wobbles 0.2 mm round (12.3, -4.5, 30.0) mm, the proxy 0.05 mm above it: both views'
    // axes span MIN_PATH_SPAN_MM, centred on the data, instead of the 0.4 mm the data covers.
    let mut wobble = trace(2000);
    for (i, s) in wobble.samples.iter_mut().enumerate() {
        let a = i as f64 * 0.01;
        s.probe_m = glam::DVec3::new(
            12.3e-3 + 0.2e-3 * a.cos(),
            -4.5e-3 + 0.2e-3 * a.sin(),
            30.0e-3 + 0.1e-3 * (2.0 * a).sin(),
        );
        s.proxy_m = s.probe_m + glam::DVec3::new(0.0, 0.0, 0.05e-3);
    }
    let centre = |r: &Range<f64>| 0.5 * (r.start + r.end);
    let span = |r: &Range<f64>| r.end - r.start;
    for (name, vertical, expected_vertical_centre) in [
        (
            "top",
            (|v: glam::DVec3| v.y) as fn(glam::DVec3) -> f64,
            -4.5,
        ),
        ("side", |v: glam::DVec3| v.z, 30.025),
    ] {
        let view = if vertical(glam::DVec3::Z) == 1.0 {
            VIEW_SIDE
        } else {
            VIEW_TOP
        };
        let (probe, proxy) = reduce(&wobble.samples).path_points(view);
        let (x, y) = path_data_limits(&probe, &proxy);
        assert!(
            (span(&x) - MIN_PATH_SPAN_MM).abs() < 1e-9,
            "{name}: x {x:?}"
        );
        assert!(
            (span(&y) - MIN_PATH_SPAN_MM).abs() < 1e-9,
            "{name}: y {y:?}"
        );
        assert!((centre(&x) - 12.3).abs() < 0.01, "{name}: x {x:?}");
        assert!(
            (centre(&y) - expected_vertical_centre).abs() < 0.01,
            "{name}: y {y:?}"
        );
        for p in probe.iter().chain(&proxy) {
            assert!(
                x.contains(&p.0) && y.contains(&p.1),
                "{name}: {p:?} off the axes"
            );
        }
    }
    // A path wider than the minimum keeps its own (robust, padded) limits.
    let wide = vec![(0.0, 0.0), (40.0, 20.0)];
    let (x, y) = path_data_limits(&wide, &wide);
    assert!(
        (x.start + 2.0).abs() < 1e-9 && (x.end - 42.0).abs() < 1e-9,
        "{x:?}"
    );
    assert!(
        (y.start + 1.0).abs() < 1e-9 && (y.end - 21.0).abs() < 1e-9,
        "{y:?}"
    );
    // Drawing the sub-millimetre trace works.
    let dir = tempfile::tempdir().unwrap();
    plot_trace(&wobble, "wobble", &dir.path().join("w.svg"), 800, 600).unwrap();
}

#[test]
fn equal_aspect_gives_equal_scales() {
    let (x, y) = equal_aspect(0.0..10.0, 0.0..1.0, 400.0, 200.0);
    let x_scale = (x.end - x.start) / 400.0;
    let y_scale = (y.end - y.start) / 200.0;
    assert!((x_scale - y_scale).abs() < 1e-12);
    assert!(x.start <= 0.0 && x.end >= 10.0 && y.start <= 0.0 && y.end >= 1.0);
}
