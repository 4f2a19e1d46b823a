//! The device state that every task shares: the process image, the outputs
//! it drives, the communication watchdog, the diagnostics counters and the
//! 100 ms refresh from the inputs and the robot. The Modbus server
//! ([`crate::server`]) answers with it through [`Service`], which it
//! implements here; the boards push input edges and robot events into it.

#[cfg(feature = "update")]
mod firmware;
mod watchdog;

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::{Duration, Instant, Ticker};

#[cfg(feature = "update")]
pub use self::firmware::{BootState, FirmwareStatus};
pub use self::watchdog::{SafeState, Watchdog};
use crate::io::{InputPins, OutputPins, Robot, RobotSample, RobotStatus};
use crate::map::Image;
use crate::map::table::reg;
use crate::modbus::mbap::MAX_ADU_LEN;
use crate::name::Name;
use crate::server::handler::{self, Context, Outcome, Policy};
use crate::server::{Identity, Service, Stats};

/// How often the source-backed points are refreshed and re-asserted.
pub const REFRESH_PERIOD: Duration = Duration::from_millis(100);

/// What the image lock guards: the image, the watchdog in force and its
/// view of the requests that change or read it (one lock per request).
struct State {
    image: Image,
    watchdog: Watchdog,
    monitor: watchdog::Monitor,
    /// The firmware update's state, once the board has set it.
    #[cfg(feature = "update")]
    update: Option<FirmwareStatus>,
    /// Its previous version as Read Device Identification's object 0x80
    /// sends it, written when the state is set rather than at each request.
    #[cfg(feature = "update")]
    previous_text: heapless::String<{ crate::io::Version::MAX_TEXT_LEN }>,
}

/// The shared device: the image behind a blocking mutex (held while one
/// request is applied, never across an `.await`), the board's outputs and
/// model, the watchdog and the counters.
pub struct Device<'a> {
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
    outputs: &'a dyn OutputPins,
    model: &'static str,
    stats: Stats,
}

impl core::fmt::Debug for Device<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Device").field("watchdog", &self.watchdog()).field("model", &self.model).finish_non_exhaustive()
    }
}

impl<'a> Device<'a> {
    /// The board `model` (Read Device Identification's ModelName: the
    /// board crate's name, `hal-sim` for hal-sim) with a fresh image: the
    /// robot NOT READY and its version 0.0.0 until the first refresh
    /// samples the robot source.
    pub fn new(watchdog: Watchdog, model: &'static str, outputs: &'a dyn OutputPins) -> Self {
        let state = State {
            image: Image::new(),
            watchdog,
            monitor: watchdog::Monitor::new(Instant::now()),
            #[cfg(feature = "update")]
            update: None,
            #[cfg(feature = "update")]
            previous_text: heapless::String::new(),
        };
        Self { state: Mutex::new(RefCell::new(state)), outputs, model, stats: Stats::new() }
    }

