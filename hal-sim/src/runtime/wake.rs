//! How a wake reaches the loop: a flag the loop reads before it sleeps, and
//! an eventfd it sleeps on, written only by a wake that finds it asleep.
//!
//! On the loop's own thread (every wake, in practice: it is hal-sim's only
//! thread) a wake is two atomic stores and no system call. The eventfd is
//! there because a [`Waker`](std::task::Waker) may be sent to, and woken
//! from, any thread.

use std::cell::Cell;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

/// The loop's wake state; one per process, leaked.
#[derive(Debug)]
pub(super) struct Signal {
    /// Set by every wake; cleared by the loop before it polls its tasks.
    pending: AtomicBool,
    /// Set while the loop is (about to be) asleep in `ppoll(2)`.
    sleeping: AtomicBool,
    /// Written by a wake that finds the loop asleep.
    eventfd: OwnedFd,
}

/// The loop's signal, for wakes that do not come through a task's waker
/// (a timer scheduled from another thread).
static SIGNAL: OnceLock<&'static Signal> = OnceLock::new();

thread_local! {
    /// True on the loop's thread.
    static ON_LOOP: Cell<bool> = const { Cell::new(false) };
}

impl Signal {
    /// The process's signal; fails only if the kernel gives no eventfd.
    pub(super) fn new() -> io::Result<&'static Self> {
        // SAFETY: eventfd takes no pointers; the descriptor returned is owned here.
        let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `fd` is a new descriptor that nothing else owns.
        let eventfd = unsafe { OwnedFd::from_raw_fd(fd) };
        let signal: &'static Self =
            Box::leak(Box::new(Self { pending: AtomicBool::new(false), sleeping: AtomicBool::new(false), eventfd }));
        let _ = SIGNAL.set(signal);
        Ok(signal)
    }

    /// The executor's context pointer, which [`pender`] turns back into `&Signal`.
    pub(super) fn context(&'static self) -> *mut () {
        std::ptr::from_ref(self).cast_mut().cast()
    }

    /// Marks the calling thread as the loop's.
    pub(super) fn enter(&self) {
        ON_LOOP.set(true);
    }

    /// A wake, from any thread: a system call only when the loop sleeps.
    fn signal(&self) {
        self.pending.store(true, Ordering::SeqCst);
        if self.sleeping.load(Ordering::SeqCst) {
            let one: u64 = 1;
            // SAFETY: writes 8 bytes from a live u64 to our eventfd. A failure
            // (the counter full) leaves it readable, which is all we need.
            let _ = unsafe { libc::write(self.eventfd.as_raw_fd(), (&raw const one).cast(), 8) };
        }
    }

    /// Forgets the wakes so far: the loop is about to poll every woken task.
    pub(super) fn clear(&self) {
        self.pending.store(false, Ordering::SeqCst);
    }

    /// Says the loop is going to sleep; true if a wake came since [`clear`](Self::clear),
    /// in which case it must not.
    pub(super) fn sleep(&self) -> bool {
        self.sleeping.store(true, Ordering::SeqCst);
        self.pending.load(Ordering::SeqCst)
    }

    /// Says the loop is awake: wakes need no eventfd write.
    pub(super) fn awake(&self) {
        self.sleeping.store(false, Ordering::SeqCst);
    }

    /// The eventfd, for the loop's `ppoll(2)`.
    pub(super) fn fd(&self) -> RawFd {
        self.eventfd.as_raw_fd()
    }

    /// Empties the eventfd after `ppoll(2)` found it written.
    pub(super) fn drain(&self) {
        let mut count: u64 = 0;
        // SAFETY: reads at most 8 bytes into a live u64; non-blocking.
        let _ = unsafe { libc::read(self.eventfd.as_raw_fd(), (&raw mut count).cast(), 8) };
    }
}

/// Something the loop reads before it sleeps has changed (the next timer):
/// wakes the loop if that happened on another thread.
pub(super) fn from_elsewhere() {
    if !ON_LOOP.get()
        && let Some(signal) = SIGNAL.get()
    {
        signal.signal();
    }
}

/// embassy's raw executor calls this when one of its tasks is woken.
#[unsafe(export_name = "__pender")]
fn pender(context: *mut ()) {
    // SAFETY: the only executor made is the loop's, whose context is
    // `Signal::context()` of a leaked `&'static Signal`.
    let signal: &'static Signal = unsafe { &*context.cast::<Signal>() };
    signal.signal();
}
