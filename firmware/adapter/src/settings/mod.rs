//! The one settings model (docs/settings.md): every setting's type and
//! default ([`Settings`]), and its key, rule, parser and when it applies
//! ([`Field`], one table row each). Every front end goes through it:
//!
//! - a board's build-time variables ([`Settings::with_build_env`], checked at
//!   compile time: a bad value stops the build naming the variable);
//! - hal-sim's command line (each setting's flag, rule and default come
//!   from the table);
//! - the flash store and the HTTP API (text per field, then [`Settings::validate`]).
//!
//! A change is parsed field by field into a copy, then validated whole;
//! only a copy that passes is put in force.

mod parse;
mod values;

use core::fmt;

pub use self::parse::{Cidr, Invalid, Ipv4};
pub use self::values::{NetMode, RobotLink};
use crate::access::{Access, AllowList, Network, Rights, Roles};
use crate::device::{SafeState, Watchdog};
use crate::map::WritePolicy;
use crate::map::table::{ANALOG_MAX_MICROAMPS, TOOL_PINS};
pub use crate::name::{MAX_NAME_LEN, Name};
use crate::server::handler::Policy;
use crate::server::{self, MAX_CONNECTIONS};
use crate::text;
use embassy_time::Duration;

/// The `device` group.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceSettings {
    /// DHCP hostname, mDNS name, 0x2B's user application name.
    pub name: Name,
}

/// The `network` group.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NetworkSettings {
    pub mode: NetMode,
    /// Required for `static`; the DHCP fallback otherwise.
    pub address: Option<Cidr>,
    pub gateway: Option<Ipv4>,
    /// Seconds without a lease before the fallback address applies.
    pub dhcp_timeout_s: u16,
}

/// The `modbus` group.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ModbusSettings {
    pub port: u16,
    /// `None`: answer every unit id.
    pub unit_id: Option<u8>,
    /// 1..=[`MAX_CONNECTIONS`].
    pub max_connections: u8,
    /// 0: never.
    pub idle_timeout_s: u32,
    pub write_policy: WritePolicy,
    /// `None`: everyone.
    pub allow_connect: Option<AllowList>,
    /// `None`: everyone.
    pub allow_write: Option<AllowList>,
}

/// The `watchdog` group: the communication watchdog and the safe state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WatchdogSettings {
    /// 0: off.
    pub timeout_ms: u32,
    /// Digital outputs in the safe state: bit n = output n + 1.
    pub safe_do: u16,
    /// Tool digital outputs in the safe state.
    pub safe_tool_do: u8,
    /// Analog outputs in the safe state, in the unit of their type.
    pub safe_ao1: u16,
    pub safe_ao2: u16,
}

/// The `robot` group: where the robot's points come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RobotSettings {
    /// `None`: no link (the board's own source, if any).
    pub link: Option<RobotLink>,
    pub poll_ms: u16,
}

/// The `tls` group: Modbus/TCP Security, and whether plain Modbus and
/// plain HTTP stay open beside TLS (docs/tls.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TlsSettings {
    /// Modbus/TCP Security on port 802.
    pub modbus: bool,
    /// The roles a client certificate may carry, and their rights.
    pub roles: Roles,
    /// Plain Modbus TCP on `modbus.port`.
    pub plain_modbus: bool,
    /// The page and the API in plain HTTP on port 80 beside HTTPS on 443;
    /// off: port 80 only redirects to HTTPS.
    pub plain_http: bool,
}

/// Every setting of the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Settings {
    pub device: DeviceSettings,
    pub network: NetworkSettings,
    pub modbus: ModbusSettings,
    pub watchdog: WatchdogSettings,
    pub robot: RobotSettings,
    pub tls: TlsSettings,
}

/// The longest idle timeout (a day).
pub const MAX_IDLE_TIMEOUT_S: u32 = 86_400;
/// The longest watchdog timeout (a day); the shortest is 100 ms.
pub const MAX_WATCHDOG_MS: u32 = 86_400_000;

