//! The command line (docs/hal-sim.md). Every mistake is a [`UsageError`]
//! with a sentence for the user; nothing here panics.

use std::fmt;
use std::net::Ipv4Addr;
use std::path::PathBuf;

use embassy_time::Duration;
use firmware::map::WritePolicy;
use firmware::server::{self, Config, Policy};
use firmware::sim_robot::Mode;

pub const USAGE: &str = "\
usage: hal-sim --tap NAME [--ip CIDR] [--gateway IP] [--port 502] [--max-connections 8]
               [--idle-timeout SECS] [--unit-id N] [--write-policy seed|strict]
               [--control PATH] [--robot demo|idle]

  --tap NAME            the TAP interface to run on (made beforehand with
                        `ip tuntap add dev NAME mode tap user $USER`, or by hal-sim as root)
  --ip CIDR             the simulated device's address (default 198.18.0.2/24)
  --gateway IP          default gateway (default: none)
  --port N              Modbus TCP port (default 502)
  --max-connections N   sessions served at once, 1..=MAX (default MAX, 8 unless rebuilt
                        with MODBUS_MAX_CONNECTIONS)
  --idle-timeout SECS   close a session with no request for SECS seconds; 0: never (default 60)
  --unit-id N           answer only unit id N (and 0, 255); others get exception 0B
                        (default: answer every unit id)
  --write-policy P      seed (default): writes to read-only points are acknowledged and
                        overwritten by their source; strict: they get exception 02
  --control PATH        a Unix socket for simulated inputs, outputs and robot events
  --robot MODE          demo (default): a robot running a looping program; idle: STANDBY, still
  -h, --help            this text
  -V, --version         hal-sim's version and the firmware version it reports";

/// The device's address unless `--ip` says otherwise.
pub const DEFAULT_IP: (Ipv4Addr, u8) = (Ipv4Addr::new(198, 18, 0, 2), 24);
/// Linux interface names are at most this long (IFNAMSIZ less the NUL).
pub const MAX_TAP_NAME_LEN: usize = 15;
/// The longest `--idle-timeout` (a year, in seconds).
pub const MAX_IDLE_TIMEOUT_SECS: u64 = 365 * 24 * 3600;

/// What the command line asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    pub tap: String,
    pub address: Ipv4Addr,
    pub prefix_len: u8,
    pub gateway: Option<Ipv4Addr>,
    pub config: Config,
    pub control: Option<PathBuf>,
    pub robot: Mode,
}

/// What to do.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    Run(Options),
    Help,
    Version,
}

/// A command line hal-sim cannot run with.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UsageError(pub String);

impl fmt::Display for UsageError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for UsageError {}

fn error<T>(message: impl Into<String>) -> Result<T, UsageError> {
    Err(UsageError(message.into()))
}

