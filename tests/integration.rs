//! Integration tests, one binary (ripgrep style).

mod volume_io;
