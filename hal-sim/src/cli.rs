//! The command line (docs/hal-sim.md). Every mistake is a [`UsageError`]
//! with a sentence for the user; nothing here panics.

use std::fmt;
use std::net::Ipv4Addr;
use std::path::PathBuf;

use adapter::map::WritePolicy;
use adapter::server::access::MAX_ALLOWED_NETWORKS;
use adapter::server::{self, Access, AllowList, Config, Network, Policy, SafeState, Watchdog};
use embassy_time::Duration;
use sim_robot::Mode;

pub const USAGE: &str = "\
usage: hal-sim --tap NAME [--ip CIDR] [--gateway IP] [--port 502] [--max-connections 8]
               [--idle-timeout SECS] [--unit-id N] [--write-policy seed|strict]
               [--control PATH] [--robot demo|idle]
               [--watchdog SECS] [--safe-do MASK] [--safe-tool-do MASK]
               [--safe-ao1 VALUE] [--safe-ao2 VALUE]
               [--allow CIDR,...] [--allow-write CIDR,...]

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
  --watchdog SECS       communication watchdog: with no valid request for SECS seconds (decimals
                        allowed, e.g. 0.5), the outputs go to their safe state until written
                        again; 0: off (default)
  --safe-do MASK        digital outputs in the safe state, bit n = output n+1 (default 0: all off;
                        decimal or 0x-hex)
  --safe-tool-do MASK   tool digital outputs in the safe state (default 0)
  --safe-ao1 VALUE      analog output 1 in the safe state, in the unit of its type (default 0)
  --safe-ao2 VALUE      analog output 2 in the safe state (default 0)
  --allow CIDR,...      only clients in these networks may connect (up to 8; default: everyone);
                        others are refused at once
  --allow-write CIDR,...
                        only clients in these networks may write (up to 8; default: everyone);
                        others get exception 01 on write functions
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
    Run(Box<Options>),
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
    let mut watchdog = None;
    let mut safe_do = None;
    let mut safe_tool_do = None;
    let mut safe_ao1 = None;
    let mut safe_ao2 = None;
    let mut allow = None;
    let mut allow_write = None;

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
            "--watchdog" => &mut watchdog,
            "--safe-do" => &mut safe_do,
            "--safe-tool-do" => &mut safe_tool_do,
            "--safe-ao1" => &mut safe_ao1,
            "--safe-ao2" => &mut safe_ao2,
            "--allow" => &mut allow,
            "--allow-write" => &mut allow_write,
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
    let timeout = watchdog.map(|text| parse_seconds("--watchdog", &text)).transpose()?.flatten();
    let safe_state = SafeState {
        digital: safe_do.map(|text| mask("--safe-do", &text, u16::MAX)).transpose()?.unwrap_or(0),
        tool: safe_tool_do.map(|text| mask("--safe-tool-do", &text, 0b11_1111)).transpose()?.unwrap_or(0) as u8,
        analog: [
            safe_ao1.map(|text| number::<u16>("--safe-ao1", &text, 0, ANALOG_MAX)).transpose()?.unwrap_or(0),
            safe_ao2.map(|text| number::<u16>("--safe-ao2", &text, 0, ANALOG_MAX)).transpose()?.unwrap_or(0),
        ],
    };
    let access = Access {
        connect: allow.map(|text| allow_list("--allow", &text)).transpose()?,
        write: allow_write.map(|text| allow_list("--allow-write", &text)).transpose()?,
    };
    let config = Config {
        port,
        max_connections,
        policy: Policy { unit_id, write_policy, read_only: false },
        idle_timeout,
        access,
        watchdog: Watchdog { timeout, safe_state },
        ..Config::DEFAULT
    };
    let options = Options { tap, address, prefix_len, gateway, config, control: control.map(PathBuf::from), robot };
    Ok(Action::Run(Box::new(options)))
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

/// The largest analog value of either type (20 000 µA; a voltage output is
/// clamped to 10 000 mV when the safe state applies).
const ANALOG_MAX: u16 = adapter::map::table::ANALOG_MAX_MICROAMPS;
/// The longest `--watchdog`, in seconds (a day).
pub const MAX_WATCHDOG_SECS: u64 = 24 * 3600;