impl Settings {
    /// The factory defaults (docs/settings.md), before a board or hal-sim sets its own.
    pub const DEFAULT: Self = Self {
        device: DeviceSettings { name: Name::UNSET },
        network: NetworkSettings { mode: NetMode::Dhcp, address: None, gateway: None, dhcp_timeout_s: 30 },
        modbus: ModbusSettings {
            port: server::MODBUS_PORT,
            unit_id: None,
            max_connections: MAX_CONNECTIONS as u8,
            idle_timeout_s: 60,
            write_policy: WritePolicy::Seed,
            allow_connect: None,
            allow_write: None,
        },
        watchdog: WatchdogSettings { timeout_ms: 0, safe_do: 0, safe_tool_do: 0, safe_ao1: 0, safe_ao2: 0 },
        robot: RobotSettings { link: None, poll_ms: 100 },
        tls: TlsSettings { modbus: true, roles: Roles::DEFAULT, plain_modbus: true, plain_http: true },
    };

    /// The rules that tie fields together; each field's own rule was checked
    /// when it was set. Every broken rule is reported, by the field to fix.
    #[allow(clippy::result_large_err, reason = "no heap: a change's errors are returned by value, once per change")]
    pub fn validate(&self) -> Result<(), Errors> {
        let mut errors = Errors::default();
        for (field, rule) in self.broken_rules().into_iter().flatten() {
            errors.add(field, rule);
        }
        errors.into_result()
    }

    /// The cross-field rules this whole breaks (in `const` context too, so
    /// a board's build-time settings are checked at compile time).
    const fn broken_rules(&self) -> [Option<(Field, &'static str)>; 4] {
        let network = &self.network;
        let address = if matches!(network.mode, NetMode::Static) && network.address.is_none() {
            Some((Field::NetworkAddress, "required when the mode is static"))
        } else {
            None
        };
        let gateway = match (network.gateway, network.address) {
            (None, _) => None,
            (Some(_), None) => Some((Field::NetworkGateway, "needs an address")),
            (Some(gateway), Some(address)) if address.contains(gateway.0) => None,
            (Some(_), Some(_)) => Some((Field::NetworkGateway, "must lie inside the address's network")),
        };
        let modbus = if !self.tls.modbus && !self.tls.plain_modbus {
            Some((Field::TlsPlainModbus, "may be off only while tls.modbus is on: Modbus must be served somewhere"))
        } else {
            None
        };
        let http = if !self.tls.plain_http && !cfg!(feature = "tls") {
            Some((Field::TlsPlainHttp, "may be off only on a firmware with HTTPS (the tls feature)"))
        } else {
            None
        };
        [address, gateway, modbus, http]
    }

    /// Whether going from these settings to `new` needs a reboot: a field
    /// that applies after reboot ([`Field::applies`]) changed.
    pub fn reboot_required(&self, new: &Self) -> bool {
        Field::ALL.iter().any(|&field| field.applies() == Applies::AfterReboot && self.differs(new, field))
    }

    /// The Modbus server's configuration, on a device whose MAC is `mac`
    /// (the default device name is made from it).
    pub fn server_config(&self, mac: [u8; 6]) -> server::Config {
        let modbus = &self.modbus;
        server::Config {
            port: modbus.port,
            max_connections: usize::from(modbus.max_connections).clamp(1, MAX_CONNECTIONS),
            policy: Policy { unit_id: modbus.unit_id, write_policy: modbus.write_policy, rights: Rights::ReadWrite },
            idle_timeout: match modbus.idle_timeout_s {
                0 => None,
                secs => Some(Duration::from_secs(u64::from(secs))),
            },
            frame_timeout: server::FRAME_TIMEOUT,
            access: Access { connect: modbus.allow_connect, write: modbus.allow_write },
            name: self.device.name.or_default(mac),
            roles: self.tls.roles,
        }
    }

    /// The communication watchdog and the outputs' safe state.
    pub fn watchdog(&self) -> Watchdog {
        let watchdog = &self.watchdog;
        Watchdog {
            timeout: match watchdog.timeout_ms {
                0 => None,
                ms => Some(Duration::from_millis(u64::from(ms))),
            },
            safe_state: SafeState {
                digital: watchdog.safe_do,
                tool: watchdog.safe_tool_do,
                analog: [watchdog.safe_ao1, watchdog.safe_ao2],
            },
        }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// When a changed setting takes effect.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Applies {
    /// As soon as it is saved.
    AtOnce,
    /// At the next start.
    AfterReboot,
}

/// How a value is written in JSON.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Kind {
    /// A number, unquoted.
    Number,
    /// A string.
    Text,
}

/// Shows a value as its parser takes it back.
trait Show {
    fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result;
}

macro_rules! show_number {
    ($($ty:ty),*) => {$(
        impl Show for $ty {
            fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
                text::write_decimal(out, *self)
            }
        }
    )*};
}

