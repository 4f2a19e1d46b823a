//! Firmware update on this board (feature `update`; docs/update.md): the
//! DFU and boot-state partitions of `memory-update.x` in the file-backed
//! PSRAM, under the same NOR flash rules as the settings (RuleFlash: 4-byte
//! words, 4 KiB pages), and [`UPDATE`]'s updater over them; the image runs from
//! ACTIVE, started by the bootloader (firmware/mps2-an386-boot).
//!
//! After a swap the new image is on trial: [`confirm_when_serving`]
//! confirms it once the network is up and the Modbus listeners serve. If it
//! never gets there, the next reset rolls back: the watchdog the bootloader
//! started makes it ([`crate::watchdog`]), as the image does not pet it
//! while on trial ([`pet_loop`]).
//!
//! The image carries its record ([`IMAGE_INFO`]) right after its vector
//! table (memory-update.x): the running image reads the other image's
//! version from DFU by it, for `/api/status` and 0x2B.

use core::sync::atomic::{AtomicBool, Ordering};

use adapter::device::Device;
use adapter::settings::NetworkSettings;
use adapter::storage::flash::RuleFlash;
use adapter::update::boot::BoardUpdate;
use adapter::update::image::{self, service};
use adapter::update::{self, Config, ImageLayout, SignatureError};
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use static_cell::StaticCell;

/// DFU and the boot state: PSRAM under NOR flash rules, as the settings.
pub type PartitionFlash = RuleFlash<'static, 4, 4096>;
/// The updater over them, with the trial flag: the confirmation's, the
/// HTTP upload's and [`pet_loop`]'s.
pub static UPDATE: BoardUpdate<CriticalSectionRawMutex, PartitionFlash, PartitionFlash> = BoardUpdate::new();

static TAKEN: AtomicBool = AtomicBool::new(false);

/// This image's record: its version, where every image for this board has
/// it (the `.image_info` section of memory-update.x).
#[used]
#[unsafe(link_section = ".image_info")]
static IMAGE_INFO: [u8; update::IMAGE_INFO_LEN] = update::image_info(adapter::VERSION);

/// The bootloader's swap page (RuleFlash's page, as in the bootloader).
const PAGE: u32 = 4096;

/// Where the records are: this image's record's offset from ACTIVE's start.
fn layout() -> ImageLayout {
    unsafe extern "C" {
        static __bootloader_active_start: u8;
    }
    let offset = (&raw const IMAGE_INFO as usize).saturating_sub(&raw const __bootloader_active_start as usize);
    ImageLayout { info_offset: u32::try_from(offset).unwrap_or(u32::MAX), page: PAGE }
}

/// `start..end` of the linker's symbols as a slice.
///
/// # Safety
///
/// The range must be memory no section uses, given out once.
unsafe fn region(start: *mut u8, end: *const u8) -> &'static mut [u8] {
    let len = (end as usize).saturating_sub(start as usize);
    // SAFETY: the caller's promise; PSRAM is RAM while QEMU runs and any
    // byte is a valid u8.
    unsafe { core::slice::from_raw_parts_mut(start, len) }
}

/// Makes [`UPDATE`]'s updater over this board's partitions, once; false
/// when it cannot (made already, or the partitions do not fit it).
pub fn install() -> bool {
    unsafe extern "C" {
        static mut __bootloader_dfu_start: u8;
        static __bootloader_dfu_end: u8;
        static mut __bootloader_state_start: u8;
        static __bootloader_state_end: u8;
        static __bootloader_active_start: u8;
        static __bootloader_active_end: u8;
    }
    if TAKEN.swap(true, Ordering::AcqRel) {
        return false;
    }
    // SAFETY: memory-update.x reserves these ranges of the PSRAM for DFU and
    // the boot state (no section is placed there), and the flag above hands
    // them out once.
    let (dfu, state) = unsafe {
        (
            region(&raw mut __bootloader_dfu_start, &raw const __bootloader_dfu_end),
            region(&raw mut __bootloader_state_start, &raw const __bootloader_state_end),
        )
    };
    let active_len =
        (&raw const __bootloader_active_end as usize).saturating_sub(&raw const __bootloader_active_start as usize);
    let max_len = u32::try_from(active_len).unwrap_or(u32::MAX);
    static ALIGNED: StaticCell<[u8; update::MAX_STATE_WORD]> = StaticCell::new();
    let Some(aligned) = ALIGNED.try_init([0; update::MAX_STATE_WORD]) else { return false };
    let config = Config::new(crate::MODEL, max_len, bootloader_check);
    UPDATE.install(RuleFlash::new(dfu), RuleFlash::new(state), aligned, config).is_some()
}

/// The signature check, in the bootloader (update_image::service): its
/// code is in ZBT SSRAM1, which QEMU loads at every start and the image
/// never writes.
fn bootloader_check(
    public_key: &[u8; image::PUBLIC_KEY_LEN],
    digest: &[u8; image::DIGEST_LEN],
    signature: &[u8; image::SIGNATURE_LEN],
) -> Result<(), SignatureError> {
    unsafe extern "C" {
        static __bootloader_code_start: u8;
        static __bootloader_code_end: u8;
    }
    let code = (&raw const __bootloader_code_start as usize)..(&raw const __bootloader_code_end as usize);
    // SAFETY: the bootloader's code region (memory-update.x) is readable
    // SSRAM the image places nothing in, and a table with the service's
    // magic there is the bootloader's own.
    unsafe { service::check_in(code, public_key, digest, signature) }
}

/// Reports the boot state and confirms an image on trial once it serves
/// (`adapter::update::boot`; `network`, the settings it started with, sets
/// the trial's limit), then pets the watchdog at once.
pub async fn confirm_when_serving(
    stack: Stack<'static>,
    device: &'static Device<'static>,
    network: &'static NetworkSettings,
) {
    UPDATE.confirm_when_serving(stack, device, layout(), network).await;
    if UPDATE.trial().settled() {
        crate::watchdog::pet();
    }
}

/// Pets the watchdog every [`crate::watchdog::PET_INTERVAL_MS`] while
/// [`UPDATE`]'s trial lets it (`Trial::feeds_watchdog`): for good once
/// settled, and on trial (or before the boot state is known) only within
/// the trial's limit. Then the bootloader's watchdog expires
/// [`crate::watchdog::EXPIRY_S`] after the last pet (an NMI,
/// [`NonMaskableInt`]) and resets the board as long again after it.
pub async fn pet_loop() -> ! {
    loop {
        if UPDATE.trial().feeds_watchdog(embassy_time::Instant::now().as_secs()) {
            crate::watchdog::pet();
        }
        embassy_time::Timer::after_millis(crate::watchdog::PET_INTERVAL_MS).await;
    }
}

/// The watchdog's first expiry, on trial: nothing to do. The line stays
/// raised (QEMU pends the NMI on its rising edge: once), and the reset
/// follows at the second expiry unless the image confirms and pets first.
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {}
