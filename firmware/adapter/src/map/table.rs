//! The data map of `docs/data-map.md`, written once as data.
//!
//! Every address of the coil space (0..=265) and the register space (0..=435)
//! belongs to exactly one row; reserved ranges are rows too, so the tables are
//! total and sorted (checked by the tests below). The process image stores
//! registers only: each coil is a *view* of a register, so the two views of the
//! same pin or flag cannot disagree.

/// What a master may do with an address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Permission {
    /// Reads 0; any write is exception 02.
    Reserved,
    /// Driven by a source (pins, robot, boot). Writes follow the write policy.
    Read,
    /// Written by the master; reads back the last value written.
    Write,
    /// Read and written by the master.
    ReadWrite,
}

impl Permission {
    /// Whether a write is accepted under the `strict` policy.
    pub const fn writable(self) -> bool {
        matches!(self, Self::Write | Self::ReadWrite)
    }
}

/// When a point changes (docs/data-map.md, *Update classes*).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Update {
    /// Never: reserved.
    Never,
    /// Only a master's write changes it (general purpose registers).
    Master,
    /// As soon as its source changes: a pin edge, a robot event, a write.
    Event,
    /// Refreshed by the 100 ms task.
    Every100Ms,
    /// Set once at start-up.
    Boot,
}

/// How a register's 16 bits are read, and which values it accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Encoding {
    /// Reserved: always 0.
    Zero,
    /// A pin mask: bit n is pin n + 1; bits above `pins` must be 0.
    Pins { pins: u8 },
    /// Thousandths of the unit the type register at `type_register` selects:
    /// µA, 0..=20 000, when it is 0 (current); mV, 0..=10 000, when it is 1 (voltage).
    Analog { type_register: u16 },
    /// 0 = current, 1 = voltage.
    AnalogType,
    /// 0 or 1.
    Bool,
    /// 0 = no, 1 = safety stopped, 2 = safety stopped, recovery mode needed.
    SafetyStop,
    /// A robot state: 0..=10 or 15 (docs/data-map.md, *Robot state*).
    RobotState,
    /// A plain unsigned number.
    Unsigned,
    /// Two's complement `i16`.
    Signed,
}

/// The analog type register's values and each type's range, as the
/// hardware seam defines them.
pub use crate::io::analog::{
    CURRENT as ANALOG_CURRENT, MAX_MICROAMPS as ANALOG_MAX_MICROAMPS, MAX_MILLIVOLTS as ANALOG_MAX_MILLIVOLTS,
    VOLTAGE as ANALOG_VOLTAGE,
};
/// Robot state NOT READY: what a gateway with no robot source reports.
pub const ROBOT_NOT_READY: u16 = 15;

impl Encoding {
    /// Whether `value` is valid for this encoding. For [`Encoding::Analog`],
    /// `analog_type` is the type in force once the write is applied.
    pub const fn accepts(self, value: u16, analog_type: u16) -> bool {
        match self {
            Self::Zero => value == 0,
            Self::Pins { pins } => pins >= 16 || value >> pins == 0,
            Self::Analog { .. } => match analog_type {
                ANALOG_CURRENT => value <= ANALOG_MAX_MICROAMPS,
                ANALOG_VOLTAGE => value <= ANALOG_MAX_MILLIVOLTS,
                _ => false,
            },
            Self::AnalogType | Self::Bool => value <= 1,
            Self::SafetyStop => value <= 2,
            Self::RobotState => value <= 10 || value == ROBOT_NOT_READY,
            Self::Unsigned | Self::Signed => true,
        }
    }

    /// Whether every `u16` is valid, so a write needs no per-value check.
    pub const fn accepts_all(self) -> bool {
        matches!(self, Self::Unsigned | Self::Signed) || matches!(self, Self::Pins { pins } if pins >= 16)
    }
}

