//! What a board with `update` runs at boot, the same on every board
//! (docs/update.md): read the boot state and the other image's version,
//! report them on the [`Device`], and confirm an image on trial once it
//! serves; and the [`Trial`] flag the board's watchdog feeding reads, so
//! that an image on trial that does not confirm itself is reset and
//! rolled back by the bootloader.

use core::sync::atomic::{AtomicU8, Ordering};

use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::NorFlash;

use super::{BootState, ImageLayout, Status, Updater};
use crate::device::Device;

/// How long an image on trial has to confirm itself, from its start
/// (DEVICE.md section 5): after that the board's watchdog resets it.
pub const TRIAL_LIMIT_S: u64 = 30;

/// Whether the running image is on trial, as the watchdog's feeder sees it.
#[derive(Debug)]
pub struct Trial(AtomicU8);

const UNKNOWN: u8 = 0;
const ON_TRIAL: u8 = 1;
const SETTLED: u8 = 2;

impl Trial {
    /// Not known yet: the boot state has not been read.
    pub const fn new() -> Self {
        Self(AtomicU8::new(UNKNOWN))
    }

    /// The image is on trial: swapped in and not (yet) confirmed.
    pub fn on_trial(&self) -> bool {
        self.0.load(Ordering::Relaxed) == ON_TRIAL
    }

    /// The image is not on trial (never was, or confirmed itself), or it
    /// cannot tell and must not reset itself in a loop for it.
    pub fn settled(&self) -> bool {
        self.0.load(Ordering::Relaxed) == SETTLED
    }

    /// No trial to wait for: the boot state says so, the image confirmed
    /// itself, or the state cannot be read (a reset every 30 s would not
    /// make that better).
    pub fn settle(&self) {
        self.0.store(SETTLED, Ordering::Relaxed);
    }

    fn set(&self, state: BootState) {
        self.0.store(if state == BootState::Trial { ON_TRIAL } else { SETTLED }, Ordering::Relaxed);
    }
}

impl Default for Trial {
    fn default() -> Self {
        Self::new()
    }
}

/// Reads the boot state and the other image's version (by `layout`), sets
/// them on `device` and `trial`, then, once the network has its address
/// (the Modbus listeners are spawned before this runs), confirms an image
/// on trial.
pub async fn confirm_when_serving<M: RawMutex, DFU: NorFlash, STATE: NorFlash>(
    stack: Stack<'_>,
    updater: &Mutex<M, Updater<'_, DFU, STATE>>,
    device: &Device<'_>,
    layout: ImageLayout,
    trial: &Trial,
) {
    {
        let mut updater = updater.lock().await;
        match updater.boot_state().await {
            Ok(state) => {
                let previous = updater.other_image(layout).await.unwrap_or(None);
                let capacity = u32::try_from(updater.capacity()).unwrap_or(u32::MAX);
                info!("update: boot state {:?}, previous firmware {:?}", state, previous);
                device.set_firmware_update(Status { state, previous, capacity });
                trial.set(state);
            }
            Err(_error) => {
                warn!("update: boot state unreadable: {:?}", _error);
                trial.settle();
            }
        }
    }
    stack.wait_config_up().await;
    match updater.lock().await.confirm().await {
        Ok(true) => {
            device.set_firmware_update_state(BootState::Confirmed);
            trial.settle();
            info!("update: this image is confirmed");
        }
        Ok(false) => {}
        Err(_error) => warn!("update: confirmation failed: {:?}", _error),
    }
}
