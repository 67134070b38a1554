//! Where a loader's bytes come from, and the limits on them: only regular files are opened, nothing is
//! read past what the header needs, and a data file named inside a header must stay in the header's folder.
//!
//! Place in the data flow: every loader in [`super`] reads through these functions, once, off the servo
//! thread. The limits are a [`LoadOptions`]: [`super::load`] uses the process-wide options that the
//! command line sets once at start ([`set_process_options`]: `--max-volume-bytes`,
//! `--allow-outside-paths`); [`super::load_with`] takes them explicitly (tests, fuzzing).
//!
//! - **Regular files only.** The path's metadata (after symlinks) is checked before it is opened, and the
//!   file is opened with `O_NONBLOCK` and checked again, so a FIFO, a device (`/dev/zero`) or a socket is
//!   refused at once instead of hanging or reading without end.
//! - **Bounded reads.** A file is read only up to the byte count the caller computed from the header (plus
//!   one byte, to tell "longer than described" from "exact"), and never more than
//!   [`LoadOptions::max_volume_bytes`].
//! - **Confined data files.** `data file:` (NRRD), `ElementDataFile` (MetaImage) and `data_file` (raw TOML)
//!   must resolve, after symlinks, inside the header's own folder unless
//!   [`LoadOptions::allow_outside_paths`]; the same rule holds for volume files named in scene files.

pub use crate::error::FileError;
use crate::error::LoadProblem;
use std::borrow::Cow;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Default of `--max-volume-bytes`: 4 GiB.
pub const DEFAULT_MAX_VOLUME_BYTES: u64 = 4 << 30;
/// Largest header (or scene file, or attached-header prefix) read before the data: 1 MiB.
pub const MAX_HEADER_BYTES: u64 = 1 << 20;

/// The limits every load obeys.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoadOptions {
    /// Most bytes one load may read or inflate from its files plus the `f32` values it builds
    /// (`--max-volume-bytes`).
    pub max_volume_bytes: u64,
    /// Let a header's data file (or a scene's volume file) lie outside the header's (scene's) folder
    /// (`--allow-outside-paths`).
    pub allow_outside_paths: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            max_volume_bytes: DEFAULT_MAX_VOLUME_BYTES,
            allow_outside_paths: false,
        }
    }
}

static PROCESS_MAX_VOLUME_BYTES: AtomicU64 = AtomicU64::new(DEFAULT_MAX_VOLUME_BYTES);
static PROCESS_ALLOW_OUTSIDE_PATHS: AtomicBool = AtomicBool::new(false);

/// Sets the options [`super::load`] uses in this process (the command line calls it once, before loading).
pub fn set_process_options(options: LoadOptions) {
    PROCESS_MAX_VOLUME_BYTES.store(options.max_volume_bytes, Ordering::Relaxed);
    PROCESS_ALLOW_OUTSIDE_PATHS.store(options.allow_outside_paths, Ordering::Relaxed);
}

/// The options [`super::load`] uses: the defaults unless [`set_process_options`] changed them.
pub fn process_options() -> LoadOptions {
    LoadOptions {
        max_volume_bytes: PROCESS_MAX_VOLUME_BYTES.load(Ordering::Relaxed),
        allow_outside_paths: PROCESS_ALLOW_OUTSIDE_PATHS.load(Ordering::Relaxed),
    }
}

/// What kind of file `metadata` describes, for messages.
fn kind_name(file_type: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if file_type.is_dir() {
        "directory"
    } else if file_type.is_fifo() {
        "FIFO (named pipe)"
    } else if file_type.is_char_device() {
        "character device"
    } else if file_type.is_block_device() {
        "block device"
    } else if file_type.is_socket() {
        "socket"
    } else {
        "special file"
    }
}

/// Opens `path` for reading only if it is a regular file (checked before and after opening, without
/// blocking on a FIFO); returns the file and its size in bytes.
pub fn open_regular(path: &Path) -> Result<(std::fs::File, u64), FileError> {
    use std::os::unix::fs::OpenOptionsExt;
    let metadata = std::fs::metadata(path)?;
    if !metadata.is_file() {
        return Err(FileError::NotRegular {
            kind: kind_name(metadata.file_type()),
        });
    }
    // O_NONBLOCK: if the path was swapped for a FIFO since the check, the open still returns at once.
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let metadata = file.metadata()?;
    if !metadata.is_file() {
        return Err(FileError::NotRegular {
            kind: kind_name(metadata.file_type()),
        });
    }
    Ok((file, metadata.len()))
}