show_number!(u8, u16, u32);

impl Show for Name {
    fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        out.write_str(self.as_str())
    }
}

impl Show for NetMode {
    fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        out.write_str(self.as_str())
    }
}

macro_rules! show_written {
    ($($ty:ty),*) => {$(
        impl Show for $ty {
            fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
                self.write_to(out)
            }
        }
    )*};
}

show_written!(Cidr, Ipv4, RobotLink, Network);

macro_rules! show_optional {
    ($($ty:ty => $none:literal),*) => {$(
        impl Show for Option<$ty> {
            fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
                match self {
                    Some(value) => value.show(out),
                    None => out.write_str($none),
                }
            }
        }
    )*};
}

show_optional!(Cidr => "none", Ipv4 => "none", RobotLink => "none", u8 => "any");

impl Show for Option<AllowList> {
    fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        let Some(list) = self else { return out.write_str("any") };
        for (i, network) in list.networks().iter().enumerate() {
            if i > 0 {
                out.write_str(",")?;
            }
            network.show(out)?;
        }
        Ok(())
    }
}

impl Show for bool {
    fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        out.write_str(if *self { "on" } else { "off" })
    }
}

show_written!(Roles);

impl Show for WritePolicy {
    fn show(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        out.write_str(match self {
            WritePolicy::Seed => "seed",
            WritePolicy::Strict => "strict",
        })
    }
}

/// `any`, or a unit id of 1..=247.
const fn unit_id(text: &str) -> Result<Option<u8>, Invalid> {
    if parse::is(text, "any") {
        return Ok(None);
    }
    match parse::number_in(text, 1, 247) {
        Ok(id) => Ok(Some(id as u8)),
        Err(e) => Err(e),
    }
}

/// `seed` or `strict`.
const fn write_policy(text: &str) -> Result<WritePolicy, Invalid> {
    if parse::is(text, "seed") {
        Ok(WritePolicy::Seed)
    } else if parse::is(text, "strict") {
        Ok(WritePolicy::Strict)
    } else {
        Err(Invalid)
    }
}

/// 0 (off), or 100..=[`MAX_WATCHDOG_MS`].
const fn watchdog_ms(text: &str) -> Result<u32, Invalid> {
    match parse::number_in(text, 0, MAX_WATCHDOG_MS as u64) {
        Ok(ms) if ms == 0 || ms >= 100 => Ok(ms as u32),
        _ => Err(Invalid),
    }
}

/// A number in `min..=max` as the field's type (the range fits it).
macro_rules! number {
    ($text:ident, $min:expr, $max:expr, $ty:ty) => {
        match parse::number_in($text, $min as u64, $max as u64) {
            Ok(value) => Ok(value as $ty),
            Err(e) => Err(e),
        }
    };
}

