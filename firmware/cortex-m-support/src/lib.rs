//! What a Cortex-M program built on the adapter has once, apart from the
//! portable core (which exports no program-wide symbol):
//!
//! - [`executor`]: the executor loop, which exports embassy's `__pender`
//!   and reports each sleep (the CPU load the device shows);
//! - [`reboot`]: the reset a board's settings service asks for;
//! - [`stack`]: the stack's high-water mark.
//!
//! A program links this crate once; a library never depends on it.
#![no_std]

pub mod executor;
pub mod stack;

pub use executor::run;

/// Resets the core now (`SYSRESETREQ`): the board boots again as from
/// power-up, the flash keeps its contents.
pub fn reboot() -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}
