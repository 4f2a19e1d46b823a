//! What a board with `update` does with its [`Updater`], the same on
//! every board (docs/update.md): a [`BoardUpdate`] holds it, made once at
//! start, for the upload ([`BoardUpdate::receive`]) and for the
//! confirmation ([`BoardUpdate::confirm_when_serving`]: read the boot state
//! and the other image's version, report them on the [`Device`], and
//! confirm an image on trial once it serves); its [`Trial`] flag is what
//! the board's watchdog feeding reads, so that an image on trial that does
//! not confirm itself is reset and rolled back by the bootloader.

use core::sync::atomic::{AtomicU8, AtomicU32, AtomicUsize, Ordering};

use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::Mutex;
use embassy_sync::once_lock::OnceLock;
use embedded_storage_async::nor_flash::NorFlash;

use super::{BootState, Config, FirmwareStatus, ImageLayout, Updater};
use crate::device::Device;
use crate::settings::{NetMode, NetworkSettings};

/// Where an upload's bytes come from: its chunks in order, then `None`
/// (the HTTP API's request body, a test's bytes).
#[allow(async_fn_in_trait, reason = "the executor is single-threaded: no future needs to be Send")]
pub trait Source {
    /// Why the bytes stopped coming.
    type Error;
    /// The next chunk; `None` at the end of the upload.
    async fn chunk(&mut self) -> Result<Option<&[u8]>, Self::Error>;
}

/// Why an upload was not taken; nothing was armed, the running image stays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refused<E> {
    /// The updater refused the file (not one for this device, a bad
    /// signature, cut off) or its flash failed.
    Update(super::Error),
    /// The source failed before the file came whole.
    Source(E),
    /// This device takes no updates: no updater.
    Unsupported,
}

/// How long an image on trial has to confirm itself once it could have
/// an address (docs/update.md): the base of [`trial_limit_s`].
pub const TRIAL_LIMIT_S: u64 = 30;

/// How long an image on trial has, from its start, to confirm itself under
/// the network settings it starts with: [`TRIAL_LIMIT_S`], and in `dhcp`
/// mode the DHCP timeout before it (the fallback address comes only after
/// it, and the image confirms once it serves on whatever address it has).
/// After that the board's watchdog resets it and the bootloader rolls back.
pub const fn trial_limit_s(network: &NetworkSettings) -> u64 {
    match network.mode {
        NetMode::Dhcp => TRIAL_LIMIT_S + network.dhcp_timeout_s as u64,
        NetMode::Static => TRIAL_LIMIT_S,
    }
}

/// Whether the running image is on trial, as the watchdog's feeder sees it,
/// and until when, in seconds from its start, the trial lasts.
#[derive(Debug)]
pub struct Trial {
    state: AtomicU8,
    limit_s: AtomicU32,
}

const UNKNOWN: u8 = 0;
const ON_TRIAL: u8 = 1;
const SETTLED: u8 = 2;

impl Trial {
    /// Not known yet: the boot state has not been read.
    pub const fn new() -> Self {
        Self { state: AtomicU8::new(UNKNOWN), limit_s: AtomicU32::new(TRIAL_LIMIT_S as u32) }
    }

    /// The image is on trial: swapped in and not (yet) confirmed.
    pub fn on_trial(&self) -> bool {
        self.state.load(Ordering::Relaxed) == ON_TRIAL
    }

    /// When the trial ends, in seconds from the start ([`trial_limit_s`]).
    pub fn limit_s(&self) -> u64 {
        u64::from(self.limit_s.load(Ordering::Relaxed))
    }

    /// Whether the board's watchdog is fed at `uptime_s` seconds from the
    /// start: always once settled; before, only within the trial's limit,
    /// so that an image that never confirms itself (or never gets to read
    /// its boot state) is reset and rolled back.
    pub fn feeds_watchdog(&self, uptime_s: u64) -> bool {
        self.settled() || uptime_s < self.limit_s()
    }