/// A run of holding registers that share access, update class and encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegisterRow {
    /// First address of the run.
    pub first: u16,
    /// Last address of the run (inclusive).
    pub last: u16,
    pub access: Permission,
    pub update: Update,
    pub encoding: Encoding,
    /// The point's name, as in docs/data-map.md (for test messages; the table's
    /// source text names every row for readers).
    #[cfg(test)]
    pub name: &'static str,
}

/// How a coil is seen in the registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CoilView {
    /// Reads 0.
    Reserved,
    /// Coil `row.first + i` is bit `bit + i` of `register`.
    Bit { register: u16, bit: u8 },
    /// The coil is on while `register` is not 0; writing on stores 1 (if it
    /// was 0), writing off stores 0.
    NonZero { register: u16 },
    /// The coil is on while `register == on`; writing on stores `on`, writing
    /// off stores `off` (if it was `on`).
    Equals { register: u16, on: u16, off: u16 },
}

/// A run of coils that share access, update class and view.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CoilRow {
    pub first: u16,
    pub last: u16,
    pub access: Permission,
    pub update: Update,
    pub view: CoilView,
    /// The point's name (test builds only, as for [`RegisterRow`]).
    #[cfg(test)]
    pub name: &'static str,
}

/// Register addresses that code elsewhere names.
pub mod reg {
    pub const DIGITAL_INPUTS: u16 = 0;
    pub const DIGITAL_OUTPUTS: u16 = 1;
    pub const ANALOG_INPUT_1: u16 = 4;
    pub const ANALOG_INPUT_1_TYPE: u16 = 5;
    pub const ANALOG_INPUT_2: u16 = 6;
    pub const ANALOG_INPUT_2_TYPE: u16 = 7;
    pub const ANALOG_OUTPUT_1: u16 = 16;
    pub const ANALOG_OUTPUT_1_TYPE: u16 = 17;
    pub const ANALOG_OUTPUT_2: u16 = 18;
    pub const ANALOG_OUTPUT_2_TYPE: u16 = 19;
    pub const TOOL_INPUTS: u16 = 21;
    pub const TOOL_OUTPUTS: u16 = 22;
    pub const GENERAL_PURPOSE: u16 = 128;
    /// The robot controller's version: major, then minor (257) and patch (258).
    pub const CONTROLLER_VERSION: u16 = 256;
    pub const ROBOT_STATE: u16 = 259;
    pub const SERVO_ON: u16 = 260;
    pub const EMERGENCY_STOP: u16 = 261;
    pub const SAFETY_STOP: u16 = 262;
    pub const DIRECT_TEACH: u16 = 263;
    pub const POWER_BUTTON: u16 = 264;
    pub const JOINT_POSITION: u16 = 270;
    pub const JOINT_VELOCITY: u16 = 280;
    pub const JOINT_CURRENT: u16 = 290;
    pub const JOINT_TEMPERATURE: u16 = 300;
    pub const JOINT_TORQUE: u16 = 310;
    pub const TASK_POSITION: u16 = 400;
    pub const TASK_ORIENTATION: u16 = 403;
    pub const TASK_VELOCITY: u16 = 410;
    pub const TASK_ANGULAR_VELOCITY: u16 = 413;
    pub const TOOL_OFFSET_LENGTH: u16 = 420;
    pub const TOOL_OFFSET_DEGREE: u16 = 423;
    pub const EXTERNAL_FORCE: u16 = 430;
    pub const EXTERNAL_MOMENT: u16 = 433;
    /// The last register of the map.
    pub const LAST: u16 = 435;
}

/// Coil addresses that code elsewhere names.
pub mod coil {
    pub const DIGITAL_INPUTS: u16 = 0;
    pub const DIGITAL_OUTPUTS: u16 = 16;
    pub const TOOL_INPUTS: u16 = 32;
    pub const TOOL_OUTPUTS: u16 = 38;
    pub const SERVO_ON: u16 = 260;
    pub const EMERGENCY_STOP: u16 = 261;
    pub const SAFETY_STOP: u16 = 262;
    pub const DIRECT_TEACH: u16 = 263;
    pub const POWER_BUTTON: u16 = 264;
    pub const SAFETY_STOP_RECOVERY: u16 = 265;
    /// The last coil of the map.
    pub const LAST: u16 = 265;
}

