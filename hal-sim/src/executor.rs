//! The executor hal-sim runs on: embassy's raw executor, on one thread that
//! sleeps in `poll(2)` on the TAP and on an eventfd, until the next timer.
//!
//! embassy's std executor sleeps on a condition variable, so a frame on the
//! TAP had to wake a reactor thread first (async-io's), which then woke the
//! executor: two thread switches per frame. Here the executor thread waits on
//! the TAP's descriptor itself ([`poll_readable`]), with the timer queue's
//! next deadline as the timeout (src/time.rs); only wakes from other threads
//! (async-io's reactor, for the control socket) go through the eventfd.

use std::cell::RefCell;
use std::io;
use std::marker::PhantomData;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::Waker;

use embassy_executor::{Spawner, raw};

use crate::time;

/// Descriptors waited on at once besides the eventfd (the TAP).
const MAX_WAITERS: usize = 4;
/// Rounds of tasks waking tasks after which the descriptors are looked at
/// anyway, so a busy executor still reads the TAP.
const MAX_BUSY_ROUNDS: u32 = 8;

/// How a wake reaches the executor thread.
#[derive(Debug)]
struct Signal {
    /// Set by every wake; cleared by the executor before it polls its tasks.
    pending: AtomicBool,
    /// Set while the executor thread is (about to be) asleep in `poll(2)`.
    sleeping: AtomicBool,
    /// Written by a wake that finds the executor asleep.
    eventfd: OwnedFd,
}

impl Signal {
    fn new() -> io::Result<Self> {
        // SAFETY: eventfd takes no pointers; the descriptor returned is owned here.
        let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `fd` is a new descriptor that nothing else owns.
        let eventfd = unsafe { OwnedFd::from_raw_fd(fd) };
        Ok(Self { pending: AtomicBool::new(false), sleeping: AtomicBool::new(false), eventfd })
    }

    /// A wake, from any thread: a system call only when the executor sleeps.
    fn signal(&self) {
        self.pending.store(true, Ordering::SeqCst);
        if self.sleeping.load(Ordering::SeqCst) {
            let one: u64 = 1;
            // SAFETY: writes 8 bytes from a live u64 to our eventfd. A failure
            // (the counter full) leaves it readable, which is all we need.
            let _ = unsafe { libc::write(self.eventfd.as_raw_fd(), (&raw const one).cast(), 8) };
        }
    }

    fn drain(&self) {
        let mut count: u64 = 0;
        // SAFETY: reads at most 8 bytes into a live u64; non-blocking.
        let _ = unsafe { libc::read(self.eventfd.as_raw_fd(), (&raw mut count).cast(), 8) };
    }
}

/// The executor's signal, for wakes that do not come through a waker.
static SIGNAL: OnceLock<&'static Signal> = OnceLock::new();

thread_local! {
    /// True on the executor's thread.
    static ON_EXECUTOR: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// A timer now falls due sooner: wakes the loop if that came from another
/// thread (the loop reads the timers itself before it sleeps).
pub fn timer_changed() {
    if !ON_EXECUTOR.get()
        && let Some(signal) = SIGNAL.get()
    {
        signal.signal();
    }
}

#[unsafe(export_name = "__pender")]
fn pender(context: *mut ()) {
    // SAFETY: the only executor made is `Executor`'s, whose context is its
    // leaked `&'static Signal`.
    let signal: &'static Signal = unsafe { &*context.cast::<Signal>() };
    signal.signal();
}

/// A descriptor waited on: its task's waker, or `None` once it was found readable.
type Waiter = Option<(RawFd, Option<Waker>)>;

thread_local! {
    /// Descriptors tasks wait on (executor thread only).
    static WAITERS: RefCell<[Waiter; MAX_WAITERS]> = const { RefCell::new([const { None }; MAX_WAITERS]) };
}

/// Whether `fd` was found readable since the last call; if not, `waker` is
/// woken once it is. Call it from a task on the executor thread, after a read
/// said `WouldBlock` (or instead of the read that would say it).
pub fn poll_readable(fd: RawFd, waker: &Waker) -> bool {
    let known = WAITERS.with_borrow_mut(|waiters| {
        let slot = match waiters.iter().position(|w| matches!(w, Some((f, _)) if *f == fd)) {
            Some(i) => waiters.get_mut(i),
            None => waiters.iter_mut().find(|w| w.is_none()),
        };
        match slot {
            Some(slot @ Some((_, None))) => {
                *slot = None;
                Some(true)
            }
            Some(slot) => {
                *slot = Some((fd, Some(waker.clone())));
                Some(false)
            }
            None => None,
        }
    });
    // More descriptors than slots: say readable, so the caller reads again.
    known.unwrap_or(true)
}

/// A single-threaded executor, as `embassy_executor::Executor` on std, that
/// sleeps in `poll(2)` (see the module's documentation).
pub struct Executor {
    inner: raw::Executor,
    signal: &'static Signal,
    not_send: PhantomData<*mut ()>,
}

impl std::fmt::Debug for Executor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Executor").field("signal", self.signal).finish_non_exhaustive()
    }
}