/// Parses the arguments (without the program name).
pub fn parse(args: impl IntoIterator<Item = String>) -> Result<Action, UsageError> {
    let mut tap = None;
    let mut ip = None;
    let mut gateway = None;
    let mut port = None;
    let mut max_connections = None;
    let mut idle_timeout = None;
    let mut unit_id = None;
    let mut write_policy = None;
    let mut control = None;
    let mut robot = None;

    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        let (flag, inline) = match arg.split_once('=') {
            Some((flag, value)) if flag.starts_with("--") => (flag.to_owned(), Some(value.to_owned())),
            _ => (arg.clone(), None),
        };
        match flag.as_str() {
            "-h" | "--help" => return Ok(Action::Help),
            "-V" | "--version" => return Ok(Action::Version),
            _ => {}
        }
        let slot: &mut Option<String> = match flag.as_str() {
            "--tap" => &mut tap,
            "--ip" => &mut ip,
            "--gateway" => &mut gateway,
            "--port" => &mut port,
            "--max-connections" => &mut max_connections,
            "--idle-timeout" => &mut idle_timeout,
            "--unit-id" => &mut unit_id,
            "--write-policy" => &mut write_policy,
            "--control" => &mut control,
            "--robot" => &mut robot,
            _ if flag.starts_with('-') => return error(format!("unknown option `{flag}`")),
            _ => return error(format!("unexpected argument `{arg}` (options start with --)")),
        };
        if slot.is_some() {
            return error(format!("`{flag}` given twice"));
        }
        let value = match inline.or_else(|| args.next()) {
            Some(value) if !value.is_empty() => value,
            _ => return error(format!("`{flag}` needs a value")),
        };
        *slot = Some(value);
    }

    let tap = tap.ok_or_else(|| UsageError("`--tap NAME` is required".into()))?;
    check_interface_name(&tap)?;
    let (address, prefix_len) = match ip {
        Some(text) => parse_cidr(&text)?,
        None => DEFAULT_IP,
    };
    let gateway = gateway.map(|text| parse_ipv4("--gateway", &text)).transpose()?;
    let port = match port {
        Some(text) => number::<u16>("--port", &text, 1, u16::MAX)?,
        None => server::MODBUS_PORT,
    };
    let max_connections = match max_connections {
        Some(text) => number::<usize>("--max-connections", &text, 1, server::MAX_CONNECTIONS).map_err(|e| {
            UsageError(format!(
                "{e} (this build serves at most {}; rebuild with MODBUS_MAX_CONNECTIONS=N for more)",
                server::MAX_CONNECTIONS
            ))
        })?,
        None => server::MAX_CONNECTIONS,
    };
    let idle_timeout = match idle_timeout {
        Some(text) => match number::<u64>("--idle-timeout", &text, 0, MAX_IDLE_TIMEOUT_SECS)? {
            0 => None,
            secs => Some(Duration::from_secs(secs)),
        },
        None => Some(server::IDLE_TIMEOUT),
    };
    let unit_id = unit_id.map(|text| number::<u8>("--unit-id", &text, 0, u8::MAX)).transpose()?;
    let write_policy = match write_policy.as_deref() {
        None | Some("seed") => WritePolicy::Seed,
        Some("strict") => WritePolicy::Strict,
        Some(other) => return error(format!("`--write-policy` must be seed or strict, not `{other}`")),
    };
    let robot = match robot.as_deref() {
        None | Some("demo") => Mode::Demo,
        Some("idle") => Mode::Idle,
        Some(other) => return error(format!("`--robot` must be demo or idle, not `{other}`")),
    };
    let config =
        Config { port, max_connections, policy: Policy { unit_id, write_policy }, idle_timeout, ..Config::DEFAULT };
    Ok(Action::Run(Options { tap, address, prefix_len, gateway, config, control: control.map(PathBuf::from), robot }))
}

/// The kernel's rules for an interface name (`dev_valid_name`).
fn check_interface_name(name: &str) -> Result<(), UsageError> {
    if name.len() > MAX_TAP_NAME_LEN {
        return error(format!("`--tap {name}`: interface names are at most {MAX_TAP_NAME_LEN} bytes"));
    }
    if name == "." || name == ".." || name.chars().any(|c| c == '/' || c == ':' || c.is_whitespace() || c.is_control())
    {
        return error(format!("`--tap {name:?}` is not a valid interface name"));
    }
    Ok(())
}

fn parse_cidr(text: &str) -> Result<(Ipv4Addr, u8), UsageError> {
    let (address, prefix) = match text.split_once('/') {
        Some((address, prefix)) => (address, number::<u8>("--ip prefix length", prefix, 1, 32)?),
        None => (text, DEFAULT_IP.1),
    };
    let address = parse_ipv4("--ip", address)?;
    if address.is_unspecified() || address.is_broadcast() || address.is_multicast() {
        return error(format!("`--ip {text}`: the device needs a unicast address"));
    }
    Ok((address, prefix))
}

fn parse_ipv4(flag: &str, text: &str) -> Result<Ipv4Addr, UsageError> {
    text.parse().or_else(|_| error(format!("`{flag}`: `{text}` is not an IPv4 address (like 198.18.0.2)")))
}

fn number<T>(flag: &str, text: &str, min: T, max: T) -> Result<T, UsageError>
where
    T: std::str::FromStr + PartialOrd + fmt::Display + Copy,
{
    match text.parse::<T>() {
        Ok(value) if value >= min && value <= max => Ok(value),
        _ => error(format!("`{flag}` must be a whole number from {min} to {max}, not `{text}`")),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic, reason = "a failed step is a failed test")]
mod tests {
    use super::*;

