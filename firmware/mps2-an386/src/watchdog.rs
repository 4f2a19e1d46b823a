//! The mps2-an386's watchdog, as the bootloader and an image with `update`
//! use it (docs/update.md): Arm's CMSDK APB watchdog at 0x4000_8000, which
//! QEMU models, clocked at 25 MHz. Counting down from LOAD, its first
//! expiry raises its interrupt (wired to the NMI) and reloads; a second one
//! with the interrupt still raised resets the board. Writing INTCLR clears
//! the interrupt and reloads the counter: that is petting it.
//!
//! The bootloader starts it before it jumps into the image ([`start`]), so
//! an image that never pets it is reset [`RESET_S`] after it started. The
//! image pets it ([`pet`]) for good once it is confirmed or was not on
//! trial, and on trial only within the trial's limit (`update::pet_loop`):
//! an image swapped in that never confirms itself is reset [`RESET_S`]
//! after its last pet, and the bootloader rolls it back.
//!
//! This file is the bootloader's too (`#[path]`): one register map.

#![allow(dead_code, reason = "the bootloader uses the registers and start, the image the rest")]

/// The watchdog's registers (Arm DDI 0479B, CMSDK APB watchdog).
const BASE: usize = 0x4000_8000;
const LOAD: usize = BASE;
const CONTROL: usize = BASE + 0x08;
const INTCLR: usize = BASE + 0x0C;
const LOCK: usize = BASE + 0xC00;
/// CONTROL: the counter and its interrupt; the reset at the second expiry.
const INTEN: u32 = 1 << 0;
const RESEN: u32 = 1 << 1;
/// What LOCK takes to allow writes to the other registers.
const UNLOCK: u32 = 0x1ACC_E551;

/// The watchdog's clock (QEMU's mps2 boards: the 25 MHz system clock).
const CLOCK_HZ: u32 = 25_000_000;
/// From the bootloader's start to the first expiry (the NMI); the reset
/// comes as long again after it.
pub const EXPIRY_S: u32 = 15;
/// How long an image runs after the last pet (or the start): two expiries.
pub const RESET_S: u32 = 2 * EXPIRY_S;
/// How often a confirmed image pets it: well inside an expiry.
pub const PET_INTERVAL_MS: u64 = 1_000;

/// Writes `value` to the register at `address`.
///
/// # Safety
///
/// `address` must be one of the watchdog's registers.
unsafe fn write(address: usize, value: u32) {
    // SAFETY: the caller's promise: a device register, 4-byte aligned.
    unsafe { (address as *mut u32).write_volatile(value) }
}

/// Starts the watchdog: the NMI at [`EXPIRY_S`], the reset at
/// [`RESET_S`], unless it is petted. The bootloader calls it last,
/// before it jumps; the registers stay unlocked for the image to pet.
pub fn start() {
    // SAFETY: the watchdog's registers, which only the bootloader (before
    // the image runs) and the image's pet touch.
    unsafe {
        write(LOCK, UNLOCK);
        write(LOAD, EXPIRY_S * CLOCK_HZ);
        write(CONTROL, INTEN | RESEN);
    }
}

/// Pets the watchdog: clears its interrupt and reloads the counter.
pub fn pet() {
    // SAFETY: as in `start`; writing INTCLR has no effect but the reload.
    unsafe { write(INTCLR, 1) }
}