    /// The image is not on trial (never was, or confirmed itself), or it
    /// cannot tell and must not reset itself in a loop for it.
    pub fn settled(&self) -> bool {
        self.state.load(Ordering::Relaxed) == SETTLED
    }

    /// No trial to wait for: the boot state says so, the image confirmed
    /// itself, or the state cannot be read (a reset every 30 s would not
    /// make that better).
    pub fn settle(&self) {
        self.state.store(SETTLED, Ordering::Relaxed);
    }

    fn set(&self, state: BootState) {
        self.state.store(if state == BootState::Trial { ON_TRIAL } else { SETTLED }, Ordering::Relaxed);
    }

    fn set_limit(&self, limit_s: u64) {
        self.limit_s.store(u32::try_from(limit_s).unwrap_or(u32::MAX), Ordering::Relaxed);
    }
}

impl Default for Trial {
    fn default() -> Self {
        Self::new()
    }
}

/// A board's updater, made once at start ([`Self::install`]), and its
/// [`Trial`]: a `static` of the board's.
pub struct BoardUpdate<M: RawMutex, DFU: NorFlash, STATE: NorFlash> {
    updater: OnceLock<Mutex<M, Updater<'static, DFU, STATE>>>,
    capacity: AtomicUsize,
    trial: Trial,
}

impl<M: RawMutex, DFU: NorFlash, STATE: NorFlash> BoardUpdate<M, DFU, STATE> {
    /// No updater yet.
    pub const fn new() -> Self {
        Self { updater: OnceLock::new(), capacity: AtomicUsize::new(0), trial: Trial::new() }
    }

    /// Makes the updater over `dfu` and `state` with `aligned` as
    /// embassy-boot's state buffer ([`Updater::new`]); `None` when the
    /// partitions do not fit it (logged) or it is made already.
    pub fn install(
        &'static self,
        dfu: DFU,
        state: STATE,
        aligned: &'static mut [u8],
        config: Config<'_>,
    ) -> Option<&'static Mutex<M, Updater<'static, DFU, STATE>>> {
        let updater = match Updater::new(dfu, state, aligned, config) {
            Ok(updater) => updater,
            Err(_error) => {
                warn!("update: no updater: {:?}", _error);
                return None;
            }
        };
        if super::DEVELOPMENT_KEY {
            warn!("update: the DEVELOPMENT key is built in (keys/update-dev.pub): anyone can sign an update");
        }
        self.capacity.store(updater.capacity(), Ordering::Relaxed);
        self.updater.init(Mutex::new(updater)).ok()?;
        self.updater.try_get()
    }

    /// The largest update file the updater takes (0 without one).
    pub fn capacity(&self) -> usize {
        self.capacity.load(Ordering::Relaxed)
    }

    /// Whether the image is on trial, for the board's watchdog feeding.
    pub fn trial(&self) -> &Trial {
        &self.trial
    }

    /// Takes an upload from `source` into the updater ([`Updater::receive`]):
    /// what the board's `Platform::receive_firmware` does. Unsupported
    /// without an updater.
    pub async fn receive<S: Source>(&self, source: &mut S) -> Result<crate::io::Version, Refused<S::Error>> {
        let Some(updater) = self.updater.try_get() else { return Err(Refused::Unsupported) };
        let received = updater.lock().await.receive(source).await;
        if let Ok(_version) = &received {
            info!("update: {:?} received and armed; rebooting into it", _version);
        }
        received
    }

