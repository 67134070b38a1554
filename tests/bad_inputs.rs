//! Keeps docs/bad-inputs.md true: every row of its tables is a case here, run against the real `voxhap`
//! binary (files made in a temporary folder) or a real server on 127.0.0.1:0, and the tables in the page
//! are generated from these cases. A case whose error text changed fails; a page that no longer matches the
//! cases fails too (rewrite it with `VOXHAP_BLESS=1 cargo test --test integration bad_inputs`).

use crate::util::server::{TestServer, TOKEN};
use std::io::Write;
use std::path::Path;
use std::process::Command;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use voxhap::servo::api::folders::VolumeDirs;

mod requests;
use requests::REQUESTS;

/// One bad input given to a command.
struct Case {
    /// What the input is (Markdown).
    input: &'static str,
    /// Makes the files the command reads, in the case's own folder.
    setup: fn(&Path),
    args: &'static [&'static str],
    /// Exit code: 2 for a flag refused when parsed, 1 for any other error.
    exit: i32,
    /// Text the error message contains.
    expected: &'static str,
}

fn write(dir: &Path, name: &str, bytes: &[u8]) {
    std::fs::write(dir.join(name), bytes).unwrap();
}

fn nothing(_: &Path) {}

fn nifti_gz(dims: u16, zeros: usize) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (i, d) in [3u16, dims, dims, dims, 1, 1, 1, 1].iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&2i16.to_le_bytes());
    h[72..74].copy_from_slice(&8i16.to_le_bytes());
    for i in 0..4 {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&1f32.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[344..348].copy_from_slice(b"n+1\0");
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    encoder.write_all(&h).unwrap();
    encoder.write_all(&vec![0u8; zeros]).unwrap();
    encoder.finish().unwrap()
}

fn nhdr(data_file: &str) -> Vec<u8> {
    format!("NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: {data_file}\n\n")
        .into_bytes()
}

fn scenario(dir: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string("sims/sphere_surface.toml")
        .unwrap()
        .replace(from, to);
    write(dir, "scene.toml", text.as_bytes());
}

/// The scenario with its `[path]` table (the last one in the file) replaced by `path_table`.
fn scenario_path(dir: &Path, path_table: &str) {
    let text = std::fs::read_to_string("sims/sphere_surface.toml").unwrap();
    let (head, _) = text.split_once("[path]").unwrap();
    write(dir, "scene.toml", format!("{head}{path_table}").as_bytes());
}

/// A sparse file of 629 MB (no disk blocks): larger than any text input's limit.
fn big_file(path: &Path) {
    std::fs::File::create(path)
        .unwrap()
        .set_len(629_000_000)
        .unwrap();
}

fn mcap(dir: &Path) {
    let text = std::fs::read_to_string("sims/sphere_surface.toml")
        .unwrap()
        .replace("duration_s = 6.0", "duration_s = 0.01");
    write(dir, "short.toml", text.as_bytes());
    let status = voxhap()
        .args(["sim", "short.toml", "--out", "trace.mcap"])
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(status.status.success(), "{status:?}");
    let mut bytes = std::fs::read(dir.join("trace.mcap")).unwrap();
    bytes[9..17].copy_from_slice(&4_300_000_000u64.to_le_bytes());
    write(dir, "trace.mcap", &bytes);
}

/// A short scenario `scene.toml` and a dangling symlink `link` (its target in a folder that exists).
fn scenario_and_dangling_link(dir: &Path, link: &str) {
    scenario(dir, "duration_s = 6.0", "duration_s = 0.01");
    std::fs::create_dir(dir.join("elsewhere")).unwrap();
    std::os::unix::fs::symlink(dir.join("elsewhere/created"), dir.join(link)).unwrap();
}

/// A short CSV trace `trace.csv` whose sidecar claims 99999 samples.
fn lying_sidecar(dir: &Path) {
    scenario(dir, "duration_s = 6.0", "duration_s = 0.01");
    let status = voxhap()
        .args(["sim", "scene.toml", "--out", "trace.csv"])
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(status.status.success(), "{status:?}");
    let path = dir.join("trace.csv.json");
    let mut sidecar: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    sidecar["sample_count"] = 99999.into();
    std::fs::write(&path, serde_json::to_vec(&sidecar).unwrap()).unwrap();
}