    /// The board, as Read Device Identification names it.
    pub fn model(&self) -> &'static str {
        self.model
    }

    /// The diagnostics counters.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// The watchdog in force.
    pub fn watchdog(&self) -> Watchdog {
        self.state.lock(|state| state.borrow().watchdog)
    }

    /// Whether the watchdog has put the outputs in their safe state and no
    /// valid request has come since.
    pub fn watchdog_tripped(&self) -> bool {
        self.state.lock(|state| state.borrow().monitor.tripped())
    }

    /// The firmware update's state (`None` until the board sets it).
    #[cfg(feature = "update")]
    pub fn firmware_update(&self) -> Option<FirmwareStatus> {
        self.state.lock(|state| state.borrow().update)
    }

    /// Sets the firmware update's state: the board at boot, from the boot
    /// state and the other image's record. From then on Read Device
    /// Identification has the previous firmware's object (0x80).
    #[cfg(feature = "update")]
    pub fn set_firmware_update(&self, status: FirmwareStatus) {
        self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            state.update = Some(status);
            state.previous_text = status.previous_text();
        });
    }

    /// Changes the update's state (a confirmation, an upload armed), once set.
    #[cfg(feature = "update")]
    pub fn set_firmware_update_state(&self, boot_state: BootState) {
        self.state.lock(|state| {
            let update = &mut state.borrow_mut().update;
            *update = update.map(|status| FirmwareStatus { state: boot_state, ..status });
        });
    }

    /// Puts a new watchdog configuration in force at once.
    pub fn set_watchdog(&self, watchdog: Watchdog) {
        self.state.lock(|state| state.borrow_mut().watchdog = watchdog);
    }

    /// Answers one request frame into `reply` under `policy`, as the device
    /// named `name`; drives the outputs at once if the request changed them,
    /// feeds the watchdog and counts.
    pub fn respond(&self, frame: &[u8], reply: &mut [u8; MAX_ADU_LEN], policy: &Policy, name: &Name) -> Outcome {
        let outcome = self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            // The previous firmware's object, once the board has set the update's state.
            #[cfg(feature = "update")]
            let previous_firmware = state.update.map(|_| state.previous_text.as_bytes());
            #[cfg(not(feature = "update"))]
            let previous_firmware = None;
            let identity = Identity { model: self.model, name, previous_firmware };
            let context = Context { identity, stats: &self.stats };
            let watching = state.watchdog.timeout.is_some();
            let outcome = handler::respond(frame, reply, &mut state.image, policy, &context);
            if let Outcome::Reply { written, exception, .. } = outcome {
                if written.outputs {
                    self.outputs.drive(&state.image.outputs());
                }
                if exception.is_none() && watching {
                    state.monitor.valid_request(Instant::now());
                }
            }
            outcome
        });
        match outcome {
            Outcome::Reply { write, exception, .. } => {
                Stats::count(&self.stats.requests);
                if let Some(exception) = exception {
                    self.stats.count_exception(exception, !policy.rights.allow(write));
                }
            }
            Outcome::Discard { .. } => Stats::count(&self.stats.bad_protocol),
            Outcome::NotWhole => {}
        }
        outcome
    }

    /// Reads the image.
    pub fn read<R>(&self, f: impl FnOnce(&Image) -> R) -> R {
        self.state.lock(|state| f(&state.borrow().image))
    }

    /// Changes the image from a source (an input edge, a robot event): the
    /// "event" update class. Bypasses the write policy.
    pub fn update<R>(&self, f: impl FnOnce(&mut Image) -> R) -> R {
        self.state.lock(|state| f(&mut state.borrow_mut().image))
    }

    /// Puts the outputs in their safe state if no valid request has come for
    /// the watchdog's timeout (once per silence). Returns whether it tripped.
    pub fn check_watchdog(&self) -> bool {
        let tripped = self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            let timeout = state.watchdog.timeout?;
            if !state.monitor.check(Instant::now(), timeout) {
                return None;
            }
            state.watchdog.safe_state.apply(&mut state.image);
            self.outputs.drive(&state.image.outputs());
            Some(timeout)
        });
        if let Some(timeout) = tripped {
            Stats::count(&self.stats.watchdog_trips);
            warn!("watchdog: no valid request for {} ms: outputs in their safe state", timeout.as_millis());
        }
        tripped.is_some()
    }

    /// An edge on the ControlBox digital inputs (bit n = input n + 1): an event.
    pub fn set_digital_inputs(&self, mask: u16) {
        self.update(|image| image.set_register(reg::DIGITAL_INPUTS, mask));
    }

    /// An edge on the tool digital inputs (bit n = input n + 1): an event.
    pub fn set_tool_inputs(&self, mask: u8) {
        self.update(|image| image.set_register(reg::TOOL_INPUTS, u16::from(mask)));
    }

    /// A new reading of analog input `channel` (0 or 1), in thousandths of the
    /// unit its type register selects; clamped to that type's range.
    pub fn set_analog_input(&self, channel: usize, value: u16) {
        self.update(|image| image.set_analog_input(channel, value));
    }

    /// A change of the robot's state or flags: an event.
    pub fn set_robot_status(&self, status: &RobotStatus) {
        self.update(|image| image.set_robot_status(status));
    }

    /// Drives the outputs from the image (at start-up, or after a fault).
    pub fn drive_outputs(&self) {
        self.read(|image| self.outputs.drive(&image.outputs()));
    }

    /// One refresh: samples every source and re-asserts every source-backed
    /// point (so a `seed`-policy write to a read-only point lasts at most one
    /// period). The robot's points are left to the robot link while it is the
    /// source ([`Robot::sample`] is `None`): it applies each poll itself.
    pub fn refresh(&self, inputs: &mut impl InputPins, robot: &mut impl Robot) {
        let types = self.read(Image::analog_input_types);
        let digital = inputs.digital();
        let tool = inputs.tool();
        let analog = [0, 1].map(|channel| {
            let kind = types.get(channel).copied().unwrap_or_default();
            inputs.analog(channel, kind).min(kind.max())
        });
        let robot = robot.sample();
        self.update(|image| {
            image.set_register(reg::DIGITAL_INPUTS, digital);
            image.set_register(reg::TOOL_INPUTS, u16::from(tool));
            for (channel, value) in analog.into_iter().enumerate() {
                image.set_analog_input(channel, value);
            }
            if let Some(RobotSample { status, telemetry, version }) = robot {
                image.set_controller_version(&version);
                image.set_robot_status(&status);
                image.set_telemetry(&telemetry);
            }
        });
    }
}

/// The server answers with the device.
impl Service for Device<'_> {
    fn respond(&self, frame: &[u8], reply: &mut [u8; MAX_ADU_LEN], policy: &Policy, name: &Name) -> Outcome {
        Device::respond(self, frame, reply, policy, name)
    }

    fn stats(&self) -> &Stats {
        Device::stats(self)
    }
}

/// The 100 ms task's body: refresh, check the communication watchdog, then
/// wait for the next period. Each binary wraps it in a task with its own
/// pins and robot.
pub async fn refresh_loop(device: &Device<'_>, inputs: &mut impl InputPins, robot: &mut impl Robot) -> ! {
    let mut ticker = Ticker::every(REFRESH_PERIOD);
    loop {
        device.refresh(inputs, robot);
        device.check_watchdog();
        ticker.next().await;
    }
}

#[cfg(test)]
mod tests;
