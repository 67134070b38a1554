//! Where a trace may be written: the checks made before any output file is created, and the size
//! estimate a sim makes before it starts.
//!
//! Where it sits: `voxhap sim --out`, `voxhap serve --record`, the control API's start-recording command
//! and `voxhap trace repair` create traces through `create_trace_writer_with`, which calls
//! [`check_output_path`] first. An existing trace or sidecar is replaced only when the user asked
//! (`--force`); a file that is an input of the run (the scenario, a volume, a replayed trace) is never an
//! output, even with `--force`. Inputs are compared as files (device and inode on Unix, canonical paths
//! elsewhere), so `./a/../x.toml` or a hard link to an input is recognised.
//!
//! Invariants of every file a trace writer creates (trace, sidecar, the Parquet compaction's temporary
//! file), enforced by [`create_new_file`]: it is a new file (`O_CREAT | O_EXCL`), and the path's last
//! component is never a symbolic link (`O_NOFOLLOW`): a symlink there, dangling or not, is refused with
//! [`TraceError::Symlink`] naming it, even with `--force`, so a trace never lands where a link points.
//! `--force` removes the old trace and sidecar (regular files) first and then creates new ones, so a hard
//! link to the old file keeps its contents. Rewriting the sidecar later opens the file the writer
//! created, again without following a symlink.

use crate::error::TraceError;
use std::path::{Path, PathBuf};

/// What a new trace may replace.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OutputPolicy {
    /// Replace an existing trace and sidecar (`--force`).
    pub overwrite: bool,
    /// The run's input files; never outputs.
    pub inputs: Vec<PathBuf>,
}

/// The identity of an existing file: (device, inode) on Unix, the canonical path elsewhere.
fn file_identity(path: &Path) -> Option<(u64, u64, PathBuf)> {
    let metadata = std::fs::metadata(path).ok()?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        Some((metadata.dev(), metadata.ino(), PathBuf::new()))
    }
    #[cfg(not(unix))]
    {
        let _ = metadata;
        Some((0, 0, std::fs::canonicalize(path).ok()?))
    }
}

/// Checks that `path` (and its sidecar `path.json`) may be written under `policy`.
pub fn check_output_path(path: &Path, policy: &OutputPolicy) -> Result<(), TraceError> {
    for candidate in [path.to_path_buf(), sidecar_path(path)] {
        if is_symlink(&candidate) {
            return Err(TraceError::Symlink { path: candidate });
        }
        let Some(identity) = file_identity(&candidate) else {
            continue;
        };
        for input in &policy.inputs {
            if file_identity(input).as_ref() == Some(&identity) {
                return Err(TraceError::IsInput {
                    path: candidate,
                    input: input.clone(),
                });
            }
        }
        if !policy.overwrite {
            return Err(TraceError::Exists { path: candidate });
        }
    }
    Ok(())
}

/// True when `path`'s last component is a symbolic link (dangling or not).
fn is_symlink(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink())
}

/// Removes the trace and sidecar that `--force` replaces (after [`check_output_path`] passed): regular
/// files only, so a new file is created in their place instead of writing through an old one.
pub(crate) fn remove_replaced(path: &Path) -> Result<(), TraceError> {
    for candidate in [path.to_path_buf(), sidecar_path(path)] {
        match std::fs::symlink_metadata(&candidate) {
            Ok(m) if m.file_type().is_symlink() => {
                return Err(TraceError::Symlink { path: candidate })
            }
            Ok(m) if m.is_file() => {
                std::fs::remove_file(&candidate).map_err(|source| TraceError::Io {
                    path: candidate.clone(),
                    source,
                })?
            }
            Ok(_) => return Err(TraceError::Exists { path: candidate }),
            Err(_) => {}
        }
    }
    Ok(())
}

/// Open flags that keep an output off symbolic links.
fn no_follow(options: &mut std::fs::OpenOptions) -> &mut std::fs::OpenOptions {
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC);
    }
    options
}

/// The error for an open of `path` that failed with `source`: a symlink or an existing file is named as
/// such, anything else is an I/O error.
fn open_error(path: &Path, source: std::io::Error) -> TraceError {
    if is_symlink(path) {
        return TraceError::Symlink {
            path: path.to_path_buf(),
        };
    }
    if source.kind() == std::io::ErrorKind::AlreadyExists {
        return TraceError::Exists {
            path: path.to_path_buf(),
        };
    }
    TraceError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Creates a new file for writing at `path`: `O_CREAT | O_EXCL | O_NOFOLLOW`, so an existing file is
/// never opened and a symlink (even a dangling one) is never followed; both are refused naming `path`.
pub fn create_new_file(path: &Path) -> Result<std::fs::File, TraceError> {
    no_follow(std::fs::OpenOptions::new().write(true).create_new(true))
        .open(path)
        .map_err(|source| open_error(path, source))
}

/// Creates `path` for writing, or truncates the regular file already there (`O_CREAT | O_TRUNC |
/// O_NOFOLLOW`): for outputs that a rerun replaces (a sweep's summary, a calibrated profile with `--force`,
/// a volume received over OpenIGTLink). A symlink at `path`, dangling or not, is refused naming it.
pub fn create_or_replace_file(path: &Path) -> Result<std::fs::File, TraceError> {
    no_follow(
        std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true),
    )
    .open(path)
    .map_err(|source| open_error(path, source))
}

