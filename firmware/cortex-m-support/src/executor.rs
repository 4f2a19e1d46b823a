//! The boards' executor loop: embassy's raw executor, polled until no task
//! is ready, then the core sleeps in `wfi` until an interrupt comes, and
//! each sleep is reported to the program (the adapter's `load::CPU_LOAD`).
//!
//! It replaces embassy's stock cortex-m thread executor, which cannot
//! report its sleeps, and which sleeps with `wfe`: QEMU runs `wfe` as a busy
//! loop (a host core at 100 %), `wfi` as a sleep. This module exports the
//! executor's `__pender`, so a program that links it has no other executor.

use core::sync::atomic::{AtomicBool, Ordering};

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

/// Runs the executor forever: `init` spawns the first tasks, and `slept`
/// is told of each sleep, from when the core went to sleep to when it
/// woke (the interrupt that woke it has run by then).
pub fn run(init: impl FnOnce(Spawner), slept: impl Fn(Instant, Instant)) -> ! {
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
            slept(from, Instant::now());
        }
    }
}
