//! hal-sim's runtime: embassy's raw executor on one thread that sleeps in
//! `ppoll(2)` on the descriptors its tasks wait for (the TAP, the control
//! socket), on an eventfd for wakes from other threads, and until the next
//! timer. It is hal-sim's only thread.
//!
//! embassy's std executor sleeps on a condition variable, so a frame on the
//! TAP had to wake a reactor thread first (async-io's), which then woke the
//! executor: two thread switches per frame. Here the loop waits on the
//! descriptors itself, with the timer queue's next deadline as the timeout.
//!
//! - [`fd`]: the descriptor waits ([`poll_readable`] for the TAP driver,
//!   [`read_with`] and [`write_with`] for the control socket);
//! - [`time`]: embassy-time's driver and its timer queue;
//! - [`wake`]: how a wake reaches the loop (embassy's pender, the eventfd).
//!
//! The loop (this file) uses all three; `time` uses `wake`, to wake the loop
//! when a timer is set from another thread. Nothing here uses the loop.
//!
//! Busy polling (`--busy-poll US`, off by default): when its tasks are all
//! waiting, the loop looks at its descriptors without blocking for up to
//! that long before it sleeps. A request that comes within it is served
//! without the kernel waking the loop's thread, which in a VM is waking an
//! idle vCPU: most of a one-connection round trip (BENCHMARKS.md). The
//! price is a CPU kept busy while a client sends faster than the spin.

mod fd;
mod time;
mod wake;

use std::cell::Cell;
use std::io;
use std::marker::PhantomData;

use embassy_executor::{Spawner, raw};

pub use self::fd::{poll_readable, read_with, write_with};
use self::wake::Signal;

/// Rounds of tasks waking tasks after which the descriptors are looked at
/// anyway, so a busy loop still hears the control socket (and the TAP, once
/// a read found it empty). The TAP driver reads one frame a round and wakes
/// itself for the next, so under load most rounds are busy: 64 of them
/// (a few hundred microseconds) make this `ppoll(2)` one per 38 requests at
/// 8 connections; at 8 rounds it was one per 8 (strace -c).
const MAX_BUSY_ROUNDS: u32 = 64;

thread_local! {
    /// The loop's rounds so far. A round polls each task woken before it
    /// once; a task woken during the round is polled in the next one.
    static ROUND: Cell<u64> = const { Cell::new(0) };
}

/// The loop's current round: the TAP driver reads one frame per round
/// (`tap.rs`, for fairness between connections).
pub fn round() -> u64 {
    ROUND.get()
}

/// Begins the loop's next round.
fn next_round() {
    ROUND.set(ROUND.get().wrapping_add(1));
}

/// Begins the next round, as the loop does, for tests of what runs on it.
#[cfg(test)]
pub fn next_round_for_test() {
    next_round();
}

/// A waker that counts its wakes, for tests of what wakes the loop.
#[cfg(test)]
#[derive(Default)]
pub struct WakeCount(pub std::sync::atomic::AtomicUsize);

#[cfg(test)]
impl std::task::Wake for WakeCount {
    fn wake(self: std::sync::Arc<Self>) {
        self.0.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
    }
}

/// The loop: a single-threaded executor, as `embassy_executor::Executor` on
/// std, that sleeps in `ppoll(2)` (see the module's documentation).
pub struct Executor {
    inner: raw::Executor,
    sleep: Sleep,
    /// How long the loop polls without blocking before it sleeps (zero: off).
    busy_poll: embassy_time::Duration,
    not_send: PhantomData<*mut ()>,
}

impl std::fmt::Debug for Executor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Executor")
            .field("sleep", &self.sleep)
            .field("busy_poll", &self.busy_poll)
            .finish_non_exhaustive()
    }
}

