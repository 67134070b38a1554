//! `voxhap completions SHELL` and `voxhap man`: shell completion scripts (clap_complete) and roff man pages
//! (clap_mangen) generated from the same clap definitions that parse the command line, so they cannot drift
//! from the flags. Output goes to stdout, or with `voxhap man --dir DIR` one page per command into DIR.

use super::common::print_out;
use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A shell clap_complete writes a completion script for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Shell {
    Bash,
    Zsh,
    Fish,
    Elvish,
    #[value(name = "powershell")]
    PowerShell,
}

impl From<Shell> for clap_complete::Shell {
    fn from(shell: Shell) -> Self {
        match shell {
            Shell::Bash => clap_complete::Shell::Bash,
            Shell::Zsh => clap_complete::Shell::Zsh,
            Shell::Fish => clap_complete::Shell::Fish,
            Shell::Elvish => clap_complete::Shell::Elvish,
            Shell::PowerShell => clap_complete::Shell::PowerShell,
        }
    }
}

#[derive(Debug, Args)]
pub struct CompletionsArgs {
    /// The shell to write a completion script for (printed on stdout). Bash:
    /// `voxhap completions bash > ~/.local/share/bash-completion/completions/voxhap`.
    #[arg(value_enum)]
    pub shell: Shell,
}

#[derive(Debug, Args)]
pub struct ManArgs {
    /// Write voxhap.1 and one voxhap-COMMAND.1 per subcommand into this existing folder (refusing to replace
    /// a file that is there) instead of printing voxhap.1 on stdout.
    #[arg(long, value_name = "DIR")]
    pub dir: Option<PathBuf>,
}

/// The completion script for `shell`.
pub fn completion_script(mut command: clap::Command, shell: Shell) -> Vec<u8> {
    let mut out = Vec::new();
    clap_complete::generate(
        clap_complete::Shell::from(shell),
        &mut command,
        "voxhap",
        &mut out,
    );
    out
}

/// The man pages: (file name, roff text), voxhap.1 first, then one per subcommand.
pub fn man_pages(command: clap::Command) -> anyhow::Result<Vec<(String, Vec<u8>)>> {
    let mut pages = Vec::new();
    let mut top = Vec::new();
    clap_mangen::Man::new(command.clone())
        .render(&mut top)
        .context("rendering voxhap.1")?;
    pages.push(("voxhap.1".to_owned(), top));
    for sub in command.get_subcommands() {
        let name = format!("voxhap-{}", sub.get_name());
        // The page's title and NAME say `voxhap-serve`, its synopsis `voxhap serve ...`.
        let sub = sub
            .clone()
            .display_name(name.clone())
            .bin_name(format!("voxhap {}", sub.get_name()));
        let mut page = Vec::new();
        clap_mangen::Man::new(sub)
            .render(&mut page)
            .with_context(|| format!("rendering {name}.1"))?;
        pages.push((format!("{name}.1"), page));
    }
    Ok(pages)
}

pub fn run_completions(args: &CompletionsArgs, command: clap::Command) -> anyhow::Result<()> {
    write_stdout(&completion_script(command, args.shell))
}

pub fn run_man(args: &ManArgs, command: clap::Command) -> anyhow::Result<()> {
    let pages = man_pages(command)?;
    match &args.dir {
        None => write_stdout(&pages[0].1),
        Some(dir) => {
            write_pages(dir, &pages)?;
            print_out(&format!(
                "wrote {} man pages into {} (read one with `man -l {}`)",
                pages.len(),
                dir.display(),
                dir.join("voxhap.1").display()
            ))
        }
    }
}

/// Writes every page into `dir`, checking first that none of them exists (nothing is written otherwise).
fn write_pages(dir: &Path, pages: &[(String, Vec<u8>)]) -> anyhow::Result<()> {
    if !dir.is_dir() {
        bail!("--dir {}: not an existing folder", dir.display());
    }
    for (name, _) in pages {
        let path = dir.join(name);
        if path.exists() {
            bail!(
                "{} exists; voxhap man does not replace files (remove it or pick another --dir)",
                path.display()
            );
        }
    }
    for (name, text) in pages {
        let path = dir.join(name);
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
            .with_context(|| format!("creating {}", path.display()))?;
        file.write_all(text)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn write_stdout(bytes: &[u8]) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(bytes).and_then(|()| out.flush()) {
        Err(err) if err.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn every_shell_gets_a_script_naming_the_subcommands() {
        for shell in Shell::value_variants() {
            let script =
                String::from_utf8(completion_script(crate::cli::Cli::command(), *shell)).unwrap();
            for word in ["voxhap", "serve", "plot", "completions", "--scene"] {
                assert!(script.contains(word), "{shell:?} script lacks {word}");
            }
        }
    }

    #[test]
    fn man_pages_cover_every_subcommand_and_never_replace_a_file() {
        let pages = man_pages(crate::cli::Cli::command()).unwrap();
        let names: Vec<&str> = pages.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names[0], "voxhap.1");
        for expected in ["voxhap-serve.1", "voxhap-plot.1", "voxhap-man.1"] {
            assert!(names.contains(&expected), "{names:?}");
        }
        let serve = String::from_utf8(
            pages[names.iter().position(|n| *n == "voxhap-serve.1").unwrap()]
                .1
                .clone(),
        )
        .unwrap();
        assert!(serve.starts_with(".ie"), "not roff: {}", &serve[..40]);
        assert!(
            serve.contains("voxhap\\-serve"),
            "the page names its command"
        );

        let dir = tempfile::tempdir().unwrap();
        write_pages(dir.path(), &pages).unwrap();
        let written = std::fs::read(dir.path().join("voxhap-plot.1")).unwrap();
        assert!(!written.is_empty());
        std::fs::write(dir.path().join("voxhap.1"), b"mine").unwrap();
        let error = write_pages(dir.path(), &pages).unwrap_err().to_string();
        assert!(error.contains("does not replace"), "{error}");
        assert_eq!(std::fs::read(dir.path().join("voxhap.1")).unwrap(), b"mine");
        let error = write_pages(&dir.path().join("nope"), &pages)
            .unwrap_err()
            .to_string();
        assert!(error.contains("not an existing folder"), "{error}");
    }
}
