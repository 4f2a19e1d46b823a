//! The control socket: a Unix stream socket with a line protocol
//! (docs/hal-sim.md). One reply line per command: `ok ...` or `err REASON`.
//!
//! [`parse`] turns a line into a [`Command`] (pure, tested below);
//! [`execute`] applies it to the [`Board`]. The sockets are non-blocking
//! std sockets that the socket tasks read and write through the runtime's
//! descriptor waits, on the runtime's one thread: a command never
//! interleaves with the 100 ms refresh, and no other thread is needed.

use std::fmt::Write as _;
use std::io::{Read as _, Write as _};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;

use adapter::io::{ANALOG_CHANNELS, RobotState, RobotStatus};
use adapter::map::table::{DIGITAL_PINS, TOOL_PINS};
use embassy_executor::Spawner;
use sim_robot::Event;

use crate::Control as SimController;
use crate::runtime;
use crate::sim::Board;

/// Control connections served at once; one more gets `err busy` and is closed.
pub const MAX_CONTROL_CLIENTS: usize = 4;
/// The longest command line, in bytes (the newline included).
pub const MAX_LINE_LEN: usize = 256;

/// One command of the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// `set di N 0|1`: ControlBox digital input N (1..=16).
    SetDigitalInput {
        pin: u8,
        on: bool,
    },
    /// `set tool-di N 0|1`: tool digital input N (1..=6).
    SetToolInput {
        pin: u8,
        on: bool,
    },
    /// `set ai N VALUE`: analog input N (1..=2), in µA or mV as its type selects.
    SetAnalogInput {
        channel: usize,
        value: u16,
    },
    /// `get di`, `get tool-di`: the input masks.
    GetDigitalInputs,
    GetToolInputs,
    /// `get ai N`: `ok VALUE TYPE`, as the image holds it.
    GetAnalogInput {
        channel: usize,
    },
    /// `get do`, `get tool-do`: what the output pins are driven to.
    GetDigitalOutputs,
    GetToolOutputs,
    /// `get ao N`: `ok VALUE TYPE`.
    GetAnalogOutput {
        channel: usize,
    },
    /// `get robot`: registers 259-264.
    GetRobot,
    /// `get stats`: the diagnostics counters, `ok name=value ...`.
    GetStats,
    /// `robot ...`: an event of the simulated robot.
    Robot(Event),
    /// `get locate`: `ok 1` while the status LED blinks (`POST /api/locate`), else `ok 0`.
    GetLocate,
    /// `factory-reset`: erases the saved settings and the password, then
    /// reboots (hal-sim executes itself again), as the board's button does.
    FactoryReset,
    /// `button`: the device's button pressed briefly, the physical act
    /// that lets the first admin password be set for 10 minutes more.
    Button,
    /// `help`.
    Help,
}

const HELP: &str = "ok commands: set di N 0|1; set tool-di N 0|1; set ai N VALUE; \
get di|tool-di|do|tool-do; get ai N; get ao N; get robot; get stats; get locate; factory-reset; button; \
robot estop press|release; robot safety-stop [recovery]; robot reset; robot recover; \
robot teach press|release; robot power press|release; robot state N|NAME; help";

/// The robot states by register value and by the name `robot state` accepts.
const STATES: [(RobotState, &str); 12] = [
    (RobotState::Initializing, "initializing"),
    (RobotState::Standby, "standby"),
    (RobotState::Operating, "operating"),
    (RobotState::SafeOff, "safe-off"),
    (RobotState::Teaching, "teaching"),
    (RobotState::SafeStop, "safe-stop"),
    (RobotState::EmergencyStop, "emergency-stop"),
    (RobotState::Homing, "homing"),
    (RobotState::Recovery, "recovery"),
    (RobotState::SafeStop2, "safe-stop2"),
    (RobotState::SafeOff2, "safe-off2"),
    (RobotState::NotReady, "not-ready"),
];

