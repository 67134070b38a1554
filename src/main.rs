//! The `voxhap` command: a thin wrapper over [`voxhap::cli`].

fn main() -> std::process::ExitCode {
    voxhap::cli::main()
}
