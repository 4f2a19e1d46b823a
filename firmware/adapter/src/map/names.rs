//! The map's points by name, with their units and scales, for the tools
//! that read and write a device by name (`mbio read cell-3
//! robot.joint_position`). A name picks registers of [`super::table`];
//! what they hold (pins, a number, an analog value, a state), who may
//! write them, and which coils view them come from the table itself
//! ([`Point::row`], [`pin_coil`]), so the names add only what the table has
//! no room for: the name, the unit and the scale.
//!
//! Nothing in the firmware uses this table, so no image carries its
//! strings (the linker drops an unused static).

use super::table::{COILS, CoilView, RegisterRow, reg, register_row};

/// A named point: `count` registers from `register`, each holding the
/// value times 10^`decimals`, in `unit`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Point {
    /// `group.point`, lower case (`di`, `ao.1`, `robot.joint_position`).
    pub name: &'static str,
    /// The first register.
    pub register: u16,
    /// Registers in the point (a pin mask is one register of several pins).
    pub count: u16,
    /// The unit of the scaled value: `""` for none; an analog value's unit
    /// is its type register's (mA or V), so it is `""` here.
    pub unit: &'static str,
    /// The register holds the value times 10^`decimals`.
    pub decimals: u8,
    /// What the point is, for a listing.
    pub about: &'static str,
}

impl Point {
    /// The table's row of the point's first register: every register of a
    /// point has the same access and encoding (tested).
    pub fn row(&self) -> Option<&'static RegisterRow> {
        register_row(self.register)
    }
}

const fn p(
    name: &'static str,
    register: u16,
    count: u16,
    unit: &'static str,
    decimals: u8,
    about: &'static str,
) -> Point {
    Point { name, register, count, unit, decimals, about }
}

/// Every named point, in register order.
#[rustfmt::skip]
pub static POINTS: [Point; 33] = [
    p("di", reg::DIGITAL_INPUTS, 1, "", 0, "ControlBox digital inputs 1-16"),
    p("do", reg::DIGITAL_OUTPUTS, 1, "", 0, "ControlBox digital outputs 1-16"),
    p("ai.1", reg::ANALOG_INPUT_1, 1, "", 3, "ControlBox analog input 1 (mA or V, as its type)"),
    p("ai.1.type", reg::ANALOG_INPUT_1_TYPE, 1, "", 0, "analog input 1's type: current or voltage"),
    p("ai.2", reg::ANALOG_INPUT_2, 1, "", 3, "ControlBox analog input 2 (mA or V, as its type)"),
    p("ai.2.type", reg::ANALOG_INPUT_2_TYPE, 1, "", 0, "analog input 2's type: current or voltage"),
    p("ao.1", reg::ANALOG_OUTPUT_1, 1, "", 3, "ControlBox analog output 1 (mA or V, as its type)"),
    p("ao.1.type", reg::ANALOG_OUTPUT_1_TYPE, 1, "", 0, "analog output 1's type: current or voltage"),
    p("ao.2", reg::ANALOG_OUTPUT_2, 1, "", 3, "ControlBox analog output 2 (mA or V, as its type)"),
    p("ao.2.type", reg::ANALOG_OUTPUT_2_TYPE, 1, "", 0, "analog output 2's type: current or voltage"),
    p("tool_di", reg::TOOL_INPUTS, 1, "", 0, "tool digital inputs 1-6"),
    p("tool_do", reg::TOOL_OUTPUTS, 1, "", 0, "tool digital outputs 1-6"),
    p("gp", reg::GENERAL_PURPOSE, 128, "", 0, "general purpose registers 1-128"),
    p("robot.controller_version", reg::CONTROLLER_VERSION, 3, "", 0, "robot controller version: major, minor, patch"),
    p("robot.state", reg::ROBOT_STATE, 1, "", 0, "robot state"),
    p("robot.servo_on", reg::SERVO_ON, 1, "", 0, "servo on"),
    p("robot.emergency_stop", reg::EMERGENCY_STOP, 1, "", 0, "emergency stopped"),
    p("robot.safety_stop", reg::SAFETY_STOP, 1, "", 0, "safety stopped: 0 no, 1 yes, 2 recovery mode needed"),
    p("robot.direct_teach", reg::DIRECT_TEACH, 1, "", 0, "direct teach button pressed"),
    p("robot.power_button", reg::POWER_BUTTON, 1, "", 0, "power button pressed"),
    p("robot.joint_position", reg::JOINT_POSITION, 6, "deg", 1, "joint positions 1-6"),
    p("robot.joint_velocity", reg::JOINT_VELOCITY, 6, "deg/s", 1, "joint velocities 1-6"),
    p("robot.joint_current", reg::JOINT_CURRENT, 6, "mA", 0, "joint motor currents 1-6"),
    p("robot.joint_temperature", reg::JOINT_TEMPERATURE, 6, "degC", 0, "joint motor temperatures 1-6"),
    p("robot.joint_torque", reg::JOINT_TORQUE, 6, "N m", 0, "joint torques 1-6"),
    p("robot.task_position", reg::TASK_POSITION, 3, "mm", 1, "task position X Y Z (base frame)"),
    p("robot.task_orientation", reg::TASK_ORIENTATION, 3, "deg", 1, "task orientation A B C (Euler ZYZ)"),
    p("robot.task_velocity", reg::TASK_VELOCITY, 3, "mm/s", 1, "task velocity X Y Z"),
    p("robot.task_angular_velocity", reg::TASK_ANGULAR_VELOCITY, 3, "deg/s", 1, "task angular velocity A B C"),
    p("robot.tool_offset_position", reg::TOOL_OFFSET_LENGTH, 3, "mm", 1, "tool offset X Y Z"),
    p("robot.tool_offset_orientation", reg::TOOL_OFFSET_DEGREE, 3, "deg", 1, "tool offset A B C"),
    p("robot.external_force", reg::EXTERNAL_FORCE, 3, "N", 0, "external force X Y Z"),
    p("robot.external_moment", reg::EXTERNAL_MOMENT, 3, "N m", 0, "external moment X Y Z"),
];

