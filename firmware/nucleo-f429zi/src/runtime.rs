//! The executor loop: embassy's raw executor, polled until no task is
//! ready, then the core sleeps in `wfi` until an interrupt (the time
//! driver's alarm, Ethernet, an input edge). Each sleep is reported to the
//! CPU load meter (`adapter::load`), which is what the stock thread
//! executor cannot do.

use core::sync::atomic::{AtomicBool, Ordering};

use adapter::load::CPU_LOAD;
use embassy_executor::{Spawner, raw};
use embassy_time::Instant;
use static_cell::StaticCell;

/// Set by the executor's pender (from any context); cleared before each poll.
static WORK: AtomicBool = AtomicBool::new(false);

/// The executor calls this when a task was woken: note it, and leave `wfi`.
#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    WORK.store(true, Ordering::Release);
}

/// Runs the executor forever: `init` spawns the first task.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    static EXECUTOR: StaticCell<raw::Executor> = StaticCell::new();
    let executor: &'static raw::Executor = EXECUTOR.init(raw::Executor::new(core::ptr::null_mut()));
    init(executor.spawner());
    loop {
        WORK.store(false, Ordering::Release);
        // SAFETY: `poll` is only ever called here, never re-entered.
        unsafe { executor.poll() };
        // With interrupts masked, check for work and sleep: an interrupt that
        // arrives after the check still ends `wfi`, and runs right after.
        // The clock is read only when the core goes to sleep, not after
        // every poll (scripts/bench-mcu counts each read).
        let asleep = cortex_m::interrupt::free(|_| {
            if WORK.load(Ordering::Acquire) {
                return None;
            }
            let from = Instant::now();
            cortex_m::asm::wfi();
            Some(from)
        });
        if let Some(from) = asleep {
            // The interrupt that woke the core has run: its time counts as asleep.
            CPU_LOAD.slept(from, Instant::now());
        }
    }
}
