//! Settings on the device and the HTTP API's board side (feature `http`,
//! on by default): the settings store over bank 2's sectors 12-13
//! ([`flash::SettingsFlash`]) and the [`Platform`] the settings service
//! (`adapter::control::Controller`) runs on, which the HTTP API calls.
//!
//! | what | how, on this board |
//! |---|---|
//! | store | [`flash::SettingsFlash`]: two 16 KiB sectors, erased and written by the interrupt-driven flash driver |
//! | model | `nucleo-f429zi` |
//! | MAC | from the unique ID (`adapter::net::mac_from_uid`) |
//! | network | the stack's address now, the mode it started with |
//! | salt | 16 bytes from the hardware RNG, drawn when a password is set |
//! | locate | LD2 (blue) blinks at 2 Hz instead of the traffic flashes ([`leds::locate`]) |
//! | reboot | `SYSRESETREQ` (`SCB::sys_reset`) |
//! | reset reason | RCC_CSR's flags, read at boot ([`crate::safety::take_reset_cause`]) |

use core::cell::RefCell;

use adapter::control::{NetworkStatus, Platform};
use adapter::settings::{NetMode, Settings};
use adapter::storage::{Loaded, Store};
use defmt::unwrap;
use embassy_net::Stack;
use embassy_stm32::peripherals::RNG;
use embassy_stm32::rng::Rng;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::Duration;

use crate::safety::ResetCause;
use crate::{SETTINGS, flash, leds};

/// The settings store over the settings flash, and what it holds, erased
/// first when `factory_reset` (the user button held at power-up). A load
/// that found something wrong is a warning: the factory settings stand in
/// for what cannot be read, and `/api/status` reports the storage not ok.
pub async fn load(flash: flash::SettingsFlash, factory_reset: bool) -> (Store<flash::SettingsFlash>, Loaded) {
    // memory.x's region, checked whole sectors at compile time: a failure
    // is a build mistake, and its panic ends in the fault handler.
    let mut store = unwrap!(Store::new(flash, 0..flash::SETTINGS_LEN));
    if factory_reset {
        match store.factory_reset().await {
            Ok(()) => defmt::warn!("settings: factory reset by the user button"),
            Err(error) => defmt::error!("settings: the factory reset failed: {}", error),
        }
    }
    let loaded = store.load(&SETTINGS).await;
    if let Some(error) = loaded.error {
        defmt::warn!("settings: {}", error);
    }
    defmt::info!("settings: {} records; storage ok: {}", loaded.status.records, loaded.status.ok);
    (store, loaded)
}

/// What only this board knows or does, for the HTTP API.
pub struct Nucleo {
    stack: Stack<'static>,
    mac: [u8; 6],
    mode: NetMode,
    reset: ResetCause,
}

/// The hardware RNG: the admin password's salts and, with `tls`, the TLS
/// generator's entropy ([`entropy`]).
static RNG_CELL: Mutex<CriticalSectionRawMutex, RefCell<Option<Rng<'static, RNG>>>> = Mutex::new(RefCell::new(None));

/// Hands the hardware RNG to [`entropy`], for good (once, at start).
pub fn install_rng(rng: Rng<'static, RNG>) {
    RNG_CELL.lock(|cell| *cell.borrow_mut() = Some(rng));
}

/// Fills `buf` from the hardware RNG (RM0090 24: a 32-bit word every 40
/// periods of its 48 MHz clock); `false` when it is not there.
pub fn entropy(buf: &mut [u8]) -> bool {
    RNG_CELL.lock(|rng| match rng.try_borrow_mut().ok().as_deref_mut().and_then(Option::as_mut) {
        Some(rng) => {
            rng.fill_bytes(buf);
            true
        }
        None => false,
    })
}

impl core::fmt::Debug for Nucleo {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Nucleo").field("mac", &self.mac).finish_non_exhaustive()
    }
}

impl Nucleo {
    /// The platform of `stack`, started with `settings` after a `reset`, on
    /// the MAC `mac`; its salts come from the RNG [`install_rng`] gave.
    pub fn new(stack: Stack<'static>, mac: [u8; 6], settings: &Settings, reset: ResetCause) -> Self {
        Self { stack, mac, mode: settings.network.mode, reset }
    }
}

impl Platform for Nucleo {
    fn model(&self) -> &'static str {
        crate::MODEL
    }

    fn mac(&self) -> [u8; 6] {
        self.mac
    }

    fn network(&self) -> NetworkStatus {
        NetworkStatus::of(self.stack, self.mode)
    }

    fn reboot(&self) {
        defmt::info!("rebooting (SYSRESETREQ)");
        cortex_m_support::reboot()
    }

    fn locate(&self, duration: Duration) {
        leds::locate(duration);
    }

    fn reset_reason(&self) -> Option<&'static str> {
        Some(self.reset.name())
    }

    fn salt(&self) -> [u8; 16] {
        let mut salt = [0u8; 16];
        entropy(&mut salt);
        salt
    }

    #[cfg(feature = "update")]
    fn firmware_capacity(&self) -> usize {
        crate::update::UPDATE.capacity()
    }

    #[cfg(feature = "update")]
    async fn receive_firmware<S: adapter::update::boot::Source>(
        &self,
        body: &mut S,
    ) -> Result<adapter::io::Version, adapter::update::boot::Refused<S::Error>> {
        crate::update::UPDATE.receive(body).await
    }
}
