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

/// A `--arm` file for the mock: the simulated arm (0.1 kg, 1 N s/m, unbounded) held by a hand with a
/// 200 N/m, 0.5 N s/m grip that rises `rise_m` while the host connects and engages, then moves down at 5 mm/s
/// to z = -8 mm and holds there: 3 mm past a floor at z = -5 mm, 0.6 N of grip pressing the handle into it.
pub fn pressing_handle(rise_m: f64) -> String {
    format!(
        "[arm]\nmass_kg = 0.1\ndamping_n_s_per_m = 1.0\nworkspace = {{ shape = \"unbounded\" }}\n\n\
         [hand]\nstiffness_n_per_m = 200.0\ndamping_n_s_per_m = 0.5\n\n\
         [path]\nkind = \"waypoints\"\n\
         points_m = [[0.0, 0.0, 0.0], [0.0, 0.0, {rise_m:?}], [0.0, 0.0, -0.008]]\n\
         speed_m_per_s = 0.005\n"
    )
}
