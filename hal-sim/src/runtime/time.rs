//! embassy-time's driver: the host's monotonic clock in microseconds, and
//! embassy-time-queue-utils' timer queue, which the loop looks at before it
//! sleeps and whose next deadline is the loop's `ppoll(2)` timeout.
//!
//! embassy-time's own std driver keeps the queue behind a mutex that `now()`
//! also takes, and runs an alarm thread that each earlier deadline wakes
//! (a futex call and a thread switch); here `now()` takes no lock and there
//! is no thread.

use std::sync::{Mutex, MutexGuard, OnceLock, PoisonError};
use std::task::Waker;
use std::time::Instant;

use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

use super::wake;

/// embassy-time's tick rate must be the microsecond this driver counts in.
const _: () = assert!(embassy_time_driver::TICK_HZ == 1_000_000, "enable embassy-time/tick-hz-1_000_000");

struct Timers {
    queue: Queue,
    /// No timer is due before this tick (`u64::MAX`: none is queued).
    alarm: u64,
}

struct HostDriver {
    /// Tick 0.
    start: OnceLock<Instant>,
    timers: Mutex<Timers>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: HostDriver = HostDriver {
    start: OnceLock::new(),
    timers: Mutex::new(Timers { queue: Queue::new(), alarm: u64::MAX }),
});

impl HostDriver {
    fn timers(&self) -> MutexGuard<'_, Timers> {
        // A panic while the lock was held cannot leave the queue half-changed
        // in a way that matters here: carry on with it.
        self.timers.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Driver for HostDriver {
    fn now(&self) -> u64 {
        let start = *self.start.get_or_init(Instant::now);
        u64::try_from(start.elapsed().as_micros()).unwrap_or(u64::MAX)
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        let earlier = {
            let mut timers = self.timers();
            let changed = timers.queue.schedule_wake(at, waker);
            let earlier = changed && at < timers.alarm;
            if earlier {
                timers.alarm = at;
            }
            earlier
        };
        if earlier {
            // From the loop's own tasks this is a no-op: the loop reads the
            // alarm before it sleeps. From another thread it wakes the loop.
            wake::from_elsewhere();
        }
    }
}

/// Wakes the tasks whose timers are due and returns the tick of the next
/// deadline (`u64::MAX`: none).
pub(super) fn expire() -> u64 {
    let now = DRIVER.now();
    let mut timers = DRIVER.timers();
    if timers.alarm <= now {
        timers.alarm = timers.queue.next_expiration(now);
    }
    timers.alarm
}

/// Microseconds from now until `tick` (0 if it has passed).
pub(super) fn until(tick: u64) -> u64 {
    tick.saturating_sub(DRIVER.now())
}