/// Registers in the map (0..=435).
pub const REGISTER_COUNT: usize = reg::LAST as usize + 1;
/// Coils in the map (0..=265).
pub const COIL_COUNT: usize = coil::LAST as usize + 1;

/// ControlBox digital inputs and outputs.
pub const DIGITAL_PINS: u8 = 16;
/// Tool digital inputs and outputs.
pub const TOOL_PINS: u8 = 6;

use Encoding::*;
use Permission::{Read, ReadWrite, Reserved, Write};
use Update::{Boot, Event, Every100Ms, Master, Never};

const fn r(
    first: u16,
    last: u16,
    access: Permission,
    update: Update,
    encoding: Encoding,
    name: &'static str,
) -> RegisterRow {
    let _ = name; // stored in test builds only: the image keeps no strings
    RegisterRow {
        first,
        last,
        access,
        update,
        encoding,
        #[cfg(test)]
        name,
    }
}

const fn gap(first: u16, last: u16) -> RegisterRow {
    r(first, last, Reserved, Never, Zero, "reserved")
}

/// The holding registers (docs/data-map.md, *Holding registers*), in address order.
#[rustfmt::skip]
pub static REGISTERS: [RegisterRow; 44] = [
    r(0, 0, Read, Event, Pins { pins: DIGITAL_PINS }, "ControlBox digital input 1-16"),
    r(1, 1, ReadWrite, Event, Pins { pins: DIGITAL_PINS }, "ControlBox digital output 1-16"),
    gap(2, 3),
    r(4, 4, Read, Event, Analog { type_register: reg::ANALOG_INPUT_1_TYPE }, "ControlBox analog input 1"),
    r(5, 5, ReadWrite, Event, AnalogType, "ControlBox analog input 1 type"),
    r(6, 6, Read, Event, Analog { type_register: reg::ANALOG_INPUT_2_TYPE }, "ControlBox analog input 2"),
    r(7, 7, ReadWrite, Event, AnalogType, "ControlBox analog input 2 type"),
    gap(8, 15),
    r(16, 16, Write, Event, Analog { type_register: reg::ANALOG_OUTPUT_1_TYPE }, "ControlBox analog output 1"),
    r(17, 17, Write, Event, AnalogType, "ControlBox analog output 1 type"),
    r(18, 18, Write, Event, Analog { type_register: reg::ANALOG_OUTPUT_2_TYPE }, "ControlBox analog output 2"),
    r(19, 19, Write, Event, AnalogType, "ControlBox analog output 2 type"),
    gap(20, 20),
    r(21, 21, Read, Every100Ms, Pins { pins: TOOL_PINS }, "Tool digital input 1-6"),
    r(22, 22, Write, Every100Ms, Pins { pins: TOOL_PINS }, "Tool digital output 1-6"),
    gap(23, 127),
    r(128, 255, ReadWrite, Master, Unsigned, "general purpose register"),
    r(256, 256, Read, Boot, Unsigned, "controller major version"),
    r(257, 257, Read, Boot, Unsigned, "controller minor version"),
    r(258, 258, Read, Boot, Unsigned, "controller patch version"),
    r(259, 259, Read, Event, RobotState, "robot state"),
    r(260, 260, Read, Event, Bool, "servo on"),
    r(261, 261, Read, Event, Bool, "emergency stopped"),
    r(262, 262, Read, Event, SafetyStop, "safety stopped"),
    r(263, 263, Read, Event, Bool, "direct teach button pressed"),
    r(264, 264, Read, Event, Bool, "power button pressed"),
    gap(265, 269),
    r(270, 275, Read, Every100Ms, Signed, "joint position 1-6 (0.1 deg)"),
    gap(276, 279),
    r(280, 285, Read, Every100Ms, Signed, "joint velocity 1-6 (0.1 deg/s)"),
    gap(286, 289),
    r(290, 295, Read, Every100Ms, Unsigned, "joint motor current 1-6 (mA)"),
    gap(296, 299),
    r(300, 305, Read, Every100Ms, Unsigned, "joint motor temperature 1-6 (degC)"),
    gap(306, 309),
    r(310, 315, Read, Every100Ms, Signed, "joint torque 1-6 (N m)"),
    gap(316, 399),
    r(400, 405, Read, Every100Ms, Signed, "task position X Y Z (0.1 mm), orientation A B C (0.1 deg, ZYZ)"),
    gap(406, 409),
    r(410, 415, Read, Every100Ms, Signed, "task velocity X Y Z (0.1 mm/s), angular velocity (0.1 deg/s)"),
    gap(416, 419),
    r(420, 425, Read, Event, Signed, "tool offset X Y Z (0.1 mm), A B C (0.1 deg)"),
    gap(426, 429),
    r(430, 435, Read, Every100Ms, Signed, "task external force X Y Z (N), moment X Y Z (N m)"),
];

