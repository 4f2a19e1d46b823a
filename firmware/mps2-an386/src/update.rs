//! Firmware update on this board (feature `update`; docs/update.md): the
//! DFU and boot-state partitions of `memory-update.x` in the file-backed
//! PSRAM, under the same NOR flash rules as the settings (RuleFlash: 4-byte
//! words, 4 KiB pages), and the [`Updater`] over them; the image runs from
//! ACTIVE, started by the bootloader (firmware/mps2-an386-boot).
//!
//! After a swap the new image is on trial: [`confirm_when_serving`]
//! confirms it once the network is up and the Modbus listeners serve. If it
//! never gets there, the next reset rolls back. (The watchdog that makes
//! that reset, and the HTTP upload, are still to come.)

use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use adapter::storage::flash::RuleFlash;
use adapter::update::{self, Config, Updater};
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_sync::once_lock::OnceLock;
use static_cell::StaticCell;

/// DFU and the boot state: PSRAM under NOR flash rules, as the settings.
pub type PartitionFlash = RuleFlash<'static, 4, 4096>;
/// The updater over them.
pub type BoardUpdater = Updater<'static, PartitionFlash, PartitionFlash>;
/// Shared by the confirmation and (later) the HTTP upload.
pub type SharedUpdater = Mutex<CriticalSectionRawMutex, BoardUpdater>;

static TAKEN: AtomicBool = AtomicBool::new(false);

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

/// The updater over this board's partitions, once (`None` after, or when
/// the partitions do not fit it).
pub fn updater() -> Option<&'static SharedUpdater> {
    unsafe extern "C" {
        static mut __bootloader_dfu_start: u8;
        static __bootloader_dfu_end: u8;
        static mut __bootloader_state_start: u8;
        static __bootloader_state_end: u8;
        static __bootloader_active_start: u8;
        static __bootloader_active_end: u8;
    }
    if TAKEN.swap(true, Ordering::AcqRel) {
        return None;
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
    let max_len = u32::try_from(active_len).ok()?;
    static ALIGNED: StaticCell<[u8; update::MAX_STATE_WORD]> = StaticCell::new();
    let aligned = ALIGNED.try_init([0; update::MAX_STATE_WORD])?;
    let config = Config::new(crate::MODEL, max_len);
    let updater = match Updater::new(RuleFlash::new(dfu), RuleFlash::new(state), aligned, config) {
        Ok(updater) => updater,
        Err(e) => {
            defmt::error!("update: {}", e);
            return None;
        }
    };
    if update::DEVELOPMENT_KEY {
        defmt::warn!("update: the DEVELOPMENT key is built in (keys/update-dev.pub): anyone can sign an update");
    }
    CAPACITY.store(updater.capacity(), Ordering::Relaxed);
    UPDATER.init(Mutex::new(updater)).ok()?;
    UPDATER.try_get()
}

/// The updater, once [`updater`] has made it: the HTTP upload's too.
static UPDATER: OnceLock<SharedUpdater> = OnceLock::new();

/// The updater [`updater`] made, if it has.
pub fn shared() -> Option<&'static SharedUpdater> {
    UPDATER.try_get()
}

/// The largest update file the updater takes (0 before it is made).
pub fn capacity() -> usize {
    CAPACITY.load(Ordering::Relaxed)
}

static CAPACITY: AtomicUsize = AtomicUsize::new(0);

/// Logs the boot state, then confirms an image on trial once the network
/// has its address (the Modbus listeners are spawned before this runs).
pub async fn confirm_when_serving(stack: Stack<'static>, updater: &'static SharedUpdater) {
    match updater.lock().await.boot_state().await {
        Ok(state) => defmt::info!("update: boot state {}", state),
        Err(e) => defmt::warn!("update: boot state unreadable: {}", e),
    }
    stack.wait_config_up().await;
    match updater.lock().await.confirm().await {
        Ok(true) => defmt::info!("update: this image is confirmed"),
        Ok(false) => {}
        Err(e) => defmt::error!("update: confirmation failed: {}", e),
    }
}
