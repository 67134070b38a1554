//! The `voxhap info` binary on real files, built-in volumes and bad input, and its memory bound.

use crate::util::volume_files::{gzip, real_scan};
use std::io::Write;
use std::process::Command;

// ---------------------------------------------------------------------------------------------
// `voxhap info`

fn info(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .arg("info")
        .args(args)
        .output()
        .unwrap()
}

/// What `voxhap info --json` reports to help choose a surface level, against independent tools on the same
/// files (loaded with nibabel 5.4.2 / pynrrd 1.1.3 as float32): `skimage.filters.threshold_otsu(data)`
/// (scikit-image 0.26.0, 256 bins), `np.percentile(data, p, method="nearest")` and
/// `np.histogram(data, bins=16, range=(data.min(), data.max()))` (NumPy 2.4.6).
#[test]
fn info_levels_match_scikit_image_and_numpy() {
    let t1_histogram = [
        6788750u64, 118, 2626, 6439, 20146, 29449, 52393, 75663, 106564, 206987, 376136, 318561,
        240017, 331047, 120359, 34,
    ];
    let anatomical_histogram = [
        388u64, 939, 2714, 5336, 8445, 11996, 3812, 163, 8, 5, 3, 3, 3, 4, 2, 4,
    ];
    for (name, otsu, percentiles, histogram) in [
        (
            "mni152_t1_1mm.nii.gz",
            89.15039,
            [0.0, 0.0, 0.0, 0.0, 0.0, 209.0, 225.0],
            Some(&t1_histogram),
        ),
        (
            "mni152_wm_1mm.nrrd",
            102.09961,
            [0.0, 0.0, 0.0, 0.0, 0.0, 192.0, 254.0],
            None,
        ),
        (
            "nibabel_anatomical.nii",
            7564.619,
            [1203.0, 3713.0, 6824.0, 8935.0, 10130.0, 11786.0, 12721.0],
            Some(&anatomical_histogram),
        ),
    ] {
        let path = real_scan(name);
        let json = info_json(&path);
        let level = json["otsu_level"].as_f64().unwrap();
        // scikit-image prints float32; a different bin would be off by a whole bin width (about 1 or 121).
        assert!(
            (level - otsu).abs() < 1e-3 * otsu.abs().max(1.0),
            "{name}: {level} against {otsu}"
        );
        let got: Vec<(f64, f64)> = json["percentiles"]
            .as_array()
            .unwrap()
            .iter()
            .map(|pair| (pair[0].as_f64().unwrap(), pair[1].as_f64().unwrap()))
            .collect();
        let expected: Vec<(f64, f64)> = [1.0, 5.0, 25.0, 50.0, 75.0, 95.0, 99.0]
            .into_iter()
            .zip(percentiles)
            .collect();
        assert_eq!(got, expected, "{name}");
        if let Some(histogram) = histogram {
            let counts: Vec<u64> = json["histogram"]["counts"]
                .as_array()
                .unwrap()
                .iter()
                .map(|c| c.as_u64().unwrap())
                .collect();
            assert_eq!(counts, histogram.to_vec(), "{name}");
        }
    }
    // The text form names the level and where serve puts the surface.
    let path = real_scan("mni152_t1_1mm.nii.gz");
    let text = String::from_utf8(info(&[path.to_str().unwrap()]).stdout).unwrap();
    assert!(
        text.contains("surface level: 89.1504 (Otsu's threshold"),
        "{text}"
    );
    assert!(
        text.contains("percentiles: p1 0 p5 0 p25 0 p50 0 p75 0 p95 209 p99 225"),
        "{text}"
    );
}

/// The `voxhap info` examples in docs/volumes.md are what `info` prints, run from the project root as a reader
/// of the docs would.
#[test]
fn the_info_examples_in_the_docs_are_what_info_prints() {
    let root = env!("CARGO_MANIFEST_DIR");
    let docs = std::fs::read_to_string(std::path::Path::new(root).join("docs/volumes.md")).unwrap();
    for args in [
        &["data/nibabel_anatomical.nii"][..],
        &["data/nibabel_anatomical.nii", "--json"][..],
    ] {
        let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
            .current_dir(root)
            .arg("info")
            .args(args)
            .output()
            .unwrap();
        assert!(output.status.success());
        let block = format!(
            "$ voxhap info {}\n{}\n```",
            args.join(" "),
            String::from_utf8(output.stdout).unwrap().trim_end()
        );
        assert!(
            docs.contains(&block),
            "docs/volumes.md does not show what `voxhap info {}` prints:\n{block}",
            args.join(" ")
        );
    }
}

