//! The command line (docs/hal-sim.md). hal-sim's own options (the TAP, the
//! control socket, the simulated robot) are here; every device setting is a
//! flag of the settings model ([`adapter::settings::Field`]), with its rule
//! and its parser, so hal-sim and the boards cannot drift. Every mistake is
//! a [`UsageError`] with a sentence for the user; nothing here panics.

use std::fmt::{self, Write as _};
use std::path::PathBuf;

use adapter::settings::{Cidr, Field, Name, NetMode, Settings};
use sim_robot::Mode;

/// The longest busy poll `--busy-poll` takes, in microseconds: a spin
/// longer than a millisecond would only burn the CPU (a client that waits
/// that long between requests gains nothing measurable from it).
pub const MAX_BUSY_POLL_US: u64 = 1_000;

/// The first lines of the usage text; the settings follow, from the table.
const USAGE_HEAD: &str = "\
usage: hal-sim --tap NAME [--control PATH] [--robot demo|idle] [--state FILE] [--http-port N]
               [--https-port N] [--mac MAC] [--client-ca FILE] [--busy-poll US] [SETTING VALUE]...

  --tap NAME            the TAP interface to run on (made beforehand with
                        `ip tuntap add dev NAME mode tap user $USER`, or by hal-sim as root)
  --control PATH        a Unix socket for simulated inputs, outputs and robot events
  --robot MODE          demo (default): a robot running a looping program; idle: STANDBY, still
  --state FILE          the settings flash, kept in FILE (64 KiB; made when missing); without it,
                        settings saved through the HTTP API last until hal-sim exits
  --http-port N         the HTTP API's port, 1-65535, or 0 for none (default 80)
  --https-port N        HTTPS's port (the page and the API), 1-65535, or 0 for none (default 443)
  --mac MAC             the device's MAC, six hex bytes such as 02:4d:42:53:49:4d (unicast; the
                        default), so that several hal-sims share a network; the default name
                        (mbio- and its last 3 bytes) follows it
  --client-ca FILE      the CA (PEM or DER) that Modbus/TCP Security clients' certificates must
                        chain to; without it, port 802 stays closed
  --busy-poll US        when idle, poll the TAP without sleeping for up to US microseconds
                        (0-1000) before each sleep: lower latency for a busy client, for a CPU
                        kept busy meanwhile (default 0: off)
  -h, --help            this text
  -V, --version         hal-sim's version and the firmware version it reports

Settings (docs/settings.md; the same rules as the boards' build-time variables; these are the
factory settings: those saved in --state FILE override them):";

/// The usage text: hal-sim's options, then every setting with its rule and
/// hal-sim's default.
pub fn usage() -> String {
    let mut text = String::from(USAGE_HEAD);
    let defaults = factory_defaults();
    for &field in Field::ALL {
        let mut default = String::new();
        let _ = defaults.show(field, &mut default);
        let _ = write!(text, "\n  --{:<20}{} (default {default})", field.flag(), field.rule());
    }
    text
}

/// hal-sim's factory settings: the model's defaults, named after its MAC,
/// on a static address in the test bench range (a TAP has no DHCP server).
pub fn factory_defaults() -> Settings {
    let mut settings = Settings::DEFAULT;
    settings.device.name = Name::from_mac(crate::MAC);
    settings.network.mode = NetMode::Static;
    settings.network.address = Some(DEFAULT_ADDRESS);
    settings
}

/// The device's address unless `--ip` says otherwise.
pub const DEFAULT_ADDRESS: Cidr = Cidr { address: [198, 18, 0, 2], prefix_len: 24 };
/// Linux interface names are at most this long (IFNAMSIZ less the NUL).
pub const MAX_TAP_NAME_LEN: usize = 15;

