//! Every output the docs show for a deterministic `voxhap` command is what that command prints.
//!
//! Where it sits: documentation checks, beside docs_reference (generated reference pages) and docs_links. The
//! test reads README.md, sims/README.md and every page under docs/, finds fenced blocks that start with a
//! `$ voxhap SUB ...` line for a subcommand in [`CHECKED`], runs each `$` line of the block in order in one
//! fresh folder (with `sims/` and `data/` of the repository linked in, so paths read as they do from the
//! project root) and compares the lines that follow it in the block with what the command printed (stdout,
//! then stderr); `$ mkdir DIR` lines make a folder. Blocks that also run other programs are illustrations and are
//! skipped. `serve`, `calibrate`, `devices` and the device commands talk to devices or run in real time,
//! so their examples are not checked here (their messages are pinned by tests/bad_inputs.rs and the device
//! tests). `VOXHAP_BLESS=1 cargo test --release --test integration docs_outputs` rewrites the outputs in the
//! docs instead (after a change that alters them; read the diff before committing it).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The subcommands whose documented outputs are checked: deterministic, no device, no wall clock.
const CHECKED: [&str; 7] = ["sim", "info", "man", "compare", "solve", "sweep", "plot"];

/// A documented command and the lines the docs say it prints.
struct Example {
    command: String,
    /// Line index (in the file) of the first output line and the number of output lines.
    first_line: usize,
    expected: Vec<String>,
}

/// One fenced block of examples.
struct Block {
    file: PathBuf,
    examples: Vec<Example>,
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn pages() -> Vec<PathBuf> {
    let mut pages = vec![root().join("README.md"), root().join("sims/README.md")];
    let mut stack = vec![root().join("docs")];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                // docs/reference/ is generated from the code and checked by docs_reference.
                if path.file_name().is_some_and(|n| n != "reference") {
                    stack.push(path);
                }
            } else if path.extension().is_some_and(|e| e == "md") {
                pages.push(path);
            }
        }
    }
    pages.sort();
    pages
}

fn checked_command(line: &str) -> bool {
    let Some(rest) = line.strip_prefix("$ voxhap ") else {
        return false;
    };
    let sub = rest.split_whitespace().next().unwrap_or("");
    CHECKED.contains(&sub)
}

fn blocks(file: &Path) -> Vec<Block> {
    let text = std::fs::read_to_string(file).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let mut blocks = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        if !lines[i].starts_with("```") {
            i += 1;
            continue;
        }
        let start = i + 1;
        let mut end = start;
        while end < lines.len() && !lines[end].starts_with("```") {
            end += 1;
        }
        // A block is checked when it starts with a checked command and every `$` line in it is one (a block
        // that also runs other programs, or kills a run half-way, illustrates rather than transcribes).
        let commands: Vec<&&str> = lines[start..end]
            .iter()
            .filter(|line| line.starts_with("$ "))
            .collect();
        let checked = start < end
            && lines[start].starts_with("$ ")
            && commands.iter().any(|line| checked_command(line))
            && commands
                .iter()
                .all(|line| checked_command(line) || line.starts_with("$ mkdir "));
        if checked {
            let mut examples: Vec<Example> = Vec::new();
            for (n, line) in lines.iter().enumerate().take(end).skip(start) {
                if line.starts_with("$ ") {
                    examples.push(Example {
                        command: line.trim_start_matches("$ ").to_owned(),
                        first_line: n + 1,
                        expected: Vec::new(),
                    });
                } else {
                    examples.last_mut().unwrap().expected.push(line.to_string());
                }
            }
            blocks.push(Block {
                file: file.to_owned(),
                examples,
            });
        }
        i = end + 1;
    }
    blocks
}

/// Splits a documented command line into arguments (plain words and single-quoted words; a `#` starts a
/// comment).
fn words(command: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut word = String::new();
    let mut quoted = false;
    let mut in_word = false;
    for c in command.chars() {
        match c {
            '\'' => {
                quoted = !quoted;
                in_word = true;
            }
            '#' if !quoted && !in_word => break,
            c if c.is_whitespace() && !quoted => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            c => {
                word.push(c);
                in_word = true;
            }
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

fn run(example: &Example, dir: &Path) -> Vec<String> {
    let args = words(&example.command);
    if args[0] == "mkdir" {
        for folder in &args[1..] {
            std::fs::create_dir(dir.join(folder)).unwrap();
        }
        return Vec::new();
    }
    assert_eq!(args[0], "voxhap");
    let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .current_dir(dir)
        .args(&args[1..])
        .output()
        .unwrap();
    let mut lines: Vec<String> = String::from_utf8_lossy(&output.stdout)
        .lines()
        .map(str::to_owned)
        .collect();
    lines.extend(
        String::from_utf8_lossy(&output.stderr)
            .lines()
            .map(str::to_owned),
    );
    lines
}

#[test]
fn documented_outputs_are_what_the_commands_print() {
    let bless = std::env::var_os("VOXHAP_BLESS").is_some_and(|v| v == "1");
    let mut checked = 0;
    let mut stale = Vec::new();
    for page in pages() {
        let mut replacements: Vec<(usize, usize, Vec<String>)> = Vec::new();
        for block in blocks(&page) {
            let dir = tempfile::tempdir().unwrap();
            for linked in ["sims", "data"] {
                std::os::unix::fs::symlink(root().join(linked), dir.path().join(linked)).unwrap();
            }
            for example in &block.examples {
                let printed = run(example, dir.path());
                checked += 1;
                if printed != example.expected {
                    stale.push(format!(
                        "{}:{}: `{}` prints\n{}\nbut the docs show\n{}",
                        block.file.display(),
                        example.first_line,
                        example.command,
                        printed.join("\n"),
                        example.expected.join("\n")
                    ));
                    replacements.push((example.first_line, example.expected.len(), printed));
                }
            }
        }
        if bless && !replacements.is_empty() {
            let text = std::fs::read_to_string(&page).unwrap();
            let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
            for (first, count, printed) in replacements.into_iter().rev() {
                lines.splice(first..first + count, printed);
            }
            std::fs::write(&page, lines.join("\n") + "\n").unwrap();
            eprintln!("blessed {}", page.display());
        }
    }
    assert!(
        checked >= 4,
        "only {checked} documented examples found: the block format changed?"
    );
    if !bless {
        assert!(
            stale.is_empty(),
            "{} documented outputs differ from what the commands print (regenerate with VOXHAP_BLESS=1 \
             cargo test --release --test integration docs_outputs):\n\n{}",
            stale.len(),
            stale.join("\n\n")
        );
    }
}

#[test]
fn command_words_split_like_a_shell() {
    assert_eq!(
        words("voxhap sweep x.toml --set 'modes[1].mu=0.3,0.5' --out-dir sw  # comment"),
        vec![
            "voxhap",
            "sweep",
            "x.toml",
            "--set",
            "modes[1].mu=0.3,0.5",
            "--out-dir",
            "sw"
        ]
    );
}
