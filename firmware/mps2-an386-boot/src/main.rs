//! The bootloader of QEMU's mps2-an386 board (docs/update.md): QEMU's
//! `-kernel`, the first code to run. It hands embassy-boot's `BootLoader`
//! the three partitions of the file-backed PSRAM (ACTIVE, DFU and the boot
//! state, from the image's `memory-update.x`), under the same NOR flash
//! rules as the image (RuleFlash: 4-byte words, 4 KiB pages, the swap's
//! unit), so it swaps in an armed update, or rolls back one that did not
//! confirm itself, page by page and power-fail safe. Then it starts the
//! watchdog (an image on trial that does not confirm itself within 30 s is
//! reset, and rolled back) and the image in ACTIVE: its vector table,
//! stack pointer and reset vector.
//!
//! It says what it did on semihosting's stderr (the image's defmt log is
//! on stdout), and ends QEMU with an exit code of its own when it cannot
//! boot: [`EXIT_BOOT_ERROR`] (the bootloader failed on the flash),
//! [`EXIT_NO_IMAGE`] (ACTIVE holds no image), 101 on a panic.
#![no_std]
#![no_main]

use adapter::storage::flash::RuleFlash;
#[path = "../../mps2-an386/src/watchdog.rs"]
mod watchdog;
use cortex_m_rt::entry;
use embassy_boot::{BootError, BootLoader, BootLoaderConfig, State};
use semihosting::{eprintln, process};

// ACTIVE_START/_LEN, DFU_START/_LEN and BOOTLOADER_STATE_START/_LEN, from
// the image's memory map (build.rs).
include!(concat!(env!("OUT_DIR"), "/partitions.rs"));

/// A partition: PSRAM under NOR flash rules, as the image sees it.
type Partition = RuleFlash<'static, 4, 4096>;

/// QEMU's exit code when the bootloader fails on the partitions.
const EXIT_BOOT_ERROR: i32 = 103;
/// QEMU's exit code when ACTIVE holds no image.
const EXIT_NO_IMAGE: i32 = 104;
/// QEMU's exit code after a panic.
const EXIT_PANIC: i32 = 101;

/// The image's RAM (ZBT SSRAM2/3, memory-update.x's RAM): where its
/// initial stack pointer must point (the top is a valid initial value).
const IMAGE_RAM: core::ops::RangeInclusive<u32> = 0x2000_0000..=0x2040_0000;

/// The copy buffer: a divisor of the 4 KiB page and a multiple of the word.
const COPY_LEN: usize = 1024;

/// The signature check this bootloader serves to the image it starts
/// (update_image::service), where the image looks for it (memory.x).
#[used]
#[unsafe(link_section = ".boot_services")]
static SERVICES: update_image::service::Services = update_image::service::Services::new();

#[entry]
fn main() -> ! {
    match prepare_boot() {
        Ok(state) => eprintln!("mps2-an386-boot: boot state {:?}", state),
        Err(error) => {
            eprintln!("mps2-an386-boot: cannot prepare the boot: {:?}", error);
            process::exit(EXIT_BOOT_ERROR)
        }
    }
    // SAFETY: ACTIVE_START is the start of ACTIVE, 4-byte aligned PSRAM.
    let (stack, reset) = unsafe {
        let table = ACTIVE_START as *const u32;
        (table.read_volatile(), table.add(1).read_volatile())
    };
    // An erased or zeroed ACTIVE, or a table that does not point into the
    // image and the RAM: nothing to start.
    let in_ram = IMAGE_RAM.contains(&stack);
    let in_active = (ACTIVE_START..ACTIVE_START + ACTIVE_LEN).contains(&(reset as usize & !1));
    if !in_ram || !in_active {
        eprintln!(
            "mps2-an386-boot: no image in ACTIVE at {:#010x} (stack {:#010x}, reset {:#010x})",
            ACTIVE_START, stack, reset
        );
        process::exit(EXIT_NO_IMAGE)
    }
    // The image has the watchdog's two expiries to confirm itself (or to
    // pet it, when it is not on trial): else the reset, and a rollback.
    watchdog::start();
    // SAFETY: the image's vector table is at ACTIVE_START (checked above as
    // far as it can be); VTOR takes its address, then `bootload` loads its
    // stack pointer and jumps to its reset handler, never to return.
    unsafe {
        (*cortex_m::peripheral::SCB::PTR).vtor.write(ACTIVE_START as u32);
        cortex_m::asm::bootload(ACTIVE_START as *const u32)
    }
}

/// Runs embassy-boot's bootloader over the partitions: a swap or a
/// revert when the state asks for one. The state it found.
fn prepare_boot() -> Result<State, BootError> {
    // SAFETY: the three ranges are the image's partitions in the PSRAM, which
    // nothing else uses while the bootloader runs (the image has not started)
    // and which do not overlap (memory-update.x asserts it). The partitions
    // live until this function returns.
    let (active, dfu, state) = unsafe {
        (
            partition(ACTIVE_START, ACTIVE_LEN),
            partition(DFU_START, DFU_LEN),
            partition(BOOTLOADER_STATE_START, BOOTLOADER_STATE_LEN),
        )
    };
    let mut buffer = [0u8; COPY_LEN];
    BootLoader::new(BootLoaderConfig { active, dfu, state }).prepare_boot(&mut buffer)
}

/// The partition of `len` bytes at `start`.
///
/// # Safety
///
/// `start..start + len` must be memory nothing else uses for as long as
/// the partition lives.
unsafe fn partition(start: usize, len: usize) -> Partition {
    // SAFETY: the caller's promise; PSRAM is RAM and any byte is a valid u8.
    RuleFlash::new(unsafe { core::slice::from_raw_parts_mut(start as *mut u8, len) })
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    eprintln!("mps2-an386-boot: {}", info);
    process::exit(EXIT_PANIC)
}
