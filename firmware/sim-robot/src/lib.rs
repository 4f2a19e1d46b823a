//! A simulated robot controller: the source of registers 259-264 and 270-435
//! when no real robot is connected (hal-sim, and the boards' `sim-robot` demo).
//!
//! - States follow a real controller's: INITIALIZING, then STANDBY, then (in
//!   [`Mode::Demo`]) OPERATING a looping motion. Events ([`Event`]) stop it the
//!   way a controller stops: an e-stop gives EMERGENCY STOP, its release SAFE
//!   OFF (servo off until [`Event::Reset`]), a protective stop SAFE STOP or,
//!   when the arm left its range, SAFE STOP2, which needs [`Event::Recover`].
//! - The flags of registers 260-262 are derived from the state alone
//!   ([`servo_on`], [`safety_stop`]), so they can never disagree with it.
//! - The arm is a 6-axis arm with an offset wrist (1.3 m reach), given by its
//!   Denavit-Hartenberg table [`LINKS`]. The task pose is its forward
//!   kinematics; velocities are exact time derivatives of the positions;
//!   torques are gravity holding torques of point masses plus inertia;
//!   currents follow the torques and temperatures follow the currents.
//! - Its controller version (registers 256-258) is a fixed, simulated one:
//!   [`CONTROLLER_VERSION`].
//! - Everything is a function of [`Instant`]: the same time gives the same
//!   values whatever the rate at which [`Robot::status`] and
//!   [`Robot::telemetry`] are called (temperatures aside, which integrate).
//!
//! `no_std`, allocation-free, panic-free (trigonometry from `libm`).
#![cfg_attr(not(test), no_std)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

use core::f32::consts::PI;
use core::fmt;

use embassy_time::Instant;
use libm::{atan2f, cosf, expf, roundf, sinf, sqrtf};

use adapter_io::{Robot, RobotState, RobotStatus, SafetyStop, Six, Telemetry, Version};

/// What the simulated controller does once it is up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// INITIALIZING for [`INIT_TIME_US`], STANDBY for [`STANDBY_DWELL_US`],
    /// then OPERATING a looping motion; back in STANDBY after a stop is
    /// cleared, the program starts again after the same dwell.
    Demo,
    /// Up and waiting: STANDBY from the start, arm still, servo on.
    Idle,
}

/// Something that happens to the controller: a button, a safety function,
/// an operator's command. See [`SimRobot::event`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The e-stop button. Pressed: EMERGENCY STOP from any state, servo off,
    /// the arm halts. Released: SAFE OFF (servo still off, register 262 = 1)
    /// until [`Event::Reset`], as a controller wants the operator to
    /// acknowledge before it powers the servo again.
    EmergencyStop { pressed: bool },
    /// A protective stop (collision, speed or force limit) while the servo is
    /// on: SAFE STOP (register 262 = 1), the arm halts with the servo on.
    /// With `recovery` (the arm left its driving range): SAFE STOP2
    /// (register 262 = 2, coil 265 = 1).
    SafetyStop { recovery: bool },
    /// The operator acknowledges a stop: SAFE STOP or SAFE OFF go to
    /// STANDBY (servo on); NOT READY restarts (INITIALIZING). A no-op in the
    /// other states that need no acknowledgement.
    Reset,
    /// Recovery mode after SAFE STOP2 or SAFE OFF2: RECOVERY for
    /// [`RECOVERY_TIME_US`] (the arm is brought back into range), then STANDBY.
    Recover,
    /// The direct-teach button (register 263). Pressed in STANDBY or
    /// OPERATING: TEACHING (the program halts; the arm is held by hand).
    /// Released in TEACHING: STANDBY.
    TeachButton { pressed: bool },
    /// The power button (register 264): only its flag.
    PowerButton { pressed: bool },
    /// Puts the controller in `state` directly (flags follow the state).
    /// Timed states move on by themselves: INITIALIZING, HOMING and RECOVERY
    /// end in STANDBY.
    SetState(RobotState),
}

/// Why an [`Event`] was refused. The state is unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refused {
    /// The e-stop is pressed: release it first.
    EmergencyStopPressed,
    /// The e-stop is not pressed: nothing to release.
    EmergencyStopNotPressed,
    /// The servo is off: there is no motion to stop.
    ServoOff,
    /// This stop needs recovery mode ([`Event::Recover`]), not a reset.
    NeedsRecovery,
    /// Only SAFE STOP2 and SAFE OFF2 need recovery mode.
    NoRecoveryNeeded,
}

impl fmt::Display for Refused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::EmergencyStopPressed => "emergency stop pressed: release it first",
            Self::EmergencyStopNotPressed => "emergency stop not pressed",
            Self::ServoOff => "servo off: nothing to stop",
            Self::NeedsRecovery => "stop needs recovery mode, not a reset",
            Self::NoRecoveryNeeded => "no stop that needs recovery mode",
        })
    }
}

impl core::error::Error for Refused {}

/// The simulated controller's version (registers 256-258). Made up: no real
/// controller's, and apart from the adapter's own version (0x2B) on purpose,
/// so a master that mixes the two up shows it.
pub const CONTROLLER_VERSION: Version = Version { major: 2, minor: 7, patch: 3 };

/// How long INITIALIZING lasts after the first sample (Demo).
pub const INIT_TIME_US: u64 = 1_000_000;
/// How long the demo waits in STANDBY before it starts the program.
pub const STANDBY_DWELL_US: u64 = 1_000_000;
/// How long RECOVERY takes before STANDBY.
pub const RECOVERY_TIME_US: u64 = 2_000_000;
/// How long HOMING takes before STANDBY.
pub const HOMING_TIME_US: u64 = 2_000_000;
/// One loop of the demo motion.
pub const LOOP_TIME_US: u64 = 20_000_000;
/// The program speeds up from rest to full speed over this time (a stop is immediate).
pub const RAMP_TIME_US: u64 = 500_000;

