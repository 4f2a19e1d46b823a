//! The hardware seam: what a board (or hal-sim) provides to the adapter's
//! portable core, as embassy-net-driver is the network's.
//!
//! - [`OutputPins`]: drives outputs as soon as a master's write lands.
//! - [`InputPins`]: samples inputs; boards also push input edges into the
//!   image at once (the adapter's `device::Device::update`).
//! - [`Robot`]: the robot controller's status, telemetry and version.
//!
//! Traits and the values that cross them, nothing else: how they map to
//! registers is the adapter's map (`adapter::map::points`). A robot source
//! (the simulated robot, a board's own) needs only this crate.
#![no_std]

/// The analog type register's values and each type's range (the data map's
/// analog points).
pub mod analog {
    /// The analog type register value for current (µA) mode.
    pub const CURRENT: u16 = 0;
    /// The analog type register value for voltage (mV) mode.
    pub const VOLTAGE: u16 = 1;
    /// The largest analog value in current mode: 20 mA in µA.
    pub const MAX_MICROAMPS: u16 = 20_000;
    /// The largest analog value in voltage mode: 10 V in mV.
    pub const MAX_MILLIVOLTS: u16 = 10_000;
}

/// What an analog point measures or drives (its type register).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AnalogType {
    /// 0..=20 000 µA (type register 0).
    #[default]
    Current,
    /// 0..=10 000 mV (type register 1).
    Voltage,
}

impl AnalogType {
    /// The type a type register holds (anything but 1 is current).
    pub const fn from_register(value: u16) -> Self {
        if value == analog::VOLTAGE { Self::Voltage } else { Self::Current }
    }

    /// The value a type register holds for this type.
    pub const fn register(self) -> u16 {
        match self {
            Self::Current => analog::CURRENT,
            Self::Voltage => analog::VOLTAGE,
        }
    }

    /// The largest valid value: µA or mV.
    pub const fn max(self) -> u16 {
        match self {
            Self::Current => analog::MAX_MICROAMPS,
            Self::Voltage => analog::MAX_MILLIVOLTS,
        }
    }
}

/// Analog channels on the ControlBox (inputs and outputs alike).
pub const ANALOG_CHANNELS: usize = 2;

/// One analog output: value in thousandths of the unit its type selects.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AnalogOutput {
    pub value: u16,
    pub kind: AnalogType,
}

/// Everything the master drives, as the board must apply it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Outputs {
    /// ControlBox digital outputs: bit n = output n + 1.
    pub digital: u16,
    /// Tool digital outputs: bit n = output n + 1 (6 used).
    pub tool: u8,
    pub analog: [AnalogOutput; ANALOG_CHANNELS],
    /// The type the master selected for each analog input (the front end's mode).
    pub analog_input_types: [AnalogType; ANALOG_CHANNELS],
}

/// Drives the outputs. Called with the image locked, right after a write
/// that changed them, so it must be quick and must not block.
pub trait OutputPins: Sync {
    fn drive(&self, outputs: &Outputs);
}

/// Samples the inputs (the 100 ms refresh re-asserts them from here).
pub trait InputPins {
    /// ControlBox digital inputs: bit n = input n + 1.
    fn digital(&mut self) -> u16;
    /// Tool digital inputs: bit n = input n + 1 (6 used).
    fn tool(&mut self) -> u8;
    /// Analog input `channel` (0 or 1) in thousandths of `kind`'s unit, clamped to its range.
    fn analog(&mut self, channel: usize, kind: AnalogType) -> u16;
}

/// The robot controller's state (register 259, docs/data-map.md *Robot state*).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum RobotState {
    Initializing = 0,
    Standby = 1,
    Operating = 2,
    SafeOff = 3,
    Teaching = 4,
    SafeStop = 5,
    EmergencyStop = 6,
    Homing = 7,
    Recovery = 8,
    SafeStop2 = 9,
    SafeOff2 = 10,
    NotReady = 15,
}

/// Register 262.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u16)]
pub enum SafetyStop {
    #[default]
    No = 0,
    Stopped = 1,
    /// Safety stopped; recovery mode needed (coil 265).
    NeedsRecovery = 2,
}

/// The robot's status flags (registers 259-264; coils 260-265 are views).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RobotStatus {
    pub state: RobotState,
    pub servo_on: bool,
    pub emergency_stop: bool,
    pub safety_stop: SafetyStop,
    pub direct_teach: bool,
    pub power_button: bool,
}

