//! hal-sim as the settings service's [`Platform`]: what only the board knows (its
//! model, its MAC, the network as the stack has it) and what only it can do
//! (draw a salt, blink, reboot).
//!
//! A reboot is a board's: hal-sim executes itself again (`/proc/self/exe`
//! with the same arguments and environment, the same process id), so the
//! settings are read again from the state file and the network, the
//! listeners and the tasks start afresh. Every descriptor is closed on
//! exec (the TAP, the sockets, the state file and its lock all have
//! `O_CLOEXEC`). The exec runs in [`reboot_task`], a moment after the
//! API asked for it, so the last frames of its response leave the TAP first.

use std::cell::Cell;
use std::ffi::{CString, OsString};
use std::io::Read as _;
use std::os::unix::ffi::OsStrExt as _;

use adapter::control::{NetworkStatus, Platform, RobotSource};
use adapter::settings::NetMode;
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};

/// How long a reboot waits for the frames already queued (the response's
/// last segments, the connection's close) to leave.
const REBOOT_DELAY: Duration = Duration::from_millis(100);

/// A reboot asked for, for [`reboot_task`].
static REBOOT: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// The simulated board, as the API sees it.
pub struct SimPlatform {
    stack: Stack<'static>,
    /// The network mode the device started with.
    mode: NetMode,
    mac: [u8; 6],
    /// Until when the (simulated) status LED blinks.
    locate_until: Cell<Option<Instant>>,
}

impl std::fmt::Debug for SimPlatform {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimPlatform").field("mode", &self.mode).field("locating", &self.locating()).finish()
    }
}

impl SimPlatform {
    pub fn new(stack: Stack<'static>, mode: NetMode, mac: [u8; 6]) -> Self {
        Self { stack, mode, mac, locate_until: Cell::new(None) }
    }

    /// Whether the status LED blinks now (`POST /api/locate`, for 10 s).
    pub fn locating(&self) -> bool {
        self.locate_until.get().is_some_and(|until| Instant::now() < until)
    }
}

impl Platform for SimPlatform {
    fn model(&self) -> &'static str {
        crate::MODEL
    }

    fn mac(&self) -> [u8; 6] {
        self.mac
    }

    fn network(&self) -> NetworkStatus {
        NetworkStatus::of(self.stack, self.mode)
    }

    fn reboot(&self) {
        log::warn!("reboot: hal-sim executes itself again in {} ms", REBOOT_DELAY.as_millis());
        REBOOT.signal(());
    }

    fn locate(&self, duration: Duration) {
        log::info!("locate: the status LED blinks for {} s", duration.as_secs());
        self.locate_until.set(Instant::now().checked_add(duration));
    }

    fn salt(&self) -> [u8; 16] {
        let mut salt = [0u8; 16];
        let read = std::fs::File::open("/dev/urandom").and_then(|mut urandom| urandom.read_exact(&mut salt));
        if let Err(e) = read {
            // Never a fixed salt: the clock's and the process's bits at least.
            log::warn!("salt: /dev/urandom cannot be read ({e}); using the clock");
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |t| t.as_nanos())
                .to_le_bytes();
            for (byte, extra) in salt.iter_mut().zip(nanos.iter().chain(&std::process::id().to_le_bytes())) {
                *byte ^= extra;
            }
        }
        salt
    }

    fn local_robot(&self) -> RobotSource {
        RobotSource::Sim
    }
}

/// Waits for a reboot, lets the last frames out, and executes hal-sim again
/// with `args` (its own command line, the program name first).
#[embassy_executor::task]
pub async fn reboot_task(args: Vec<OsString>) {
    REBOOT.wait().await;
    Timer::after(REBOOT_DELAY).await;
    let error = exec_self(&args);
    log::error!("reboot: cannot execute hal-sim again ({error}); exiting instead");
    std::process::exit(1);
}

/// Replaces the process with `/proc/self/exe` run with `args`; returns only on failure.
fn exec_self(args: &[OsString]) -> std::io::Error {
    let Ok(args) = args.iter().map(|arg| CString::new(arg.as_bytes())).collect::<Result<Vec<_>, _>>() else {
        return std::io::Error::new(std::io::ErrorKind::InvalidInput, "an argument holds a NUL byte");
    };
    let mut argv: Vec<*const libc::c_char> = args.iter().map(|arg| arg.as_ptr()).collect();
    argv.push(std::ptr::null());
    // SAFETY: a NUL-terminated path and a null-terminated array of pointers
    // to NUL-terminated strings, all alive for the call (which, on success,
    // does not return).
    unsafe { libc::execv(c"/proc/self/exe".as_ptr(), argv.as_ptr()) };
    std::io::Error::last_os_error()
}
