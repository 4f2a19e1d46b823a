//! The simulated board: input pins set through the control socket, output
//! pins driven by the masters' writes, and the simulated robot.
//!
//! Everything runs on the one executor thread: the 100 ms refresh and the
//! control socket's commands never interleave, so an input or a robot event
//! reaches the image and stays there (the refresh re-asserts what the pins
//! hold, not a stale copy).

use std::cell::{Cell, RefCell};

use adapter::device::Device;
use adapter::io::{
    ANALOG_CHANNELS, AnalogType, InputPins, OutputPins, Outputs, Robot, RobotStatus, Telemetry, Version,
};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use sim_robot::{Event, Refused, SimRobot};

/// The simulated input pins: what the control socket last set.
#[derive(Debug, Default)]
pub struct Inputs {
    digital: Cell<u16>,
    tool: Cell<u8>,
    /// Thousandths of the unit the input's type selects (µA or mV).
    analog: Cell<[u16; ANALOG_CHANNELS]>,
}

/// The simulated output pins: what the masters last drove.
pub struct OutputLatch {
    outputs: Mutex<CriticalSectionRawMutex, Cell<Outputs>>,
}

impl std::fmt::Debug for OutputLatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("OutputLatch").field(&self.get()).finish()
    }
}

impl OutputLatch {
    pub fn new() -> Self {
        Self { outputs: Mutex::new(Cell::new(Outputs::default())) }
    }

    /// What the output pins are driven to now.
    pub fn get(&self) -> Outputs {
        self.outputs.lock(Cell::get)
    }
}

impl OutputPins for OutputLatch {
    fn drive(&self, outputs: &Outputs) {
        let before = self.outputs.lock(|cell| cell.replace(*outputs));
        if before != *outputs {
            let [ao1, ao2] = outputs.analog;
            log::info!(
                "outputs: do {:#06x}, tool-do {:#04x}, ao1 {} {}, ao2 {} {}, ai types {:?}",
                outputs.digital,
                outputs.tool,
                ao1.value,
                unit(ao1.kind),
                ao2.value,
                unit(ao2.kind),
                outputs.analog_input_types.map(unit),
            );
        }
    }
}

/// The unit of an analog value of type `kind`.
pub fn unit(kind: AnalogType) -> &'static str {
    match kind {
        AnalogType::Current => "uA",
        AnalogType::Voltage => "mV",
    }
}

/// The board hal-sim simulates, shared by the refresh task and the control socket.
#[derive(Debug)]
pub struct Board {
    pub device: &'static Device<'static>,
    pub outputs: &'static OutputLatch,
    inputs: Inputs,
    robot: RefCell<SimRobot>,
}

impl Board {
    pub fn new(device: &'static Device<'static>, outputs: &'static OutputLatch, robot: SimRobot) -> Self {
        Self { device, outputs, inputs: Inputs::default(), robot: RefCell::new(robot) }
    }

    /// Digital input `pin` (0-based) on or off: an edge, in the image at once.
    pub fn set_digital_input(&self, pin: u8, on: bool) {
        let mask = with_bit(self.inputs.digital.get(), pin, on);
        self.inputs.digital.set(mask);
        self.device.set_digital_inputs(mask);
    }

    /// Tool digital input `pin` (0-based) on or off.
    pub fn set_tool_input(&self, pin: u8, on: bool) {
        let mask = with_bit(u16::from(self.inputs.tool.get()), pin, on).to_le_bytes()[0];
        self.inputs.tool.set(mask);
        self.device.set_tool_inputs(mask);
    }

    /// Analog input `channel` (0-based) reads `value`, in thousandths of the
    /// unit its type selects (clamped to that type's range in the image).
    pub fn set_analog_input(&self, channel: usize, value: u16) {
        let mut analog = self.inputs.analog.get();
        if let Some(slot) = analog.get_mut(channel) {
            *slot = value;
        }
        self.inputs.analog.set(analog);
        self.device.set_analog_input(channel, value);
    }

    /// The digital and tool input masks and the raw analog values.
    pub fn inputs(&self) -> (u16, u8, [u16; ANALOG_CHANNELS]) {
        (self.inputs.digital.get(), self.inputs.tool.get(), self.inputs.analog.get())
    }

    /// Applies a robot event and pushes the new status into the image at
    /// once (while no robot link is set: then the link feeds the image).
    pub fn robot_event(&self, event: Event) -> Result<RobotStatus, Refused> {
        let status = self.robot.borrow_mut().event(event)?;
        if !crate::ROBOT_LINK.is_set() {
            self.device.set_robot_status(&status);
        }
        Ok(status)
    }

    /// The robot's status now.
    pub fn robot_status(&self) -> RobotStatus {
        self.robot.borrow_mut().status()
    }

    /// The 100 ms refresh's view of the pins and the robot.
    pub fn sources(&self) -> (PinReader<'_>, RobotReader<'_>) {
        (PinReader(&self.inputs), RobotReader(&self.robot))
    }
}

fn with_bit(mask: u16, pin: u8, on: bool) -> u16 {
    let bit = 1u16.checked_shl(u32::from(pin)).unwrap_or(0);
    if on { mask | bit } else { mask & !bit }
}

/// [`InputPins`] over the simulated inputs.
#[derive(Debug)]
pub struct PinReader<'a>(&'a Inputs);

impl InputPins for PinReader<'_> {
    fn digital(&mut self) -> u16 {
        self.0.digital.get()
    }

    fn tool(&mut self) -> u8 {
        self.0.tool.get()
    }

    fn analog(&mut self, channel: usize, kind: AnalogType) -> u16 {
        self.0.analog.get().get(channel).copied().unwrap_or(0).min(kind.max())
    }
}

/// [`Robot`] over the shared simulated robot.
#[derive(Debug)]
pub struct RobotReader<'a>(&'a RefCell<SimRobot>);

impl Robot for RobotReader<'_> {
    fn status(&mut self) -> RobotStatus {
        self.0.borrow_mut().status()
    }

    fn telemetry(&mut self) -> Telemetry {
        self.0.borrow_mut().telemetry()
    }

    fn version(&mut self) -> Version {
        self.0.borrow_mut().version()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_outside_the_mask_are_ignored() {
        assert_eq!(with_bit(0, 0, true), 1);
        assert_eq!(with_bit(0xffff, 15, false), 0x7fff);
        assert_eq!(with_bit(5, 16, true), 5);
    }
}
