//! Factory reset by the user button (B1, PC13; docs/settings.md): held
//! down at power-up for [`HOLD`], the saved settings and the admin password
//! are erased before they are read.
//!
//! It runs in [`crate::board::init`], before the executor runs anything
//! else, so it waits by blocking and pets the independent watchdog itself,
//! every [`STEP`] (100 ms: well inside its shortest period, 1.36 s).
//! What the user sees: while the button is held, LD1-LD3 blink together at
//! 5 Hz; after [`HOLD`], all three stay on for a second (the reset will
//! happen). Released sooner, the LEDs go out and the board starts with its
//! saved settings. A button held at power-up is never taken for an input:
//! B1 is on no point of the map.

use embassy_stm32::gpio::{Input, Level};
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_time::{Duration, Instant, block_for};

use crate::leds::Leds;

/// How long the button must be held at power-up.
pub const HOLD: Duration = Duration::from_secs(5);

/// How often the button is read (and the watchdog petted) while it is held.
const STEP: Duration = Duration::from_millis(100);

/// How long the LEDs stay on to say the reset is accepted.
const ACKNOWLEDGE: Duration = Duration::from_secs(1);

/// Whether B1 is held for [`HOLD`] from now: a factory reset asked for.
/// Returns at once when it is not pressed.
pub fn factory_reset_held(button: &Input<'_>, watchdog: &mut IndependentWatchdog<'_, IWDG>, leds: &mut Leds) -> bool {
    if button.is_low() {
        return false;
    }
    defmt::info!("user button held at power-up: factory reset after {} s", HOLD.as_secs());
    let start = Instant::now();
    let mut lit = false;
    while start.elapsed() < HOLD {
        if button.is_low() {
            defmt::info!("user button released: no factory reset");
            set_all(leds, Level::Low);
            return false;
        }
        lit = !lit;
        set_all(leds, Level::from(lit));
        watchdog.pet();
        block_for(STEP);
    }
    set_all(leds, Level::High);
    let start = Instant::now();
    while start.elapsed() < ACKNOWLEDGE {
        watchdog.pet();
        block_for(STEP);
    }
    watchdog.pet();
    set_all(leds, Level::Low);
    true
}

fn set_all(leds: &mut Leds, level: Level) {
    leds.link.set_level(level);
    leds.traffic.set_level(level);
    leds.fault.set_level(level);
}