const fn c(first: u16, last: u16, access: Permission, view: CoilView, name: &'static str) -> CoilRow {
    let update = if matches!(view, CoilView::Reserved) { Never } else { Event };
    let _ = name; // stored in test builds only
    CoilRow {
        first,
        last,
        access,
        update,
        view,
        #[cfg(test)]
        name,
    }
}

/// The coils (docs/data-map.md, *Coils*), in address order.
#[rustfmt::skip]
pub static COILS: [CoilRow; 11] = [
    c(0, 15, Read, CoilView::Bit { register: reg::DIGITAL_INPUTS, bit: 0 }, "ControlBox digital input 1-16"),
    c(16, 31, ReadWrite, CoilView::Bit { register: reg::DIGITAL_OUTPUTS, bit: 0 }, "ControlBox digital output 1-16"),
    c(32, 37, Read, CoilView::Bit { register: reg::TOOL_INPUTS, bit: 0 }, "Tool digital input 1-6"),
    c(38, 43, ReadWrite, CoilView::Bit { register: reg::TOOL_OUTPUTS, bit: 0 }, "Tool digital output 1-6"),
    c(44, 259, Reserved, CoilView::Reserved, "reserved"),
    c(260, 260, Read, CoilView::NonZero { register: reg::SERVO_ON }, "servo on"),
    c(261, 261, Read, CoilView::NonZero { register: reg::EMERGENCY_STOP }, "emergency stopped"),
    c(262, 262, Read, CoilView::NonZero { register: reg::SAFETY_STOP }, "safety stopped"),
    c(263, 263, Read, CoilView::NonZero { register: reg::DIRECT_TEACH }, "direct teach button pressed"),
    c(264, 264, Read, CoilView::NonZero { register: reg::POWER_BUTTON }, "power button pressed"),
    c(265, 265, Read, CoilView::Equals { register: reg::SAFETY_STOP, on: 2, off: 1 }, "safety stopped, requiring recovery mode"),
];

/// The rows that cover `first..=last` of a sorted, total table, in order.
pub(crate) fn rows_in<T>(rows: &[T], first: u16, last: u16, bounds: impl Fn(&T) -> (u16, u16)) -> &[T] {
    let from = rows.partition_point(|row| bounds(row).1 < first);
    let to = rows.partition_point(|row| bounds(row).0 <= last);
    // `from <= to <= len` for a sorted table; were it not, no row covers the
    // range and the request gets exception 02 (fail closed).
    rows.get(from..to).unwrap_or_default()
}

