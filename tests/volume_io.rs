//! Volume loaders end to end: the real scans in data/ against numbers from independent
//! readers, every format/encoding/endianness/type combination written here into a temp dir, and the
//! `voxhap info` binary.
//!
//! By topic: [`real_files`] the real scans; [`formats`] every written format and broken files; [`info`] the
//! `voxhap info` binary. The shared scans' paths and the synthetic volume are tests/util/volume_files.rs.

mod formats;
mod info;
mod real_files;