impl RobotStatus {
    /// What a gateway with no robot source reports.
    pub const NOT_READY: Self = Self {
        state: RobotState::NotReady,
        servo_on: false,
        emergency_stop: false,
        safety_stop: SafetyStop::No,
        direct_teach: false,
        power_button: false,
    };

    /// Registers 259-264 as the map holds them.
    pub const fn registers(&self) -> [u16; 6] {
        [
            self.state as u16,
            self.servo_on as u16,
            self.emergency_stop as u16,
            self.safety_stop as u16,
            self.direct_teach as u16,
            self.power_button as u16,
        ]
    }
}

/// Six values, one per joint or per Cartesian axis (X Y Z then A B C / RX RY RZ).
pub type Six = [i16; 6];

/// The robot's periodic data (registers 270-435), in the map's units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Telemetry {
    /// 0.1 deg.
    pub joint_position: Six,
    /// 0.1 deg/s.
    pub joint_velocity: Six,
    /// mA.
    pub joint_current: [u16; 6],
    /// degC.
    pub joint_temperature: [u16; 6],
    /// N m.
    pub joint_torque: Six,
    /// X Y Z in 0.1 mm, then A B C (Euler ZYZ) in 0.1 deg; base frame.
    pub task_pose: Six,
    /// X Y Z in 0.1 mm/s, then RX RY RZ in 0.1 deg/s; base frame.
    pub task_velocity: Six,
    /// X Y Z in 0.1 mm, then A B C in 0.1 deg; tool frame.
    pub tool_offset: Six,
    /// Force X Y Z in N, then moment X Y Z in N m; base frame.
    pub external_wrench: Six,
}

/// The robot data source, sampled by the 100 ms refresh. Event-class changes
/// (an e-stop, a button) are pushed at once (the adapter's `device::Device::update`).
pub trait Robot {
    fn status(&mut self) -> RobotStatus;
    fn telemetry(&mut self) -> Telemetry;
    /// The controller's version (registers 256-258); [`Version::NONE`]
    /// while the source does not know it.
    fn version(&mut self) -> Version;

    /// What the refresh applies to the robot's points, as one whole; `None`
    /// when this source does not feed them through the refresh (the robot
    /// link applies each of its polls itself, `link`).
    fn sample(&mut self) -> Option<RobotSample> {
        Some(RobotSample { status: self.status(), telemetry: self.telemetry(), version: self.version() })
    }
}

/// One sample of every robot point, applied to the image under one lock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RobotSample {
    pub status: RobotStatus,
    pub telemetry: Telemetry,
    pub version: Version,
}

/// No robot link: NOT READY and zeros (docs/data-map.md, *Robot state*).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoRobot;

impl Robot for NoRobot {
    fn status(&mut self) -> RobotStatus {
        RobotStatus::NOT_READY
    }

    fn telemetry(&mut self) -> Telemetry {
        Telemetry::default()
    }

    fn version(&mut self) -> Version {
        Version::NONE
    }
}

/// A version, major.minor.patch: the robot controller's (registers
/// 256-258, from the [`Robot`] source), this firmware's (the adapter's
/// `VERSION`), or an update file's (update-image's header).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Version {
    pub major: u16,
    pub minor: u16,
    pub patch: u16,
}

impl Version {
    /// No version known: 0.0.0, what registers 256-258 hold without a robot source.
    pub const NONE: Self = Self { major: 0, minor: 0, patch: 0 };

    /// The longest version as text (`65535.65535.65535`).
    pub const MAX_TEXT_LEN: usize = 17;

    /// Registers 256-258 as the map holds them.
    pub const fn registers(&self) -> [u16; 3] {
        [self.major, self.minor, self.patch]
    }

    /// Parses `X.Y.Z`, each part a decimal `u16`.
    pub fn parse(text: &str) -> Option<Self> {
        let mut parts = text.split('.');
        let mut next = || -> Option<u16> {
            let part = parts.next()?;
            if part.is_empty() || !part.bytes().all(|b| b.is_ascii_digit()) {
                return None;
            }
            part.parse().ok()
        };
        let version = Self { major: next()?, minor: next()?, patch: next()? };
        parts.next().is_none().then_some(version)
    }
}

impl core::fmt::Display for Version {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}
