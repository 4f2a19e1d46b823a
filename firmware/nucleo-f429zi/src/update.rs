//! Firmware update on this board (feature `update`; docs/update.md): the
//! image runs from ACTIVE (`memory-update.x`), started by the bootloader
//! (firmware/nucleo-f429zi-boot), and [`UPDATE`]'s updater writes DFU and the
//! boot state in bank 2 ([`flash::Partitions`]).
//!
//! After a swap the new image is on trial: `adapter::update::boot`
//! confirms it once it has an address and the Modbus listeners serve. If
//! it has not within the trial's limit (`adapter::update::boot::trial_limit_s`:
//! 30 s, after the DHCP timeout in `dhcp` mode) of its start, the
//! watchdog's feeder stops ([`keeps_feeding`]) and the IWDG resets the MCU:
//! the bootloader rolls back. An image that hangs before its feeder runs is reset by the
//! bootloader's 30 s watchdog, or by its own 2 s one once started.
//!
//! The signature check is the bootloader's (`update_image::service`): the
//! image does not carry ed25519's 14 KiB.

use adapter::device::Device;
use adapter::settings::NetworkSettings;
use adapter::update::boot::BoardUpdate;
use adapter::update::image::{self, service};
use adapter::update::{self, Config, ImageLayout, SignatureError};
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::Instant;
use static_cell::StaticCell;

use crate::flash::{self, ACTIVE_LEN, ACTIVE_START, BOOTLOADER_LEN, BOOTLOADER_START};

/// The updater over DFU and the boot state, with the trial flag: the
/// confirmation's, the HTTP upload's and the watchdog feeder's.
pub static UPDATE: BoardUpdate<CriticalSectionRawMutex, flash::DfuFlash, flash::StateFlash> = BoardUpdate::new();

/// This image's record: its version, where every image for this board has
/// it (the `.image_info` section of memory-update.x).
#[used]
#[unsafe(link_section = ".image_info")]
static IMAGE_INFO: [u8; update::IMAGE_INFO_LEN] = update::image_info(adapter::VERSION);

/// embassy-boot's swap page: the largest erase size of ACTIVE and DFU.
const PAGE: u32 = 128 * 1024;

/// Where the records are: this image's record's offset from ACTIVE's start.
fn layout() -> ImageLayout {
    let offset = (&raw const IMAGE_INFO as usize).saturating_sub(ACTIVE_START as usize);
    ImageLayout { info_offset: u32::try_from(offset).unwrap_or(u32::MAX), page: PAGE }
}

/// The signature check, in the bootloader's flash (sectors 0-3), which
/// the image never writes.
fn bootloader_check(
    public_key: &[u8; image::PUBLIC_KEY_LEN],
    digest: &[u8; image::DIGEST_LEN],
    signature: &[u8; image::SIGNATURE_LEN],
) -> Result<(), SignatureError> {
    let code = BOOTLOADER_START as usize..(BOOTLOADER_START + BOOTLOADER_LEN) as usize;
    // SAFETY: the BOOTLOADER partition is readable flash that nothing
    // writes while the image runs (its partitions are bank 2's), and a
    // table with the service's magic there is the bootloader's own.
    unsafe { service::check_in(code, public_key, digest, signature) }
}

/// Makes [`UPDATE`]'s updater over the partitions, once; false when it
/// cannot (made already, or the partitions do not fit it).
pub fn install(dfu: flash::DfuFlash, state: flash::StateFlash) -> bool {
    static ALIGNED: StaticCell<[u8; update::MAX_STATE_WORD]> = StaticCell::new();
    let Some(aligned) = ALIGNED.try_init([0; update::MAX_STATE_WORD]) else { return false };
    let config = Config::new(crate::MODEL, ACTIVE_LEN, bootloader_check);
    UPDATE.install(dfu, state, aligned, config).is_some()
}

/// Reports the boot state and confirms an image on trial once it serves
/// (without an updater, settles the trial flag); `network`, the settings
/// it started with, sets the trial's limit.
pub async fn confirm_when_serving(
    stack: Stack<'static>,
    device: &'static Device<'static>,
    network: &'static NetworkSettings,
) {
    UPDATE.confirm_when_serving(stack, device, layout(), network).await;
}

/// Whether the watchdog's feeder goes on: not when the image has not
/// settled its trial (confirmed, or not on one) within the trial's limit.
pub fn keeps_feeding() -> bool {
    UPDATE.trial().feeds_watchdog(Instant::now().as_secs())
}
