//! The executor loop, faults, panics and the way out of QEMU.
//!
//! The stock cortex-m thread executor sleeps with `wfe`, which QEMU runs as a
//! busy loop (a host core at 100 %). This one sleeps with `wfi` and keeps a
//! host core at about 10 % when idle, and reports each sleep to the CPU
//! load meter (`adapter::load`). A panic or a fault logs through defmt
//! and ends QEMU through semihosting with a non-zero exit code, so a test
//! sees it both in the log and in QEMU's exit status.

use core::sync::atomic::{AtomicBool, Ordering};

use adapter::load::CPU_LOAD;
use cortex_m_rt::{ExceptionFrame, exception};
use embassy_executor::{Spawner, raw};
use embassy_time::Instant;
use static_cell::StaticCell;

/// QEMU's exit code after a panic.
pub const EXIT_PANIC: i32 = 101;
/// QEMU's exit code after a hard fault or an unexpected exception.
pub const EXIT_FAULT: i32 = 102;

/// Set by the executor's pender (from any context); cleared before each poll.
static WORK: AtomicBool = AtomicBool::new(false);

/// The executor calls this when a task was woken: note it, and leave `wfi`.
#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    WORK.store(true, Ordering::Release);
}

/// Runs the executor forever: `init` spawns the first tasks; between polls
/// the core sleeps in `wfi` until an interrupt (SysTick, Ethernet) comes.
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

/// Ends the QEMU process with `code` (semihosting `SYS_EXIT_EXTENDED`).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

defmt::timestamp!("{=u64:ms}", embassy_time::Instant::now().as_millis());

static PANICKED: AtomicBool = AtomicBool::new(false);

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    // A panic while logging the first one must not log again.
    if !PANICKED.swap(true, Ordering::AcqRel) {
        // The location only: formatting the message would link all of
        // core::fmt (about 2 KiB) for a path the library cannot take.
        match info.location() {
            Some(at) => defmt::error!("panicked at {=str}:{=u32}", at.file(), at.line()),
            None => defmt::error!("panicked"),
        }
    }
    exit(EXIT_PANIC)
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    if !PANICKED.swap(true, Ordering::AcqRel) {
        defmt::error!("HardFault at pc {=u32:#010x}, lr {=u32:#010x}", frame.pc(), frame.lr());
    }
    exit(EXIT_FAULT)
}

/// Interrupts of devices with no handler land here, as do core exceptions
/// without one (negative numbers).
pub(super) fn unexpected_exception(irqn: i16) -> ! {
    if !PANICKED.swap(true, Ordering::AcqRel) {
        defmt::error!("unexpected exception {=i16}", irqn);
    }
    exit(EXIT_FAULT)
}