const MICROS_PER_SECOND: f32 = 1_000_000.0;
/// Standard gravity, m/s².
const GRAVITY: f32 = 9.81;
/// Ambient temperature, degC: where the motors start and cool down to.
const AMBIENT_C: f32 = 25.0;
/// Motor temperature rise per ampere at steady state, degC/A.
const HEATING_C_PER_A: f32 = 4.0;
/// Thermal time constant of a joint, s.
const THERMAL_TIME_S: f32 = 300.0;
/// Mass held at the tool centre point, kg.
const PAYLOAD_KG: f32 = 2.0;
/// Tool centre point along the flange's z axis, m (the tool offset registers).
const TOOL_LENGTH_M: f32 = 0.12;
/// Below this, sin(B) of the Euler angles counts as 0 (gimbal lock).
const GIMBAL_EPSILON: f32 = 1e-6;

/// One joint and the link after it: standard Denavit-Hartenberg parameters
/// (m, rad), the link's mass (kg, a point mass halfway along the link), and
/// the drive's figures.
#[derive(Clone, Copy, Debug)]
pub struct Link {
    pub a: f32,
    pub d: f32,
    pub alpha: f32,
    pub mass: f32,
    /// Inertia seen by the joint, kg m².
    pub inertia: f32,
    /// Viscous friction, N m s/rad.
    pub friction: f32,
    /// Motor current per N m at the joint, mA.
    pub milliamps_per_newton_metre: f32,
    /// Current with the servo on and no load, mA.
    pub idle_milliamps: f32,
}

const HALF_PI: f32 = PI / 2.0;

/// The arm: base (joint 1) to flange (joint 6).
#[rustfmt::skip]
pub const LINKS: [Link; 6] = [
    Link { a: 0.0,      d: 0.1807,  alpha: HALF_PI,  mass: 7.4,  inertia: 4.0, friction: 20.0, milliamps_per_newton_metre: 25.0,  idle_milliamps: 300.0 },
    Link { a: -0.6127,  d: 0.0,     alpha: 0.0,      mass: 13.1, inertia: 8.0, friction: 20.0, milliamps_per_newton_metre: 25.0,  idle_milliamps: 300.0 },
    Link { a: -0.57155, d: 0.0,     alpha: 0.0,      mass: 4.0,  inertia: 2.0, friction: 10.0, milliamps_per_newton_metre: 40.0,  idle_milliamps: 250.0 },
    Link { a: 0.0,      d: 0.17415, alpha: HALF_PI,  mass: 2.1,  inertia: 0.3, friction: 2.0,  milliamps_per_newton_metre: 150.0, idle_milliamps: 150.0 },
    Link { a: 0.0,      d: 0.11985, alpha: -HALF_PI, mass: 2.0,  inertia: 0.3, friction: 2.0,  milliamps_per_newton_metre: 150.0, idle_milliamps: 150.0 },
    Link { a: 0.0,      d: 0.11655, alpha: 0.0,      mass: 0.6,  inertia: 0.1, friction: 2.0,  milliamps_per_newton_metre: 150.0, idle_milliamps: 150.0 },
];

/// One joint's share of the demo loop: `home + amplitude * sin(harmonic * 2 pi t / loop)`, degrees.
#[derive(Clone, Copy, Debug)]
struct Swing {
    home: f32,
    amplitude: f32,
    harmonic: f32,
}

/// The demo loop: the tool sweeps 0.6-0.96 m in front of the base, 0.2-0.7 m
/// high, tilted 100-170 degrees from vertical. Joints with harmonic 1 and 2
/// never stop at the same instant, so some register moves every 100 ms.
#[rustfmt::skip]
const MOTION: [Swing; 6] = [
    Swing { home: 0.0,   amplitude: 30.0, harmonic: 1.0 },
    Swing { home: -50.0, amplitude: 10.0, harmonic: 2.0 },
    Swing { home: 50.0,  amplitude: 15.0, harmonic: 1.0 },
    Swing { home: -50.0, amplitude: 20.0, harmonic: 2.0 },
    Swing { home: -90.0, amplitude: 20.0, harmonic: 1.0 },
    Swing { home: 0.0,   amplitude: 60.0, harmonic: 1.0 },
];

/// The tool offset registers (420-425): the tool centre point on the flange's z axis.
const TOOL_OFFSET: Six = [0, 0, (TOOL_LENGTH_M * 10_000.0) as i16, 0, 0, 0];

type Vec3 = [f32; 3];

/// Whether the servo is powered in `state`.
pub const fn servo_on(state: RobotState) -> bool {
    use RobotState::*;
    matches!(state, Standby | Operating | Teaching | SafeStop | Homing | Recovery | SafeStop2)
}

/// Register 262 for `state`: the safety-stop states and their servo-off forms.
pub const fn safety_stop(state: RobotState) -> SafetyStop {
    match state {
        RobotState::SafeStop | RobotState::SafeOff => SafetyStop::Stopped,
        RobotState::SafeStop2 | RobotState::SafeOff2 => SafetyStop::NeedsRecovery,
        _ => SafetyStop::No,
    }
}

/// The simulated controller. Call [`Robot::status`] and [`Robot::telemetry`]
/// periodically, and [`SimRobot::event`] when something happens; then push
/// the returned status at once (`adapter::device::Device::set_robot_status`).
#[derive(Clone, Debug)]
pub struct SimRobot {
    mode: Mode,
    state: RobotState,
    /// When `state` began (µs of embassy time); `None` until the first sample.
    since: Option<u64>,
    /// The latest time seen: the model never runs backwards.
    now: u64,
    teach_button: bool,
    power_button: bool,
    /// Where along the loop (µs of motion) the arm is while it is still.
    paused_at: u64,
    /// When the program last started moving, while OPERATING.
    moving_since: Option<u64>,
    temperature: [f32; 6],
    /// When the temperatures were last brought up to date.
    thermal_at: Option<u64>,
}

impl SimRobot {
    pub const fn new(mode: Mode) -> Self {
        let state = match mode {
            Mode::Demo => RobotState::Initializing,
            Mode::Idle => RobotState::Standby,
        };
        Self {
            mode,
            state,
            since: None,
            now: 0,
            teach_button: false,
            power_button: false,
            paused_at: 0,
            moving_since: None,
            temperature: [AMBIENT_C; 6],
            thermal_at: None,
        }
    }

    pub const fn mode(&self) -> Mode {
        self.mode
    }