/// What the command line asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    pub tap: String,
    pub control: Option<PathBuf>,
    pub robot: Mode,
    /// The settings flash's file (`None`: in memory).
    pub state: Option<PathBuf>,
    /// The device's MAC.
    pub mac: [u8; 6],
    /// The client CA's file (Modbus/TCP Security).
    pub client_ca: Option<PathBuf>,
    /// The HTTP API's port (`None`: no HTTP).
    pub http_port: Option<u16>,
    /// HTTPS's port (`None`: no HTTPS).
    pub https_port: Option<u16>,
    /// How long the loop polls without blocking before it sleeps, in
    /// microseconds (0: never; at most [`MAX_BUSY_POLL_US`]).
    pub busy_poll_us: u64,
    /// The device's factory settings: the model's defaults with the flags
    /// applied. What the state file holds overrides them.
    pub settings: Settings,
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
    let mut control = None;
    let mut robot = None;
    let mut state = None;
    let mut http_port = None;
    let mut https_port = None;
    let mut busy_poll = None;
    let mut mac = None;
    let mut client_ca = None;
    let mut settings = factory_defaults();
    let mut given: Vec<Field> = Vec::new();

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
        let option = match flag.as_str() {
            "--tap" => Target::Own(&mut tap),
            "--control" => Target::Own(&mut control),
            "--robot" => Target::Own(&mut robot),
            "--state" => Target::Own(&mut state),
            "--http-port" => Target::Own(&mut http_port),
            "--https-port" => Target::Own(&mut https_port),
            "--busy-poll" => Target::Own(&mut busy_poll),
            "--mac" => Target::Own(&mut mac),
            "--client-ca" => Target::Own(&mut client_ca),
            _ => match flag.strip_prefix("--").and_then(|name| Field::ALL.iter().find(|f| f.flag() == name)) {
                Some(&field) => Target::Setting(field),
                None if flag.starts_with('-') => return error(format!("unknown option `{flag}`")),
                None => return error(format!("unexpected argument `{arg}` (options start with --)")),
            },
        };
        let value = match inline.or_else(|| args.next()) {
            Some(value) if !value.is_empty() => value,
            _ => return error(format!("`{flag}` needs a value")),
        };
        match option {
            Target::Own(slot) if slot.is_some() => return error(format!("`{flag}` given twice")),
            Target::Own(slot) => *slot = Some(value),
            Target::Setting(field) if given.contains(&field) => return error(format!("`{flag}` given twice")),
            Target::Setting(field) => {
                settings.set(field, &value).or_else(|rule| error(format!("`{flag}` must be {rule}, not `{value}`")))?;
                given.push(field);
            }
        }
    }

    let tap = tap.ok_or_else(|| UsageError("`--tap NAME` is required".into()))?;
    check_interface_name(&tap)?;
    let robot = match robot.as_deref() {
        None | Some("demo") => Mode::Demo,
        Some("idle") => Mode::Idle,
        Some(other) => return error(format!("`--robot` must be demo or idle, not `{other}`")),
    };
    if let Err(errors) = settings.validate() {
        let reasons: Vec<String> = errors.iter().map(|(field, rule)| format!("`--{}` {rule}", field.flag())).collect();
        return error(reasons.join("; "));
    }
    let http_port = port_option("--http-port", http_port.as_deref(), adapter::http::HTTP_PORT)?;
    let https_port = port_option("--https-port", https_port.as_deref(), adapter::http::HTTPS_PORT)?;
    for (flag, port) in [("--http-port", http_port), ("--https-port", https_port)] {
        if port == Some(settings.modbus.port) {
            let modbus = settings.modbus.port;
            return error(format!("`{flag}` and `--port` are both {modbus}: give them different ports"));
        }
        if port == Some(adapter::server::secure::SECURE_PORT) {
            return error(format!("`{flag}` may not be 802, Modbus/TCP Security's port"));
        }
    }
    if http_port.is_some() && http_port == https_port {
        return error("`--http-port` and `--https-port` are the same port: give them different ones");
    }
    let busy_poll_us = match busy_poll.as_deref().map(str::parse::<u64>) {
        None => 0,
        Some(Ok(us)) if us <= MAX_BUSY_POLL_US => us,
        Some(_) => {
            return error(format!(
                "`--busy-poll` must be 0-{MAX_BUSY_POLL_US} microseconds, not `{}`",
                busy_poll.unwrap_or_default()
            ));
        }
    };
    let mac = match mac.as_deref() {
        None => crate::MAC,
        Some(text) => parse_mac(text).ok_or_else(|| {
            UsageError(format!("`--mac` must be six hex bytes such as 02:4d:42:53:49:4d, unicast, not `{text}`"))
        })?,
    };
    if !given.contains(&Field::DeviceName) {
        settings.device.name = Name::from_mac(mac);
    }
    let options = Options {
        tap,
        control: control.map(PathBuf::from),
        robot,
        state: state.map(PathBuf::from),
        mac,
        client_ca: client_ca.map(PathBuf::from),
        http_port,
        https_port,
        busy_poll_us,
        settings,
    };
    Ok(Action::Run(Box::new(options)))
}