/// Parses one line (without its newline). The error is the reply's REASON.
pub fn parse(line: &str) -> Result<Command, String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    let command = match words.as_slice() {
        ["set", "di", n, v] => Command::SetDigitalInput { pin: pin(n, DIGITAL_PINS)?, on: level(v)? },
        ["set", "tool-di", n, v] => Command::SetToolInput { pin: pin(n, TOOL_PINS)?, on: level(v)? },
        ["set", "ai", n, v] => Command::SetAnalogInput {
            channel: channel(n)?,
            value: v.parse().map_err(|_| format!("analog value must be 0..=65535 (uA or mV), not `{v}`"))?,
        },
        ["set", "do" | "tool-do" | "ao", ..] => return Err("outputs are driven by the Modbus masters; use get".into()),
        ["set", ..] => return Err("usage: set di N 0|1 | set tool-di N 0|1 | set ai N VALUE".into()),
        ["get", "di"] => Command::GetDigitalInputs,
        ["get", "tool-di"] => Command::GetToolInputs,
        ["get", "ai", n] => Command::GetAnalogInput { channel: channel(n)? },
        ["get", "do"] => Command::GetDigitalOutputs,
        ["get", "tool-do"] => Command::GetToolOutputs,
        ["get", "ao", n] => Command::GetAnalogOutput { channel: channel(n)? },
        ["get", "robot"] => Command::GetRobot,
        ["get", "stats"] => Command::GetStats,
        ["get", "locate"] => Command::GetLocate,
        ["get", ..] => {
            return Err("usage: get di | get tool-di | get ai N | get do | get tool-do | get ao N | get robot | \
                 get stats | get locate"
                .into());
        }
        ["factory-reset"] => Command::FactoryReset,
        ["button"] => Command::Button,
        ["robot", rest @ ..] => Command::Robot(robot_event(rest)?),
        ["help"] => Command::Help,
        [] => return Err("empty command".into()),
        [word, ..] => return Err(format!("unknown command `{word}` (try help)")),
    };
    Ok(command)
}

fn robot_event(words: &[&str]) -> Result<Event, String> {
    let event = match words {
        ["estop", action] => Event::EmergencyStop { pressed: pressed(action)? },
        ["safety-stop"] => Event::SafetyStop { recovery: false },
        ["safety-stop", "recovery"] => Event::SafetyStop { recovery: true },
        ["reset"] => Event::Reset,
        ["recover"] => Event::Recover,
        ["teach", action] => Event::TeachButton { pressed: pressed(action)? },
        ["power", action] => Event::PowerButton { pressed: pressed(action)? },
        ["state", state] => Event::SetState(robot_state(state)?),
        _ => {
            return Err("usage: robot estop press|release | robot safety-stop [recovery] | robot reset | \
                 robot recover | robot teach press|release | robot power press|release | robot state N|NAME"
                .into());
        }
    };
    Ok(event)
}

/// A 1-based pin number, 1..=`count`, as a 0-based bit.
fn pin(text: &str, count: u8) -> Result<u8, String> {
    match text.parse::<u8>() {
        Ok(n) if (1..=count).contains(&n) => Ok(n - 1),
        _ => Err(format!("pin must be 1..={count}, not `{text}`")),
    }
}

fn channel(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(n) if (1..=ANALOG_CHANNELS).contains(&n) => Ok(n - 1),
        _ => Err(format!("analog channel must be 1..={ANALOG_CHANNELS}, not `{text}`")),
    }
}

fn level(text: &str) -> Result<bool, String> {
    match text {
        "0" => Ok(false),
        "1" => Ok(true),
        _ => Err(format!("level must be 0 or 1, not `{text}`")),
    }
}

fn pressed(text: &str) -> Result<bool, String> {
    match text {
        "press" => Ok(true),
        "release" => Ok(false),
        _ => Err(format!("button action must be press or release, not `{text}`")),
    }
}