    /// Applies `event` now; the new status is to be pushed at once.
    pub fn event(&mut self, event: Event) -> Result<RobotStatus, Refused> {
        self.event_at(event, Instant::now())
    }

    /// Applies `event` at time `now`.
    pub fn event_at(&mut self, event: Event, now: Instant) -> Result<RobotStatus, Refused> {
        let now = self.advance(now);
        use RobotState::*;
        let next = match (event, self.state) {
            (Event::EmergencyStop { pressed: true }, _) => EmergencyStop,
            (Event::EmergencyStop { pressed: false }, EmergencyStop) => SafeOff,
            (Event::EmergencyStop { pressed: false }, _) => return Err(Refused::EmergencyStopNotPressed),
            (Event::SafetyStop { .. } | Event::Reset | Event::Recover, EmergencyStop) => {
                return Err(Refused::EmergencyStopPressed);
            }
            (Event::SafetyStop { .. }, state) if !servo_on(state) => return Err(Refused::ServoOff),
            (Event::SafetyStop { recovery }, state) => {
                if recovery || state == SafeStop2 {
                    SafeStop2
                } else {
                    SafeStop
                }
            }
            (Event::Reset, SafeStop | SafeOff) => Standby,
            (Event::Reset, SafeStop2 | SafeOff2) => return Err(Refused::NeedsRecovery),
            (Event::Reset, NotReady) => Initializing,
            (Event::Reset, state) => state,
            (Event::Recover, SafeStop2 | SafeOff2) => Recovery,
            (Event::Recover, _) => return Err(Refused::NoRecoveryNeeded),
            (Event::TeachButton { pressed }, state) => {
                self.teach_button = pressed;
                match (pressed, state) {
                    (true, Standby | Operating) => Teaching,
                    (false, Teaching) => Standby,
                    (_, state) => state,
                }
            }
            (Event::PowerButton { pressed }, state) => {
                self.power_button = pressed;
                state
            }
            (Event::SetState(state), _) => state,
        };
        if next != self.state || matches!(event, Event::SetState(_)) {
            self.enter(next, now);
        }
        Ok(self.current_status())
    }

    /// The status at time `now`.
    pub fn status_at(&mut self, now: Instant) -> RobotStatus {
        self.advance(now);
        self.current_status()
    }

    /// The telemetry at time `now`.
    pub fn telemetry_at(&mut self, now: Instant) -> Telemetry {
        let now = self.advance(now);
        let motion = self.motion(now);
        let arm = Arm::new(&motion.position);
        let servo = servo_on(self.state);

        let mut telemetry = Telemetry { tool_offset: TOOL_OFFSET, ..Telemetry::default() };
        let torque = arm.holding_torque(&motion.acceleration);
        let mut current = [0.0f32; 6];
        for (((amps, link), torque), velocity) in current.iter_mut().zip(&LINKS).zip(&torque).zip(&motion.velocity) {
            if servo {
                let load = (torque + link.friction * velocity).abs();
                *amps = link.idle_milliamps + link.milliamps_per_newton_metre * load;
            }
        }
        self.heat(&current, now);

        telemetry.joint_position = motion.position.map(tenths_of_degree);
        telemetry.joint_velocity = motion.velocity.map(tenths_of_degree);
        telemetry.joint_current = current.map(unsigned);
        telemetry.joint_temperature = self.temperature.map(unsigned);
        telemetry.joint_torque = torque.map(signed);
        telemetry.task_pose = arm.task_pose();
        telemetry.task_velocity = arm.task_velocity(&motion.velocity);
        telemetry.external_wrench = if servo { sensor_ripple(now) } else { [0; 6] };
        telemetry
    }

    fn current_status(&self) -> RobotStatus {
        RobotStatus {
            state: self.state,
            servo_on: servo_on(self.state),
            emergency_stop: self.state == RobotState::EmergencyStop,
            safety_stop: safety_stop(self.state),
            direct_teach: self.teach_button,
            power_button: self.power_button,
        }
    }

    /// Brings the state machine up to `now` (µs), taking each timed
    /// transition at the instant it was due, not when it was noticed.
    fn advance(&mut self, now: Instant) -> u64 {
        let now = now.as_micros().max(self.now);
        self.now = now;
        let Some(mut since) = self.since else {
            self.since = Some(now);
            if self.state == RobotState::Operating {
                self.moving_since = Some(now);
            }
            return now;
        };
        // Each step leaves a timed state; STANDBY->OPERATING ends the chain.
        for _ in 0..3 {
            let (after, next) = match (self.state, self.mode) {
                (RobotState::Initializing, _) => (INIT_TIME_US, RobotState::Standby),
                (RobotState::Standby, Mode::Demo) => (STANDBY_DWELL_US, RobotState::Operating),
                (RobotState::Recovery, _) => (RECOVERY_TIME_US, RobotState::Standby),
                (RobotState::Homing, _) => (HOMING_TIME_US, RobotState::Standby),
                _ => break,
            };
            let due = since.saturating_add(after);
            if due > now {
                break;
            }
            self.enter(next, due);
            since = due;
        }
        now
    }

    /// Enters `state` at time `at` (µs): starts or freezes the motion.
    fn enter(&mut self, state: RobotState, at: u64) {
        let moving = state == RobotState::Operating;
        match (self.moving_since, moving) {
            (Some(_), false) => {
                self.paused_at = self.loop_time(at).0;
                self.moving_since = None;
            }
            (Some(_), true) => {
                // Re-entering OPERATING restarts the ramp from where the arm is.
                self.paused_at = self.loop_time(at).0;
                self.moving_since = Some(at);
            }
            (None, true) => self.moving_since = Some(at),
            (None, false) => {}
        }
        self.state = state;
        self.since = Some(at);
    }

    /// Where along the loop the arm is at `at` (µs of motion, wrapped to one
    /// loop), the speed factor (0..=1) and its rate of change (1/s).
    fn loop_time(&self, at: u64) -> (u64, f32, f32) {
        let Some(start) = self.moving_since else {
            return (self.paused_at, 0.0, 0.0);
        };
        let moving = at.saturating_sub(start);
        let (travelled, speed, ramping) = if moving < RAMP_TIME_US {
            let travelled = moving.saturating_mul(moving) / (2 * RAMP_TIME_US);
            (travelled, moving as f32 / RAMP_TIME_US as f32, MICROS_PER_SECOND / RAMP_TIME_US as f32)
        } else {
            (moving - RAMP_TIME_US / 2, 1.0, 0.0)
        };
        (self.paused_at.saturating_add(travelled) % LOOP_TIME_US, speed, ramping)
    }

