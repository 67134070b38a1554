#!/usr/bin/env bash
# voxhap-solver builds without the standard library and without an allocator (run from .ci/run).
#
# 1. `cargo build -p voxhap-solver --no-default-features`: the crate is `#![no_std]` in that configuration
#    (`#![cfg_attr(not(feature = "std"), no_std)]` at its root and no `extern crate std`), so any `std::` path in
#    the solve or the certificate is a compile error.
#    voxhap-local (the device-side local loop, `#![no_std]` always) likewise.
# 2. .ci/no-std: a `#![no_std]` static library with its own `#[panic_handler]` that runs a solve in
#    `storage::Fixed` arrays and one cycle of voxhap-local's loop. A dependency that pulled in std would bring std's panic handler as well (duplicate
#    lang item), and one that needed an allocator would fail to link `alloc`: either way the build fails.
# No embedded target can be installed here (rustup needs the network), so both build for the host.
set -euo pipefail
cd "$(dirname "$0")/.."
name=check-no-std
. .ci/lib.sh
cargo build --release -p voxhap-solver --no-default-features || fail "voxhap-solver does not build without std"
cargo build --release -p voxhap-local || fail "voxhap-local (the device-side local loop) does not build without std"
CARGO_TARGET_DIR="$PWD/target/no-std-check" cargo build --release --manifest-path .ci/no-std/Cargo.toml ||
  fail "a no_std consumer of voxhap-solver does not build (something in its tree needs std or alloc)"
echo "$name: voxhap-solver and voxhap-local build as no_std, allocation-free"
