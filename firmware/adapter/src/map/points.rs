//! The seam's values in the image: where [`crate::io`]'s types live in the
//! register map, and the image's accessors that read and write them.

use super::Image;
use super::table::reg;
use crate::io::{ANALOG_CHANNELS, AnalogOutput, AnalogType, Outputs, RobotStatus, Six, Telemetry, Version};

/// Analog outputs 1 and 2: (value register, type register).
pub const ANALOG_OUTPUT_REGISTERS: [(u16, u16); ANALOG_CHANNELS] =
    [(reg::ANALOG_OUTPUT_1, reg::ANALOG_OUTPUT_1_TYPE), (reg::ANALOG_OUTPUT_2, reg::ANALOG_OUTPUT_2_TYPE)];
/// Analog inputs 1 and 2: (value register, type register).
pub const ANALOG_INPUT_REGISTERS: [(u16, u16); ANALOG_CHANNELS] =
    [(reg::ANALOG_INPUT_1, reg::ANALOG_INPUT_1_TYPE), (reg::ANALOG_INPUT_2, reg::ANALOG_INPUT_2_TYPE)];

impl Image {
    /// The outputs as a master set them.
    pub fn outputs(&self) -> Outputs {
        let analog = ANALOG_OUTPUT_REGISTERS.map(|(value, kind)| AnalogOutput {
            value: self.register(value),
            kind: AnalogType::from_register(self.register(kind)),
        });
        let [tool, _] = self.register(reg::TOOL_OUTPUTS).to_le_bytes();
        Outputs {
            digital: self.register(reg::DIGITAL_OUTPUTS),
            tool,
            analog,
            analog_input_types: self.analog_input_types(),
        }
    }

    /// The analog input types the master selected.
    pub fn analog_input_types(&self) -> [AnalogType; ANALOG_CHANNELS] {
        ANALOG_INPUT_REGISTERS.map(|(_, kind)| AnalogType::from_register(self.register(kind)))
    }

    /// Analog input `channel`'s reading, clamped to its type's range; other channels are ignored.
    pub fn set_analog_input(&mut self, channel: usize, value: u16) {
        let types = self.analog_input_types();
        if let (Some(kind), Some(&(address, _))) = (types.get(channel), ANALOG_INPUT_REGISTERS.get(channel)) {
            self.set_register(address, value.min(kind.max()));
        }
    }

    /// Analog input `channel`'s reading (0 for a channel that does not exist).
    pub fn analog_input(&self, channel: usize) -> u16 {
        ANALOG_INPUT_REGISTERS.get(channel).map_or(0, |&(address, _)| self.register(address))
    }

    /// Registers 259-264 (coils 260-265 are views of them).
    pub fn set_robot_status(&mut self, status: &RobotStatus) {
        self.set_registers(reg::ROBOT_STATE, &status.registers());
    }

    /// Registers 270-435 (the gaps stay 0).
    pub fn set_telemetry(&mut self, telemetry: &Telemetry) {
        let signed = |values: &Six| values.map(|v| v as u16);
        self.set_registers(reg::JOINT_POSITION, &signed(&telemetry.joint_position));
        self.set_registers(reg::JOINT_VELOCITY, &signed(&telemetry.joint_velocity));
        self.set_registers(reg::JOINT_CURRENT, &telemetry.joint_current);
        self.set_registers(reg::JOINT_TEMPERATURE, &telemetry.joint_temperature);
        self.set_registers(reg::JOINT_TORQUE, &signed(&telemetry.joint_torque));
        self.set_registers(reg::TASK_POSITION, &signed(&telemetry.task_pose));
        self.set_registers(reg::TASK_VELOCITY, &signed(&telemetry.task_velocity));
        self.set_registers(reg::TOOL_OFFSET_LENGTH, &signed(&telemetry.tool_offset));
        self.set_registers(reg::EXTERNAL_FORCE, &signed(&telemetry.external_wrench));
    }

    /// Registers 256-258: the robot controller's version.
    pub fn set_controller_version(&mut self, version: &Version) {
        self.set_registers(reg::CONTROLLER_VERSION, &version.registers());
    }
}
