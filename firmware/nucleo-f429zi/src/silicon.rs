//! The STM32F429's own traps that the image and its bootloader both step
//! around (docs/nucleo-f429zi.md, "Silicon: what the code does about the
//! chip's traps"), as plain register writes through the PAC. Nothing here
//! logs: the bootloader has no logger and includes this file as it is
//! (`#[path]` in firmware/nucleo-f429zi-boot/src/main.rs), so the two
//! programs do the same thing the same way.

use embassy_stm32::Peri;
use embassy_stm32::pac;
use embassy_stm32::pac::flash::vals::Psize;
use embassy_stm32::pac::gpio::vals::{Moder, Pupdr};
use embassy_stm32::peripherals::PA12;

/// DBGMCU_IDCODE.REV_ID of revision A, the first silicon (ES0206, table 2:
/// A 0x1000, Y 0x1003, 1 0x1007, 3 0x2001, 5 and B 0x2003).
pub const REVISION_A: u16 = 0x1000;

/// The silicon revision, DBGMCU_IDCODE.REV_ID (RM0090, DBGMCU_IDCODE).
pub fn revision() -> u16 {
    pac::DBGMCU.idcode().read().rev_id()
}

/// Turns the flash accelerator (ART) on: embassy-stm32 0.6 writes
/// FLASH_ACR with the wait states alone (rcc/f247.rs), which leaves the
/// instruction cache, the data cache and the prefetch off, so at 5 wait
/// states every fetch that misses waits for the flash. The caches are
/// reset first (ICRST and DCRST may be written only while the caches are
/// off, RM0090 FLASH_ACR), so no line left by an earlier program (the
/// bootloader) survives. The prefetch stays off on revision A, the earliest
/// silicon: whether ES0206 restricts it on some revision could not be
/// checked (docs), so the earliest does without; returns whether it is
/// on. embassy's flash writes and erases turn DCEN off and
/// back on with a reset around each operation (ES0206 2.2.12, as
/// embassy-stm32 numbers it), which this leaves as it is.
pub fn flash_accelerator_on() -> bool {
    let acr = pac::FLASH.acr();
    acr.modify(|w| {
        w.set_icen(false);
        w.set_dcen(false);
    });
    acr.modify(|w| {
        w.set_icrst(true);
        w.set_dcrst(true);
    });
    acr.modify(|w| {
        w.set_icrst(false);
        w.set_dcrst(false);
    });
    // A REV_ID that reads 0 counts as the earliest too.
    let prefetch = revision() > REVISION_A;
    acr.modify(|w| {
        w.set_icen(true);
        w.set_dcen(true);
        w.set_prften(prefetch);
    });
    prefetch
}

/// Holds PA12 an output driven low with its pull-down, for good. On
/// silicon before revision 3 (REV_ID below 0x2001) activity on PA12 (USB
/// OTG FS D+) can corrupt reads of flash bank 2 (ES0206 2.2.11, as
/// embassy-stm32 numbers it), and embassy-stm32's flash reads panic on
/// such a chip unless PA12 is so (`assert_not_corrupted_read`, flash/f4.rs).
/// PA12 is unused on this board (the user USB connector, CN13). The pin's
/// token is consumed, so no driver can take the pin, and none can return
/// it to analog on drop as an `Output` would. GPIOA's clock is on from
/// `embassy_stm32::init`.
pub fn hold_pa12_low(_pin: Peri<'static, PA12>) {
    const PIN: usize = 12;
    let gpioa = pac::GPIOA;
    // The output level first, so the pin never drives high.
    gpioa.bsrr().write(|w| w.set_br(PIN, true));
    gpioa.pupdr().modify(|w| w.set_pupdr(PIN, Pupdr::PULL_DOWN));
    gpioa.moder().modify(|w| w.set_moder(PIN, Moder::OUTPUT));
}

/// Sets the erase parallelism to x32 (FLASH_CR.PSIZE) for the next erase.
/// embassy-stm32 0.6 never sets PSIZE for an erase (its erase modifies
/// FLASH_CR, its writes rewrite it with PSIZE 0), so its erases ran at x8,
/// twice as slow; x32 needs 2.7-3.6 V (RM0090, program/erase parallelism),
/// and the NUCLEO runs at 3.3 V. FLASH_CR cannot be written while locked,
/// so this unlocks it first (the KEYR sequence, only when LOCK is set, as
/// embassy and ST's HAL do: RM0090 locks FLASH_CR until reset after a
/// wrong sequence). embassy's erase then finds it unlocked (its own unlock
/// does nothing), keeps PSIZE, and locks it again when done. Call it right
/// before each one-sector erase, with nothing else using the flash
/// controller in between (a write would rewrite FLASH_CR).
pub fn erase_at_x32() {
    let flash = pac::FLASH;
    if flash.cr().read().lock() {
        flash.keyr().write_value(0x4567_0123);
        flash.keyr().write_value(0xCDEF_89AB);
    }
    flash.cr().modify(|w| w.set_psize(Psize::PSIZE32));
}
