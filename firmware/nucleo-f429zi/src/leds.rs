//! The three user LEDs:
//!
//! | LED | colour | pin | shows |
//! |---|---|---|---|
//! | LD1 | green | PB0 | off: no Ethernet link; blinking: link, no address yet; on: link and address |
//! | LD2 | blue | PB7 | flashes for each Modbus connection and request ([`TRAFFIC_FLASH`]); blinks at 2 Hz while the HTTP API's locate runs ([`locate`]) |
//! | LD3 | red | PB14 | on: a fault (outputs off, reset follows); on for [`WATCHDOG_SHOWN`] after a watchdog reset; blinking at 1 Hz: no 8 MHz clock from the ST-LINK, running on the internal RC ([`crate::clock`]) |

use embassy_net::Stack;
use embassy_stm32::gpio::{Level, Output};
use embassy_time::{Duration, Instant, Ticker};

use crate::ModbusServer;

/// How often the LEDs are updated, and how long a traffic flash lasts.
pub const TRAFFIC_FLASH: Duration = Duration::from_millis(50);
/// The link LED's blink half-period while no address is configured, in LED ticks.
const BLINK_TICKS: u32 = 5;
/// How long LD3 stays on after a watchdog reset.
pub const WATCHDOG_SHOWN: Duration = Duration::from_secs(10);
/// LD3's blink half-period on the fallback clock, in LED ticks (500 ms: 1 Hz,
/// unlike LD1's 2 Hz, and never steady like a fault).
const CLOCK_FALLBACK_TICKS: u32 = 10;
/// LD2's locate blink half-period, in LED ticks (250 ms: 2 Hz).
#[cfg(feature = "http")]
const LOCATE_TICKS: u32 = 5;

/// Until when LD2 blinks for locate (`POST /api/locate`).
#[cfg(feature = "http")]
static LOCATE_UNTIL: embassy_sync::blocking_mutex::Mutex<
    embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex,
    core::cell::Cell<Instant>,
> = embassy_sync::blocking_mutex::Mutex::new(core::cell::Cell::new(Instant::from_ticks(0)));

/// Blinks LD2 for `duration` from now, in place of the traffic flashes
/// (no LED is free: LD1 is the link, LD3 the fault, which must not be
/// mistaken for a blink).
#[cfg(feature = "http")]
pub fn locate(duration: Duration) {
    LOCATE_UNTIL.lock(|until| until.set(Instant::now() + duration));
}

/// The LEDs and what the last reset was.
pub struct Leds {
    pub link: Output<'static>,
    pub traffic: Output<'static>,
    pub fault: Output<'static>,
    /// The last reset came from the watchdog.
    pub watchdog_reset: bool,
    /// No 8 MHz clock from the ST-LINK: the clocks run from the HSI.
    pub clock_fallback: bool,
}

impl core::fmt::Debug for Leds {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Leds")
            .field("watchdog_reset", &self.watchdog_reset)
            .field("clock_fallback", &self.clock_fallback)
            .finish_non_exhaustive()
    }
}

/// Drives the LEDs from the link state and the session slots.
#[embassy_executor::task]
pub async fn led_task(mut leds: Leds, stack: Stack<'static>, shared: &'static ModbusServer) -> ! {
    let mut ticker = Ticker::every(TRAFFIC_FLASH);
    let fault_until = Instant::now() + if leds.watchdog_reset { WATCHDOG_SHOWN } else { Duration::from_ticks(0) };
    let mut seen = shared.slots().last_activity();
    let mut tick = 0u32;
    loop {
        let blink_on = (tick / BLINK_TICKS).is_multiple_of(2);
        let link = stack.is_link_up() && (stack.is_config_up() || blink_on);
        leds.link.set_level(Level::from(link));

        // Request times only grow, so anything newer than `seen` is new traffic.
        let activity = shared.slots().last_activity();
        let traffic = activity > seen;
        #[cfg(feature = "http")]
        let traffic = if Instant::now() < LOCATE_UNTIL.lock(core::cell::Cell::get) {
            (tick / LOCATE_TICKS).is_multiple_of(2)
        } else {
            traffic
        };
        leds.traffic.set_level(Level::from(traffic));
        seen = seen.max(activity);

        // After a watchdog reset, steady first; then the clock fallback's blink.
        let fault =
            Instant::now() < fault_until || (leds.clock_fallback && (tick / CLOCK_FALLBACK_TICKS).is_multiple_of(2));
        leds.fault.set_level(Level::from(fault));
        tick = tick.wrapping_add(1);
        ticker.next().await;
    }
}