macro_rules! fields {
    ($(
        $(#[$doc:meta])*
        $variant:ident: $group:ident . $field:ident, $kind:ident, $applies:ident,
            env $env:literal, flag $flag:literal, rule $rule:literal, |$text:ident| $parse:expr;
    )*) => {
        /// One setting: a row of the table.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub enum Field {
            $( $(#[$doc])* $variant, )*
        }

        impl Field {
            /// Every setting, in the order of docs/settings.md.
            pub const ALL: &[Field] = &[$(Field::$variant),*];

            /// Its group (`modbus`).
            pub const fn group(self) -> &'static str {
                match self { $(Self::$variant => stringify!($group),)* }
            }

            /// Its name within the group (`unit_id`).
            pub const fn name(self) -> &'static str {
                match self { $(Self::$variant => stringify!($field),)* }
            }

            /// `group.name`, as error messages and logs name it.
            pub const fn key(self) -> &'static str {
                match self { $(Self::$variant => concat!(stringify!($group), ".", stringify!($field)),)* }
            }

            /// The build-time variable that sets its factory default on the boards.
            pub const fn env(self) -> &'static str {
                match self { $(Self::$variant => $env,)* }
            }

            /// hal-sim's command-line flag (without `--`).
            pub const fn flag(self) -> &'static str {
                match self { $(Self::$variant => $flag,)* }
            }

            /// What a valid value looks like, for the user.
            pub const fn rule(self) -> &'static str {
                match self { $(Self::$variant => $rule,)* }
            }

            /// When a change takes effect.
            pub const fn applies(self) -> Applies {
                match self { $(Self::$variant => Applies::$applies,)* }
            }

            /// How JSON writes it.
            pub const fn kind(self) -> Kind {
                match self { $(Self::$variant => Kind::$kind,)* }
            }

            /// The build error for a bad build-time value.
            const fn build_error(self) -> &'static str {
                match self { $(Self::$variant => concat!($env, " must be ", $rule),)* }
            }

            /// The build error for build-time values that do not fit together.
            const fn cross_field_error(self) -> &'static str {
                match self {
                    $(Self::$variant => concat!($env, " does not fit the other build-time settings (see docs/reliability.md)"),)*
                }
            }
        }

        impl Settings {
            /// Sets `field` from `text`; on `Err` (the field's rule) nothing changed.
            pub const fn set(&mut self, field: Field, text: &str) -> Result<(), &'static str> {
                match field {
                    $(Field::$variant => {
                        let $text = text;
                        match $parse {
                            Ok(value) => self.$group.$field = value,
                            Err(Invalid) => return Err($rule),
                        }
                    })*
                }
                Ok(())
            }

            /// Whether `field` holds another value in `other`.
            pub fn differs(&self, other: &Self, field: Field) -> bool {
                match field {
                    $(Field::$variant => self.$group.$field != other.$group.$field,)*
                }
            }

            /// Writes `field`'s value as [`Settings::set`] takes it.
            pub fn show(&self, field: Field, out: &mut dyn fmt::Write) -> fmt::Result {
                match field {
                    $(Field::$variant => Show::show(&self.$group.$field, out),)*
                }
            }

            /// These settings with the build-time variables that are set
            /// applied. Evaluated in a `const`, a bad value stops the build
            /// with the variable's name and rule.
            #[allow(clippy::panic, reason = "evaluated at compile time only: a bad setting is a build error")]
            pub const fn with_build_env(self) -> Self {
                let mut settings = self;
                $(
                    if let Some(text) = option_env!($env) {
                        if settings.set(Field::$variant, text).is_err() {
                            panic!("{}", Field::$variant.build_error());
                        }
                    }
                )*
                let broken = settings.broken_rules();
                let mut rules = broken.as_slice();
                while let [rule, rest @ ..] = rules {
                    if let Some((field, _)) = rule {
                        panic!("{}", field.cross_field_error());
                    }
                    rules = rest;
                }
                settings
            }
        }
    };
}