    /// Joint positions (rad), velocities (rad/s) and accelerations (rad/s²) at `at`.
    fn motion(&self, at: u64) -> Motion {
        let (loop_us, speed, ramping) = self.loop_time(at);
        let rate = 2.0 * PI * MICROS_PER_SECOND / LOOP_TIME_US as f32;
        let angle = 2.0 * PI * (loop_us as f32 / LOOP_TIME_US as f32);
        let mut motion = Motion { position: [0.0; 6], velocity: [0.0; 6], acceleration: [0.0; 6] };
        let joints = motion.position.iter_mut().zip(motion.velocity.iter_mut()).zip(motion.acceleration.iter_mut());
        for (((q, dq), ddq), swing) in joints.zip(&MOTION) {
            let amplitude = swing.amplitude.to_radians();
            let phase = swing.harmonic * angle;
            let slope = amplitude * swing.harmonic * cosf(phase) * rate;
            *q = swing.home.to_radians() + amplitude * sinf(phase);
            *dq = slope * speed;
            let curvature = -amplitude * swing.harmonic * swing.harmonic * sinf(phase) * rate * rate;
            *ddq = curvature * speed * speed + slope * ramping;
        }
        motion
    }

    /// Motor temperatures approach `AMBIENT + HEATING * current` exponentially.
    fn heat(&mut self, milliamps: &[f32; 6], now: u64) {
        let last = self.thermal_at.replace(now).unwrap_or(now);
        let dt = now.saturating_sub(last) as f32 / MICROS_PER_SECOND;
        let keep = expf(-dt / THERMAL_TIME_S);
        for (temperature, current) in self.temperature.iter_mut().zip(milliamps) {
            let target = AMBIENT_C + HEATING_C_PER_A * current / 1000.0;
            *temperature = target + (*temperature - target) * keep;
        }
    }
}

impl Robot for SimRobot {
    fn status(&mut self) -> RobotStatus {
        self.status_at(Instant::now())
    }

    fn telemetry(&mut self) -> Telemetry {
        self.telemetry_at(Instant::now())
    }

    fn version(&mut self) -> Version {
        CONTROLLER_VERSION
    }
}

/// Joint space at one instant.
struct Motion {
    position: [f32; 6],
    velocity: [f32; 6],
    acceleration: [f32; 6],
}

/// A frame in the base frame: its axes and origin.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Frame {
    x: Vec3,
    y: Vec3,
    z: Vec3,
    origin: Vec3,
}

impl Frame {
    const BASE: Self = Self { x: [1.0, 0.0, 0.0], y: [0.0, 1.0, 0.0], z: [0.0, 0.0, 1.0], origin: [0.0; 3] };

    /// The next frame: Rz(theta) Tz(d) Tx(a) Rx(alpha).
    fn next(&self, link: &Link, theta: f32) -> Self {
        let (c, s) = (cosf(theta), sinf(theta));
        let x = add(scale(self.x, c), scale(self.y, s));
        let y = add(scale(self.x, -s), scale(self.y, c));
        let origin = add(add(self.origin, scale(self.z, link.d)), scale(x, link.a));
        let (ca, sa) = (cosf(link.alpha), sinf(link.alpha));
        Self { x, y: add(scale(y, ca), scale(self.z, sa)), z: add(scale(y, -sa), scale(self.z, ca)), origin }
    }
}

/// The arm's forward kinematics for one set of joint angles.
struct Arm {
    /// Joint i's axis (z of frame i-1) and a point on it.
    axes: [(Vec3, Vec3); 6],
    /// Each link's centre of mass.
    masses: [Vec3; 6],
    /// The tool centre point's frame.
    tool: Frame,
}

impl Arm {
    fn new(q: &[f32; 6]) -> Self {
        let mut frame = Frame::BASE;
        let mut axes = [([0.0; 3], [0.0; 3]); 6];
        let mut masses = [[0.0; 3]; 6];
        for (((axis, mass), link), &theta) in axes.iter_mut().zip(masses.iter_mut()).zip(&LINKS).zip(q) {
            *axis = (frame.z, frame.origin);
            let next = frame.next(link, theta);
            *mass = scale(add(frame.origin, next.origin), 0.5);
            frame = next;
        }
        let tool = Frame { origin: add(frame.origin, scale(frame.z, TOOL_LENGTH_M)), ..frame };
        Self { axes, masses, tool }
    }

    /// X Y Z (0.1 mm) and Euler Z-Y-Z A B C (0.1 deg) of the tool centre point.
    fn task_pose(&self) -> Six {
        let [x, y, z] = self.tool.origin.map(tenths_of_millimetre);
        let [a, b, c] = euler_zyz(&self.tool).map(tenths_of_degree);
        [x, y, z, a, b, c]
    }

    /// Linear (0.1 mm/s) and angular (0.1 deg/s) velocity of the tool centre
    /// point for joint rates `dq` (rad/s): the geometric Jacobian times `dq`.
    fn task_velocity(&self, dq: &[f32; 6]) -> Six {
        let (linear, angular) = self.twist(dq);
        let [vx, vy, vz] = linear.map(tenths_of_millimetre);
        let [wx, wy, wz] = angular.map(tenths_of_degree);
        [vx, vy, vz, wx, wy, wz]
    }

    fn twist(&self, dq: &[f32; 6]) -> (Vec3, Vec3) {
        let mut linear = [0.0; 3];
        let mut angular = [0.0; 3];
        for (&(axis, point), &rate) in self.axes.iter().zip(dq) {
            linear = add(linear, scale(cross(axis, sub(self.tool.origin, point)), rate));
            angular = add(angular, scale(axis, rate));
        }
        (linear, angular)
    }

