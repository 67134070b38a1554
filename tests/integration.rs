//! Integration tests, one binary (ripgrep style).
mod record;
mod util;