/// Opens an existing output (a sidecar the writer created) for rewriting in place, never through a
/// symlink and never creating it.
pub(crate) fn open_existing_output(path: &Path) -> Result<std::fs::File, TraceError> {
    no_follow(std::fs::OpenOptions::new().write(true))
        .open(path)
        .map_err(|source| open_error(path, source))
}

/// A trace file being written that stops accepting bytes at its first failed write (or when
/// [`OutputFile::stop`] is called), so that nothing reaches the file after a failure: not a buffered
/// writer's flush on drop, not a library's attempt to end the file. The trace therefore ends where the
/// failure left it, and the sample count the writer recorded as reaching the file stays exact.
pub(crate) struct OutputFile {
    file: std::fs::File,
    stopped: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

/// The switch that stops an [`OutputFile`] from the writer that owns it (through a library's buffers).
#[derive(Clone, Debug, Default)]
pub(crate) struct StopSwitch(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl StopSwitch {
    /// No byte reaches the file after this.
    pub(crate) fn stop(&self) {
        self.0.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

impl OutputFile {
    /// Wraps `file`; `switch` stops it.
    pub(crate) fn new(file: std::fs::File, switch: &StopSwitch) -> Self {
        OutputFile {
            file,
            stopped: switch.0.clone(),
        }
    }

    fn check(&self) -> std::io::Result<()> {
        if self.stopped.load(std::sync::atomic::Ordering::Relaxed) {
            return Err(std::io::Error::other(
                "the trace stopped at an earlier error; nothing more is written to it",
            ));
        }
        Ok(())
    }

    fn note<T>(&self, result: std::io::Result<T>) -> std::io::Result<T> {
        if result.is_err() {
            self.stopped
                .store(true, std::sync::atomic::Ordering::Relaxed);
        }
        result
    }

    /// The file, for the final `sync_all`.
    pub(crate) fn file(&self) -> &std::fs::File {
        &self.file
    }
}

impl std::io::Write for OutputFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.check()?;
        let result = self.file.write(buf);
        self.note(result)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.check()?;
        let result = self.file.flush();
        self.note(result)
    }
}

impl std::io::Seek for OutputFile {
    fn seek(&mut self, position: std::io::SeekFrom) -> std::io::Result<u64> {
        self.check()?;
        let result = self.file.seek(position);
        self.note(result)
    }
}

/// The sidecar's path for a trace: the trace path with `.json` appended (`run.csv` -> `run.csv.json`).
pub fn sidecar_path(trace_path: &Path) -> PathBuf {
    let mut name = trace_path.as_os_str().to_os_string();
    name.push(".json");
    PathBuf::from(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn existing_files_need_force_and_inputs_are_never_outputs() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run.csv");
        let input = dir.path().join("scene.toml");
        std::fs::write(&input, "x").unwrap();
        let policy = OutputPolicy {
            overwrite: false,
            inputs: vec![input.clone()],
        };
        check_output_path(&out, &policy).unwrap();
        std::fs::write(&out, "old").unwrap();
        let err = check_output_path(&out, &policy).unwrap_err().to_string();
        assert!(err.contains("exists") && err.contains("--force"), "{err}");
        let forced = OutputPolicy {
            overwrite: true,
            ..policy.clone()
        };
        check_output_path(&out, &forced).unwrap();
        // The input under another spelling is refused even with --force; a symlink (to an input or
        // anywhere) is refused as a symlink.
        let other_name = dir.path().join(".").join("scene.toml");
        let err = check_output_path(&other_name, &forced)
            .unwrap_err()
            .to_string();
        assert!(err.contains("is an input"), "{err}");
        #[cfg(unix)]
        {
            let link = dir.path().join("link.csv");
            std::os::unix::fs::symlink(&input, &link).unwrap();
            assert!(matches!(
                check_output_path(&link, &forced),
                Err(TraceError::Symlink { .. })
            ));
        }
        // A sidecar that would overwrite an input is refused too.
        let sidecar_target = dir.path().join("x.csv");
        std::fs::write(sidecar_path(&sidecar_target), "{}").unwrap();
        let guarded = OutputPolicy {
            overwrite: true,
            inputs: vec![sidecar_path(&sidecar_target)],
        };
        assert!(check_output_path(&sidecar_target, &guarded).is_err());
    }
}