    /// N m each joint applies to hold the links and the payload against
    /// gravity, plus its own inertia times `ddq` (rad/s²).
    fn holding_torque(&self, ddq: &[f32; 6]) -> [f32; 6] {
        let mut torque = [0.0; 6];
        for (joint, ((torque, &(axis, point)), (link, &accel))) in
            torque.iter_mut().zip(&self.axes).zip(LINKS.iter().zip(ddq)).enumerate()
        {
            // The weight m g acting at r about the axis: (axis x r) . (0, 0, -m g).
            let weight = |mass: f32, at: Vec3| mass * GRAVITY * cross(axis, sub(at, point))[2];
            let links: f32 = LINKS.iter().zip(&self.masses).skip(joint).map(|(l, &at)| weight(l.mass, at)).sum();
            *torque = links + weight(PAYLOAD_KG, self.tool.origin) + link.inertia * accel;
        }
        torque
    }
}

/// Euler Z-Y-Z angles (rad) of a frame: A in (-pi, pi], B in [0, pi], C in (-pi, pi].
fn euler_zyz(frame: &Frame) -> Vec3 {
    let ([r11, r21, r31], [_, _, r32], [r13, r23, r33]) = (frame.x, frame.y, frame.z);
    let b = atan2f(sqrtf(r13 * r13 + r23 * r23), r33);
    if sinf(b).abs() > GIMBAL_EPSILON {
        [atan2f(r23, r13), b, atan2f(r32, -r31)]
    } else if r33 > 0.0 {
        // B = 0: only A + C is defined; report it as A.
        [atan2f(r21, r11), b, 0.0]
    } else {
        // B = pi: only A - C is defined; report it as A.
        [atan2f(-r21, -r11), b, 0.0]
    }
}

/// A force/torque sensor's reading with nothing touching the tool: a small
/// ripple (about 1 N, 0.3 N m), periodic over a minute.
fn sensor_ripple(now: u64) -> Six {
    const PERIOD_US: u64 = 60_000_000;
    let t = 2.0 * PI * ((now % PERIOD_US) as f32 / PERIOD_US as f32);
    [
        1.2 * sinf(37.0 * t),
        0.9 * sinf(23.0 * t + 1.0),
        1.5 * sinf(29.0 * t + 2.0),
        0.3 * sinf(31.0 * t + 3.0),
        0.3 * sinf(19.0 * t + 4.0),
        0.2 * sinf(41.0 * t + 5.0),
    ]
    .map(signed)
}

fn add(a: Vec3, b: Vec3) -> Vec3 {
    let ([ax, ay, az], [bx, by, bz]) = (a, b);
    [ax + bx, ay + by, az + bz]
}

fn sub(a: Vec3, b: Vec3) -> Vec3 {
    add(a, scale(b, -1.0))
}

fn scale(a: Vec3, k: f32) -> Vec3 {
    a.map(|v| v * k)
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    let ([ax, ay, az], [bx, by, bz]) = (a, b);
    [ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx]
}

/// Saturating, rounded conversions to the map's units (`as` saturates and maps NaN to 0).
fn signed(value: f32) -> i16 {
    roundf(value) as i16
}

fn unsigned(value: f32) -> u16 {
    roundf(value) as u16
}

fn tenths_of_degree(radians: f32) -> i16 {
    signed(radians.to_degrees() * 10.0)
}

