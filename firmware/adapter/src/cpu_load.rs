//! CPU load (docs/http-api.md, `cpu_load_percent`): the share of each second that the
//! executor is not asleep waiting for an interrupt (or, in hal-sim, for a
//! descriptor or a timer).
//!
//! Every program's executor loop reports each sleep to [`CPU_LOAD`]
//! ([`CpuLoad::slept`], with the time it went to sleep and woke); each
//! time a window of [`WINDOW`] has passed, the window's busy share becomes
//! the figure [`CpuLoad::percent`] gives (`/api/status`, the page). The
//! time is embassy-time's, so the figure's resolution is its tick (1 µs on
//! every board and in hal-sim).
//!
//! ```ignore
//! loop {
//!     unsafe { executor.poll() };
//!     let asleep = Instant::now();
//!     wait_for_interrupt();
//!     CPU_LOAD.slept(asleep, Instant::now());
//! }
//! ```

use core::cell::Cell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::{Duration, Instant};

/// The window the load is measured over.
pub const WINDOW: Duration = Duration::from_secs(1);

/// The load meter of the program's one executor.
pub static CPU_LOAD: CpuLoad = CpuLoad::new();

/// Sleeps reported in the current window, and the last whole window's load.
#[derive(Clone, Copy, Debug)]
struct Meter {
    /// When the current window began (`None`: no sleep reported yet).
    window_start: Option<Instant>,
    /// Time asleep in the current window.
    asleep: Duration,
    /// The last whole window's busy share in percent.
    percent: Option<u8>,
}

/// The meter, behind a critical section: the executor loop reports,
/// anyone reads (a few instructions with interrupts masked, once a sleep).
#[derive(Debug)]
pub struct CpuLoad {
    meter: Mutex<CriticalSectionRawMutex, Cell<Meter>>,
}

impl CpuLoad {
    pub const fn new() -> Self {
        let meter = Meter { window_start: None, asleep: Duration::from_ticks(0), percent: None };
        Self { meter: Mutex::new(Cell::new(meter)) }
    }

    /// The executor slept from `from` to `to`. A sleep that spans the end of
    /// a window counts in the window it ends in (which is then longer).
    pub fn slept(&self, from: Instant, to: Instant) {
        self.meter.lock(|cell| {
            let mut meter = cell.get();
            let start = *meter.window_start.get_or_insert(from);
            meter.asleep += to.checked_duration_since(from).unwrap_or_default();
            let elapsed = to.checked_duration_since(start).unwrap_or_default();
            if elapsed >= WINDOW {
                let busy = elapsed.as_ticks().saturating_sub(meter.asleep.as_ticks());
                // busy <= elapsed, so the share is at most 100.
                let percent = busy.saturating_mul(100) / elapsed.as_ticks().max(1);
                meter.percent = Some(u8::try_from(percent).unwrap_or(100));
                meter.asleep = Duration::from_ticks(0);
                meter.window_start = Some(to);
            }
            cell.set(meter);
        });
    }

    /// The busy share of the last whole window, in percent (`None` during the first).
    pub fn percent(&self) -> Option<u8> {
        self.meter.lock(|cell| cell.get().percent)
    }
}

impl Default for CpuLoad {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    #[test]
    fn no_figure_until_a_whole_window_has_passed() {
        let load = CpuLoad::new();
        assert_eq!(load.percent(), None);
        load.slept(at(10), at(500));
        assert_eq!(load.percent(), None);
    }

    #[test]
    fn the_busy_share_of_each_window() {
        let load = CpuLoad::new();
        // Window 1 from 10 ms: asleep 250 + 500 of 1000 ms: 25 % busy.
        load.slept(at(10), at(260));
        load.slept(at(510), at(1010));
        assert_eq!(load.percent(), Some(25));
        // Window 2 from 1010 ms: asleep 100 of 1000 ms: 90 % busy.
        load.slept(at(1910), at(2010));
        assert_eq!(load.percent(), Some(90));
        // Window 3: asleep all the time.
        load.slept(at(2010), at(3010));
        assert_eq!(load.percent(), Some(0));
    }

    #[test]
    fn a_long_sleep_ends_a_longer_window() {
        let load = CpuLoad::new();
        load.slept(at(1), at(1));
        // Busy 500 ms, then asleep 4.5 s: 10 % of the 5 s window.
        load.slept(at(501), at(5001));
        assert_eq!(load.percent(), Some(10));
    }

    #[test]
    fn a_clock_that_goes_backwards_counts_nothing() {
        let load = CpuLoad::new();
        load.slept(at(100), at(50));
        load.slept(at(1200), at(1200));
        assert_eq!(load.percent(), Some(100));
    }
}