/// A 2x2x2 gzip NRRD whose byte skip is 256 MiB of zeros (four gzip members of 64 MiB, 256 kB on disk)
/// with no data after it.
fn gzip_skip_bomb(dir: &Path) {
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    encoder.write_all(&vec![0u8; 64 << 20]).unwrap();
    let member = encoder.finish().unwrap();
    let mut bytes = format!(
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\nbyte skip: {}\n\n",
        4u64 << 26
    )
    .into_bytes();
    for _ in 0..4 {
        bytes.extend_from_slice(&member);
    }
    write(dir, "skip.nrrd", &bytes);
}

const CASES: &[Case] = &[
    Case {
        input: "a FIFO (named pipe) as a volume",
        setup: |dir| mkfifo(&dir.join("pipe.nii")),
        args: &["info", "pipe.nii"],
        exit: 1,
        expected: "it is a FIFO (named pipe), not a regular file (only regular files are read)",
    },
    Case {
        input: "a symlink to `/dev/zero` as a volume",
        setup: |dir| std::os::unix::fs::symlink("/dev/zero", dir.join("zero.nii")).unwrap(),
        args: &["info", "zero.nii"],
        exit: 1,
        expected: "it is a character device, not a regular file",
    },
    Case {
        input: "a folder named like a volume",
        setup: |dir| std::fs::create_dir(dir.join("folder.nrrd")).unwrap(),
        args: &["info", "folder.nrrd"],
        exit: 1,
        expected: "it is a directory, not a regular file",
    },
    Case {
        input: "a .nii.gz whose header claims 1024^3 voxels (a gzip bomb)",
        setup: |dir| write(dir, "bomb.nii.gz", &nifti_gz(1024, 1024)),
        args: &["info", "bomb.nii.gz"],
        exit: 1,
        expected: "loading this volume needs 5368709472 bytes (the data read or inflated plus 4 bytes per value), more than --max-volume-bytes 4294967296",
    },
    Case {
        input: "a 2x2x2 .nii.gz followed by 64 MiB of compressed zeros",
        setup: |dir| write(dir, "long.nii.gz", &nifti_gz(2, 64 << 20)),
        args: &["info", "long.nii.gz"],
        exit: 1,
        expected: "data is longer than the header describes (8 bytes expected, more found)",
    },
    Case {
        input: "a 2x2x2 NRRD with `byte skip: 5000000000`",
        setup: |dir| {
            write(
                dir,
                "skip.nrrd",
                b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\nbyte skip: 5000000000\n\n",
            )
        },
        args: &["info", "skip.nrrd"],
        exit: 1,
        expected: "more than --max-volume-bytes 4294967296",
    },
    Case {
        input: "a volume within a lowered limit",
        setup: |dir| write(dir, "small.nii.gz", &nifti_gz(64, 0)),
        args: &["info", "small.nii.gz", "--max-volume-bytes", "1M"],
        exit: 1,
        expected: "loading this volume needs 1311072 bytes (the data read or inflated plus 4 bytes per value), more than --max-volume-bytes 1048576",
    },
    Case {
        input: "a .nhdr whose `data file:` climbs out of its folder",
        setup: |dir| write(dir, "climb.nhdr", &nhdr("../../../../../../../../etc/passwd")),
        args: &["info", "climb.nhdr"],
        exit: 1,
        expected: "resolves to /etc/passwd, outside the folder",
    },
    Case {
        input: "a .nhdr whose `data file:` is `/dev/zero`, outside paths allowed",
        setup: |dir| write(dir, "zero.nhdr", &nhdr("/dev/zero")),
        args: &["info", "zero.nhdr", "--allow-outside-paths"],
        exit: 1,
        expected: "cannot read the data file /dev/zero: it is a character device, not a regular file",
    },
    Case {
        input: "a .mhd whose `ElementDataFile` is absolute",
        setup: |dir| {
            write(
                dir,
                "abs.mhd",
                b"NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = /etc/passwd\n",
            )
        },
        args: &["info", "abs.mhd"],
        exit: 1,
        expected: "(add --allow-outside-paths to allow this)",
    },
    Case {
        input: "a raw .toml whose `data_file` is a symlink out of its folder",
        setup: |dir| {
            std::os::unix::fs::symlink("/etc/passwd", dir.join("link.raw")).unwrap();
            write(
                dir,
                "raw.toml",
                b"data_file = \"link.raw\"\ndims = [2, 2, 2]\nscalar_type = \"u8\"\nspacing = [1, 1, 1]\n",
            );
        },
        args: &["info", "raw.toml"],
        exit: 1,
        expected: "resolves to /etc/passwd, outside the folder",
    },
    Case {
        input: "a scenario whose volume file is a symlink out of its folder",
        setup: |dir| {
            std::os::unix::fs::symlink("/etc/passwd", dir.join("link.nii")).unwrap();
            scenario(dir, "builtin = \"sphere\"", "file = \"link.nii\"");
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "(add --allow-outside-paths to allow this)",
    },
    Case {
        input: "a scenario with `substeps_per_tick = 4000000000`",
        setup: |dir| scenario(dir, "[arm]", "[arm]\nsubsteps_per_tick = 4000000000"),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "arm.substeps_per_tick: 4000000000 is out of range 1..=1000",
    },
    Case {
        input: "a scenario with `speed_m_per_s = \"fast\"` in `[path]`",
        setup: |dir| scenario(dir, "speed_m_per_s = 0.02", "speed_m_per_s = \"fast\""),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "scene.toml: path.speed_m_per_s: invalid type: string \"fast\", expected f64 (line 35, column 17)",
    },
    Case {
        input: "a scenario whose `[path]` has a key of another kind (`radius_m` in a waypoints path)",
        setup: |dir| scenario(dir, "speed_m_per_s = 0.02", "speed_m_per_s = 0.02\nradius_m = 0.01"),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "scene.toml: path: kind = \"waypoints\" takes no key `radius_m` (its keys: `points_m`, `speed_m_per_s`)",
    },
    Case {
        input: "a scenario with `radius_m = \"big\"` in `[arm.workspace]`",
        setup: |dir| {
            scenario(
                dir,
                "workspace = { shape = \"box\", min_m = [-0.08, -0.08, -0.08], max_m = [0.08, 0.08, 0.08] }",
                "workspace = { shape = \"sphere\", center_m = [0.0, 0.0, 0.0], radius_m = \"big\" }",
            )
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "scene.toml: arm.workspace.radius_m: invalid type: string \"big\", expected f64",
    },
    Case {
        input: "a scenario with `duration_s = \"slow\"` in `[path.profile]`",
        setup: |dir| {
            scenario_path(
                dir,
                "[path]\nkind = \"force\"\n[path.profile]\nshape = \"ramp\"\nfrom_n = [0.0, 0.0, 0.0]\n\
                 to_n = [0.0, 0.0, -1.0]\nduration_s = \"slow\"\n",
            )
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "scene.toml: path.profile.duration_s: invalid type: string \"slow\", expected f64",
    },
    Case {
        input: "a device profile with `scale = \"big\"` in `[mapping]`",
        setup: |dir| write(dir, "arm.toml", b"[mapping]\nscale = \"big\"\n"),
        args: &["serve", "--device-profile", "arm.toml", "--no-http", "--no-foxglove"],
        exit: 1,
        expected: "device profile arm.toml: mapping.scale: invalid type: string \"big\", expected f64",
    },
    Case {
        input: "a scenario with `rate_hz = 1e12`",
        setup: |dir| scenario(dir, "rate_hz = 1000.0", "rate_hz = 1e12"),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "rate_hz: 1000000000000 Hz is out of range 1..=100000 Hz",
    },
    Case {
        input: "a scenario with a path speed of `1e300` m/s (ran to an all-NaN trace)",
        setup: |dir| scenario(dir, "speed_m_per_s = 0.02", "speed_m_per_s = 1e300"),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "path.speed_m_per_s = 1e300 is out of range: give a number > 0 and at most 100 m/s",
    },
    Case {
        input: "a scenario whose surface transfer function reaches `1e300` N",
        setup: |dir| scenario(dir, "[0.5, 2.0]]", "[0.5, 1e300]]"),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "modes[0].transfer: strength must be from 0 to 1000000 N (breakpoint 1: 1e300)",
    },
    Case {
        input: "`sim --set modes[0].transfer[0][0]=-1e308` (breakpoints whose span overflows)",
        setup: |dir| scenario(dir, "", ""),
        args: &["sim", "scene.toml", "--set", "modes[0].transfer[0][0]=-1e308", "--out", "t.csv"],
        exit: 1,
        expected: "modes[0].transfer: x must be from -1e300 to 1e300 (breakpoint 0: -1e308)",
    },
    Case {
        input: "a scenario with friction `mu = 1e300`",
        setup: |dir| {
            scenario(
                dir,
                "[arm]",
                "[[modes]]\nkind = \"friction\"\nsurface = \"surface\"\nmu = 1e300\n\n[arm]",
            )
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "modes[1].mu: must be a finite number from 0 to 10, got 1e300",
    },
    Case {
        input: "a support plane of `strength_n = 1e300`",
        setup: |dir| {
            scenario(
                dir,
                "[arm]",
                "[[modes]]\nkind = \"support_plane\"\npoint_m = [0.0, 0.0, -0.04]\nnormal = [0.0, 0.0, 1.0]\nstrength_n = 1e300\n\n[arm]",
            )
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "modes[1].strength_n: must be a finite number from 0 to 1000000 N, got 1e300",
    },
    Case {
        input: "a support plane through a point `1e300` m away",
        setup: |dir| {
            scenario(
                dir,
                "[arm]",
                "[[modes]]\nkind = \"support_plane\"\npoint_m = [0.0, 0.0, 1e300]\nnormal = [0.0, 0.0, 1.0]\nstrength_n = 2.0\n\n[arm]",
            )
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "modes[1].point_m: must be three finite numbers, each from -1000 to 1000 m, got [0, 0, 1e300]",
    },
    Case {
        input: "a support plane with a zero normal",
        setup: |dir| {
            scenario(
                dir,
                "[arm]",
                "[[modes]]\nkind = \"support_plane\"\npoint_m = [0.0, 0.0, -0.04]\nnormal = [0.0, 0.0, 0.0]\nstrength_n = 2.0\n\n[arm]",
            )
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "modes[1].normal: direction must not be zero",
    },
    Case {
        input: "`sim --set k_n_per_m=1e300`",
        setup: |dir| scenario(dir, "", ""),
        args: &["sim", "scene.toml", "--set", "k_n_per_m=1e300", "--out", "t.csv"],
        exit: 1,
        expected: "k_n_per_m: 1e300 N/m is out of range: give a number from 0.001 to 10000000 N/m",
    },
    Case {
        input: "a sweep over a hand mass of `1e300` kg",
        setup: |dir| scenario(dir, "", ""),
        args: &["sweep", "scene.toml", "--set", "arm.mass_kg=0.1,1e300", "--out-dir", "out"],
        exit: 1,
        expected: "arm.mass_kg = 1e300 is out of range: give a number > 0 and at most 1000 kg",
    },
    Case {
        input: "a scenario with a sine force of `frequency_hz = 1e300`",
        setup: |dir| {
            scenario_path(
                dir,
                "[path]\nkind = \"force\"\n[path.profile]\nshape = \"sine\"\noffset_n = [0.0, 0.0, 0.0]\n\
                 amplitude_n = [0.0, 0.0, 1.0]\nfrequency_hz = 1e300\n",
            )
        },
        args: &["sim", "scene.toml", "--set", "start_m=[0.0, 0.0, 0.03]", "--out", "t.csv"],
        exit: 1,
        expected: "path.profile.frequency_hz = 1e300 is out of range: give a number > 0 and at most 10000 Hz",
    },
    Case {
        input: "a raster path of `lines = 4000000000` (walked every substep)",
        setup: |dir| {
            scenario_path(
                dir,
                "[path]\nkind = \"raster\"\norigin_m = [0.0, 0.0, 0.03]\nsweep_m = [0.01, 0.0, 0.0]\n\
                 step_m = [0.0, 0.01, 0.0]\nlines = 4000000000\nspeed_m_per_s = 0.02\n",
            )
        },
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "path.lines = 4000000000 is out of range: give a number from 1 to 10000 lines",
    },
    Case {
        input: "a solve scene with `k = 1e300`",
        setup: |dir| {
            write(dir, "scene.json", br#"{"k": 1e300, "probe": [0, 0, 0], "primitives": []}"#)
        },
        args: &["solve", "--scene", "scene.json"],
        exit: 1,
        expected: "scene.json: k: 1e300 N/m is out of range: give a number from 0.001 to 10000000 N/m",
    },
    Case {
        input: "a solve scene with a primitive of strength `1e300` N",
        setup: |dir| {
            write(
                dir,
                "scene.json",
                br#"{"k": 500, "probe": [0, 0, 0], "primitives": [{"type": "point", "position": [0, 0, 0], "strength": 1e300}]}"#,
            )
        },
        args: &["solve", "--scene", "scene.json"],
        exit: 1,
        expected: "scene.json: primitives[0].strength: 1e300 N is out of range: give a number from 0 to 1000000 N",
    },
    Case {
        input: "a solve scene with its probe at `1e300` m",
        setup: |dir| {
            write(dir, "scene.json", br#"{"k": 500, "probe": [1e300, 0, 0], "primitives": []}"#)
        },
        args: &["solve", "--scene", "scene.json"],
        exit: 1,
        expected: "scene.json: probe: [1e300, 0.0, 0.0] is out of range: each of x, y, z must be from -1000 to 1000 m",
    },
    Case {
        input: "a 629 MB (sparse) scenario to `sim --set`",
        setup: |dir| big_file(&dir.join("big.toml")),
        args: &["sim", "big.toml", "--set", "k_n_per_m=400", "--out", "t.csv"],
        exit: 1,
        expected: "cannot read scenario file big.toml: it is 629000000 bytes, more than the 16777216-byte limit for a text file (16 MiB)",
    },
    Case {
        input: "a 629 MB (sparse) scenario to `sweep`",
        setup: |dir| big_file(&dir.join("big.toml")),
        args: &["sweep", "big.toml", "--set", "k_n_per_m=400,500", "--out-dir", "out"],
        exit: 1,
        expected: "cannot read scenario file big.toml: it is 629000000 bytes, more than the 16777216-byte limit for a text file (16 MiB)",
    },
    Case {
        input: "a FIFO as a scenario",
        setup: |dir| mkfifo(&dir.join("scene.toml")),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "it is a FIFO (named pipe), not a regular file",
    },
    Case {
        input: "an MCAP trace with 8 bytes of a record length overwritten",
        setup: mcap,
        args: &["plot", "trace.mcap", "--out", "p.png"],
        exit: 1,
        expected: "damaged file: a record claims 4300000000 bytes, more than remain at byte 8",
    },
    Case {
        input: "`/dev/zero` as a trace to plot",
        setup: nothing,
        args: &["plot", "/dev/zero", "--out", "p.png"],
        exit: 1,
        expected: "cannot read /dev/zero: it is a character device, not a regular file",
    },
    Case {
        input: "`/dev/zero` as a trace to replay",
        setup: nothing,
        args: &["serve", "--device", "replay:/dev/zero", "--no-http", "--no-foxglove"],
        exit: 1,
        expected: "replay trace /dev/zero: cannot read /dev/zero",
    },
    Case {
        input: "`--max-volume-bytes 1k`",
        setup: nothing,
        args: &["info", "builtin:sphere", "--max-volume-bytes", "1k"],
        exit: 2,
        expected: "1024 bytes is out of range: give 1M (1048576) to 1T (1099511627776)",
    },
    Case {
        input: "`serve --duration 1e20`",
        setup: nothing,
        args: &["serve", "--duration", "1e20"],
        exit: 2,
        expected: "1e20 s is out of range: give a number of seconds > 0 and <= 1e9",
    },
    Case {
        input: "`bench-loop --seconds 1e20`",
        setup: nothing,
        args: &["bench-loop", "--seconds", "1e20"],
        exit: 2,
        expected: "1e20 s is out of range: give a number of seconds > 0 and <= 1e9",
    },
    Case {
        input: "`bench-loop --load-threads 2000`",
        setup: nothing,
        args: &["bench-loop", "--load-threads", "2000"],
        exit: 2,
        expected: "2000 is not in 0..=64",
    },
    Case {
        input: "`plot --width 100000`",
        setup: nothing,
        args: &["plot", "t.csv", "--out", "p.png", "--width", "100000"],
        exit: 2,
        expected: "100000 is not in 400..=8192",
    },
    Case {
        input: "`plot --height 4294967295`",
        setup: nothing,
        args: &["plot", "t.csv", "--out", "p.png", "--height", "4294967295"],
        exit: 2,
        expected: "4294967295 is not in 300..=8192",
    },
    Case {
        input: "`serve --volume-dir` naming no folder",
        setup: nothing,
        args: &["serve", "--volume-dir", "/nonexistent", "--no-http", "--no-foxglove"],
        exit: 1,
        expected: "--volume-dir /nonexistent: not a folder",
    },
    Case {
        input: "an OpenIGTLink idle timeout of 0 s",
        setup: nothing,
        args: &["serve", "--igtl", "--igtl-idle-timeout", "0", "--no-http", "--no-foxglove"],
        exit: 2,
        expected: "0 is not in 1..=3600",
    },
    Case {
        input: "a gzip NRRD whose `byte skip` is 256 MiB of compressed zeros, no data after it",
        setup: gzip_skip_bomb,
        args: &["info", "skip.nrrd"],
        exit: 1,
        expected: "data is truncated: the header describes 268435464 bytes but only 268435456 are there",
    },
    Case {
        input: "`plot --out` naming a dangling symlink",
        setup: |dir| scenario_and_dangling_link(dir, "p.png"),
        args: &["plot", "t.csv", "--out", "p.png"],
        exit: 1,
        expected: "p.png is a symbolic link; voxhap never writes a plot through one",
    },
    Case {
        input: "`sim --out` naming a dangling symlink",
        setup: |dir| scenario_and_dangling_link(dir, "t.csv"),
        args: &["sim", "scene.toml", "--out", "t.csv", "--force"],
        exit: 1,
        expected: "t.csv is a symbolic link; voxhap never writes a trace or sidecar through one, even with --force",
    },
    Case {
        input: "a trace whose sidecar path is a symlink",
        setup: |dir| scenario_and_dangling_link(dir, "t.csv.json"),
        args: &["sim", "scene.toml", "--out", "t.csv"],
        exit: 1,
        expected: "t.csv.json is a symbolic link",
    },
    Case {
        input: "`serve --record` naming a dangling symlink",
        setup: |dir| scenario_and_dangling_link(dir, "t.mcap"),
        args: &["serve", "--record", "t.mcap", "--duration", "0.1", "--no-http", "--no-foxglove"],
        exit: 1,
        expected: "t.mcap is a symbolic link",
    },
    Case {
        input: "`serve --record-dir` naming no folder",
        setup: nothing,
        args: &["serve", "--record-dir", "/nonexistent", "--no-http", "--no-foxglove"],
        exit: 1,
        expected: "--record-dir /nonexistent: not a folder",
    },
    Case {
        input: "a sidecar that claims more samples than its trace holds (a warning; the data win)",
        setup: lying_sidecar,
        args: &["trace", "repair", "trace.csv"],
        exit: 0,
        expected: "warning: trace.csv: the sidecar trace.csv.json does not match the trace: it says 99999 samples, the trace holds 10",
    },
    Case {
        input: "the same lying sidecar, replayed",
        setup: lying_sidecar,
        args: &["serve", "--device", "replay:trace.csv", "--duration", "0.1", "--no-http", "--no-foxglove"],
        exit: 0,
        expected: "it says 99999 samples, the trace holds 10",
    },
];

fn voxhap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
}

fn mkfifo(path: &Path) {
    let c_path = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only creates the node.
    assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
}

fn escape(text: &str) -> String {
    text.replace('|', "\\|")
}

/// `text` as a Markdown code span in a table cell (a double-backtick span when it holds a backtick).
fn code(text: &str) -> String {
    if text.contains('`') {
        format!("`` {} ``", escape(text))
    } else {
        format!("`{}`", escape(text))
    }
}

/// The page's tables, as generated from the cases.
fn tables() -> String {
    let mut out =
        String::from("| input | command | exit | error message contains |\n|---|---|---|---|\n");
    for case in CASES {
        out.push_str(&format!(
            "| {} | `voxhap {}` | {} | {} |\n",
            case.input,
            case.args.join(" "),
            case.exit,
            code(case.expected)
        ));
    }
    out.push_str(
        "\nRequests to `voxhap serve --volume-dir DIR` on 127.0.0.1:PORT (DIR holds a FIFO `pipe.nii`):\n\n",
    );
    out.push_str("| input | request | status | error message contains |\n|---|---|---|---|\n");
    for case in REQUESTS {
        let first_line = case.request.lines().next().unwrap_or_default();
        let (head, body) = case
            .request
            .split_once("\r\n\r\n")
            .unwrap_or((case.request, ""));
        let mut parts: Vec<String> = head
            .split("\r\n")
            .skip(1)
            .filter(|h| h.starts_with("Host") || h.starts_with("Origin") || h.starts_with("Auth"))
            .map(|h| {
                h.replace("{addr}", "127.0.0.1:PORT")
                    .replace("{port}", "PORT")
            })
            .collect();
        if !body.is_empty() {
            parts.push(format!("body {body}"));
        }
        out.push_str(&format!(
            "| {} | `{first_line}` {} | {} | `{}` |\n",
            case.input,
            parts
                .iter()
                .map(|part| format!("`{}`", escape(part)))
                .collect::<Vec<_>>()
                .join(" "),
            case.status,
            escape(&case.expected.replace("{port}", "PORT"))
        ));
    }
    out
}

const BEGIN: &str = "<!-- bad-inputs:begin (generated by tests/bad_inputs.rs) -->\n";
const END: &str = "<!-- bad-inputs:end -->";

#[test]
fn the_page_lists_exactly_the_cases_that_are_run() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/bad-inputs.md");
    let page = std::fs::read_to_string(&path).unwrap();
    let (head, rest) = page.split_once(BEGIN).expect("the begin marker");
    let (_, tail) = rest.split_once(END).expect("the end marker");
    let wanted = format!("{head}{BEGIN}{}{END}{tail}", tables());
    if std::env::var_os("VOXHAP_BLESS").is_some() {
        std::fs::write(&path, &wanted).unwrap();
    }
    assert!(
        page == wanted,
        "docs/bad-inputs.md does not match the cases in tests/bad_inputs.rs; rerun with VOXHAP_BLESS=1"
    );
}

#[test]
fn every_bad_input_in_the_table_gets_its_error() {
    let mut failures = Vec::new();
    for case in CASES {
        let dir = tempfile::tempdir().unwrap();
        (case.setup)(dir.path());
        let output = voxhap()
            .args(case.args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        if output.status.code() != Some(case.exit) || !stderr.contains(case.expected) {
            failures.push(format!(
                "{}: expected exit {} and {:?}; got {:?}: {stderr}",
                case.input,
                case.exit,
                case.expected,
                output.status.code()
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_bad_request_in_the_table_gets_its_error() {
    let volumes = tempfile::tempdir().unwrap();
    mkfifo(&volumes.path().join("pipe.nii"));
    let dirs = VolumeDirs::new(&[volumes.path().to_path_buf()]).unwrap();
    let server = TestServer::start_full(4, |_| {}, Some(dirs)).await;
    for case in REQUESTS {
        let addr = server.addr.to_string();
        let port = server.addr.port().to_string();
        let request = case
            .request
            .replace("{addr}", &addr)
            .replace("{port}", &port)
            .replace("TOKEN", TOKEN);
        let mut stream = tokio::net::TcpStream::connect(server.addr).await.unwrap();
        stream.write_all(request.as_bytes()).await.unwrap();
        let mut response = Vec::new();
        let _ = tokio::time::timeout(
            std::time::Duration::from_secs(5),
            stream.read_to_end(&mut response),
        )
        .await;
        let text = String::from_utf8_lossy(&response);
        let status: u16 = text
            .split(' ')
            .nth(1)
            .and_then(|s| s.parse().ok())
            .unwrap_or(0);
        assert_eq!(status, case.status, "{}: {text}", case.input);
        let body = text.split_once("\r\n\r\n").map_or("", |(_, body)| body);
        let message = serde_json::from_str::<serde_json::Value>(body)
            .ok()
            .and_then(|v| v["error"].as_str().map(str::to_owned))
            .unwrap_or_else(|| text.to_string());
        let expected = case.expected.replace("{port}", &port);
        assert!(
            message.contains(&expected),
            "{}: {expected:?} not in {message}",
            case.input
        );
    }
}