fn robot_state(text: &str) -> Result<RobotState, String> {
    let by_number = text.parse::<u16>().ok().and_then(|n| STATES.iter().find(|(s, _)| *s as u16 == n));
    let by_name = STATES.iter().find(|(_, name)| name.eq_ignore_ascii_case(text));
    by_number
        .or(by_name)
        .map(|&(state, _)| state)
        .ok_or_else(|| format!("robot state must be 0..=10 or 15 or a name ({}), not `{text}`", names()))
}

fn names() -> String {
    STATES.iter().map(|(_, name)| *name).collect::<Vec<_>>().join(", ")
}

/// Registers 259-264 as the reply shows them: `STATE SERVO ESTOP SAFETY TEACH POWER`.
pub fn status_words(status: &RobotStatus) -> String {
    status.registers().map(|value| value.to_string()).join(" ")
}

/// Runs `command` on the board; the reply line, without its newline. A
/// factory reset is only answered here: [`serve`] does it once the reply
/// is out.
pub fn execute(board: &Board, controller: &SimController, command: Command) -> String {
    match command {
        Command::SetDigitalInput { pin, on } => {
            board.set_digital_input(pin, on);
            log::info!("control: digital input {} = {}", pin + 1, u8::from(on));
            "ok".into()
        }
        Command::SetToolInput { pin, on } => {
            board.set_tool_input(pin, on);
            log::info!("control: tool digital input {} = {}", pin + 1, u8::from(on));
            "ok".into()
        }
        Command::SetAnalogInput { channel, value } => {
            board.set_analog_input(channel, value);
            log::info!("control: analog input {} = {}", channel + 1, value);
            "ok".into()
        }
        Command::GetDigitalInputs => format!("ok {}", board.inputs().0),
        Command::GetToolInputs => format!("ok {}", board.inputs().1),
        Command::GetAnalogInput { channel } => {
            let (value, kind) = board.device.read(|image| {
                let kind = image.analog_input_types().get(channel).copied().unwrap_or_default();
                (image.analog_input(channel), kind)
            });
            format!("ok {value} {}", kind.register())
        }
        Command::GetDigitalOutputs => format!("ok {}", board.outputs.get().digital),
        Command::GetToolOutputs => format!("ok {}", board.outputs.get().tool),
        Command::GetAnalogOutput { channel } => {
            let output = board.outputs.get().analog.get(channel).copied().unwrap_or_default();
            format!("ok {} {}", output.value, output.kind.register())
        }
        Command::GetRobot => format!("ok {}", status_words(&board.robot_status())),
        Command::GetStats => format!("ok {}", board.device.stats().snapshot()),
        Command::Robot(event) => match board.robot_event(event) {
            Ok(status) => {
                log::info!("control: robot {:?}: state {:?}", event, status.state);
                format!("ok {}", status_words(&status))
            }
            Err(refused) => {
                log::info!("control: robot {:?} refused: {}", event, refused);
                format!("err {refused}")
            }
        },
        Command::GetLocate => format!("ok {}", u8::from(controller.platform().locating())),
        Command::FactoryReset => {
            log::warn!("control: factory reset");
            "ok erasing the settings, then rebooting".into()
        }
        Command::Button => {
            controller.open_first_password_window();
            log::info!("control: the button, pressed briefly");
            format!("ok first password open: {}", u8::from(controller.first_password_open()))
        }
        Command::Help => HELP.into(),
    }
}

/// One reply for one line of bytes, and the command it ran.
pub fn reply(board: &Board, controller: &SimController, line: &[u8]) -> (String, Option<Command>) {
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    let result = std::str::from_utf8(line).map_err(|_| "command is not UTF-8".to_owned()).and_then(parse);
    match result {
        Ok(command) => (execute(board, controller, command), Some(command)),
        Err(reason) => (format!("err {reason}"), None),
    }
}

/// Binds the control socket at `path`, replacing a stale socket file left
/// by a hal-sim that is gone (but not one that still answers). The listener
/// is non-blocking.
pub fn bind(path: &Path) -> std::io::Result<UnixListener> {
    if path.exists() {
        if UnixStream::connect(path).is_ok() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AddrInUse,
                "another program is listening on this control socket",
            ));
        }
        std::fs::remove_file(path)?;
    }
    let listener = UnixListener::bind(path)?;
    listener.set_nonblocking(true)?;
    Ok(listener)
}

