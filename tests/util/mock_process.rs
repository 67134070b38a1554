//! `voxhap mock-device` as a separate process on a pseudo-terminal, killed on drop (tests/device_pty.rs,
//! tests/workspace.rs).

use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStdout, Command, Stdio};

/// A running mock device, killed on drop.
pub struct MockProcess {
    child: Child,
    pub path: String,
    stdout: BufReader<ChildStdout>,
}

impl MockProcess {
    pub fn start(args: &[&str]) -> MockProcess {
        let mut child = Command::new(env!("CARGO_BIN_EXE_voxhap"))
            .arg("mock-device")
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("start voxhap mock-device");
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        stdout.read_line(&mut line).unwrap();
        let path = line
            .trim()
            .strip_prefix("serving ")
            .unwrap_or_else(|| panic!("mock said {line:?}"))
            .to_string();
        MockProcess {
            child,
            path,
            stdout,
        }
    }

    /// The mock opened as `serve` opens it (the reconnecting supervisor with its default settings, the built-in
    /// scene's arm, 1 kHz), with a stop slot, and connected.
    pub fn open_connected(&self) -> Box<dyn voxhap::servo::device::ServoDevice> {
        let setup = voxhap::servo::setup::SceneSetup::builtin().unwrap();
        let mut device = voxhap::servo::device::open_device(
            &voxhap::servo::device::DeviceSpec::Mock(self.path.clone().into()),
            voxhap::device::supervisor::SupervisorConfig::default(),
            (setup.arm.clone(), setup.start_m),
            1e-3,
        )
        .unwrap()
        .device;
        device.set_stop_slot(voxhap::servo::monitor::StopSlot::new());
        device.connect(0).unwrap();
        device
    }

    /// True once the process has exited (its stdout may still hold lines to read).
    pub fn has_exited(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(Some(_)))
    }

    pub fn next_line(&mut self) -> String {
        let mut line = String::new();
        self.stdout.read_line(&mut line).unwrap();
        line.trim().to_string()
    }
}

impl Drop for MockProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
