//! Settings on the device and the HTTP API's board side (feature `http`):
//! the settings store over the PSRAM region ([`settings_flash`]) and the
//! [`Platform`] the settings service ([`Controller`](adapter::control::Controller)) runs on.
//!
//! | what | how, on this board |
//! |---|---|
//! | store | [`RuleFlash`] (4-byte words, 4 KiB pages) over `board::settings_region()`: 64 KiB of PSRAM, a state file under QEMU |
//! | model | `mps2-an386` |
//! | MAC | the LAN9118's |
//! | network | the stack's address now, the mode it started with |
//! | salt | **weak**: no entropy source on this board; the MAC, the SysTick time and its counter, and a count of salts, mixed |
//! | locate | FPGA user LED1 blinks (2 Hz) instead of showing output 2 ([`board::locate`]) |
//! | reboot | `SYSRESETREQ` (`SCB::sys_reset`): QEMU resets the machine and boots the image again; the state file keeps its contents |

use core::sync::atomic::{AtomicU32, Ordering};

use adapter::control::{NetworkStatus, Platform};
use adapter::settings::NetMode;
use adapter::storage::flash::RuleFlash;
use embassy_futures::select::{Either, select};
use embassy_net::Stack;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};

use crate::board;

/// The settings store's flash: the PSRAM region under NOR flash rules.
pub type SettingsFlash = RuleFlash<'static, 4, 4096>;

/// The settings region as the store's flash, once (`None` after). A
/// region of all 0x00 is RAM no state file backs (QEMU started without
/// the scripts' `memory-backend` options): it is erased to 0xFF, blank,
/// and a warning says the settings last only until QEMU exits.
pub fn settings_flash() -> Option<SettingsFlash> {
    let region = board::settings_region()?;
    if region.iter().all(|&byte| byte == 0) {
        region.fill(0xff);
        defmt::warn!(
            "settings: the settings region reads all zeros (QEMU without a state file): erased; \
             saved settings last until QEMU exits (scripts/qemu-run keeps them in a state file)"
        );
    }
    Some(RuleFlash::new(region))
}

/// Half a period of the locate blink.
const BLINK: Duration = Duration::from_millis(250);

/// Locate requests: how long to blink.
static LOCATE: Signal<CriticalSectionRawMutex, Duration> = Signal::new();

/// Blinks LED1 for as long as each locate request asks (a new request
/// starts the time again), then gives it back to output 2.
pub async fn locate_loop() -> ! {
    loop {
        let mut until = Instant::now() + LOCATE.wait().await;
        let mut lit = true;
        while Instant::now() < until {
            board::locate::show(Some(lit));
            lit = !lit;
            if let Either::Second(duration) = select(Timer::after(BLINK), LOCATE.wait()).await {
                until = Instant::now() + duration;
            }
        }
        board::locate::show(None);
    }
}

/// What only this board knows or does, for the HTTP API.
pub struct Mps2 {
    stack: Stack<'static>,
    mac: [u8; 6],
    mode: NetMode,
    /// Salts drawn so far: two in the same tick still differ.
    salts: AtomicU32,
}

impl core::fmt::Debug for Mps2 {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Mps2").field("mac", &self.mac).finish_non_exhaustive()
    }
}

impl Mps2 {
    /// The platform of the stack `stack`, started in `mode`, on the NIC with `mac`.
    pub fn new(stack: Stack<'static>, mac: [u8; 6], mode: NetMode) -> Self {
        Self { stack, mac, mode, salts: AtomicU32::new(0) }
    }
}

impl Platform for Mps2 {
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
        LOCATE.signal(duration);
    }

    /// Weak: this board has no entropy source. The MAC (differs between
    /// boards), the time in ms since boot and the SysTick counter within
    /// the ms (when the request came: network timing), and a count of
    /// salts, through splitmix64. Unique per password set on one board,
    /// hard to guess only as far as the timing is.
    fn salt(&self) -> [u8; 16] {
        let count = self.salts.fetch_add(1, Ordering::Relaxed);
        let [a, b, c, d, e, f] = self.mac;
        let mut state = u64::from_le_bytes([a, b, c, d, e, f, 0, 0])
            ^ Instant::now().as_ticks().rotate_left(20)
            ^ (u64::from(cortex_m::peripheral::SYST::get_current()) << 40)
            ^ u64::from(count).rotate_left(56);
        let first = splitmix64(&mut state);
        let second = splitmix64(&mut state);
        let mut salt = [0u8; 16];
        let (low, high) = salt.split_at_mut(8);
        low.copy_from_slice(&first.to_le_bytes());
        high.copy_from_slice(&second.to_le_bytes());
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

/// One step of splitmix64 (Steele, Lea and Flood, 2014): spreads every
/// bit of the state over the output.
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}