impl Executor {
    /// The loop, busy polling for `busy_poll` (zero: never) before each
    /// sleep; fails only if the kernel gives no eventfd.
    pub fn new(busy_poll: embassy_time::Duration) -> io::Result<Self> {
        let signal = Signal::new()?;
        let inner = raw::Executor::new(signal.context());
        Ok(Self { inner, sleep: Sleep { signal, pollfds: Vec::new() }, busy_poll, not_send: PhantomData })
    }

    /// Runs `init` with a spawner, then the tasks, forever, on this thread.
    pub fn run(&'static mut self, init: impl FnOnce(Spawner)) -> ! {
        let Self { inner, sleep, busy_poll, .. } = self;
        let busy_poll = *busy_poll;
        let signal = sleep.signal;
        signal.enter();
        init(inner.spawner());
        let mut busy_rounds = 0;
        // When the tasks last found nothing to do (busy polling since).
        let mut idle_since = None;
        loop {
            next_round();
            signal.clear();
            // SAFETY: `poll` runs only here, on this thread, never reentrantly
            // (the pender only sets flags and writes the eventfd).
            unsafe { inner.poll() };
            let alarm = time::expire();
            let busy = signal.sleep();
            if !busy {
                let asleep = embassy_time::Instant::now();
                let since = *idle_since.get_or_insert(asleep);
                if asleep.saturating_duration_since(since) < busy_poll {
                    // A poll that returns at once; the timers are looked at
                    // each round, so none is late for it.
                    sleep.wait(Some(0));
                } else {
                    sleep.wait(Some(time::until(alarm)).filter(|_| alarm != u64::MAX));
                    idle_since = None;
                }
                // Busy polling is waiting too: the load is the tasks' work.
                adapter::cpu_load::CPU_LOAD.slept(asleep, embassy_time::Instant::now());
                busy_rounds = 0;
            } else {
                idle_since = None;
                if busy_rounds >= MAX_BUSY_ROUNDS {
                    sleep.wait(Some(0));
                    busy_rounds = 0;
                } else {
                    busy_rounds += 1;
                }
            }
            signal.awake();
        }
    }
}

/// The loop's sleep: `ppoll(2)` on the eventfd and the descriptor waits.
#[derive(Debug)]
struct Sleep {
    signal: &'static Signal,
    /// The eventfd first, then one entry per descriptor wait; kept between
    /// rounds so that a round allocates nothing.
    pollfds: Vec<libc::pollfd>,
}

impl Sleep {
    /// Waits at most `timeout_us` microseconds (`None`: without end) until a
    /// waited-on descriptor is ready or the eventfd is written, and wakes the
    /// tasks whose descriptor is ready.
    fn wait(&mut self, timeout_us: Option<u64>) {
        self.pollfds.clear();
        self.pollfds.push(libc::pollfd { fd: self.signal.fd(), events: libc::POLLIN, revents: 0 });
        fd::fill(&mut self.pollfds);
        let timeout = timeout_us.map(|us| libc::timespec {
            tv_sec: libc::time_t::try_from(us / 1_000_000).unwrap_or(libc::time_t::MAX),
            // Below 1e9: fits any c_long.
            tv_nsec: ((us % 1_000_000) * 1_000) as libc::c_long,
        });
        let timeout_ptr = timeout.as_ref().map_or(std::ptr::null(), std::ptr::from_ref);
        // SAFETY: `pollfds` is a live array of `pollfds.len()` pollfd (entries
        // with a negative descriptor are ignored); `timeout_ptr` is null or
        // points to a live timespec; no signal mask is passed.
        let n = unsafe {
            libc::ppoll(self.pollfds.as_mut_ptr(), self.pollfds.len() as libc::nfds_t, timeout_ptr, std::ptr::null())
        };
        // Awake again: the wakes below need no eventfd write.
        self.signal.awake();
        if n <= 0 {
            return; // nothing ready, or EINTR: go round again
        }
        if let Some((eventfd, waits)) = self.pollfds.split_first() {
            if eventfd.revents != 0 {
                self.signal.drain();
            }
            fd::dispatch(waits);
        }
    }
}