fields! {
    /// The device's name.
    DeviceName: device.name, Text, AtOnce,
        env "DEVICE_NAME", flag "name",
        rule "1-32 of a-z 0-9 -, not starting or ending with - (empty: mbio- and the MAC's last 3 bytes)",
        |text| Name::parse(text);
    /// DHCP or a static address.
    NetworkMode: network.mode, Text, AfterReboot,
        env "NET_MODE", flag "mode",
        rule "dhcp or static",
        |text| NetMode::parse(text);
    /// The static address, or DHCP's fallback.
    NetworkAddress: network.address, Text, AfterReboot,
        env "NET_ADDRESS", flag "ip",
        rule "none, or an IPv4 address with its prefix length such as 192.168.1.50/24",
        |text| Cidr::parse_optional(text);
    /// The default gateway.
    NetworkGateway: network.gateway, Text, AfterReboot,
        env "NET_GATEWAY", flag "gateway",
        rule "none, or an IPv4 address such as 192.168.1.1",
        |text| Ipv4::parse_optional(text);
    /// How long to wait for DHCP.
    NetworkDhcpTimeout: network.dhcp_timeout_s, Number, AfterReboot,
        env "NET_DHCP_TIMEOUT_S", flag "dhcp-timeout",
        rule "5-600 seconds",
        |text| number!(text, 5, 600, u16);
    /// The Modbus TCP port.
    ModbusPort: modbus.port, Number, AfterReboot,
        env "MODBUS_PORT", flag "port",
        rule "1-65535",
        |text| number!(text, 1, u16::MAX, u16);
    /// The unit id answered.
    ModbusUnitId: modbus.unit_id, Text, AtOnce,
        env "MODBUS_UNIT_ID", flag "unit-id",
        rule "any, or 1-247",
        |text| unit_id(text);
    /// Sessions served at once.
    ModbusMaxConnections: modbus.max_connections, Number, AtOnce,
        env "MODBUS_MAX_CONNECTIONS", flag "max-connections",
        rule "1 to the build's maximum (MODBUS_MAX_CONNECTIONS, 8 by default)",
        |text| number!(text, 1, MAX_CONNECTIONS, u8);
    /// Idle sessions close after this long.
    ModbusIdleTimeout: modbus.idle_timeout_s, Number, AtOnce,
        env "MODBUS_IDLE_TIMEOUT_S", flag "idle-timeout",
        rule "0 (never) to 86400 seconds",
        |text| number!(text, 0, MAX_IDLE_TIMEOUT_S, u32);
    /// Writes to read-only points.
    ModbusWritePolicy: modbus.write_policy, Text, AtOnce,
        env "MODBUS_WRITE_POLICY", flag "write-policy",
        rule "seed or strict",
        |text| write_policy(text);
    /// Who may connect.
    ModbusAllowConnect: modbus.allow_connect, Text, AtOnce,
        env "MODBUS_ALLOW_CONNECT", flag "allow",
        rule "any, or up to 8 comma-separated networks such as 192.168.1.0/24,10.0.0.9 (empty is refused: write any)",
        |text| parse::allow_list(text);
    /// Who may write.
    ModbusAllowWrite: modbus.allow_write, Text, AtOnce,
        env "MODBUS_ALLOW_WRITE", flag "allow-write",
        rule "any, or up to 8 comma-separated networks such as 192.168.1.0/24,10.0.0.9 (empty is refused: write any)",
        |text| parse::allow_list(text);
    /// The communication watchdog's timeout.
    WatchdogTimeout: watchdog.timeout_ms, Number, AtOnce,
        env "MODBUS_WATCHDOG_MS", flag "watchdog-ms",
        rule "0 (off) or 100-86400000 milliseconds",
        |text| watchdog_ms(text);
    /// Digital outputs in the safe state.
    WatchdogSafeDo: watchdog.safe_do, Number, AtOnce,
        env "MODBUS_SAFE_DO", flag "safe-do",
        rule "a bit mask 0-65535 (bit n = output n+1; decimal or 0x-hex)",
        |text| parse::mask(text, u16::MAX);
    /// Tool digital outputs in the safe state.
    WatchdogSafeToolDo: watchdog.safe_tool_do, Number, AtOnce,
        env "MODBUS_SAFE_TOOL_DO", flag "safe-tool-do",
        rule "a bit mask 0-63 (bit n = tool output n+1; decimal or 0x-hex)",
        |text| match parse::mask(text, (1 << TOOL_PINS) - 1) {
            Ok(mask) => Ok(mask as u8),
            Err(e) => Err(e),
        };
    /// Analog output 1 in the safe state.
    WatchdogSafeAo1: watchdog.safe_ao1, Number, AtOnce,
        env "MODBUS_SAFE_AO1", flag "safe-ao1",
        rule "0-20000 (µA or mV, as the output's type)",
        |text| number!(text, 0, ANALOG_MAX_MICROAMPS, u16);
    /// Analog output 2 in the safe state.
    WatchdogSafeAo2: watchdog.safe_ao2, Number, AtOnce,
        env "MODBUS_SAFE_AO2", flag "safe-ao2",
        rule "0-20000 (µA or mV, as the output's type)",
        |text| number!(text, 0, ANALOG_MAX_MICROAMPS, u16);
    /// The robot controller to mirror.
    RobotLinkAddress: robot.link, Text, AtOnce,
        env "ROBOT_LINK", flag "robot-link",
        rule "none, or IPv4[:port][/unit] such as 192.168.1.10:502/1",
        |text| RobotLink::parse_optional(text);
    /// How often the link polls.
    RobotPollInterval: robot.poll_ms, Number, AtOnce,
        env "ROBOT_POLL_MS", flag "robot-poll-ms",
        rule "20-1000 milliseconds",
        |text| number!(text, 20, 1000, u16);
    /// Modbus/TCP Security on port 802.
    TlsModbus: tls.modbus, Text, AfterReboot,
        env "TLS_MODBUS", flag "tls-modbus",
        rule "on or off (Modbus/TCP Security on port 802)",
        |text| parse::on_off(text);
    /// The client certificates' roles and their rights.
    TlsRoles: tls.roles, Text, AtOnce,
        env "TLS_ROLES", flag "tls-roles",
        rule "none, or up to 4 comma-separated role=rights (rights read_write or read; a role is 1-24 printable ASCII characters but , and =) such as operator=read_write,viewer=read",
        |text| parse::roles(text);
    /// Plain Modbus TCP on modbus.port.
    TlsPlainModbus: tls.plain_modbus, Text, AfterReboot,
        env "TLS_PLAIN_MODBUS", flag "plain-modbus",
        rule "on or off (plain Modbus TCP on modbus.port; off only while tls.modbus is on)",
        |text| parse::on_off(text);
    /// The page and the API in plain HTTP on port 80.
    TlsPlainHttp: tls.plain_http, Text, AtOnce,
        env "TLS_PLAIN_HTTP", flag "plain-http",
        rule "on or off (the page and the API in plain HTTP on port 80; off: port 80 only redirects to HTTPS on 443)",
        |text| parse::on_off(text);
}