fn tenths_of_millimetre(metres: f32) -> i16 {
    signed(metres * 10_000.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use adapter::map::Image;
    use adapter::map::table::{coil, reg};

    const PERIOD_US: u64 = 100_000;

    fn at(us: u64) -> Instant {
        Instant::from_micros(us)
    }

    /// A demo robot sampled from 0 until it has moved for `us` µs.
    fn operating_for(us: u64) -> (SimRobot, u64) {
        let mut robot = SimRobot::new(Mode::Demo);
        robot.status_at(at(0));
        let start = INIT_TIME_US + STANDBY_DWELL_US;
        assert_eq!(robot.status_at(at(start)).state, RobotState::Operating);
        (robot, start + us)
    }

    fn image_of(status: &RobotStatus) -> Image {
        let mut image = Image::new();
        image.set_robot_status(status);
        image
    }

    fn close(a: f32, b: f32, tolerance: f32) -> bool {
        (a - b).abs() <= tolerance
    }

    #[test]
    fn the_controller_version_is_the_simulated_one_whatever_the_state() {
        for mode in [Mode::Demo, Mode::Idle] {
            let mut robot = SimRobot::new(mode);
            assert_eq!(Robot::version(&mut robot), CONTROLLER_VERSION);
        }
        let mut image = Image::new();
        image.set_controller_version(&CONTROLLER_VERSION);
        assert_eq!([256, 257, 258].map(|a| image.register(a)), [2, 7, 3]);
        assert_ne!(CONTROLLER_VERSION, adapter::VERSION, "told apart from the adapter's own");
    }

    #[test]
    fn zero_pose_forward_kinematics_matches_the_table() {
        // At q = 0 the arm lies along -X: a2 + a3 in X, -(d4 + d6 + tool) in Y, d1 - d5 in Z.
        let arm = Arm::new(&[0.0; 6]);
        let [x, y, z] = arm.tool.origin;
        assert!(close(x, -0.6127 - 0.57155, 1e-5), "{x}");
        assert!(close(y, -(0.17415 + 0.11655 + TOOL_LENGTH_M), 1e-5), "{y}");
        assert!(close(z, 0.1807 - 0.11985, 1e-5), "{z}");
        // 608.5 rounds either way in f32.
        let [x, y, z, a, b, c] = arm.task_pose();
        assert_eq!(([x, y, a, b, c]), [-11843, -4107, -900, 900, 900]);
        assert!((608..=609).contains(&z), "{z}");
    }

    #[test]
    fn base_rotation_turns_the_tool_about_z() {
        let q = [0.3, -0.8, 0.9, -0.7, -1.4, 0.2];
        let turned = [q[0] + 0.5, q[1], q[2], q[3], q[4], q[5]];
        let (a, b) = (Arm::new(&q).tool, Arm::new(&turned).tool);
        let (c, s) = (cosf(0.5), sinf(0.5));
        let rotated = [c * a.origin[0] - s * a.origin[1], s * a.origin[0] + c * a.origin[1], a.origin[2]];
        for (p, r) in b.origin.iter().zip(rotated) {
            assert!(close(*p, r, 1e-5));
        }
        let (ea, eb) = (euler_zyz(&a), euler_zyz(&b));
        assert!(close(eb[0] - ea[0], 0.5, 1e-4) && close(eb[1], ea[1], 1e-4) && close(eb[2], ea[2], 1e-4));
    }

    #[test]
    fn euler_angles_rebuild_the_rotation() {
        for &(a, b, c) in &[(0.3, 1.2, -2.0), (-2.9, 0.4, 1.0), (1.5, 2.8, 3.0), (0.0, 1.0e-3, 0.7)] {
            // Rz(a) Ry(b) Rz(c) as a frame: apply it through DH-like steps.
            let rz = |f: Frame, t: f32| Frame {
                x: add(scale(f.x, cosf(t)), scale(f.y, sinf(t))),
                y: add(scale(f.x, -sinf(t)), scale(f.y, cosf(t))),
                ..f
            };
            let ry = |f: Frame, t: f32| Frame {
                x: add(scale(f.x, cosf(t)), scale(f.z, -sinf(t))),
                z: add(scale(f.x, sinf(t)), scale(f.z, cosf(t))),
                ..f
            };
            let frame = rz(ry(rz(Frame::BASE, a), b), c);
            let [ea, eb, ec] = euler_zyz(&frame);
            assert!(close(ea, a, 1e-3) && close(eb, b, 1e-3) && close(ec, c, 1e-3), "{a} {b} {c} -> {ea} {eb} {ec}");
        }
    }

    #[test]
    fn demo_goes_initializing_standby_operating() {
        let mut robot = SimRobot::new(Mode::Demo);
        let first = robot.status_at(at(5_000_000));
        assert_eq!((first.state, first.servo_on), (RobotState::Initializing, false));
        let standby = robot.status_at(at(5_000_000 + INIT_TIME_US));
        assert_eq!((standby.state, standby.servo_on), (RobotState::Standby, true));
        let operating = robot.status_at(at(5_000_000 + INIT_TIME_US + STANDBY_DWELL_US));
        assert_eq!((operating.state, operating.servo_on), (RobotState::Operating, true));
        assert!(!operating.emergency_stop && operating.safety_stop == SafetyStop::No);
    }

    #[test]
    fn a_late_sample_takes_every_transition_on_time() {
        // Sampled once at init, then only 3 s later: the motion began at 2 s, not 3 s.
        let (mut reference, _) = operating_for(0);
        let mut late = SimRobot::new(Mode::Demo);
        late.status_at(at(0));
        let t = INIT_TIME_US + STANDBY_DWELL_US + 1_000_000;
        assert_eq!(late.telemetry_at(at(t)).joint_position, reference.telemetry_at(at(t)).joint_position);
    }

    #[test]
    fn motion_does_not_depend_on_the_call_rate() {
        let (mut every_100ms, start) = operating_for(0);
        let (mut every_730ms, _) = operating_for(0);
        for step in 1..=300u64 {
            let t = start + step * PERIOD_US;
            let a = every_100ms.telemetry_at(at(t));
            if step % 73 == 0 {
                let b = every_730ms.telemetry_at(at(t));
                assert_eq!(a.joint_position, b.joint_position);
                assert_eq!(a.joint_velocity, b.joint_velocity);
                assert_eq!(a.task_pose, b.task_pose);
            }
        }
    }

    #[test]
    fn task_pose_follows_the_joints() {
        let (mut robot, start) = operating_for(0);
        let mut poses = 0;
        let mut last = None;
        for step in 0..200u64 {
            let t = robot.telemetry_at(at(start + step * PERIOD_US));
            // Rebuild the pose from the joint registers alone.
            let q = t.joint_position.map(|v| (f32::from(v) / 10.0).to_radians());
            let pose = Arm::new(&q).task_pose();
            for (axis, (reported, rebuilt)) in t.task_pose.iter().zip(pose).enumerate() {
                // 0.05 deg of rounding on each of six joints moves the tool up to about 4 mm.
                let tolerance = if axis < 3 { 40 } else { 8 };
                assert!((i32::from(*reported) - i32::from(rebuilt)).abs() <= tolerance, "step {step} axis {axis}");
            }
            if last.is_some_and(|l| l != t.task_pose) {
                poses += 1;
            }
            last = Some(t.task_pose);
        }
        assert!(poses > 190, "the tool moves while the joints move ({poses})");
    }

    #[test]
    fn velocities_match_position_changes() {
        let (mut robot, start) = operating_for(0);
        let mut previous = robot.telemetry_at(at(start));
        // One whole loop, including the ramp from rest.
        for step in 1..=(LOOP_TIME_US / PERIOD_US + 10) {
            let now = robot.telemetry_at(at(start + step * PERIOD_US));
            let pairs = previous
                .joint_position
                .iter()
                .zip(&now.joint_position)
                .zip(previous.joint_velocity.iter().zip(&now.joint_velocity));
            for ((&p0, &p1), (&v0, &v1)) in pairs {
                let moved = f32::from(p1 - p0) / 0.1; // 0.1 deg/s
                let mean = (f32::from(v0) + f32::from(v1)) / 2.0;
                assert!(close(moved, mean, 12.0 + 0.05 * mean.abs()), "step {step}: moved {moved}, velocity {mean}");
            }
            let linear = previous
                .task_pose
                .iter()
                .zip(&now.task_pose)
                .zip(previous.task_velocity.iter().zip(&now.task_velocity));
            for ((&p0, &p1), (&v0, &v1)) in linear.take(3) {
                let moved = f32::from(p1 - p0) / 0.1; // 0.1 mm/s
                let mean = (f32::from(v0) + f32::from(v1)) / 2.0;
                assert!(close(moved, mean, 20.0 + 0.05 * mean.abs()), "step {step}: moved {moved}, velocity {mean}");
            }
            previous = now;
        }
    }

    #[test]
    fn angular_velocity_turns_the_tool_frame() {
        let (robot, start) = operating_for(3_000_000);
        let h = 1_000u64; // 1 ms
        let before = Arm::new(&robot.motion(start - h).position).tool;
        let after = Arm::new(&robot.motion(start + h).position).tool;
        let (_, omega) = Arm::new(&robot.motion(start).position).twist(&robot.motion(start).velocity);
        let here = Arm::new(&robot.motion(start).position).tool;
        for (now, (b, a)) in [(here.x, (before.x, after.x)), (here.z, (before.z, after.z))] {
            // d(axis)/dt = omega x axis.
            let rate = scale(sub(a, b), 1.0 / 0.002);
            let expected = cross(omega, now);
            for (r, e) in rate.iter().zip(expected) {
                assert!(close(*r, e, 2e-3), "{rate:?} vs {expected:?}");
            }
        }
    }

    #[test]
    fn values_stay_in_sane_ranges() {
        let (mut robot, start) = operating_for(0);
        // Ten minutes of motion, sampled every second.
        for step in 0..600u64 {
            let t = robot.telemetry_at(at(start + step * 1_000_000));
            assert!(t.joint_velocity.iter().all(|v| v.abs() <= 1_800), "{:?}", t.joint_velocity);
            assert!(t.joint_current.iter().all(|&ma| (100..=8_000).contains(&ma)), "{:?}", t.joint_current);
            assert!(t.joint_temperature.iter().all(|&c| (20..=60).contains(&c)), "{:?}", t.joint_temperature);
            assert!(t.joint_torque.iter().all(|n| n.abs() <= 300), "{:?}", t.joint_torque);
            let [x, y, z, _, b, _] = t.task_pose.map(i32::from);
            let reach = f32::sqrt((x * x + y * y + z * z) as f32) / 10.0;
            assert!((300.0..=1_400.0).contains(&reach) && z > 1_000, "{:?}", t.task_pose);
            assert!((0..=1_800).contains(&b));
            assert!(t.task_velocity.iter().all(|v| v.abs() <= 10_000), "{:?}", t.task_velocity);
            assert!(t.external_wrench.iter().all(|v| v.abs() <= 2));
            assert_eq!(t.tool_offset, [0, 0, 1_200, 0, 0, 0]);
        }
        let warm = robot.telemetry_at(at(start + 600 * 1_000_000));
        assert!(warm.joint_temperature.iter().any(|&c| c >= 30), "loaded joints warm up: {:?}", warm.joint_temperature);
        // Joint 2 carries the arm: the largest holding torque and current.
        let max = warm.joint_torque.iter().map(|t| t.abs()).max().unwrap();
        assert_eq!(warm.joint_torque[1].abs(), max);
        assert!(max >= 50);
    }

    #[test]
    fn emergency_stop_sets_state_6_register_261_and_coil_261() {
        let (mut robot, now) = operating_for(2_000_000);
        let moving = robot.telemetry_at(at(now));
        let status = robot.event_at(Event::EmergencyStop { pressed: true }, at(now)).unwrap();
        assert_eq!(status.state, RobotState::EmergencyStop);
        assert!(status.emergency_stop && !status.servo_on);
        let image = image_of(&status);
        assert_eq!(image.register(reg::ROBOT_STATE), 6);
        assert_eq!(image.register(reg::EMERGENCY_STOP), 1);
        assert!(image.coil(coil::EMERGENCY_STOP));
        assert!(!image.coil(coil::SERVO_ON));

        // The arm halts where it was, and stays there.
        let stopped = robot.telemetry_at(at(now + 500_000));
        assert!(stopped.joint_position.iter().zip(&moving.joint_position).all(|(a, b)| (a - b).abs() <= 1));
        assert_eq!(stopped.joint_velocity, [0; 6]);
        assert_eq!(stopped.task_velocity, [0; 6]);
        assert_eq!(stopped.joint_current, [0; 6], "servo off");
        assert_eq!(robot.status_at(at(now + 30_000_000)).state, RobotState::EmergencyStop);
        assert_eq!(robot.event_at(Event::Reset, at(now + 30_000_000)), Err(Refused::EmergencyStopPressed));
    }

    #[test]
    fn releasing_the_e_stop_needs_a_reset_before_the_servo_comes_back() {
        let (mut robot, now) = operating_for(2_000_000);
        robot.event_at(Event::EmergencyStop { pressed: true }, at(now)).unwrap();
        let released = robot.event_at(Event::EmergencyStop { pressed: false }, at(now + 1_000_000)).unwrap();
        assert_eq!(released.state, RobotState::SafeOff);
        assert!(!released.emergency_stop && !released.servo_on);
        assert_eq!(released.safety_stop, SafetyStop::Stopped);
        let image = image_of(&released);
        assert_eq!(image.register(reg::EMERGENCY_STOP), 0);
        assert!(!image.coil(coil::EMERGENCY_STOP) && image.coil(coil::SAFETY_STOP));
        assert_eq!(robot.status_at(at(now + 20_000_000)).state, RobotState::SafeOff, "no servo on by itself");

        let reset = robot.event_at(Event::Reset, at(now + 20_000_000)).unwrap();
        assert_eq!((reset.state, reset.servo_on, reset.safety_stop), (RobotState::Standby, true, SafetyStop::No));
        let resumed = robot.status_at(at(now + 20_000_000 + STANDBY_DWELL_US));
        assert_eq!(resumed.state, RobotState::Operating, "the demo program starts again");
        assert_eq!(
            robot.event_at(Event::EmergencyStop { pressed: false }, at(now + 21_000_000)),
            Err(Refused::EmergencyStopNotPressed)
        );
    }

    #[test]
    fn motion_resumes_from_where_it_stopped() {
        let (mut robot, now) = operating_for(4_000_000);
        robot.event_at(Event::SafetyStop { recovery: false }, at(now)).unwrap();
        let held = robot.telemetry_at(at(now + 5_000_000));
        robot.event_at(Event::Reset, at(now + 5_000_000)).unwrap();
        let restart = now + 5_000_000 + STANDBY_DWELL_US;
        let first = robot.telemetry_at(at(restart + 50_000));
        assert!(first.joint_position.iter().zip(&held.joint_position).all(|(a, b)| (a - b).abs() <= 1), "no jump");
        assert!(
            first
                .joint_velocity
                .iter()
                .zip(&robot.telemetry_at(at(restart + 2_000_000)).joint_velocity)
                .any(|(a, b)| a.abs() < b.abs()),
            "ramps up"
        );
    }

    #[test]
    fn safety_stop_with_recovery_needs_recovery_mode() {
        let (mut robot, now) = operating_for(1_000_000);
        let stopped = robot.event_at(Event::SafetyStop { recovery: true }, at(now)).unwrap();
        assert_eq!((stopped.state, stopped.servo_on), (RobotState::SafeStop2, true));
        let image = image_of(&stopped);
        assert_eq!(image.register(reg::SAFETY_STOP), 2);
        assert!(image.coil(coil::SAFETY_STOP) && image.coil(coil::SAFETY_STOP_RECOVERY));
        assert_eq!(robot.event_at(Event::Reset, at(now + 1)), Err(Refused::NeedsRecovery));
        let recovering = robot.event_at(Event::Recover, at(now + 2)).unwrap();
        assert_eq!((recovering.state, recovering.safety_stop), (RobotState::Recovery, SafetyStop::No));
        assert_eq!(robot.status_at(at(now + 2 + RECOVERY_TIME_US)).state, RobotState::Standby);
        assert_eq!(robot.event_at(Event::Recover, at(now + 3 + RECOVERY_TIME_US)), Err(Refused::NoRecoveryNeeded));
    }

    #[test]
    fn plain_safety_stop_keeps_the_servo_and_resets_to_standby() {
        let (mut robot, now) = operating_for(1_000_000);
        let stopped = robot.event_at(Event::SafetyStop { recovery: false }, at(now)).unwrap();
        assert_eq!(
            (stopped.state, stopped.servo_on, stopped.safety_stop),
            (RobotState::SafeStop, true, SafetyStop::Stopped)
        );
        let image = image_of(&stopped);
        assert!(image.coil(coil::SAFETY_STOP) && !image.coil(coil::SAFETY_STOP_RECOVERY));
        assert_eq!(robot.telemetry_at(at(now + 1_000_000)).joint_velocity, [0; 6]);
        assert_eq!(robot.event_at(Event::Reset, at(now + 1_000_000)).unwrap().state, RobotState::Standby);
        robot.event_at(Event::EmergencyStop { pressed: true }, at(now + 1_000_001)).unwrap();
        assert_eq!(
            robot.event_at(Event::SafetyStop { recovery: false }, at(now + 1_000_002)),
            Err(Refused::EmergencyStopPressed)
        );
        robot.event_at(Event::EmergencyStop { pressed: false }, at(now + 1_000_003)).unwrap();
        assert_eq!(robot.event_at(Event::SafetyStop { recovery: false }, at(now + 1_000_004)), Err(Refused::ServoOff));
    }

    #[test]
    fn buttons_set_their_flags_and_teach_halts_the_program() {
        let (mut robot, now) = operating_for(1_000_000);
        let teach = robot.event_at(Event::TeachButton { pressed: true }, at(now)).unwrap();
        assert_eq!((teach.state, teach.direct_teach), (RobotState::Teaching, true));
        assert!(image_of(&teach).coil(coil::DIRECT_TEACH));
        assert_eq!(robot.telemetry_at(at(now + 1_000_000)).joint_velocity, [0; 6]);
        let released = robot.event_at(Event::TeachButton { pressed: false }, at(now + 1_000_000)).unwrap();
        assert_eq!((released.state, released.direct_teach), (RobotState::Standby, false));

        let power = robot.event_at(Event::PowerButton { pressed: true }, at(now + 1_000_001)).unwrap();
        assert!(power.power_button && image_of(&power).coil(coil::POWER_BUTTON));
        assert_eq!(image_of(&power).register(reg::POWER_BUTTON), 1);
        assert!(!robot.event_at(Event::PowerButton { pressed: false }, at(now + 1_000_002)).unwrap().power_button);
    }

    #[test]
    fn set_state_derives_the_flags() {
        let mut robot = SimRobot::new(Mode::Idle);
        for (state, servo, estop, safety) in [
            (RobotState::SafeOff2, false, false, SafetyStop::NeedsRecovery),
            (RobotState::EmergencyStop, false, true, SafetyStop::No),
            (RobotState::NotReady, false, false, SafetyStop::No),
            (RobotState::Homing, true, false, SafetyStop::No),
        ] {
            let status = robot.event_at(Event::SetState(state), at(0)).unwrap();
            assert_eq!(
                (status.state, status.servo_on, status.emergency_stop, status.safety_stop),
                (state, servo, estop, safety)
            );
        }
        assert_eq!(robot.status_at(at(HOMING_TIME_US)).state, RobotState::Standby, "homing ends");
        robot.event_at(Event::SetState(RobotState::NotReady), at(HOMING_TIME_US)).unwrap();
        assert_eq!(robot.event_at(Event::Reset, at(HOMING_TIME_US)).unwrap().state, RobotState::Initializing);
        assert_eq!(robot.status_at(at(HOMING_TIME_US + INIT_TIME_US)).state, RobotState::Standby);
    }

    #[test]
    fn idle_stays_in_standby_and_still() {
        let mut robot = SimRobot::new(Mode::Idle);
        let first = robot.telemetry_at(at(1_000));
        for step in 1..=600u64 {
            let now = at(1_000 + step * PERIOD_US);
            let status = robot.status_at(now);
            assert_eq!((status.state, status.servo_on), (RobotState::Standby, true));
            let t = robot.telemetry_at(now);
            assert_eq!(t.joint_position, first.joint_position);
            assert_eq!(t.joint_velocity, [0; 6]);
            assert_eq!(t.task_pose, first.task_pose);
            assert_eq!(t.task_velocity, [0; 6]);
            assert!(t.joint_current.iter().all(|&ma| ma >= 100), "servo on, holding the arm");
        }
    }

    #[test]
    fn time_running_backwards_is_ignored() {
        let (mut robot, now) = operating_for(1_000_000);
        let ahead = robot.telemetry_at(at(now));
        assert_eq!(robot.telemetry_at(at(now - 500_000)).joint_position, ahead.joint_position);
    }
}
