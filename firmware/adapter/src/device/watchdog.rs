//! The communication watchdog (as Moxa's safe mode, Advantech's fail-safe
//! values, WAGO's watchdog): when no valid request arrives for the timeout,
//! the outputs go to a configured safe state and stay there until a client
//! writes them again.
//!
//! "Valid" is a request answered without an exception, from any client.
//! The timer starts at power-up, so a master that never comes also leaves
//! the outputs safe. After a trip the watchdog re-arms with the next valid
//! request; reading alone re-arms it but does not restore the outputs.
//! The 100 ms refresh checks it, so a trip comes at most 100 ms late.

use embassy_time::{Duration, Instant};

use crate::io::{ANALOG_CHANNELS, AnalogType};
use crate::map::Image;
use crate::map::points::ANALOG_OUTPUT_REGISTERS;
use crate::map::table::reg;

/// What the outputs are set to when the watchdog trips.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SafeState {
    /// ControlBox digital outputs: bit n = output n + 1.
    pub digital: u16,
    /// Tool digital outputs: bit n = output n + 1.
    pub tool: u8,
    /// Analog outputs 1 and 2, in the unit of their present type (clamped to its range).
    pub analog: [u16; ANALOG_CHANNELS],
}

impl SafeState {
    /// Every output off, analog outputs 0.
    pub const OFF: Self = Self { digital: 0, tool: 0, analog: [0; ANALOG_CHANNELS] };

    /// Writes the safe state into the image (as a source: no write policy).
    pub(crate) fn apply(&self, image: &mut Image) {
        image.set_register(reg::DIGITAL_OUTPUTS, self.digital);
        image.set_register(reg::TOOL_OUTPUTS, u16::from(self.tool) & TOOL_MASK);
        for ((value, kind), safe) in ANALOG_OUTPUT_REGISTERS.into_iter().zip(self.analog) {
            let max = AnalogType::from_register(image.register(kind)).max();
            image.set_register(value, safe.min(max));
        }
    }
}

const TOOL_MASK: u16 = (1 << crate::map::table::TOOL_PINS) - 1;

/// The watchdog's configuration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Watchdog {
    /// `None`: off (the default).
    pub timeout: Option<Duration>,
    /// Where the outputs go on a trip.
    pub safe_state: SafeState,
}

impl Watchdog {
    /// No watchdog.
    pub const OFF: Self = Self { timeout: None, safe_state: SafeState::OFF };
}

/// When the last valid request came, and whether the watchdog has tripped since.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Monitor {
    last_valid: Instant,
    tripped: bool,
}

impl Monitor {
    pub(crate) const fn new(now: Instant) -> Self {
        Self { last_valid: now, tripped: false }
    }

    /// A valid request arrived: the watchdog re-arms.
    pub(crate) fn valid_request(&mut self, now: Instant) {
        self.last_valid = now;
        self.tripped = false;
    }

    /// Whether the watchdog has tripped since the last valid request.
    pub(crate) const fn tripped(&self) -> bool {
        self.tripped
    }

    /// Whether the watchdog trips now (once per silence).
    pub(crate) fn check(&mut self, now: Instant, timeout: Duration) -> bool {
        let silent = now.checked_duration_since(self.last_valid).is_some_and(|d| d >= timeout);
        let trips = silent && !self.tripped;
        self.tripped |= trips;
        trips
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trips_once_per_silence_and_re_arms_on_a_valid_request() {
        let at = Instant::from_millis;
        let timeout = Duration::from_millis(500);
        let mut monitor = Monitor::new(at(0));
        assert!(!monitor.check(at(499), timeout));
        assert!(!monitor.tripped());
        assert!(monitor.check(at(500), timeout));
        assert!(monitor.tripped());
        assert!(!monitor.check(at(600), timeout), "once per silence");
        assert!(!monitor.check(at(5_000), timeout));
        monitor.valid_request(at(5_000));
        assert!(!monitor.tripped(), "a valid request re-arms it");
        assert!(!monitor.check(at(5_499), timeout));
        assert!(monitor.check(at(5_500), timeout), "re-armed");
    }

    #[test]
    fn safe_state_respects_the_analog_types() {
        let mut image = Image::new();
        image.set_register(reg::ANALOG_OUTPUT_2_TYPE, 1); // voltage: at most 10 000 mV
        image.set_register(reg::DIGITAL_OUTPUTS, 0xffff);
        let safe = SafeState { digital: 0b101, tool: 0xff, analog: [20_000, 20_000] };
        safe.apply(&mut image);
        assert_eq!(image.register(reg::DIGITAL_OUTPUTS), 0b101);
        assert_eq!(image.register(reg::TOOL_OUTPUTS), 0b11_1111, "6 tool outputs");
        assert_eq!(image.register(reg::ANALOG_OUTPUT_1), 20_000);
        assert_eq!(image.register(reg::ANALOG_OUTPUT_2), 10_000, "clamped to the voltage range");
        SafeState::OFF.apply(&mut image);
        assert_eq!([1, 16, 18, 22].map(|a| image.register(a)), [0; 4]);
        assert_eq!(image.register(reg::ANALOG_OUTPUT_2_TYPE), 1, "types are left as they are");
    }
}
