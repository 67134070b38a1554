//! Tests of the OpenIGTLink server: flags, the stream, control, limits.

use super::codec::{Header, Transform, HEADER_BYTES};
use super::config::{IgtlArgs, IgtlConfig, DEFAULT_ADDR};
use super::state::{choose_victim, Candidate};
use super::stream::encode_stream;
use glam::DVec3;
use std::time::Duration;
use voxhap_api::Snapshot;

fn parse(args: &[&str]) -> Result<IgtlArgs, clap::Error> {
    crate::config::parse_flags(args)
}

#[test]
fn off_by_default_and_a_bare_flag_is_loopback_18944_at_60_hz() {
    assert_eq!(parse(&[]).unwrap().resolve().unwrap(), None);
    let config = parse(&["--igtl"]).unwrap().resolve().unwrap().unwrap();
    assert_eq!(config.addr, DEFAULT_ADDR);
    assert_eq!(config.rate_hz, 60);
    let config = parse(&["--igtl", "localhost:0", "--igtl-rate", "250"])
        .unwrap()
        .resolve()
        .unwrap()
        .unwrap();
    assert_eq!((config.addr.port(), config.rate_hz), (0, 250));
    assert_eq!(config.idle_timeout, Duration::from_secs(30));
    let config = parse(&["--igtl", "--igtl-idle-timeout", "5"])
        .unwrap()
        .resolve()
        .unwrap()
        .unwrap();
    assert_eq!(config.idle_timeout, Duration::from_secs(5));
}

#[test]
fn an_idle_timeout_out_of_range_is_refused() {
    for bad in ["0", "3601", "-1", "1.5"] {
        assert!(
            parse(&["--igtl", "--igtl-idle-timeout", bad]).is_err(),
            "{bad} accepted"
        );
    }
    let mut config = IgtlConfig::new(DEFAULT_ADDR);
    config.idle_timeout = Duration::from_millis(500);
    let error = config.check(false).unwrap_err().to_string();
    assert!(error.contains("--igtl-idle-timeout"), "{error}");
}

/// The documented order (module header): without the token first, then stalled, then silent longest,
/// then the oldest.
#[test]
fn the_connection_closed_for_a_newcomer_follows_the_documented_order() {
    let c = |authorised, stalled, silent_ms| Candidate {
        authorised,
        stalled,
        silent_ms,
    };
    let cases: [(&str, &[Candidate], Option<usize>); 6] = [
        ("none", &[], None),
        (
            "equal: the oldest",
            &[c(false, false, 5), c(false, false, 5)],
            Some(0),
        ),
        (
            "silent longest",
            &[c(false, false, 5), c(false, false, 9)],
            Some(1),
        ),
        (
            "a stalled one before one silent longer",
            &[c(false, false, 90_000), c(false, true, 10)],
            Some(1),
        ),
        (
            "one without the token before a stalled, silent token holder",
            &[c(true, true, 90_000), c(false, false, 0)],
            Some(1),
        ),
        (
            "all with the token: the same order among them",
            &[c(true, false, 7), c(true, true, 1), c(true, false, 8)],
            Some(1),
        ),
    ];
    for (case, candidates, victim) in cases {
        assert_eq!(choose_victim(candidates), victim, "{case}");
    }
}

#[test]
fn a_remote_address_needs_the_flag_and_bad_values_are_refused() {
    let error = parse(&["--igtl", "0.0.0.0:18944"])
        .unwrap()
        .resolve()
        .unwrap_err();
    assert!(error.to_string().contains("--igtl-allow-remote"), "{error}");
    assert!(parse(&["--igtl", "0.0.0.0:18944", "--igtl-allow-remote"])
        .unwrap()
        .resolve()
        .unwrap()
        .is_some());
    for bad in [
        &["--igtl-rate", "0"][..],
        &["--igtl", "--igtl-rate", "1001"],
        &["--igtl", "18944"],
        &["--igtl-allow-remote"],
    ] {
        assert!(parse(bad).is_err(), "{bad:?} accepted");
    }
}

#[test]
fn the_stream_is_millimetres_and_newtons_and_never_non_finite() {
    let snapshot = Snapshot {
        probe_m: DVec3::new(0.01, -0.02, 0.03),
        proxy_m: DVec3::new(0.0, 0.0, 0.001),
        probe_velocity_m_per_s: DVec3::new(f64::NAN, 0.0, 0.0),
        sent_force_n: DVec3::new(0.5, 0.0, -1.5),
        ..Snapshot::example()
    };
    let mut out = Vec::new();
    encode_stream(&mut out, 1, &snapshot, 0);
    let mut at = 0;
    let mut seen = Vec::new();
    while at < out.len() {
        let raw: &[u8; HEADER_BYTES] = out[at..at + HEADER_BYTES].try_into().unwrap();
        let header = Header::decode(raw, 1000).unwrap();
        let body = &out[at + HEADER_BYTES..at + HEADER_BYTES + header.body_size as usize];
        header.check_crc(body).unwrap();
        let transform = Transform::decode(body).unwrap();
        assert_eq!(transform.rotation, glam::DMat3::IDENTITY);
        seen.push((header.device_name, transform.translation));
        at += HEADER_BYTES + header.body_size as usize;
    }
    let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-4;
    assert_eq!(seen.len(), 4);
    assert_eq!(seen[0].0, "Probe");
    assert!(close(seen[0].1, DVec3::new(10.0, -20.0, 30.0)));
    assert!(close(seen[1].1, DVec3::new(0.0, 0.0, 1.0)));
    assert_eq!(seen[2].0, "ProbeVelocity");
    assert_eq!(seen[2].1, DVec3::ZERO);
    assert_eq!(seen[3].0, "Force");
    assert!(close(seen[3].1, DVec3::new(0.5, 0.0, -1.5)));
}