/// The next connection, non-blocking like the listener.
async fn accept(listener: &UnixListener) -> std::io::Result<UnixStream> {
    let (stream, _) = runtime::read_with(listener, UnixListener::accept).await?;
    stream.set_nonblocking(true)?;
    Ok(stream)
}

/// Writes all of `bytes`, waiting whenever the socket's buffer is full.
async fn write_all(stream: &UnixStream, mut bytes: &[u8]) -> std::io::Result<()> {
    while !bytes.is_empty() {
        match runtime::write_with(stream, |mut s| s.write(bytes)).await? {
            0 => return Err(std::io::ErrorKind::WriteZero.into()),
            n => bytes = bytes.get(n..).unwrap_or_default(),
        }
    }
    Ok(())
}

/// Accepts control connections forever; each is served by its own task.
#[embassy_executor::task]
pub async fn accept_task(
    spawner: Spawner,
    listener: UnixListener,
    board: &'static Board,
    controller: &'static SimController,
) -> ! {
    static ACTIVE: ActiveClients = ActiveClients(std::sync::atomic::AtomicUsize::new(0));
    loop {
        let stream = match accept(&listener).await {
            Ok(stream) => stream,
            Err(e) => {
                log::warn!("control: accept failed: {e}");
                embassy_time::Timer::after_millis(100).await;
                continue;
            }
        };
        let admitted = ACTIVE.0.load(std::sync::atomic::Ordering::Relaxed) < MAX_CONTROL_CLIENTS;
        if !admitted {
            let _ = write_all(&stream, b"err busy: too many control connections\n").await;
            continue;
        }
        match client_task(stream, board, controller, &ACTIVE) {
            Ok(token) => spawner.spawn(token),
            Err(e) => log::warn!("control: cannot serve a connection: {e:?}"),
        }
    }
}

/// How many control connections are open.
struct ActiveClients(std::sync::atomic::AtomicUsize);

#[embassy_executor::task(pool_size = MAX_CONTROL_CLIENTS)]
async fn client_task(
    stream: UnixStream,
    board: &'static Board,
    controller: &'static SimController,
    active: &'static ActiveClients,
) {
    use std::sync::atomic::Ordering::Relaxed;
    active.0.fetch_add(1, Relaxed);
    if let Err(e) = serve(&stream, board, controller).await {
        log::debug!("control: connection ended: {e}");
    }
    active.0.fetch_sub(1, Relaxed);
}