    /// Sets the trial's limit for `network` ([`trial_limit_s`]), reads the
    /// boot state and the other image's version (by `layout`), sets them on
    /// `device` and [`Self::trial`], then, once the network has an address,
    /// whichever (DHCP's or the fallback; the Modbus listeners are spawned
    /// before this runs), confirms an image on trial. Without an updater:
    /// nothing to wait for ([`Trial::settle`]).
    pub async fn confirm_when_serving(
        &self,
        stack: Stack<'_>,
        device: &Device<'_>,
        layout: ImageLayout,
        network: &NetworkSettings,
    ) {
        self.trial.set_limit(trial_limit_s(network));
        let Some(updater) = self.updater.try_get() else {
            self.trial.settle();
            return;
        };
        {
            let mut updater = updater.lock().await;
            match updater.boot_state().await {
                Ok(state) => {
                    let previous = updater.other_image(layout).await.unwrap_or(None);
                    let capacity = u32::try_from(updater.capacity()).unwrap_or(u32::MAX);
                    info!("update: boot state {:?}, previous firmware {:?}", state, previous);
                    if state == BootState::Trial {
                        info!(
                            "update: on trial: confirms once it serves, within {} s of its start",
                            self.trial.limit_s()
                        );
                    }
                    device.set_firmware_update(FirmwareStatus { state, previous, capacity });
                    self.trial.set(state);
                }
                Err(_error) => {
                    warn!("update: boot state unreadable: {:?}", _error);
                    self.trial.settle();
                }
            }
        }
        stack.wait_config_up().await;
        match updater.lock().await.confirm().await {
            Ok(true) => {
                device.set_firmware_update_state(BootState::Confirmed);
                self.trial.settle();
                info!("update: this image is confirmed");
            }
            Ok(false) => {}
            Err(_error) => warn!("update: confirmation failed: {:?}", _error),
        }
    }
}

impl<M: RawMutex, DFU: NorFlash, STATE: NorFlash> core::fmt::Debug for BoardUpdate<M, DFU, STATE> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("BoardUpdate")
            .field("installed", &self.updater.try_get().is_some())
            .field("capacity", &self.capacity())
            .field("trial", &self.trial)
            .finish()
    }
}

impl<M: RawMutex, DFU: NorFlash, STATE: NorFlash> Default for BoardUpdate<M, DFU, STATE> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the boards' watchdog feeders read: fed once settled, and
    /// before that only within the trial's limit.
    #[test]
    fn the_trial_flag_follows_the_boot_state_and_the_confirmation() {
        let trial = Trial::new();
        assert!(!trial.on_trial() && !trial.settled(), "unknown at start");
        trial.set(BootState::Trial);
        assert!(trial.on_trial() && !trial.settled());
        trial.settle();
        assert!(!trial.on_trial() && trial.settled(), "confirmed");
        for state in [BootState::Confirmed, BootState::RolledBack, BootState::Armed, BootState::DfuDetach] {
            let trial = Trial::new();
            trial.set(state);
            assert!(!trial.on_trial() && trial.settled(), "{state:?}");
        }
    }

    /// The trial outlasts the DHCP timeout, after which the fallback
    /// address comes: with the defaults (dhcp, 30 s), 60 s from the start.
    #[test]
    fn the_trial_outlasts_the_dhcp_timeout() {
        let mut network = crate::settings::Settings::DEFAULT.network;
        assert_eq!((network.mode, network.dhcp_timeout_s), (NetMode::Dhcp, 30), "the defaults");
        assert_eq!(trial_limit_s(&network), 60);
        network.dhcp_timeout_s = 600;
        assert_eq!(trial_limit_s(&network), 630);
        network.mode = NetMode::Static;
        assert_eq!(trial_limit_s(&network), TRIAL_LIMIT_S, "a static address needs no wait");
    }

    #[test]
    fn the_watchdog_is_fed_until_the_limit_unless_settled() {
        let trial = Trial::new();
        assert!(trial.feeds_watchdog(0) && trial.feeds_watchdog(29), "unknown: within the base limit");
        assert!(!trial.feeds_watchdog(30), "a boot state never read ends in a reset");
        trial.set_limit(60);
        trial.set(BootState::Trial);
        assert!(trial.feeds_watchdog(59), "on trial, within the limit: the DHCP fallback has time");
        assert!(!trial.feeds_watchdog(60), "on trial past the limit: reset, rolled back");
        trial.settle();
        assert!(trial.feeds_watchdog(u64::MAX), "confirmed: fed for good");
    }
}
