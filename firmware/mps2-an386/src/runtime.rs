//! The executor loop, faults, panics and the way out of QEMU.
//!
//! The executor loop is `cortex_m_support`'s: it sleeps with `wfi` (the
//! stock cortex-m executor's `wfe` is a busy loop in QEMU, a host core at
//! 100 %; `wfi` keeps it at about 10 % when idle) and measures the CPU
//! load. A panic or a fault logs through defmt and ends QEMU through
//! semihosting with a non-zero exit code, so a test sees it both in the log
//! and in QEMU's exit status.

use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m_rt::{ExceptionFrame, exception};
use embassy_executor::Spawner;

/// QEMU's exit code after a panic.
pub const EXIT_PANIC: i32 = 101;
/// QEMU's exit code after a hard fault or an unexpected exception.
pub const EXIT_FAULT: i32 = 102;

/// Runs the executor forever (`cortex_m_support`: `wfi` between polls,
/// each sleep reported to the CPU load meter): `init` spawns the first tasks.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    cortex_m_support::run(init, |from, to| adapter::cpu_load::CPU_LOAD.slept(from, to))
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