/// Answers every line of one connection until it closes (or a factory
/// reset, after its reply, ends hal-sim's run).
async fn serve(stream: &UnixStream, board: &Board, controller: &SimController) -> std::io::Result<()> {
    let mut buffer = [0u8; MAX_LINE_LEN];
    let mut filled = 0;
    let mut discarding = false;
    loop {
        let free = buffer.get_mut(filled..).unwrap_or_default();
        let n = runtime::read_with(stream, |mut s| s.read(free)).await?;
        if n == 0 {
            return Ok(());
        }
        filled += n;
        let mut start = 0;
        let mut out = String::new();
        let mut reset = false;
        while let Some(end) = buffer.get(start..filled).and_then(|rest| rest.iter().position(|&b| b == b'\n')) {
            let line = buffer.get(start..start + end).unwrap_or_default();
            if std::mem::take(&mut discarding) {
                let _ = writeln!(out, "err line longer than {MAX_LINE_LEN} bytes");
            } else {
                let (text, command) = reply(board, controller, line);
                let _ = writeln!(out, "{text}");
                if command == Some(Command::FactoryReset) {
                    // Nothing after it runs: the reboot ends this run.
                    reset = true;
                    break;
                }
            }
            start += end + 1;
        }
        if reset {
            write_all(stream, out.as_bytes()).await?;
            controller.factory_reset().await;
            return Ok(());
        }
        buffer.copy_within(start..filled, 0);
        filled -= start;
        if filled == buffer.len() {
            // No newline in a whole buffer: drop it and the rest of the line.
            discarding = true;
            filled = 0;
        }
        if !out.is_empty() {
            write_all(stream, out.as_bytes()).await?;
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "a failed step is a failed test")]
mod tests {
    use super::*;

    #[test]
    fn commands_of_the_issue() {
        assert_eq!(parse("set di 1 1"), Ok(Command::SetDigitalInput { pin: 0, on: true }));
        assert_eq!(parse("set di 16 0"), Ok(Command::SetDigitalInput { pin: 15, on: false }));
        assert_eq!(parse("set tool-di 6 1"), Ok(Command::SetToolInput { pin: 5, on: true }));
        assert_eq!(parse("set ai 2 12000"), Ok(Command::SetAnalogInput { channel: 1, value: 12000 }));
        assert_eq!(parse("get do"), Ok(Command::GetDigitalOutputs));
        assert_eq!(parse("get tool-do"), Ok(Command::GetToolOutputs));
        assert_eq!(parse("  get   ao 1 "), Ok(Command::GetAnalogOutput { channel: 0 }));
    }

    #[test]
    fn robot_events() {
        assert_eq!(parse("robot estop press"), Ok(Command::Robot(Event::EmergencyStop { pressed: true })));
        assert_eq!(parse("robot estop release"), Ok(Command::Robot(Event::EmergencyStop { pressed: false })));
        assert_eq!(parse("robot safety-stop"), Ok(Command::Robot(Event::SafetyStop { recovery: false })));
        assert_eq!(parse("robot safety-stop recovery"), Ok(Command::Robot(Event::SafetyStop { recovery: true })));
        assert_eq!(parse("robot reset"), Ok(Command::Robot(Event::Reset)));
        assert_eq!(parse("robot recover"), Ok(Command::Robot(Event::Recover)));
        assert_eq!(parse("robot teach press"), Ok(Command::Robot(Event::TeachButton { pressed: true })));
        assert_eq!(parse("robot power release"), Ok(Command::Robot(Event::PowerButton { pressed: false })));
        assert_eq!(parse("robot state 7"), Ok(Command::Robot(Event::SetState(RobotState::Homing))));
        assert_eq!(parse("robot state NOT-READY"), Ok(Command::Robot(Event::SetState(RobotState::NotReady))));
        assert_eq!(parse("get robot"), Ok(Command::GetRobot));
        assert_eq!(parse("get stats"), Ok(Command::GetStats));
    }

    #[test]
    fn locate_and_factory_reset() {
        assert_eq!(parse("get locate"), Ok(Command::GetLocate));
        assert_eq!(parse("factory-reset"), Ok(Command::FactoryReset));
        assert!(parse("factory-reset now").unwrap_err().contains("unknown command"));
        assert!(HELP.contains("get locate") && HELP.contains("factory-reset"));
        assert_eq!(parse("button"), Ok(Command::Button));
        assert!(HELP.contains("button"));
    }

    #[test]
    fn mistakes_have_reasons() {
        for (line, needle) in [
            ("set di 0 1", "1..=16"),
            ("set di 17 1", "1..=16"),
            ("set di 1 2", "0 or 1"),
            ("set tool-di 7 1", "1..=6"),
            ("set ai 3 5", "1..=2"),
            ("set ai 1 -5", "0..=65535"),
            ("set do 1 1", "masters"),
            ("get ao 0", "1..=2"),
            ("get", "usage"),
            ("robot state 11", "0..=10 or 15"),
            ("robot estop push", "press or release"),
            ("robot dance", "usage"),
            ("", "empty"),
            ("launch", "unknown command `launch`"),
        ] {
            let e = parse(line).unwrap_err();
            assert!(e.contains(needle), "{line:?}: {e}");
        }
    }
}
