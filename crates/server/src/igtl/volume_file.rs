//! Turns an IMAGE received over OpenIGTLink into a volume file voxhap's loaders read (a raw float32 data
//! file and its TOML header, `voxhap_io::raw`), so the image reaches the scene through the
//! session's ordinary `load_volume` control command: the same validation, the same scene building off the
//! servo thread, the same report in `/api/scene`.
//!
//! Where it sits: the OpenIGTLink server (`super`) calls [`ImageFolder::write`] on tokio's blocking pool after
//! decoding an authorised IMAGE, then sends `ControlCommand::LoadVolume` with the header's path. The folder
//! is private to the server (created with a random name under the system's temporary directory) and removed
//! when the server stops; only the newest few images are kept on disk.

use super::codec::Image;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Images kept on disk; older ones are deleted when a new one is written (a recording that started with an
/// old one has already read it).
pub const KEPT_IMAGES: usize = 4;

/// Why an image could not be written.
#[derive(Debug, thiserror::Error)]
pub enum VolumeFileError {
    #[error("cannot create the image folder {path}: {source}")]
    Folder {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot get random bytes for the folder name: {0}")]
    Random(getrandom::Error),
}

/// The server's private folder of received images.
#[derive(Debug)]
pub struct ImageFolder {
    path: PathBuf,
    written: Vec<PathBuf>,
    count: u64,
}

impl ImageFolder {
    /// Creates `voxhap-igtl-<pid>-<random>` under the system's temporary directory.
    pub fn create() -> Result<ImageFolder, VolumeFileError> {
        let mut random = [0u8; 6];
        getrandom::fill(&mut random).map_err(VolumeFileError::Random)?;
        let suffix: String = random.iter().map(|b| format!("{b:02x}")).collect();
        let path =
            std::env::temp_dir().join(format!("voxhap-igtl-{}-{suffix}", std::process::id()));
        std::fs::create_dir(&path).map_err(|source| VolumeFileError::Folder {
            path: path.clone(),
            source,
        })?;
        Ok(ImageFolder {
            path,
            written: Vec::new(),
            count: 0,
        })
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `image` as `<device>-<n>.f32` and `<device>-<n>.toml` (RAS, millimetres) and returns the header's
    /// path. `device` is cut to letters, digits, `-` and `_`.
    pub fn write(&mut self, device: &str, image: &Image) -> Result<PathBuf, VolumeFileError> {
        self.count += 1;
        let stem: String = device
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
            .take(20)
            .collect();
        let stem = if stem.is_empty() {
            "image".to_owned()
        } else {
            stem
        };
        let name = format!("{stem}-{}", self.count);
        let data_path = self.path.join(format!("{name}.f32"));
        let header_path = self.path.join(format!("{name}.toml"));
        let write = |path: &Path, bytes: &[u8]| -> Result<(), VolumeFileError> {
            let mut file = voxhap_record::create_or_replace_file(path).map_err(|error| {
                VolumeFileError::Write {
                    path: path.to_path_buf(),
                    source: std::io::Error::other(error.to_string()),
                }
            })?;
            file.write_all(bytes)
                .map_err(|source| VolumeFileError::Write {
                    path: path.to_path_buf(),
                    source,
                })
        };
        let mut data = Vec::with_capacity(image.values.len() * 4);
        for value in &image.values {
            data.extend_from_slice(&value.to_le_bytes());
        }
        write(&data_path, &data)?;
        drop(data);
        write(&header_path, header_text(&name, image).as_bytes())?;
        self.written.push(header_path.clone());
        while self.written.len() > KEPT_IMAGES {
            let old = self.written.remove(0);
            let _ = std::fs::remove_file(old.with_extension("f32"));
            let _ = std::fs::remove_file(&old);
        }
        Ok(header_path)
    }

    /// Deletes the folder and everything in it.
    pub fn remove(self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

/// The raw loader's TOML header for `image` (data file `<name>.f32`, little-endian float32). The index axes
/// split into unit directions and spacings; RAS millimetres.
fn header_text(name: &str, image: &Image) -> String {
    let axes = [
        image.axes_mm.x_axis,
        image.axes_mm.y_axis,
        image.axes_mm.z_axis,
    ];
    let spacing = axes.map(|a| a.length());
    let direction = axes.map(|a| a.normalize_or_zero().to_array());
    let list = |v: [f64; 3]| format!("[{:?}, {:?}, {:?}]", v[0], v[1], v[2]);
    format!(
        "# Written by voxhap's OpenIGTLink server from an IMAGE message.\n\
         data_file = \"{name}.f32\"\n\
         dims = [{}, {}, {}]\n\
         scalar_type = \"f32\"\n\
         endianness = \"little\"\n\
         spacing = {}\n\
         origin = {}\n\
         direction = [{}, {}, {}]\n\
         units = \"mm\"\n",
        image.dims[0],
        image.dims[1],
        image.dims[2],
        list(spacing),
        list(image.origin_mm.to_array()),
        list(direction[0]),
        list(direction[1]),
        list(direction[2]),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn a_written_image_loads_back_in_ras_metres() {
        let image = Image::ramp([4, 3, 2], [2.0, 1.0, 0.5], [-10.0, 20.0, 5.0]);
        let mut folder = ImageFolder::create().unwrap();
        let path = folder.write("Volume 1!", &image).unwrap();
        assert!(path.ends_with("Volume1-1.toml"), "{}", path.display());
        let loaded = voxhap_io::load(&path).unwrap();
        let grid = loaded.volume.grid();
        assert_eq!(grid.dims(), [4, 3, 2]);
        let origin = grid.origin_m();
        assert!(
            (origin - DVec3::new(-0.010, 0.020, 0.005)).length() < 1e-12,
            "{origin}"
        );
        let far = grid.index_to_world(DVec3::new(3.0, 2.0, 1.0));
        assert!(
            (far - DVec3::new(-0.004, 0.022, 0.0055)).length() < 1e-12,
            "{far}"
        );
        assert_eq!(loaded.volume.value_range(), (0.0, 23.0));
        for n in 0..KEPT_IMAGES + 2 {
            folder.write("v", &image).unwrap();
            let _ = n;
        }
        let files = std::fs::read_dir(folder.path()).unwrap().count();
        assert_eq!(files, 2 * KEPT_IMAGES);
        let dir = folder.path().to_path_buf();
        folder.remove();
        assert!(!dir.exists());
    }
}
