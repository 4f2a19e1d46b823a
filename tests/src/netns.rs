//! A private network namespace per test, so test traffic never leaves it.
//!
//! `Namespace::new()` runs `ip netns add`, brings `lo` up and adds a TAP with
//! the host side at [`HOST_CIDR`]. [`Namespace::enter`] moves the *calling
//! thread* into the namespace (`setns`): sockets it opens afterwards live
//! there, so a test runs its client on a current-thread runtime after
//! entering. Programs run inside with [`Namespace::command`]. Dropping the
//! namespace deletes it, and the TAP with it.

use std::fs::File;
use std::io;
use std::os::fd::AsRawFd;
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};

/// The test bench range (RFC 2544): the host side of every TAP.
pub const HOST_CIDR: &str = "198.18.0.1/24";
/// The device under test, as hal-sim and the firmware are configured.
pub const DEVICE_IP: &str = "198.18.0.2";
/// The TAP's name inside each namespace (names are per namespace).
pub const TAP: &str = "tap0";

/// A network namespace made for one test, deleted on drop.
#[derive(Debug)]
pub struct Namespace {
    name: String,
}

impl Namespace {
    /// A new namespace with `lo` up and a TAP at [`HOST_CIDR`] (link up once
    /// a program opens the TAP). Fails with a clear message without root.
    pub fn new() -> io::Result<Self> {
        require_root();
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let name = format!("mbtest-{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed));
        run(Command::new("ip").args(["netns", "add", &name]))?;
        let ns = Self { name };
        ns.ip(&["link", "set", "lo", "up"])?;
        ns.ip(&["tuntap", "add", "dev", TAP, "mode", "tap"])?;
        ns.ip(&["addr", "add", HOST_CIDR, "dev", TAP])?;
        ns.ip(&["link", "set", TAP, "up"])?;
        Ok(ns)
    }

    /// The namespace's name (for `ip netns exec`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Runs `ip ARGS` inside the namespace.
    pub fn ip(&self, args: &[&str]) -> io::Result<()> {
        run(Command::new("ip").args(["-n", &self.name]).args(args))
    }

    /// A command that runs `program` inside the namespace.
    pub fn command(&self, program: impl AsRef<std::ffi::OsStr>) -> Command {
        let mut command = Command::new("ip");
        command.args(["netns", "exec", &self.name]).arg(program);
        command
    }

    /// Moves the calling thread into the namespace: its new sockets live there.
    pub fn enter(&self) -> io::Result<()> {
        let file = File::open(format!("/run/netns/{}", self.name))?;
        // SAFETY: `setns` only reads the descriptor, which `file` keeps open
        // for the duration of the call.
        let rc = unsafe { libc::setns(file.as_raw_fd(), libc::CLONE_NEWNET) };
        if rc == 0 { Ok(()) } else { Err(io::Error::last_os_error()) }
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        let _ = run(Command::new("ip").args(["netns", "delete", &self.name]));
    }
}

/// Fails the test, loudly and with the reason, unless it runs as root:
/// namespaces and TAPs need CAP_NET_ADMIN. CI runs as root.
pub fn require_root() {
    // SAFETY: geteuid has no preconditions and cannot fail.
    let euid = unsafe { libc::geteuid() };
    assert!(
        euid == 0,
        "this system test needs root (CAP_NET_ADMIN) to create a network namespace and a TAP; \
         run the README's test command as root (CI does)"
    );
}

fn run(command: &mut Command) -> io::Result<()> {
    let output = command.output()?;
    if output.status.success() {
        return Ok(());
    }
    Err(io::Error::other(format!("{:?} failed: {}", command, String::from_utf8_lossy(&output.stderr).trim())))
}
