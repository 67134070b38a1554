//! `voxhap completions SHELL` and `voxhap man` through the real binary: the bash script is valid bash that
//! completes the subcommands, and the man page is roff that `man` renders (each skipped with a message when
//! the tool is missing).

use std::process::{Command, Stdio};

fn voxhap(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(args)
        .output()
        .expect("run voxhap")
}

fn tool_exists(name: &str) -> bool {
    Command::new(name)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok()
}

#[test]
fn the_bash_completion_script_completes_subcommands() {
    let out = voxhap(&["completions", "bash"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("voxhap.bash");
    std::fs::write(&script, &out.stdout).unwrap();
    if !tool_exists("bash") {
        eprintln!("SKIPPED: bash not found; the completion script was not run");
        return;
    }
    // Source the script and ask its function what `voxhap se<TAB>` completes to.
    let probe = format!(
        "source {}; COMP_WORDS=(voxhap se); COMP_CWORD=1; COMP_LINE='voxhap se'; COMP_POINT=9; \
         _voxhap voxhap se voxhap; printf '%s\\n' \"${{COMPREPLY[@]}}\"",
        script.display()
    );
    let run = Command::new("bash").args(["-c", &probe]).output().unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let words = String::from_utf8_lossy(&run.stdout);
    assert!(
        words.lines().any(|w| w == "serve"),
        "completions: {words:?}"
    );
    assert!(
        !words.lines().any(|w| w == "plot"),
        "completions: {words:?}"
    );

    let bad = voxhap(&["completions", "tcsh"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("possible values"));
}

#[test]
fn the_man_page_renders() {
    let out = voxhap(&["man"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let roff = String::from_utf8(out.stdout).unwrap();
    assert!(
        roff.contains(".TH voxhap 1"),
        "{}",
        &roff[..200.min(roff.len())]
    );
    assert!(
        roff.contains("completions"),
        "the page lists the subcommands"
    );

    let dir = tempfile::tempdir().unwrap();
    let written = voxhap(&["man", "--dir", dir.path().to_str().unwrap()]);
    assert!(
        written.status.success(),
        "{}",
        String::from_utf8_lossy(&written.stderr)
    );
    let page = dir.path().join("voxhap-serve.1");
    assert!(page.exists());
    // A second run refuses to replace the pages.
    let again = voxhap(&["man", "--dir", dir.path().to_str().unwrap()]);
    assert_eq!(again.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&again.stderr).contains("does not replace"));

    if !tool_exists("man") {
        eprintln!("SKIPPED: man not found; the page was not rendered");
        return;
    }
    let rendered = Command::new("man")
        .arg("-l")
        .arg(&page)
        .env("MANWIDTH", "80")
        .env("MANPAGER", "cat")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&rendered.stdout);
    assert!(
        rendered.status.success(),
        "{}",
        String::from_utf8_lossy(&rendered.stderr)
    );
    assert!(text.contains("--scene"), "{text}");
}
