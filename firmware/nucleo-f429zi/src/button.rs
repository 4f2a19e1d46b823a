//! The user button (B1, PC13). Held down at power-up for [`HOLD`]: a
//! factory reset (docs/settings.md), the saved settings and the admin
//! password erased before they are read. Pressed briefly while running
//! ([`watch`]): the physical act that lets the first admin password be set
//! for 10 minutes more (docs/http-api.md, "The first password").
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
use embassy_time::{Duration, Instant, Ticker, block_for};

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

/// How often [`watch`] reads the button: a press is a human's, 100 ms or more.
const LOOK: Duration = Duration::from_millis(50);

/// Follows the button's presses while the device runs: each press shorter
/// than [`HOLD`], once released, opens the first password's window
/// (`Controller::open_first_password_window`; nothing once a password is
/// set). Read every [`LOOK`]: PC13's EXTI line is input 14's (PE13).
pub async fn watch(button: Input<'static>, control: &'static crate::Control) -> ! {
    let mut ticker = Ticker::every(LOOK);
    let mut pressed_at = None;
    loop {
        ticker.next().await;
        match (button.is_high(), pressed_at) {
            (true, None) => pressed_at = Some(Instant::now()),
            (false, Some(at)) => {
                pressed_at = None;
                if at.elapsed() < HOLD {
                    defmt::info!("user button pressed");
                    control.open_first_password_window();
                }
            }
            _ => {}
        }
    }
}