/// A port option's value: `default` when not given, `None` for 0.
fn port_option(flag: &str, value: Option<&str>, default: u16) -> Result<Option<u16>, UsageError> {
    match value.map(str::parse::<u16>) {
        None => Ok(Some(default)),
        Some(Ok(0)) => Ok(None),
        Some(Ok(port)) => Ok(Some(port)),
        Some(Err(_)) => error(format!("`{flag}` must be 1-65535, or 0 for none, not `{}`", value.unwrap_or_default())),
    }
}

/// `aa:bb:cc:dd:ee:ff`, a unicast MAC (the first byte's lowest bit clear).
fn parse_mac(text: &str) -> Option<[u8; 6]> {
    let mut mac = [0u8; 6];
    let mut parts = text.split(':');
    for byte in &mut mac {
        let part = parts.next()?;
        if part.len() != 2 {
            return None;
        }
        *byte = u8::from_str_radix(part, 16).ok()?;
    }
    (parts.next().is_none() && mac[0] & 1 == 0).then_some(mac)
}

/// Where a flag's value goes: one of hal-sim's own options, or a setting.
enum Target<'a> {
    Own(&'a mut Option<String>),
    Setting(Field),
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

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic, reason = "a failed step is a failed test")]
mod tests {
    use super::*;
    use adapter::device::SafeState;
    use adapter::map::WritePolicy;
    use adapter::server::{Access, Policy, Rights};
    use embassy_time::Duration;

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
        assert_eq!(o.settings, factory_defaults());
        assert_eq!(o.settings.network.address, Some(DEFAULT_ADDRESS));
        let config = o.settings.server_config(crate::MAC);
        assert_eq!(config, adapter::server::Config { name: config.name, ..adapter::server::Config::DEFAULT });
        assert_eq!(config.name.as_str(), "mbio-53494d", "the default name, from the MAC");
        assert_eq!(o.control, None);
        assert_eq!(o.robot, Mode::Demo);
        assert_eq!(o.state, None);
        assert_eq!(o.http_port, Some(80));
        assert_eq!(o.busy_poll_us, 0, "busy polling is off unless asked for");
    }

    #[test]
    fn busy_poll() {
        assert_eq!(run(&["--tap", "t", "--busy-poll", "50"]).unwrap().busy_poll_us, 50);
        assert_eq!(run(&["--tap", "t", "--busy-poll=0"]).unwrap().busy_poll_us, 0);
        assert_eq!(run(&["--tap", "t", "--busy-poll", "1000"]).unwrap().busy_poll_us, MAX_BUSY_POLL_US);
        fails(&["--tap", "t", "--busy-poll", "1001"], "`--busy-poll` must be 0-1000 microseconds, not `1001`");
        fails(&["--tap", "t", "--busy-poll", "-5"], "not `-5`");
        fails(&["--tap", "t", "--busy-poll", "1", "--busy-poll", "2"], "given twice");
        assert!(usage().contains("--busy-poll US"));
    }

    #[test]
    fn a_mac_of_its_own_names_the_device_after_it() {
        let o = run(&["--tap", "t", "--mac", "02:00:00:0a:0b:0c"]).unwrap();
        assert_eq!(o.mac, [2, 0, 0, 0x0a, 0x0b, 0x0c]);
        assert_eq!(o.settings.device.name.as_str(), "mbio-0a0b0c");
        let named = run(&["--tap", "t", "--mac", "02:00:00:0a:0b:0c", "--name", "cell-1"]).unwrap();
        assert_eq!(named.settings.device.name.as_str(), "cell-1", "a name given wins");
        assert_eq!(run(&["--tap", "t"]).unwrap().mac, crate::MAC);
        for bad in [
            "01:00:00:00:00:01",
            "02:00:00:00:00",
            "02:00:00:00:00:00:00",
            "02-00-00-00-00-01",
            "2:0:0:0:0:1",
            "zz:00:00:00:00:01",
        ] {
            fails(&["--tap", "t", "--mac", bad], "`--mac` must be six hex bytes");
        }
    }

    #[test]
    fn state_and_http_port() {
        let o = run(&["--tap", "t", "--state", "/tmp/s.flash", "--http-port", "8080"]).unwrap();
        assert_eq!(o.state, Some(PathBuf::from("/tmp/s.flash")));
        assert_eq!(o.http_port, Some(8080));
        assert_eq!(run(&["--tap", "t", "--http-port=0"]).unwrap().http_port, None);
        assert_eq!(run(&["--tap", "t", "--port", "80", "--http-port", "0"]).unwrap().http_port, None);
        fails(&["--tap", "t", "--http-port", "65536"], "`--http-port` must be 1-65535, or 0 for none");
        fails(&["--tap", "t", "--http-port", "x"], "not `x`");
        fails(&["--tap", "t", "--port", "80"], "`--http-port` and `--port` are both 80");
        fails(&["--tap", "t", "--port", "1502", "--http-port", "1502"], "both 1502");
        fails(&["--tap", "t", "--state", "a", "--state", "b"], "given twice");
        assert!(usage().contains("--state FILE") && usage().contains("--http-port N"));
    }

    #[test]
    fn https_port() {
        assert_eq!(run(&["--tap", "t"]).unwrap().https_port, Some(443));
        assert_eq!(run(&["--tap", "t", "--https-port", "8443"]).unwrap().https_port, Some(8443));
        assert_eq!(run(&["--tap", "t", "--https-port", "0"]).unwrap().https_port, None);
        fails(&["--tap", "t", "--https-port", "802"], "may not be 802");
        fails(&["--tap", "t", "--https-port", "80"], "`--http-port` and `--https-port` are the same port");
        fails(&["--tap", "t", "--port", "443"], "`--https-port` and `--port` are both 443");
        fails(&["--tap", "t", "--https-port", "-1"], "`--https-port` must be 1-65535, or 0 for none");
        assert!(usage().contains("--https-port N"));
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
        let network = o.settings.network;
        assert_eq!(network.address, Some(Cidr { address: [198, 18, 1, 9], prefix_len: 16 }));
        assert_eq!(network.gateway.map(|g| g.0), Some([198, 18, 0, 1]));
        let config = o.settings.server_config(crate::MAC);
        assert_eq!(config.port, 1502);
        assert_eq!(config.max_connections, 3);
        assert_eq!(config.idle_timeout, None);
        assert_eq!(
            config.policy,
            Policy { unit_id: Some(17), write_policy: WritePolicy::Strict, rights: Rights::ReadWrite }
        );
        assert_eq!(o.control, Some(PathBuf::from("/tmp/c.sock")));
        assert_eq!(o.robot, Mode::Idle);
        let five = run(&["--tap", "t", "--idle-timeout", "5"]).unwrap();
        assert_eq!(five.settings.server_config(crate::MAC).idle_timeout, Some(Duration::from_secs(5)));
    }

    #[test]
    fn every_setting_has_a_flag_in_the_usage() {
        let text = usage();
        for &field in Field::ALL {
            assert!(text.contains(&format!("--{} ", field.flag())), "--{}", field.flag());
        }
        assert!(text.contains("--ip                  none, or an IPv4 address"), "{text}");
        assert!(text.contains("(default 198.18.0.2/24)"), "{text}");
        assert!(text.contains("(default mbio-53494d)"), "{text}");
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
        fails(&["--tap", "t", "--port", "1", "--port", "2"], "given twice");
        fails(&["--tap", "waytoolonginterface0"], "at most 15 bytes");
        fails(&["--tap", "a/b"], "not a valid interface name");
        fails(&["--tap", "t", "--ip", "198.18.0.300/24"], "`--ip` must be none, or an IPv4 address");
        fails(&["--tap", "t", "--ip", "198.18.0.2/33"], "not `198.18.0.2/33`");
        fails(&["--tap", "t", "--ip", "0.0.0.0/8"], "`--ip` must be");
        fails(&["--tap", "t", "--port", "0"], "`--port` must be 1-65535, not `0`");
        fails(&["--tap", "t", "--port", "70000"], "1-65535");
        fails(&["--tap", "t", "--max-connections", "0"], "MODBUS_MAX_CONNECTIONS");
        fails(&["--tap", "t", "--max-connections", "999"], "the build's maximum");
        fails(&["--tap", "t", "--idle-timeout", "-1"], "--idle-timeout");
        fails(&["--tap", "t", "--unit-id", "256"], "any, or 1-247");
        fails(&["--tap", "t", "--write-policy", "lax"], "seed or strict");
        fails(&["--tap", "t", "--robot", "dance"], "demo or idle");
        fails(&["--tap", "t", "--frobnicate"], "unknown option");
        fails(&["--tap", "t", "extra"], "unexpected argument");
        fails(&["--tap", "t", "--gateway", "x"], "an IPv4 address");
        fails(&["--tap", "t", "--gateway", "10.0.0.1"], "`--gateway` must lie inside the address's network");
        fails(&["--tap", "t", "--control="], "needs a value");
        fails(&["--tap", "t", "--watchdog-ms", "50"], "0 (off) or 100-86400000 milliseconds");
        fails(&["--tap", "t", "--watchdog-ms", "-1"], "milliseconds");
        fails(&["--tap", "t", "--watchdog", "1"], "unknown option");
        fails(&["--tap", "t", "--safe-do", "65536"], "bit mask");
        fails(&["--tap", "t", "--safe-tool-do", "0x40"], "0-63");
        fails(&["--tap", "t", "--safe-ao1", "20001"], "0-20000");
        fails(&["--tap", "t", "--allow", "198.18.0.0/33"], "networks");
        fails(&["--tap", "t", "--allow-write", "198.18.0"], "networks");
        fails(&["--tap", "t", "--mode", "dhcp", "--ip", "none", "--mode", "static"], "given twice");
        fails(&["--tap", "t", "--ip", "none"], "`--ip` required when the mode is static");
        let nine = (1..=9).map(|i| format!("10.0.0.{i}")).collect::<Vec<_>>().join(",");
        fails(&["--tap", "t", "--allow", &nine], "up to 8");
        // A leading zero (octal to many parsers) in any address; an empty
        // allow-list, which is not `any`.
        fails(&["--tap", "t", "--ip", "198.018.0.2/24"], "`--ip` must be");
        fails(&["--tap", "t", "--gateway", "198.18.0.01"], "an IPv4 address");
        fails(&["--tap", "t", "--allow", "010.0.0.0/8"], "networks");
        fails(&["--tap", "t", "--allow-write", ""], "needs a value");
    }

    #[test]
    fn watchdog_safe_state_and_access() {
        let o = run(&[
            "--tap",
            "t",
            "--watchdog-ms",
            "500",
            "--safe-do",
            "0x8001",
            "--safe-tool-do",
            "3",
            "--safe-ao1",
            "4000",
            "--allow",
            "198.18.0.0/24,10.0.0.7",
            "--allow-write",
            "198.18.0.9/32",
        ])
        .unwrap();
        let watchdog = o.settings.watchdog();
        assert_eq!(watchdog.timeout, Some(Duration::from_millis(500)));
        assert_eq!(watchdog.safe_state, SafeState { digital: 0x8001, tool: 3, analog: [4000, 0] });
        let access = o.settings.server_config(crate::MAC).access;
        assert!(access.may_connect([198, 18, 0, 200]) && access.may_connect([10, 0, 0, 7]));
        assert!(!access.may_connect([10, 0, 0, 8]));
        assert!(access.may_write([198, 18, 0, 9]) && !access.may_write([198, 18, 0, 1]));
        assert_eq!(run(&["--tap", "t", "--watchdog-ms", "0"]).unwrap().settings.watchdog().timeout, None);
        assert_eq!(run(&["--tap", "t"]).unwrap().settings.server_config(crate::MAC).access, Access::OPEN);
    }

    #[test]
    fn an_address_without_prefix_is_a_slash_24() {
        let o = run(&["--tap", "t", "--ip", "198.18.5.5"]).unwrap();
        assert_eq!(o.settings.network.address.map(|a| a.prefix_len), Some(24));
    }
}
