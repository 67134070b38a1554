//! Integration tests, compiled into one binary (ripgrep style) with a shared `util` module.
//!
//! The binary installs a counting global allocator (util::alloc) so that any test can prove a code path
//! allocates nothing.

mod util;

mod alloc_free;
mod bad_inputs;
mod cli_shell;
mod cli_solve;
mod device_bringup;
mod device_connect;
mod device_drivers;
mod device_hardware;
mod device_passivity_pty;
mod device_pty;
mod device_safety;
mod device_spec;
mod docs_links;
mod docs_outputs;
mod docs_reference;
mod docs_stability;
mod drivers_alloc_free;
mod falcon;
mod falcon_late;
mod foxglove;
mod foxglove_scene_change;
mod fuzz_corpus;
mod hand_target;
mod haply_2diy_pty;
mod haply_inverse;
mod haply_inverse_frame;
mod haply_inverse_trace;
mod igtl;
mod late_states;
mod layers;
mod local_model_pty;
mod mode_loops;
mod modes;
mod paper;
mod plot_stream;
mod record;
mod replay;
mod robustness;
mod safety_props;
mod serve_e2e;
mod server;
mod servo;
mod servo_session;
mod servo_truth;
mod sim;
mod sim_path;
mod solver_props;
mod volume_io;
mod woodenhaptics_serial;
mod workspace;

#[global_allocator]
static ALLOCATOR: util::alloc::CountingAllocator = util::alloc::CountingAllocator;