/// Seconds with up to 3 decimals; 0 is `None` (off).
fn parse_seconds(flag: &str, text: &str) -> Result<Option<Duration>, UsageError> {
    let bad =
        || UsageError(format!("`{flag}` must be seconds from 0 to {MAX_WATCHDOG_SECS} (like 2 or 0.5), not `{text}`"));
    let (whole, fraction) = text.split_once('.').unwrap_or((text, ""));
    if whole.is_empty() || fraction.len() > 3 || !fraction.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad());
    }
    let secs: u64 = whole.parse().map_err(|_| bad())?;
    let millis: u64 = if fraction.is_empty() { 0 } else { format!("{fraction:0<3}").parse().map_err(|_| bad())? };
    if secs > MAX_WATCHDOG_SECS || (secs == MAX_WATCHDOG_SECS && millis > 0) {
        return Err(bad());
    }
    Ok(Some(Duration::from_millis(secs * 1000 + millis)).filter(|d| d.as_millis() > 0))
}

/// A bit mask, decimal or `0x` hexadecimal, at most `max`.
fn mask(flag: &str, text: &str, max: u16) -> Result<u16, UsageError> {
    let value = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    };
    match value {
        Some(value) if value <= max => Ok(value),
        _ => error(format!("`{flag}` must be a bit mask from 0 to {max} (or 0x{max:x}), not `{text}`")),
    }
}

/// A comma-separated list of networks, such as `198.18.0.0/24,10.1.2.3/32`.
fn allow_list(flag: &str, text: &str) -> Result<AllowList, UsageError> {
    let mut list = AllowList::EMPTY;
    for item in text.split(',').map(str::trim) {
        let (address, prefix) = match item.split_once('/') {
            Some((address, prefix)) => (address, number::<u8>(&format!("{flag} prefix length"), prefix, 0, 32)?),
            None => (item, 32),
        };
        let address = parse_ipv4(flag, address)?;
        let network = Network::new(address.octets(), prefix)
            .ok_or_else(|| UsageError(format!("`{flag}`: bad network `{item}`")))?;
        list = list
            .with(network)
            .ok_or_else(|| UsageError(format!("`{flag}` takes at most {MAX_ALLOWED_NETWORKS} networks")))?;
    }
    Ok(list)
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
            Action::Run(options) => Ok(*options),
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
        assert_eq!(o.config.policy, Policy { unit_id: Some(17), write_policy: WritePolicy::Strict, read_only: false });
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
        fails(&["--tap", "t", "--watchdog", "1.2345"], "like 2 or 0.5");
        fails(&["--tap", "t", "--watchdog", "-1"], "like 2 or 0.5");
        fails(&["--tap", "t", "--watchdog", "86401"], "like 2 or 0.5");
        fails(&["--tap", "t", "--safe-do", "65536"], "bit mask");
        fails(&["--tap", "t", "--safe-tool-do", "0x40"], "from 0 to 63");
        fails(&["--tap", "t", "--safe-ao1", "20001"], "from 0 to 20000");
        fails(&["--tap", "t", "--allow", "198.18.0.0/33"], "prefix length");
        fails(&["--tap", "t", "--allow-write", "198.18.0"], "not an IPv4 address");
        let nine = (1..=9).map(|i| format!("10.0.0.{i}")).collect::<Vec<_>>().join(",");
        fails(&["--tap", "t", "--allow", &nine], "at most 8 networks");
    }

    #[test]
    fn watchdog_safe_state_and_access() {
        let o = run(&[
            "--tap",
            "t",
            "--watchdog",
            "0.5",
            "--safe-do",
            "0x8001",
            "--safe-tool-do",
            "3",
            "--safe-ao1",
            "4000",
            "--allow",
            "198.18.0.0/24, 10.0.0.7",
            "--allow-write",
            "198.18.0.9/32",
        ])
        .unwrap();
        let watchdog = o.config.watchdog;
        assert_eq!(watchdog.timeout, Some(Duration::from_millis(500)));
        assert_eq!(watchdog.safe_state, SafeState { digital: 0x8001, tool: 3, analog: [4000, 0] });
        let access = o.config.access;
        assert!(access.may_connect([198, 18, 0, 200]) && access.may_connect([10, 0, 0, 7]));
        assert!(!access.may_connect([10, 0, 0, 8]));
        assert!(access.may_write([198, 18, 0, 9]) && !access.may_write([198, 18, 0, 1]));
        assert_eq!(run(&["--tap", "t", "--watchdog", "0"]).unwrap().config.watchdog.timeout, None);
        assert_eq!(
            run(&["--tap", "t", "--watchdog", "3"]).unwrap().config.watchdog.timeout,
            Some(Duration::from_secs(3))
        );
        assert_eq!(run(&["--tap", "t"]).unwrap().config.access, Access::OPEN);
    }

    #[test]
    fn an_address_without_prefix_is_a_slash_24() {
        assert_eq!(run(&["--tap", "t", "--ip", "198.18.5.5"]).unwrap().prefix_len, 24);
    }
}