/// Reads a whole regular file of at most `limit_bytes` (`what` names the limit in the message).
pub fn read_regular(
    path: &Path,
    limit_bytes: u64,
    what: &'static str,
) -> Result<Vec<u8>, FileError> {
    let (file, size_bytes) = open_regular(path)?;
    if size_bytes > limit_bytes {
        return Err(FileError::TooLong {
            size_bytes,
            limit_bytes,
            what,
        });
    }
    read_at_most(file, size_bytes, limit_bytes, what)
}

/// Reads up to `limit_bytes + 1` bytes (a file that grew since its size was taken is still bounded).
fn read_at_most(
    file: std::fs::File,
    size_hint: u64,
    limit_bytes: u64,
    what: &'static str,
) -> Result<Vec<u8>, FileError> {
    let mut bytes = Vec::with_capacity(usize::try_from(size_hint.min(limit_bytes)).unwrap_or(0));
    file.take(limit_bytes.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit_bytes {
        return Err(FileError::TooLong {
            size_bytes: bytes.len() as u64,
            limit_bytes,
            what,
        });
    }
    Ok(bytes)
}

/// Largest text file (scene, scenario, solve JSON) read: 16 MiB.
pub const MAX_TEXT_FILE_BYTES: u64 = 16 << 20;

/// Reads a scene, scenario or other settings file as UTF-8 text: a regular file of at most
/// [`MAX_TEXT_FILE_BYTES`]. Errors are `std::io::Error`s whose message says what is wrong.
pub fn read_text_file(path: &Path) -> std::io::Result<String> {
    let bytes =
        read_regular(path, MAX_TEXT_FILE_BYTES, "a text file (16 MiB)").map_err(|e| match e {
            FileError::Io(error) => error,
            other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other.to_string()),
        })?;
    String::from_utf8(bytes)
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "it is not UTF-8 text"))
}

/// Reads a regular file for a loader: a header, or a header with attached data. It may be at most
/// `max_volume_bytes` plus [`MAX_HEADER_BYTES`] long.
pub(crate) fn read_volume_file(path: &Path, options: &LoadOptions) -> Result<Vec<u8>, LoadProblem> {
    let limit = options.max_volume_bytes.saturating_add(MAX_HEADER_BYTES);
    read_regular(
        path,
        limit,
        "a volume file (--max-volume-bytes plus 1 MiB of header)",
    )
    .map_err(LoadProblem::File)
}

/// Where a detached data file's bytes start and how many the header needs from there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum DataRange {
    /// Skip this many bytes, then read `needed` (raw) or everything up to `needed` more (compressed).
    From { skip: u64, needed: u64 },
    /// The last `needed` bytes of the file (NRRD `byte skip: -1`, MetaImage `HeaderSize = -1`).
    Tail { needed: u64 },
}

/// Reads the bytes of a detached data file that a header describes: nothing before `skip` is kept and
/// nothing past `skip + needed + 1` is read (the extra byte tells a too-long file from an exact one).
/// For compressed data `needed` is the compressed stream's bound, i.e. the file's remaining size capped by
/// the limit.
pub(crate) fn read_data_file(
    path: &Path,
    range: DataRange,
    options: &LoadOptions,
) -> Result<Vec<u8>, LoadProblem> {
    use std::io::{Seek, SeekFrom};
    let error = |source: FileError| LoadProblem::DataFile {
        path: path.to_path_buf(),
        source,
    };
    let (mut file, size_bytes) = open_regular(path).map_err(error)?;
    let (start, needed) = match range {
        DataRange::From { skip, needed } => (skip, needed),
        DataRange::Tail { needed } => match size_bytes.checked_sub(needed) {
            Some(start) => (start, needed),
            None => {
                return Err(LoadProblem::Truncated {
                    expected_bytes: needed,
                    actual_bytes: size_bytes,
                })
            }
        },
    };
    if needed > options.max_volume_bytes {
        return Err(LoadProblem::OverLimit {
            needed_bytes: needed,
            limit_bytes: options.max_volume_bytes,
        });
    }
    if start > size_bytes {
        return Err(LoadProblem::Truncated {
            expected_bytes: start.saturating_add(needed),
            actual_bytes: size_bytes,
        });
    }
    file.seek(SeekFrom::Start(start))
        .map_err(|e| error(e.into()))?;
    let mut bytes =
        Vec::with_capacity(usize::try_from(needed.min(size_bytes - start)).unwrap_or(0));
    file.take(needed.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| error(e.into()))?;
    Ok(bytes)
}

