//! Shared helpers for the integration tests.
//!
//! [`alloc::CountingAllocator`] is the test binary's global allocator (installed in tests/integration.rs): it
//! counts allocations, reallocations and frees per thread, so a test can prove that a hot path (the solver, the
//! servo tick, `SimArm::step`) does not allocate while other tests run in parallel on other threads.
//! [`server`] starts a session with the visualiser server and speaks HTTP and WebSocket to it.
//! [`spec_device`] is a voxhap-protocol device written from protocol/SPEC.md alone, on a pseudo-terminal, that logs
//! every force the host sends it and misbehaves on request (tests/device_spec/), and
//! [`spec_serve`] runs `voxhap serve` against it and waits for what a test checks. [`scene_strategies`] draws
//! the solver property tests' random scenes. [`supervised`] holds what the serial-arm tests share (the
//! supervisor's test configuration, the glitch drive, a bounded wait). [`igtl_client`] is an OpenIGTLink client
//! written from the specification, [`sim`] runs sims/ scenarios, and [`volume_files`] writes and finds the volume
//! files the loader tests read.

pub mod alloc;
pub mod scene_strategies;
pub mod server;
pub mod sim;
pub mod spec_device;
pub mod spec_serve;
pub mod supervised;
pub mod volume_files;

/// `voxhap serve --device DEVICE` without servers or real-time scheduling (`--no-http --no-foxglove --rt off`);
/// the caller adds the rest (scene, duration, recording, output pipes).
pub fn serve_headless(device: &str) -> std::process::Command {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_voxhap"));
    command
        .args([
            "serve",
            "--no-http",
            "--no-foxglove",
            "--rt",
            "off",
            "--device",
        ])
        .arg(device);
    command
}

/// Runs `f` and returns how many allocation events (alloc, realloc, free) the current thread made meanwhile.
pub fn count_allocations(f: impl FnOnce()) -> u64 {
    alloc::count_allocations(f).1
}
pub mod falcon_firmware;
pub mod haply_board;
pub mod igtl_client;
pub mod inverse_service;
pub mod inverse_ticks;
pub mod late_device;
pub mod mock_process;
pub mod nifalcon;
pub mod pty;
pub mod woody_firmware;