impl Executor {
    /// A new executor; fails only if the kernel gives no eventfd.
    pub fn new() -> io::Result<Self> {
        let signal: &'static Signal = Box::leak(Box::new(Signal::new()?));
        let _ = SIGNAL.set(signal);
        let context = std::ptr::from_ref(signal).cast_mut().cast::<()>();
        Ok(Self { inner: raw::Executor::new(context), signal, not_send: PhantomData })
    }

    /// Runs `init` with a spawner, then the tasks, forever.
    pub fn run(&'static mut self, init: impl FnOnce(Spawner)) -> ! {
        ON_EXECUTOR.set(true);
        init(self.inner.spawner());
        let mut busy_rounds = 0;
        loop {
            self.signal.pending.store(false, Ordering::SeqCst);
            // SAFETY: `poll` runs only here, on this thread, never reentrantly
            // (the pender only sets flags and writes the eventfd).
            unsafe { self.inner.poll() };
            let alarm = time::expire();
            self.signal.sleeping.store(true, Ordering::SeqCst);
            let idle = !self.signal.pending.load(Ordering::SeqCst);
            if idle {
                self.wait(Some(time::until(alarm)).filter(|_| alarm != u64::MAX));
                busy_rounds = 0;
            } else if busy_rounds >= MAX_BUSY_ROUNDS {
                self.wait(Some(0));
                busy_rounds = 0;
            } else {
                busy_rounds += 1;
            }
            self.signal.sleeping.store(false, Ordering::SeqCst);
        }
    }

    /// Waits at most `timeout_us` microseconds (`None`: without end) until a
    /// waited-on descriptor is readable or the eventfd is written, and wakes
    /// the tasks whose descriptor is ready.
    fn wait(&self, timeout_us: Option<u64>) {
        const IDLE: libc::pollfd = libc::pollfd { fd: -1, events: 0, revents: 0 };
        let eventfd = self.signal.eventfd.as_raw_fd();
        let mut fds = [IDLE; MAX_WAITERS + 1];
        let (signal, waited) = fds.split_at_mut(1);
        if let Some(first) = signal.first_mut() {
            *first = libc::pollfd { fd: eventfd, events: libc::POLLIN, revents: 0 };
        }
        WAITERS.with_borrow(|waiters| {
            for (pollfd, waiter) in waited.iter_mut().zip(waiters) {
                if let Some((fd, Some(_))) = waiter {
                    *pollfd = libc::pollfd { fd: *fd, events: libc::POLLIN, revents: 0 };
                }
            }
        });
        let timeout = timeout_us.map(|us| libc::timespec {
            tv_sec: libc::time_t::try_from(us / 1_000_000).unwrap_or(libc::time_t::MAX),
            // Below 1e9: fits any c_long.
            tv_nsec: ((us % 1_000_000) * 1_000) as libc::c_long,
        });
        let timeout_ptr = timeout.as_ref().map_or(std::ptr::null(), std::ptr::from_ref);
        // SAFETY: `fds` is a live array of `fds.len()` pollfd (entries with a
        // negative descriptor are ignored); `timeout_ptr` is null or points to
        // a live timespec; no signal mask is passed.
        let n = unsafe { libc::ppoll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, timeout_ptr, std::ptr::null()) };
        // Awake again: the wakes below need no eventfd write.
        self.signal.sleeping.store(false, Ordering::SeqCst);
        if n <= 0 {
            return; // nothing ready, or EINTR: go round again
        }
        let (signal, waited) = fds.split_at(1);
        if signal.first().is_some_and(|p| p.revents != 0) {
            self.signal.drain();
        }
        for (i, pollfd) in waited.iter().enumerate() {
            if pollfd.fd >= 0 && pollfd.revents != 0 {
                // Mark it readable and wake its task, which will read it.
                let waker = WAITERS.with_borrow_mut(|waiters| match waiters.get_mut(i) {
                    Some(Some((_, waker))) => waker.take(),
                    _ => None,
                });
                if let Some(waker) = waker {
                    waker.wake();
                }
            }
        }
    }
}