/// Resolves `name` (from inside a header or scene file) against `folder`, following symlinks, and
/// checks that the result lies inside `folder` unless `allow_outside_paths`.
pub fn confined_path(
    folder: &Path,
    name: &Path,
    allow_outside_paths: bool,
) -> Result<PathBuf, FileError> {
    let folder = if folder.as_os_str().is_empty() {
        Path::new(".")
    } else {
        folder
    };
    let joined = folder.join(name);
    if allow_outside_paths {
        return Ok(joined);
    }
    let resolved = joined.canonicalize()?;
    let folder = folder.canonicalize()?;
    if resolved.starts_with(&folder) {
        Ok(resolved)
    } else {
        Err(FileError::Outside { resolved, folder })
    }
}

/// [`confined_path`] for a data file named in a volume header at `header_path`.
pub(crate) fn data_file_path(
    header_path: &Path,
    name: &str,
    options: &LoadOptions,
) -> Result<PathBuf, LoadProblem> {
    let folder = header_path.parent().unwrap_or(Path::new("."));
    confined_path(folder, Path::new(name), options.allow_outside_paths).map_err(|source| {
        LoadProblem::DataFile {
            path: folder.join(name),
            source,
        }
    })
}

/// A header-and-data volume file (NRRD, MetaImage) held in memory: its bytes, where it was read from (a
/// detached data file is found beside it) and the limits of the load.
pub(crate) struct HeaderFile<'a> {
    pub bytes: &'a [u8],
    pub path: &'a Path,
    pub options: &'a LoadOptions,
}

impl<'a> HeaderFile<'a> {
    /// The data the header describes: what follows it in the file's bytes (from `header_bytes` on) when
    /// `data_file` is `None`, else the detached file it names (confined to the header's folder), read as
    /// `range`.
    pub(crate) fn data(
        &self,
        header_bytes: usize,
        data_file: Option<&str>,
        range: impl FnOnce() -> DataRange,
    ) -> Result<Cow<'a, [u8]>, LoadProblem> {
        match data_file {
            Some(name) => {
                let data_path = data_file_path(self.path, name, self.options)?;
                Ok(Cow::Owned(read_data_file(
                    &data_path,
                    range(),
                    self.options,
                )?))
            }
            None => Ok(Cow::Borrowed(
                self.bytes.get(header_bytes..).unwrap_or_default(),
            )),
        }
    }
}

/// The four entry points of a header-and-data format's module (`load`, `load_with`, `parse`, `parse_with`),
/// around its `parse_header` and `from_header(header, &HeaderFile)`; `$files` names its file endings,
/// `$name` the format and `$budget` what is checked against the limit.
macro_rules! header_format_entry_points {
    (files: $files:literal, name: $name:literal, budget: $budget:literal) => {
        #[doc = concat!("Loads a ", $files, " file with the default limits.")]
        pub fn load(path: &Path) -> Result<LoadedVolume, LoadProblem> {
            load_with(path, &$crate::source::LoadOptions::default())
        }

        #[doc = concat!("Loads a ", $files, " file within `options`' limits.")]
        pub fn load_with(
            path: &Path,
            options: &$crate::source::LoadOptions,
        ) -> Result<LoadedVolume, LoadProblem> {
            let bytes = $crate::source::read_volume_file(path, options)?;
            parse_with(&bytes, path, options)
        }

        #[doc = concat!(
            "Parses a ", $name, " file held in memory with the default limits; a detached data file is ",
            "read relative to `path`'s folder."
        )]
        pub fn parse(bytes: &[u8], path: &Path) -> Result<LoadedVolume, LoadProblem> {
            parse_with(bytes, path, &$crate::source::LoadOptions::default())
        }

        #[doc = concat!(
            "[`parse`] within `options`' limits: ", $budget, " are checked against `--max-volume-bytes` ",
            "before anything is read or inflated, and a detached data file must lie in the header's folder."
        )]
        pub fn parse_with(
            bytes: &[u8],
            path: &Path,
            options: &$crate::source::LoadOptions,
        ) -> Result<LoadedVolume, LoadProblem> {
            let file = $crate::source::HeaderFile {
                bytes,
                path,
                options,
            };
            from_header(parse_header(bytes)?, &file)
        }
    };
}
pub(crate) use header_format_entry_points;