/// Most errors one change can have: one per field.
pub const MAX_ERRORS: usize = 24;

/// The rules a change broke, by field.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Errors {
    errors: heapless::Vec<(Field, &'static str), MAX_ERRORS>,
}

impl Errors {
    /// Notes that `field` broke `rule` (a field is reported once).
    pub fn add(&mut self, field: Field, rule: &'static str) {
        if !self.errors.iter().any(|(f, _)| *f == field) {
            // More errors than fields cannot happen; were it full, the first ones stand.
            let _ = self.errors.push((field, rule));
        }
    }

    /// Each field and the rule it broke.
    pub fn iter(&self) -> impl Iterator<Item = &(Field, &'static str)> {
        self.errors.iter()
    }

    /// Whether nothing was broken.
    pub fn is_empty(&self) -> bool {
        self.errors.is_empty()
    }

    #[allow(clippy::result_large_err, reason = "as `Settings::validate`")]
    fn into_result(self) -> Result<(), Self> {
        if self.is_empty() { Ok(()) } else { Err(self) }
    }
}

impl fmt::Display for Errors {
    /// `group.field: rule`, one per line.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (field, rule)) in self.errors.iter().enumerate() {
            write!(f, "{}{}: {rule}", if i == 0 { "" } else { "\n" }, field.key())?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
