//! The folders a client of the control API may reach: [`VolumeDirs`] (where `load_volume` may read volume
//! files, `voxhap serve --volume-dir`), [`RecordDir`] (where a recording may be started, `--record-dir`) and
//! [`ConfinedVolumes`], a [`SessionApi`] that checks both before a command reaches the session.
//!
//! Invariant: a path reaches the session only after it is resolved (symlinks followed) inside one of the
//! folders; `builtin:NAME` always passes.

use super::{
    ControlCommand, ControlError, ControlReply, SceneReport, SessionApi, Slice, SliceRequest,
    Snapshot, StatsReport,
};
use std::path::PathBuf;

/// A folder given on the command line (`--volume-dir`, `--record-dir`) that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FolderError {
    /// The path does not exist or is not a folder.
    #[error("{flag} {}: not a folder", path.display())]
    NotAFolder {
        /// The option that named it.
        flag: &'static str,
        /// The path as given.
        path: PathBuf,
    },
}

/// The folders the control API may load volume files from (`voxhap serve --volume-dir DIR`), checked before
/// a `load_volume` command reaches the session: a relative path is looked up in each folder in turn, an
/// absolute one must lie in one of them, both after following symlinks. `builtin:NAME` always passes.
/// Without folders only built-ins load through the API, so a client with the token cannot make the
/// server read (and `/api/slice` serve) an arbitrary file.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct VolumeDirs {
    /// Canonical folders.
    dirs: Vec<PathBuf>,
}

impl VolumeDirs {
    /// The folders, each of which must exist; errors name the folder.
    pub fn new(dirs: &[PathBuf]) -> Result<VolumeDirs, FolderError> {
        let dirs = dirs
            .iter()
            .map(|dir| {
                dir.canonicalize()
                    .ok()
                    .filter(|d| d.is_dir())
                    .ok_or_else(|| FolderError::NotAFolder {
                        flag: "--volume-dir",
                        path: dir.clone(),
                    })
            })
            .collect::<Result<_, _>>()?;
        Ok(VolumeDirs { dirs })
    }

    /// The file `path` names, resolved inside one of the folders, or why not.
    pub fn resolve(&self, path: &std::path::Path) -> Result<PathBuf, ControlError> {
        if path.to_str().is_some_and(|p| p.starts_with("builtin:")) {
            return Ok(path.to_path_buf());
        }
        if self.dirs.is_empty() {
            return Err(ControlError::Invalid(format!(
                "volume {}: loading files through the API is off; start voxhap serve with \
                 --volume-dir DIR to allow files from DIR (builtin:NAME volumes always load)",
                path.display()
            )));
        }
        let mut found = false;
        for dir in &self.dirs {
            let Ok(resolved) = dir.join(path).canonicalize() else {
                continue;
            };
            found = true;
            if resolved.starts_with(dir) {
                return Ok(resolved);
            }
        }
        let folders = self
            .dirs
            .iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", ");
        if found {
            Err(ControlError::Invalid(format!(
                "volume {}: outside the --volume-dir folders ({folders})",
                path.display()
            )))
        } else {
            Err(ControlError::NotFound(format!(
                "volume file {} does not exist in the --volume-dir folders ({folders})",
                path.display()
            )))
        }
    }
}

/// The folder the control API may record traces into (`voxhap serve --record-dir DIR`), checked before a
/// `start_recording` command reaches the session: the command names a plain file name (no folder part,
/// not `.` or `..`), and the trace and its sidecar are created in DIR under that name (new files, never
/// through a symlink: see `record::output`). Without the folder, recording through the API is off, so a
/// client with the token cannot make the server write files anywhere it can (`../`, `/tmp`, a relative
/// path). `--record FILE` on the command line is not affected.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RecordDir {
    /// The canonical folder, if recording through the API is on.
    dir: Option<PathBuf>,
}

impl RecordDir {
    /// The folder `dir` (it must exist), or API recording off for `None`; errors name the folder.
    pub fn new(dir: Option<&std::path::Path>) -> Result<RecordDir, FolderError> {
        let Some(dir) = dir else {
            return Ok(RecordDir::default());
        };
        let canonical = dir
            .canonicalize()
            .ok()
            .filter(|d| d.is_dir())
            .ok_or_else(|| FolderError::NotAFolder {
                flag: "--record-dir",
                path: dir.to_path_buf(),
            })?;
        Ok(RecordDir {
            dir: Some(canonical),
        })
    }

    /// The trace path a `start_recording` for `path` writes, or why it is refused.
    pub fn resolve(&self, path: &std::path::Path) -> Result<PathBuf, ControlError> {
        let Some(dir) = &self.dir else {
            return Err(ControlError::Invalid(format!(
                "recording to {}: recording through the API is off; start voxhap serve with \
                 --record-dir DIR to allow traces named by a plain file name in DIR",
                path.display()
            )));
        };
        let mut components = path.components();
        match (components.next(), components.next()) {
            (Some(std::path::Component::Normal(name)), None) => Ok(dir.join(name)),
            _ => Err(ControlError::Invalid(format!(
                "recording to {}: path must be a plain file name (no folder, no `..`); the trace is \
                 written in the --record-dir folder {}",
                path.display(),
                dir.display()
            ))),
        }
    }
}

/// A [`SessionApi`] whose `load_volume` commands may only name files in [`VolumeDirs`] and whose
/// `start_recording` commands may only name a file in the [`RecordDir`]; everything else passes straight
/// through. `voxhap serve` hands this to its servers.
pub struct ConfinedVolumes<A: ?Sized> {
    inner: std::sync::Arc<A>,
    dirs: VolumeDirs,
    records: RecordDir,
}

impl<A: SessionApi + ?Sized> ConfinedVolumes<A> {
    /// Wraps `inner`; recording through the API is off until [`ConfinedVolumes::with_record_dir`].
    pub fn new(inner: std::sync::Arc<A>, dirs: VolumeDirs) -> Self {
        ConfinedVolumes {
            inner,
            dirs,
            records: RecordDir::default(),
        }
    }

    /// Lets `start_recording` write into `records`.
    pub fn with_record_dir(mut self, records: RecordDir) -> Self {
        self.records = records;
        self
    }
}

impl<A: SessionApi + ?Sized> SessionApi for ConfinedVolumes<A> {
    fn snapshot(&self) -> Option<Snapshot> {
        self.inner.snapshot()
    }
    fn stats(&self) -> StatsReport {
        self.inner.stats()
    }
    fn scene(&self) -> SceneReport {
        self.inner.scene()
    }
    fn control(&self, command: ControlCommand) -> Result<ControlReply, ControlError> {
        let command = match command {
            ControlCommand::LoadVolume { path, name } => ControlCommand::LoadVolume {
                path: self.dirs.resolve(&path)?,
                name,
            },
            ControlCommand::StartRecording { path, format } => ControlCommand::StartRecording {
                path: self.records.resolve(&path)?,
                format,
            },
            other => other,
        };
        self.inner.control(command)
    }
    fn slice(&self, request: SliceRequest) -> Result<Slice, ControlError> {
        self.inner.slice(request)
    }
}
