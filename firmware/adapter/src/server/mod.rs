//! The Modbus TCP server: request handling, sessions, connection slots and the
//! embassy-net listener, shared by every board and by hal-sim.

pub mod access;
pub mod handler;
mod listener;
mod session;
mod slots;
mod stats;
mod watchdog;

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::{Duration, Instant, Ticker};

pub use access::{Access, AllowList, Network};
pub use handler::{Outcome, Policy};
pub use listener::{CLOSE_TIMEOUT, SOCKET_RX_LEN, SOCKET_TX_LEN, listen};
pub use session::{Error, SESSION_BUFFER_LEN, serve};
pub use slots::{SlotId, Slots};
pub use stats::{Counters, Stats};
pub use watchdog::{SafeState, Watchdog};

use crate::io::{self, InputPins, OutputPins, Outputs, Robot, RobotStatus, Version};
use crate::map::Image;
use crate::map::table::reg;
use crate::modbus::mbap::MAX_ADU_LEN;

/// The Modbus TCP port (Implementation Guide V1.0b, 4.1).
pub const MODBUS_PORT: u16 = 502;

/// Sessions served at once. Override at build time with the environment
/// variable `MODBUS_MAX_CONNECTIONS` (1..=32).
pub const MAX_CONNECTIONS: usize = match option_env!("MODBUS_MAX_CONNECTIONS") {
    Some(text) => {
        let n = crate::parse_u16(text) as usize;
        assert!(n >= 1 && n <= 32, "MODBUS_MAX_CONNECTIONS must be 1..=32");
        n
    }
    None => 8,
};

/// Listening sockets kept beyond the sessions: a new client is accepted even
/// when all sessions are busy (then the idlest session is closed to make
/// room), and still finds one listening while another socket is closing,
/// which can take up to [`CLOSE_TIMEOUT`] twice when packets are lost. Two,
/// also because QEMU's slirp accepts a connection before the guest does.
pub const SPARE_SOCKETS: usize = 2;

/// Sockets (and listener tasks): [`MAX_CONNECTIONS`] + [`SPARE_SOCKETS`].
pub const SOCKET_POOL: usize = MAX_CONNECTIONS + SPARE_SOCKETS;

/// Default for [`Config::idle_timeout`].
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(60);
/// Default for [`Config::frame_timeout`].
pub const FRAME_TIMEOUT: Duration = Duration::from_secs(2);
/// How often the source-backed points are refreshed and re-asserted.
pub const REFRESH_PERIOD: Duration = Duration::from_millis(100);

/// How the server runs. Built at start-up by each binary.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// TCP port to listen on.
    pub port: u16,
    /// Sessions served at once (1..=[`MAX_CONNECTIONS`]).
    pub max_connections: usize,
    /// Unit id filtering and write policy.
    pub policy: Policy,
    /// A session with no complete request for this long is closed (`None`: never).
    pub idle_timeout: Option<Duration>,
    /// A frame that has started must be complete within this time.
    pub frame_timeout: Duration,
    /// Who may connect and who may write.
    pub access: Access,
    /// The communication watchdog and the outputs' safe state.
    pub watchdog: Watchdog,
}

impl Config {
    /// Port 502, 8 connections, every unit id, `seed` writes, 60 s idle, 2 s
    /// per frame, everyone may connect and write, no watchdog.
    pub const DEFAULT: Self = Self {
        port: MODBUS_PORT,
        max_connections: MAX_CONNECTIONS,
        policy: Policy { unit_id: None, write_policy: crate::map::WritePolicy::Seed, read_only: false },
        idle_timeout: Some(IDLE_TIMEOUT),
        frame_timeout: FRAME_TIMEOUT,
        access: Access::OPEN,
        watchdog: Watchdog::OFF,
    };
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What the image lock guards: the image, and the watchdog's view of the
/// requests that change or read it.
struct State {
    image: Image,
    monitor: watchdog::Monitor,
}

/// Everything the sessions and tasks share: the process image behind a
/// blocking mutex (held while one request is applied, never across an
/// `.await`), the board's outputs, the configuration, the session slots and
/// the diagnostics counters.
pub struct Shared<'a> {
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
    outputs: &'a dyn OutputPins,
    config: Config,
    version: Version,
    slots: Slots,
    stats: Stats,
}

impl core::fmt::Debug for Shared<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Shared").field("config", &self.config).field("version", &self.version).finish_non_exhaustive()
    }
}