/// Checks the memory a load needs (`data_bytes` read or inflated plus 4 bytes per `f32` value) against
/// the limit.
pub(crate) fn check_budget(
    data_bytes: u64,
    values: u64,
    options: &LoadOptions,
) -> Result<(), LoadProblem> {
    let needed = values
        .checked_mul(4)
        .and_then(|f32_bytes| f32_bytes.checked_add(data_bytes))
        .unwrap_or(u64::MAX);
    if needed > options.max_volume_bytes {
        return Err(LoadProblem::OverLimit {
            needed_bytes: needed,
            limit_bytes: options.max_volume_bytes,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_and_fifos_are_refused_without_blocking() {
        let message = open_regular(Path::new("/dev/zero"))
            .unwrap_err()
            .to_string();
        assert!(message.contains("character device"), "{message}");
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        let c_path = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates the node.
        assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
        let message = read_regular(&fifo, 10, "test").unwrap_err().to_string();
        assert!(message.contains("FIFO"), "{message}");
        let message = open_regular(dir.path()).unwrap_err().to_string();
        assert!(message.contains("directory"), "{message}");
    }

    #[test]
    fn reads_stop_at_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f");
        std::fs::write(&path, [1u8; 100]).unwrap();
        assert_eq!(read_regular(&path, 100, "test").unwrap().len(), 100);
        let message = read_regular(&path, 99, "test").unwrap_err().to_string();
        assert!(message.contains("more than the 99-byte limit"), "{message}");
        let options = LoadOptions::default();
        let bytes = read_data_file(
            &path,
            DataRange::From {
                skip: 90,
                needed: 4,
            },
            &options,
        )
        .unwrap();
        assert_eq!(bytes.len(), 5, "needed plus one byte to see trailing data");
        let bytes = read_data_file(&path, DataRange::Tail { needed: 7 }, &options).unwrap();
        assert_eq!(bytes.len(), 7);
        assert!(matches!(
            read_data_file(
                &path,
                DataRange::From {
                    skip: 101,
                    needed: 1
                },
                &options
            ),
            Err(LoadProblem::Truncated { .. })
        ));
    }

    #[test]
    fn paths_stay_in_their_folder_unless_allowed() {
        let dir = tempfile::tempdir().unwrap();
        let inner = dir.path().join("inner");
        std::fs::create_dir(&inner).unwrap();
        std::fs::write(inner.join("ok.raw"), b"x").unwrap();
        std::fs::write(dir.path().join("secret"), b"x").unwrap();
        std::os::unix::fs::symlink(dir.path().join("secret"), inner.join("link.raw")).unwrap();
        assert!(confined_path(&inner, Path::new("ok.raw"), false).is_ok());
        for name in ["../secret", "link.raw", "/etc/passwd"] {
            let message = confined_path(&inner, Path::new(name), false)
                .unwrap_err()
                .to_string();
            assert!(
                message.contains("--allow-outside-paths"),
                "{name}: {message}"
            );
        }
        assert!(confined_path(&inner, Path::new("../secret"), true).is_ok());
    }

    #[test]
    fn the_budget_counts_data_and_f32_values() {
        let options = LoadOptions {
            max_volume_bytes: 1000,
            allow_outside_paths: false,
        };
        assert!(check_budget(600, 100, &options).is_ok());
        let message = check_budget(601, 100, &options).unwrap_err().to_string();
        assert!(message.contains("--max-volume-bytes"), "{message}");
        assert!(check_budget(0, u64::MAX, &options).is_err());
    }
}
