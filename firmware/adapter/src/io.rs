//! The hardware seam: what a board (or hal-sim) provides to the shared logic.
//!
//! - [`OutputPins`]: drives outputs as soon as a master's write lands.
//! - [`InputPins`]: samples inputs; boards also push input edges into the image
//!   at once through [`crate::device::Device`].
//! - [`Robot`]: the robot controller's status, telemetry and version.
//!
//! Traits and the values that cross them, nothing else: how they map to
//! registers is the map's business ([`crate::map::points`]).

use crate::map::table;

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
        if value == table::ANALOG_VOLTAGE { Self::Voltage } else { Self::Current }
    }

    /// The value a type register holds for this type.
    pub const fn register(self) -> u16 {
        match self {
            Self::Current => table::ANALOG_CURRENT,
            Self::Voltage => table::ANALOG_VOLTAGE,
        }
    }

    /// The largest valid value: µA or mV.
    pub const fn max(self) -> u16 {
        match self {
            Self::Current => table::ANALOG_MAX_MICROAMPS,
            Self::Voltage => table::ANALOG_MAX_MILLIVOLTS,
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
/// (an e-stop, a button) are pushed at once through [`crate::device::Device::update`].
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

/// A version: the robot controller's (registers 256-258, from the
/// [`Robot`] source), or this firmware's ([`crate::VERSION`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Version {
    pub major: u16,
    pub minor: u16,
    pub patch: u16,
}

impl Version {
    /// No version known: 0.0.0, what registers 256-258 hold without a robot source.
    pub const NONE: Self = Self { major: 0, minor: 0, patch: 0 };

    /// Registers 256-258 as the map holds them.
    pub const fn registers(&self) -> [u16; 3] {
        [self.major, self.minor, self.patch]
    }

    /// Writes `major.minor.patch`.
    pub fn write_to(&self, out: &mut dyn core::fmt::Write) -> core::fmt::Result {
        for (i, part) in self.registers().into_iter().enumerate() {
            if i > 0 {
                out.write_str(".")?;
            }
            crate::text::write_decimal(out, part)?;
        }
        Ok(())
    }
}