impl<'a> Shared<'a> {
    /// A fresh image with `version` in registers 256-258 and the robot NOT READY.
    pub fn new(config: Config, version: Version, outputs: &'a dyn OutputPins) -> Self {
        let mut image = Image::new();
        version.apply(&mut image);
        let config = Config { max_connections: config.max_connections.clamp(1, MAX_CONNECTIONS), ..config };
        let state = State { image, monitor: watchdog::Monitor::new(Instant::now()) };
        Self {
            state: Mutex::new(RefCell::new(state)),
            outputs,
            config,
            version,
            slots: Slots::new(),
            stats: Stats::new(),
        }
    }

    /// The configuration in force.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The session slots.
    pub fn slots(&self) -> &Slots {
        &self.slots
    }

    /// The diagnostics counters.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// Answers one request frame into `reply` under the configured policy.
    pub fn respond(&self, frame: &[u8], reply: &mut [u8; MAX_ADU_LEN]) -> Outcome {
        self.respond_as(frame, reply, &self.config.policy)
    }

    /// Answers one request frame into `reply` under `policy` (the
    /// configured one, narrowed for the client), drives the outputs at once
    /// if the request changed them, feeds the watchdog and counts.
    pub fn respond_as(&self, frame: &[u8], reply: &mut [u8; MAX_ADU_LEN], policy: &Policy) -> Outcome {
        let outcome = self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            let outcome = handler::respond(frame, reply, &mut state.image, policy);
            if let Outcome::Reply { written, exception, .. } = outcome {
                if written.outputs {
                    self.outputs.drive(&Outputs::from_image(&state.image));
                }
                if exception.is_none() && self.config.watchdog.timeout.is_some() {
                    state.monitor.valid_request(Instant::now());
                }
            }
            outcome
        });
        match outcome {
            Outcome::Reply { function, exception, .. } => {
                Stats::count(&self.stats.requests);
                if let Some(exception) = exception {
                    self.stats.count_exception(exception, policy.read_only && function.is_write());
                }
            }
            Outcome::Discard { .. } => Stats::count(&self.stats.bad_protocol),
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
        let Some(timeout) = self.config.watchdog.timeout else { return false };
        let tripped = self.state.lock(|state| {
            let state = &mut *state.borrow_mut();
            let trips = state.monitor.check(Instant::now(), timeout);
            if trips {
                self.config.watchdog.safe_state.apply(&mut state.image);
                self.outputs.drive(&Outputs::from_image(&state.image));
            }
            trips
        });
        if tripped {
            Stats::count(&self.stats.watchdog_trips);
            warn!("watchdog: no valid request for {} ms: outputs in their safe state", timeout.as_millis());
        }
        tripped
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
        self.update(|image| {
            let types = io::analog_input_types(image);
            if let (Some(kind), Some(&(address, _))) = (types.get(channel), io::ANALOG_INPUT_REGISTERS.get(channel)) {
                image.set_register(address, value.min(kind.max()));
            }
        });
    }

    /// A change of the robot's state or flags: an event.
    pub fn set_robot_status(&self, status: &RobotStatus) {
        self.update(|image| status.apply(image));
    }

    /// What the master has the outputs set to now.
    pub fn outputs(&self) -> Outputs {
        self.read(Outputs::from_image)
    }

    /// Drives the outputs from the image (at start-up, or after a fault).
    pub fn drive_outputs(&self) {
        self.read(|image| self.outputs.drive(&Outputs::from_image(image)));
    }

    /// One refresh: samples every source and re-asserts every source-backed
    /// point (so a `seed`-policy write to a read-only point lasts at most one period).
    pub fn refresh(&self, inputs: &mut impl InputPins, robot: &mut impl Robot) {
        let types = self.read(io::analog_input_types);
        let digital = inputs.digital();
        let tool = inputs.tool();
        let analog = [0, 1].map(|channel| {
            let kind = types.get(channel).copied().unwrap_or_default();
            inputs.analog(channel, kind).min(kind.max())
        });
        let status = robot.status();
        let telemetry = robot.telemetry();
        self.update(|image| {
            image.set_register(reg::DIGITAL_INPUTS, digital);
            image.set_register(reg::TOOL_INPUTS, u16::from(tool));
            for ((address, _), value) in io::ANALOG_INPUT_REGISTERS.into_iter().zip(analog) {
                image.set_register(address, value);
            }
            self.version.apply(image);
            status.apply(image);
            telemetry.apply(image);
        });
    }
}

/// The 100 ms task's body: refresh, check the communication watchdog, then
/// wait for the next period. Each binary wraps it in a task with its own
/// pins and robot.
pub async fn refresh_loop(shared: &Shared<'_>, inputs: &mut impl InputPins, robot: &mut impl Robot) -> ! {
    let mut ticker = Ticker::every(REFRESH_PERIOD);
    loop {
        shared.refresh(inputs, robot);
        shared.check_watchdog();
        ticker.next().await;
    }
}

#[cfg(test)]
pub(crate) mod testing;
#[cfg(test)]
mod tests;