/// The named point `name` (exactly as in [`POINTS`]).
pub fn point(name: &str) -> Option<&'static Point> {
    POINTS.iter().find(|point| point.name == name)
}

/// The coil that views pin `pin` (counted from 1) of the pin mask in
/// `register`, from the coil table: `None` for a register no coil row
/// views bit by bit, or a pin beyond the row.
pub fn pin_coil(register: u16, pin: u8) -> Option<u16> {
    let bit = u16::from(pin.checked_sub(1)?);
    COILS.iter().find_map(|row| match row.view {
        CoilView::Bit { register: viewed, bit: first } if viewed == register => {
            let offset = bit.checked_sub(u16::from(first))?;
            let coil = row.first.checked_add(offset)?;
            (coil <= row.last).then_some(coil)
        }
        _ => None,
    })
}

/// The robot state register's values by name (docs/data-map.md, "Robot
/// state"), as the API, the page and host tools show them; `unknown` for
/// a code the map gives no name.
pub const fn robot_state_name(code: u16) -> &'static str {
    match code {
        0 => "initializing",
        1 => "standby",
        2 => "operating",
        3 => "safe_off",
        4 => "teaching",
        5 => "safe_stop",
        6 => "emergency_stop",
        7 => "homing",
        8 => "recovery",
        9 => "safe_stop_2",
        10 => "safe_off_2",
        15 => "not_ready",
        _ => "unknown",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{Encoding, Permission};

    #[test]
    fn every_points_registers_share_access_and_encoding_and_names_are_unique() {
        for (i, point) in POINTS.iter().enumerate() {
            let row = point.row().unwrap();
            assert_ne!(row.access, Permission::Reserved, "{}", point.name);
            assert!(point.count >= 1, "{}", point.name);
            let last = point.register + point.count - 1;
            for address in point.register..=last {
                let other = register_row(address).unwrap();
                assert_eq!((other.access, other.encoding), (row.access, row.encoding), "{} at {address}", point.name);
            }
            assert!(POINTS[i + 1..].iter().all(|other| other.name != point.name), "{} twice", point.name);
            if let Some(next) = POINTS.get(i + 1) {
                assert!(next.register > last, "{} overlaps or is out of order", next.name);
            }
            // Scaled or with a unit: a plain number (or an analog value).
            if point.decimals > 0 || !point.unit.is_empty() {
                assert!(matches!(row.encoding, Encoding::Signed | Encoding::Unsigned | Encoding::Analog { .. }));
            }
        }
    }

    #[test]
    fn the_named_rows_cover_every_row_that_is_not_reserved() {
        for row in crate::map::table::REGISTERS.iter().filter(|row| row.access != Permission::Reserved) {
            for address in row.first..=row.last {
                let named = POINTS.iter().any(|p| (p.register..p.register + p.count).contains(&address));
                assert!(named, "register {address} ({}) has no name", row.name);
            }
        }
    }

    #[test]
    fn names_units_and_coils() {
        let joints = point("robot.joint_position").unwrap();
        assert_eq!((joints.register, joints.count, joints.unit, joints.decimals), (270, 6, "deg", 1));
        assert_eq!(joints.row().unwrap().encoding, Encoding::Signed);
        assert!(point("robot.joint").is_none());
        assert_eq!(point("do").unwrap().row().unwrap().access, Permission::ReadWrite);
        assert_eq!(pin_coil(reg::DIGITAL_OUTPUTS, 1), Some(16));
        assert_eq!(pin_coil(reg::DIGITAL_OUTPUTS, 3), Some(18));
        assert_eq!(pin_coil(reg::DIGITAL_OUTPUTS, 16), Some(31));
        assert_eq!(pin_coil(reg::DIGITAL_OUTPUTS, 17), None);
        assert_eq!(pin_coil(reg::DIGITAL_INPUTS, 16), Some(15));
        assert_eq!(pin_coil(reg::TOOL_OUTPUTS, 6), Some(43));
        assert_eq!(pin_coil(reg::TOOL_OUTPUTS, 7), None);
        assert_eq!(pin_coil(reg::TOOL_INPUTS, 0), None);
        assert_eq!(pin_coil(reg::ROBOT_STATE, 1), None);
    }
}