#[test]
fn info_json_on_real_files() {
    for (name, format, expected_max, origin_x_m) in [
        ("mni152_t1_1mm.nii.gz", "nifti", 255.0, -0.098),
        ("mni152_wm_1mm.nrrd", "nrrd", 255.0, -0.098),
        ("nibabel_anatomical.nii", "nifti", 30393.0, 0.032),
    ] {
        let path = real_scan(name);
        let json = info_json(&path);
        assert_eq!(json["format"], format);
        assert_eq!(json["kind"], "scalar");
        assert_eq!(json["max"], expected_max);
        assert_eq!(json["path"], path.to_str().unwrap());
        let affine = json["affine"].as_array().unwrap();
        assert_eq!(affine.len(), 4);
        assert!((affine[0][3].as_f64().unwrap() - origin_x_m).abs() < 1e-12);
        assert_eq!(affine[3], serde_json::json!([0.0, 0.0, 0.0, 1.0]));
        let spacing = json["spacing"].as_array().unwrap();
        assert!(spacing.iter().all(|s| s.as_f64().unwrap() > 0.0));
    }
    let path = real_scan("nibabel_anatomical.nii");
    let output = info(&[path.to_str().unwrap()]);
    let text = String::from_utf8(output.stdout).unwrap();
    assert!(text.contains("33 x 41 x 25"), "{text}");
    assert!(text.contains("type:     i16"), "{text}");
}

/// `voxhap info PATH --json`, which must succeed.
fn info_json(path: &std::path::Path) -> serde_json::Value {
    let output = info(&[path.to_str().unwrap(), "--json"]);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).unwrap()
}

#[test]
fn info_on_builtins_and_errors() {
    let output = info(&["builtin:rankine", "--json"]);
    assert!(output.status.success());
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(json["kind"], "vector");
    assert_eq!(json["type"], "f32");
    let output = info(&["builtin:density-flow", "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let kinds: Vec<&str> = json
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["scalar", "vector"]);
    let output = info(&["/nonexistent/brain.nrrd"]);
    assert!(!output.status.success());
    let stderr = String::from_utf8(output.stderr).unwrap();
    assert!(
        stderr.contains("brain.nrrd") && stderr.contains("error"),
        "{stderr}"
    );
}

/// Runs `voxhap info` with its address space limited to `limit_bytes` (`RLIMIT_AS`), so any allocation
/// beyond it fails (and a Rust program aborts on it) instead of succeeding quietly.
fn info_with_memory_limit(args: &[&str], limit_bytes: u64) -> std::process::Output {
    use std::os::unix::process::CommandExt;
    let mut command = Command::new(env!("CARGO_BIN_EXE_voxhap"));
    command.arg("info").args(args);
    // SAFETY: only setrlimit, async-signal-safe, between fork and exec.
    unsafe {
        command.pre_exec(move || {
            let limit = libc::rlimit {
                rlim_cur: limit_bytes as libc::rlim_t,
                rlim_max: limit_bytes as libc::rlim_t,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command.output().unwrap()
}

/// A crafted gzip NRRD whose byte skip (1.27 GB) is zeros that compress to about 1.2 MB (19 gzip
/// members of 64 MiB each, which NRRD's gzip encoding allows): the loader skips the inflated bytes in
/// bounded chunks without keeping them, so `voxhap info` inside a 768 MiB address space ends with the
/// truncation error (no data after the skip), never an allocation failure. Checked to fail with a
/// loader that inflates the skip into memory: it aborted ("memory allocation of 2147483648 bytes
/// failed"). The same holds for a detached raw file with a byte skip past its end (sought, not read).
#[test]
fn a_huge_byte_skip_allocates_nothing_like_it() {
    let dir = tempfile::tempdir().unwrap();
    let member = gzip(&vec![0u8; 64 << 20]);
    let members = 19usize;
    let skip = members as u64 * (64 << 20);
    let path = dir.path().join("bomb.nrrd");
    let mut file = std::fs::File::create(&path).unwrap();
    write!(
        file,
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\nbyte skip: {skip}\n\n"
    )
    .unwrap();
    for _ in 0..members {
        file.write_all(&member).unwrap();
    }
    drop(file);
    assert!(std::fs::metadata(&path).unwrap().len() < 4 << 20);
    let output = info_with_memory_limit(&[path.to_str().unwrap()], 768 << 20);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains(&format!(
            "data is truncated: the header describes {} bytes but only {skip} are there",
            skip + 8
        )),
        "{stderr}"
    );

    // Detached raw data with a byte skip far past the end of a tiny file.
    std::fs::write(dir.path().join("tiny.raw"), [0u8; 8]).unwrap();
    let header = dir.path().join("far.nhdr");
    std::fs::write(
        &header,
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: raw\nbyte skip: 3000000000\n\
         data file: tiny.raw\n",
    )
    .unwrap();
    let output = info_with_memory_limit(&[header.to_str().unwrap()], 768 << 20);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("the header describes 3000000008 bytes but only 8 are there"),
        "{stderr}"
    );
}
