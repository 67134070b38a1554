//! The layering holds inside each crate: no module imports a module that imports it back. Across crates
//! Cargo already refuses a cycle; inside one crate only this check does. It runs `.ci/module-cycles.py` (the
//! import graph of a crate's modules, following `crate::`, `super::`, `self::` and re-exports to the module
//! that defines an item) on every workspace crate and fails with the cycle's edges. Edges from unit tests
//! (`mod tests`) are allowed: a test may reach for anything. It also checks, with `cargo tree` on the lock file,
//! that no I/O or command-line crate is in the dependency tree of the pure core (voxhap-solver, voxhap-core).
//!
//! Needs python3: without it the test says SKIPPED, except under CI (`CI=true`), where it fails.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Every crate source directory of the workspace: the root crate, protocol/ and crates/*.
fn crate_sources(root: &Path) -> Vec<PathBuf> {
    let mut dirs = vec![root.join("src"), root.join("protocol/src")];
    let mut crates: Vec<PathBuf> = std::fs::read_dir(root.join("crates"))
        .expect("crates/ is readable")
        .map(|entry| entry.expect("a crates/ entry").path().join("src"))
        .filter(|src| src.is_dir())
        .collect();
    crates.sort();
    dirs.extend(crates);
    dirs
}

#[test]
fn no_module_imports_a_module_that_imports_it_back() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if Command::new("python3").arg("--version").output().is_err() {
        assert!(
            std::env::var("CI").map_or(true, |v| v != "true"),
            "python3 is needed for the module-cycle check in CI"
        );
        eprintln!("SKIPPED no_module_imports_a_module_that_imports_it_back: python3 not found");
        return;
    }
    let sources = crate_sources(root);
    assert!(sources.len() >= 10, "found only {sources:?}");
    let mut failures = Vec::new();
    for src in &sources {
        let output = Command::new("python3")
            .arg(root.join(".ci/module-cycles.py"))
            .arg(src)
            .env("VERBOSE", "1")
            .output()
            .expect("python3 runs");
        if !output.status.success() {
            failures.push(format!(
                "{}:\n{}{}",
                src.display(),
                String::from_utf8_lossy(&output.stdout),
                String::from_utf8_lossy(&output.stderr)
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "module cycles:\n{}",
        failures.join("\n")
    );
}

/// The checker finds a cycle when there is one: two modules that import each other.
#[test]
fn the_cycle_check_sees_a_cycle() {
    if Command::new("python3").arg("--version").output().is_err() {
        eprintln!("SKIPPED the_cycle_check_sees_a_cycle: python3 not found");
        return;
    }
    let dir = tempfile::tempdir().expect("a temporary directory");
    let src = dir.path();
    std::fs::write(src.join("lib.rs"), "mod a;\nmod b;\n").unwrap();
    std::fs::write(src.join("a.rs"), "use crate::b::B;\npub struct A(B);\n").unwrap();
    std::fs::write(
        src.join("b.rs"),
        "use super::a::A;\npub struct B;\npub fn f(_: &A) {}\n",
    )
    .unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let output = Command::new("python3")
        .arg(root.join(".ci/module-cycles.py"))
        .arg(src)
        .output()
        .expect("python3 runs");
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(!output.status.success(), "no cycle reported:\n{text}");
    assert!(text.contains("a -> b") && text.contains("b -> a"), "{text}");
}

/// Crates that do I/O or parse command lines: none may be in the pure core's dependency tree (the solver and
/// the core: volume sampling, primitives, modes, the tick).
const IO_CRATES: &[&str] = &[
    "tokio",
    "mio",
    "serialport",
    "hidapi",
    "axum",
    "hyper",
    "tungstenite",
    "mcap",
    "parquet",
    "arrow",
    "clap",
];

/// The names of the crates in `package`'s normal and build dependency tree, as `cargo tree` resolves it from
/// the lock file (no network).
fn dependency_names(package: &str) -> Vec<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let output = Command::new(env!("CARGO"))
        .args(["tree", "--frozen", "--prefix", "none", "-e", "normal,build"])
        .args(["--format", "{lib}", "-p", package, "--manifest-path"])
        .arg(root.join("Cargo.toml"))
        .output()
        .expect("cargo runs");
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "cargo tree -p {package} failed:\n{text}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    text.lines()
        .map(|line| line.split_whitespace().next().unwrap_or("").to_owned())
        .filter(|name| !name.is_empty())
        .collect()
}

#[test]
fn the_pure_core_has_no_io_crate_in_its_dependency_tree() {
    for package in ["voxhap-solver", "voxhap-core"] {
        let names = dependency_names(package);
        assert!(
            names.iter().any(|name| name == "glam"),
            "{package}: glam not seen in {names:?}"
        );
        let io: Vec<&String> = names
            .iter()
            .filter(|name| IO_CRATES.contains(&name.as_str()))
            .collect();
        assert!(io.is_empty(), "{package} depends on I/O crates {io:?}");
    }
}

/// The same listing finds I/O crates where they belong: the servers run on tokio and axum.
#[test]
fn the_dependency_listing_sees_io_crates_where_they_are() {
    let names = dependency_names("voxhap-server");
    for wanted in ["tokio", "axum"] {
        assert!(
            names.iter().any(|name| name == wanted),
            "voxhap-server: {wanted} not seen in {names:?}"
        );
    }
}