    fn run(args: &[&str]) -> Result<Options, UsageError> {
        match parse(args.iter().map(|s| s.to_string()))? {
            Action::Run(options) => Ok(options),
            other => panic!("{other:?}"),
        }
    }

    fn fails(args: &[&str], needle: &str) {
        let e = run(args).unwrap_err();
        assert!(e.0.contains(needle), "{e}");
    }

    #[test]
    fn defaults() {
        let o = run(&["--tap", "tap0"]).unwrap();
        assert_eq!(o.tap, "tap0");
        assert_eq!((o.address, o.prefix_len), DEFAULT_IP);
        assert_eq!(o.gateway, None);
        assert_eq!(o.config, Config::DEFAULT);
        assert_eq!(o.control, None);
        assert_eq!(o.robot, Mode::Demo);
    }

    #[test]
    fn every_option() {
        let o = run(&[
            "--tap=sim1",
            "--ip",
            "198.18.1.9/16",
            "--gateway",
            "198.18.0.1",
            "--port",
            "1502",
            "--max-connections",
            "3",
            "--idle-timeout",
            "0",
            "--unit-id",
            "17",
            "--write-policy",
            "strict",
            "--control",
            "/tmp/c.sock",
            "--robot",
            "idle",
        ])
        .unwrap();
        assert_eq!((o.address, o.prefix_len), (Ipv4Addr::new(198, 18, 1, 9), 16));
        assert_eq!(o.gateway, Some(Ipv4Addr::new(198, 18, 0, 1)));
        assert_eq!(o.config.port, 1502);
        assert_eq!(o.config.max_connections, 3);
        assert_eq!(o.config.idle_timeout, None);
        assert_eq!(o.config.policy, Policy { unit_id: Some(17), write_policy: WritePolicy::Strict });
        assert_eq!(o.control, Some(PathBuf::from("/tmp/c.sock")));
        assert_eq!(o.robot, Mode::Idle);
        assert_eq!(
            run(&["--tap", "t", "--idle-timeout", "5"]).unwrap().config.idle_timeout,
            Some(Duration::from_secs(5))
        );
    }

    #[test]
    fn help_and_version() {
        assert_eq!(parse(["--tap".into(), "x".into(), "-h".into()]).unwrap(), Action::Help);
        assert_eq!(parse(["--version".into()]).unwrap(), Action::Version);
    }

    #[test]
    fn bad_arguments_say_what_is_wrong() {
        fails(&[], "--tap NAME` is required");
        fails(&["--tap"], "needs a value");
        fails(&["--tap", "a", "--tap", "b"], "given twice");
        fails(&["--tap", "waytoolonginterface0"], "at most 15 bytes");
        fails(&["--tap", "a/b"], "not a valid interface name");
        fails(&["--tap", "t", "--ip", "198.18.0.300/24"], "not an IPv4 address");
        fails(&["--tap", "t", "--ip", "198.18.0.2/33"], "from 1 to 32");
        fails(&["--tap", "t", "--ip", "0.0.0.0/8"], "unicast");
        fails(&["--tap", "t", "--port", "0"], "from 1 to 65535");
        fails(&["--tap", "t", "--port", "70000"], "from 1 to 65535");
        fails(&["--tap", "t", "--max-connections", "0"], "MODBUS_MAX_CONNECTIONS");
        fails(&["--tap", "t", "--max-connections", "999"], "at most");
        fails(&["--tap", "t", "--idle-timeout", "-1"], "--idle-timeout");
        fails(&["--tap", "t", "--unit-id", "256"], "from 0 to 255");
        fails(&["--tap", "t", "--write-policy", "lax"], "seed or strict");
        fails(&["--tap", "t", "--robot", "dance"], "demo or idle");
        fails(&["--tap", "t", "--frobnicate"], "unknown option");
        fails(&["--tap", "t", "extra"], "unexpected argument");
        fails(&["--tap", "t", "--gateway", "x"], "not an IPv4 address");
        fails(&["--tap", "t", "--control="], "needs a value");
    }

    #[test]
    fn an_address_without_prefix_is_a_slash_24() {
        assert_eq!(run(&["--tap", "t", "--ip", "198.18.5.5"]).unwrap().prefix_len, 24);
    }
}
