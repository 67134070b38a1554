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
