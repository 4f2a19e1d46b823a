//! The robot controller of the robot link's tests: tests/peers/robot_controller.py
//! (pymodbus's server, or a plain asyncio one that misbehaves as told), run
//! in a test's namespace at the TAP's host side.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::netns::Namespace;

/// Where the controller listens: the host side of the namespace's TAP.
pub const CONTROLLER_IP: &str = "198.18.0.1";

pub fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("peers/robot_controller.py")
}

/// A controller process (tests/peers/robot_controller.py), killed on drop.
#[derive(Debug)]
pub struct Controller {
    child: Child,
}

impl Controller {
    /// Starts tests/peers/robot_controller.py in `ns` on `port` in `mode`
    /// and waits for its "ready" line.
    pub fn start(ns: &Namespace, port: u16, mode: &str) -> Self {
        let probe = Command::new("python3").args(["-c", "import pymodbus"]).output();
        assert!(probe.is_ok_and(|o| o.status.success()), "these tests need python3 with pymodbus");
        let mut child = ns
            .command("python3")
            .arg(script())
            .args([CONTROLLER_IP, &port.to_string(), mode])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("python3 starts");
        let stdout = child.stdout.take().expect("its stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if line.starts_with("write") {
                    eprintln!("controller: {line}");
                }
                let _ = tx.send(line);
            }
        });
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            match rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
                Ok(line) if line == "ready" => break,
                Ok(_) => {}
                Err(_) => panic!("the controller ({mode}) did not get ready"),
            }
        }
        // The rest of its lines: a write would show as "write FC" (asserted by the tests through `writes`).
        Self { child }
    }

    pub fn signal(&self, signal: i32) {
        // SAFETY: kill(2) with a pid this test started and still owns.
        let rc = unsafe { libc::kill(self.child.id() as i32, signal) };
        assert_eq!(rc, 0, "kill({signal})");
    }

    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Controller {
    fn drop(&mut self) {
        // A stopped process must go on to die.
        // SAFETY: as in `signal`; the process may already be gone.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGCONT) };
        self.kill();
    }
}