/// The register row that holds `address`.
pub fn register_row(address: u16) -> Option<&'static RegisterRow> {
    rows_in(&REGISTERS, address, address, |r| (r.first, r.last)).first()
}

/// The coil row that holds `address`.
pub fn coil_row(address: u16) -> Option<&'static CoilRow> {
    rows_in(&COILS, address, address, |r| (r.first, r.last)).first()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_total(bounds: impl Iterator<Item = (u16, u16)>, count: usize) {
        let mut next = 0u16;
        for (first, last) in bounds {
            assert_eq!(first, next, "rows must be contiguous");
            assert!(last >= first);
            next = last + 1;
        }
        assert_eq!(usize::from(next), count);
    }

    #[test]
    fn tables_are_sorted_and_total() {
        assert_total(REGISTERS.iter().map(|r| (r.first, r.last)), REGISTER_COUNT);
        assert_total(COILS.iter().map(|r| (r.first, r.last)), COIL_COUNT);
    }

    #[test]
    fn reserved_rows_are_consistent() {
        for row in &REGISTERS {
            let reserved = row.access == Permission::Reserved;
            assert_eq!(reserved, row.encoding == Encoding::Zero, "{}", row.name);
            assert_eq!(reserved, row.update == Update::Never, "{}", row.name);
        }
        for row in &COILS {
            assert_eq!(row.access == Permission::Reserved, row.view == CoilView::Reserved, "{}", row.name);
        }
    }

    #[test]
    fn coil_views_point_at_matching_registers() {
        for row in &COILS {
            match row.view {
                CoilView::Bit { register, bit } => {
                    let target = register_row(register).unwrap();
                    let Encoding::Pins { pins } = target.encoding else { panic!("{}", row.name) };
                    assert_eq!(u16::from(bit) + row.last - row.first + 1, u16::from(pins), "{}", row.name);
                    assert_eq!(row.access.writable(), target.access.writable(), "{}", row.name);
                }
                CoilView::NonZero { register } | CoilView::Equals { register, .. } => {
                    assert_eq!(row.first, row.last);
                    assert_eq!(register_row(register).unwrap().access, Permission::Read);
                }
                CoilView::Reserved => {}
            }
        }
    }

    #[test]
    fn lookups() {
        assert_eq!(register_row(0).unwrap().name, "ControlBox digital input 1-16");
        assert_eq!(register_row(200).unwrap().first, 128);
        assert_eq!(register_row(435).unwrap().first, 430);
        assert!(register_row(436).is_none());
        assert_eq!(coil_row(265).unwrap().view, CoilView::Equals { register: 262, on: 2, off: 1 });
        assert!(coil_row(266).is_none());
        assert_eq!(rows_in(&REGISTERS, 0, 435, |r| (r.first, r.last)).len(), REGISTERS.len());
        assert_eq!(rows_in(&REGISTERS, 127, 129, |r| (r.first, r.last)).len(), 2);
    }

    #[test]
    fn encodings() {
        let analog = Analog { type_register: 17 };
        assert!(analog.accepts(20_000, ANALOG_CURRENT));
        assert!(!analog.accepts(20_001, ANALOG_CURRENT));
        assert!(analog.accepts(10_000, ANALOG_VOLTAGE));
        assert!(!analog.accepts(10_001, ANALOG_VOLTAGE));
        assert!(!analog.accepts(0, 2));
        assert!(Pins { pins: 6 }.accepts(0x3f, 0));
        assert!(!Pins { pins: 6 }.accepts(0x40, 0));
        assert!(Pins { pins: 16 }.accepts(0xffff, 0));
        assert!(RobotState.accepts(15, 0) && RobotState.accepts(10, 0));
        assert!(!RobotState.accepts(11, 0) && !RobotState.accepts(16, 0));
        assert!(SafetyStop.accepts(2, 0) && !SafetyStop.accepts(3, 0));
        assert!(!Zero.accepts(1, 0));
    }
}
