//! Build-time settings: environment variables read when the firmware is
//! compiled, parsed in `const` context, so a malformed value stops the build
//! with a message naming the variable instead of misbehaving in the field.
//!
//! [`CONFIG`] is the Modbus server's configuration for the boards (hal-sim
//! takes the same settings on its command line):
//!
//! | variable | default | meaning |
//! |---|---|---|
//! | `MODBUS_UNIT_ID` | unset | answer only this unit id (and 0, 255); others get exception 0B |
//! | `MODBUS_WRITE_POLICY` | `seed` | `seed` or `strict` (docs/data-map.md) |
//! | `MODBUS_IDLE_TIMEOUT_S` | `60` | close a session idle this long; `0`: never |
//! | `MODBUS_WATCHDOG_MS` | `0` | communication watchdog timeout; `0`: off |
//! | `MODBUS_SAFE_DO` | `0` | digital outputs in the safe state (bit n = output n+1; decimal or 0x-hex) |
//! | `MODBUS_SAFE_TOOL_DO` | `0` | tool digital outputs in the safe state |
//! | `MODBUS_SAFE_AO1`, `MODBUS_SAFE_AO2` | `0` | analog outputs in the safe state (µA or mV, as their type) |
//! | `MODBUS_ALLOW_CONNECT` | unset: everyone | comma-separated networks that may connect, e.g. `192.168.1.0/24,10.0.0.9` |
//! | `MODBUS_ALLOW_WRITE` | unset: everyone | networks that may write; others get exception 01 on writes |
//!
//! The number of sessions is `MODBUS_MAX_CONNECTIONS` ([`crate::server::MAX_CONNECTIONS`]).

use crate::map::WritePolicy;
use crate::map::table::{ANALOG_MAX_MICROAMPS, TOOL_PINS};
use crate::server::{Access, AllowList, Config, Network, Policy, SafeState, Watchdog};
use embassy_time::Duration;

/// The server's configuration from the `MODBUS_*` variables above.
pub const CONFIG: Config = Config {
    policy: Policy { unit_id: UNIT_ID, write_policy: WRITE_POLICY, read_only: false },
    idle_timeout: IDLE_TIMEOUT,
    access: Access {
        connect: allow_list(
            option_env!("MODBUS_ALLOW_CONNECT"),
            "MODBUS_ALLOW_CONNECT must be up to 8 networks like 192.168.1.0/24,10.0.0.9",
        ),
        write: allow_list(
            option_env!("MODBUS_ALLOW_WRITE"),
            "MODBUS_ALLOW_WRITE must be up to 8 networks like 192.168.1.0/24,10.0.0.9",
        ),
    },
    watchdog: Watchdog { timeout: WATCHDOG, safe_state: SAFE_STATE },
    ..Config::DEFAULT
};

const UNIT_ID: Option<u8> = match option_env!("MODBUS_UNIT_ID") {
    None => None,
    Some(text) => match parse_decimal(text) {
        Some(id) if id <= 255 => Some(id as u8),
        _ => invalid("MODBUS_UNIT_ID must be 0..=255"),
    },
};

const WRITE_POLICY: WritePolicy = match option_env!("MODBUS_WRITE_POLICY") {
    None => WritePolicy::Seed,
    Some(text) => match text.as_bytes() {
        b"seed" => WritePolicy::Seed,
        b"strict" => WritePolicy::Strict,
        _ => invalid("MODBUS_WRITE_POLICY must be `seed` or `strict`"),
    },
};

const IDLE_TIMEOUT: Option<Duration> = match option_env!("MODBUS_IDLE_TIMEOUT_S") {
    None => Some(crate::server::IDLE_TIMEOUT),
    Some(text) => match parse_decimal(text) {
        Some(0) => None,
        Some(secs) if secs <= 365 * 24 * 3600 => Some(Duration::from_secs(secs)),
        _ => invalid("MODBUS_IDLE_TIMEOUT_S must be 0..=31536000 seconds"),
    },
};

const WATCHDOG: Option<Duration> = match option_env!("MODBUS_WATCHDOG_MS") {
    None => None,
    Some(text) => match parse_decimal(text) {
        Some(0) => None,
        Some(ms) if ms <= 24 * 3600 * 1000 => Some(Duration::from_millis(ms)),
        _ => invalid("MODBUS_WATCHDOG_MS must be 0..=86400000"),
    },
};

const SAFE_STATE: SafeState = SafeState {
    digital: mask(option_env!("MODBUS_SAFE_DO"), u16::MAX, "MODBUS_SAFE_DO must be a bit mask 0..=0xffff"),
    tool: mask(
        option_env!("MODBUS_SAFE_TOOL_DO"),
        (1 << TOOL_PINS) - 1,
        "MODBUS_SAFE_TOOL_DO must be a bit mask 0..=0x3f",
    ) as u8,
    analog: [
        analog(option_env!("MODBUS_SAFE_AO1"), "MODBUS_SAFE_AO1 must be 0..=20000 (µA or mV, as the output's type)"),
        analog(option_env!("MODBUS_SAFE_AO2"), "MODBUS_SAFE_AO2 must be 0..=20000 (µA or mV, as the output's type)"),
    ],
};

/// A bit mask setting, at most `max`; unset is 0.
const fn mask(text: Option<&str>, max: u16, error: &str) -> u16 {
    match text {
        None => 0,
        Some(text) => match parse_mask(text) {
            Some(value) if value <= max => value,
            _ => invalid(error),
        },
    }
}

/// An analog value setting (0..=20 000); unset is 0.
const fn analog(text: Option<&str>, error: &str) -> u16 {
    match text {
        None => 0,
        Some(text) => match parse_decimal(text) {
            Some(value) if value <= ANALOG_MAX_MICROAMPS as u64 => value as u16,
            _ => invalid(error),
        },
    }
}

/// An allow-list setting; unset is `None` (everyone).
const fn allow_list(text: Option<&str>, error: &str) -> Option<AllowList> {
    match text {
        None => None,
        Some(text) => match parse_allow_list(text) {
            Some(list) => Some(list),
            None => invalid(error),
        },
    }
}

/// Stops the build: a setting is malformed. Only ever evaluated in a `const`.
#[allow(clippy::panic, reason = "evaluated at compile time only: a bad setting is a build error")]
pub const fn invalid<T>(message: &str) -> T {
    panic!("{}", message)
}

/// `on`/`off` (also `1`/`0`, `true`/`false`, `yes`/`no`).
pub const fn parse_switch(text: &str) -> Option<bool> {
    match text.as_bytes() {
        b"on" | b"1" | b"true" | b"yes" => Some(true),
        b"off" | b"0" | b"false" | b"no" => Some(false),
        _ => None,
    }
}

/// A decimal number of at most 9 digits.
pub const fn parse_decimal(text: &str) -> Option<u64> {
    let mut rest = text.as_bytes();
    if rest.is_empty() || rest.len() > 9 {
        return None;
    }
    let mut value = 0u64;
    while let [digit, tail @ ..] = rest {
        if !digit.is_ascii_digit() {
            return None;
        }
        value = value * 10 + (*digit - b'0') as u64;
        rest = tail;
    }
    Some(value)
}

/// Dotted-quad IPv4 address, such as `192.168.1.50`.
pub const fn parse_ipv4(text: &str) -> Option<[u8; 4]> {
    let mut rest = text.as_bytes();
    let mut address = 0u32;
    let mut octets = 0;
    loop {
        let (octet, tail) = match split_once(rest, b'.') {
            Some(parts) => parts,
            None => (rest, &[] as &[u8]),
        };
        let value = match parse_decimal_bytes(octet) {
            Some(value) if value <= 255 && octet.len() <= 3 => value,
            _ => return None,
        };
        address = (address << 8) | value as u32;
        octets += 1;
        if tail.is_empty() {
            // "1.2.3." leaves an empty tail after a separator: caught by the length check below.
            let ends_with_dot = matches!(rest, [.., b'.']);
            return if octets == 4 && !ends_with_dot { Some(address.to_be_bytes()) } else { None };
        }
        if octets == 4 {
            return None;
        }
        rest = tail;
    }
}

/// [`parse_decimal`] over bytes.
pub const fn parse_decimal_bytes(bytes: &[u8]) -> Option<u64> {
    match core::str::from_utf8(bytes) {
        Ok(text) => parse_decimal(text),
        Err(_) => None,
    }
}

/// An address with its prefix length, such as `192.168.1.50/24` (prefix 1..=32).
pub const fn parse_cidr(text: &str) -> Option<([u8; 4], u8)> {
    let (address, prefix) = match split_once(text.as_bytes(), b'/') {
        Some(parts) => parts,
        None => return None,
    };
    let address = match core::str::from_utf8(address) {
        Ok(text) => parse_ipv4(text),
        Err(_) => None,
    };
    match (address, parse_decimal_bytes(prefix)) {
        (Some(address), Some(prefix)) if prefix >= 1 && prefix <= 32 => Some((address, prefix as u8)),
        _ => None,
    }
}

/// Splits `bytes` at the first `separator`.
pub const fn split_once(bytes: &[u8], separator: u8) -> Option<(&[u8], &[u8])> {
    let mut rest = bytes;
    while let [byte, tail @ ..] = rest {
        if *byte == separator {
            let (head, _) = bytes.split_at(bytes.len() - rest.len());
            return Some((head, tail));
        }
        rest = tail;
    }
    None
}

/// A bit mask: decimal, or hexadecimal after `0x`.
pub const fn parse_mask(text: &str) -> Option<u16> {
    let value = match text.as_bytes() {
        [b'0', b'x' | b'X', hex @ ..] => parse_hex(hex),
        _ => parse_decimal(text),
    };
    match value {
        Some(value) if value <= u16::MAX as u64 => Some(value as u16),
        _ => None,
    }
}

/// At most 4 hexadecimal digits.
const fn parse_hex(digits: &[u8]) -> Option<u64> {
    if digits.is_empty() || digits.len() > 4 {
        return None;
    }
    let mut value = 0u64;
    let mut rest = digits;
    while let [digit, tail @ ..] = rest {
        let nibble = match digit {
            b'0'..=b'9' => *digit - b'0',
            b'a'..=b'f' => *digit - b'a' + 10,
            b'A'..=b'F' => *digit - b'A' + 10,
            _ => return None,
        };
        value = value * 16 + nibble as u64;
        rest = tail;
    }
    Some(value)
}

/// A network: `address/prefix` (prefix 0..=32) or a bare address (a /32).
pub const fn parse_network(text: &[u8]) -> Option<Network> {
    let (address, prefix) = match split_once(text, b'/') {
        Some((address, prefix)) => match parse_decimal_bytes(prefix) {
            Some(prefix) if prefix <= 32 => (address, prefix as u8),
            _ => return None,
        },
        None => (text, 32),
    };
    let address = match core::str::from_utf8(address) {
        Ok(text) => parse_ipv4(text),
        Err(_) => None,
    };
    match address {
        Some(address) => Network::new(address, prefix),
        None => None,
    }
}

/// Comma-separated networks, at most [`crate::server::access::MAX_ALLOWED_NETWORKS`].
pub const fn parse_allow_list(text: &str) -> Option<AllowList> {
    let mut list = AllowList::EMPTY;
    let mut rest = text.as_bytes();
    loop {
        let (item, tail) = match split_once(rest, b',') {
            Some(parts) => parts,
            None => (rest, &[] as &[u8]),
        };
        let network = match parse_network(item) {
            Some(network) => network,
            None => return None,
        };
        list = match list.with(network) {
            Some(list) => list,
            None => return None,
        };
        if tail.is_empty() {
            return if matches!(rest, [.., b',']) { None } else { Some(list) };
        }
        rest = tail;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        assert_eq!(parse_ipv4("192.168.1.50"), Some([192, 168, 1, 50]));
        assert_eq!(parse_ipv4("0.0.0.0"), Some([0, 0, 0, 0]));
        assert_eq!(parse_ipv4("255.255.255.255"), Some([255; 4]));
        for bad in
            ["", "1.2.3", "1.2.3.4.5", "256.1.1.1", "1..2.3", "1.2.3.", ".1.2.3", "a.b.c.d", "1.2.3.4 ", "0001.2.3.4"]
        {
            assert_eq!(parse_ipv4(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn prefixes_parse() {
        assert_eq!(parse_cidr("10.0.0.7/8"), Some(([10, 0, 0, 7], 8)));
        assert_eq!(parse_cidr("198.18.0.2/32"), Some(([198, 18, 0, 2], 32)));
        for bad in ["10.0.0.7", "10.0.0.7/", "10.0.0.7/0", "10.0.0.7/33", "/24", "10.0.0.7/2x"] {
            assert_eq!(parse_cidr(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn switches_and_numbers_parse() {
        assert_eq!(parse_switch("on"), Some(true));
        assert_eq!(parse_switch("0"), Some(false));
        assert_eq!(parse_switch("maybe"), None);
        assert_eq!(parse_decimal("10"), Some(10));
        assert_eq!(parse_decimal(""), None);
        assert_eq!(parse_decimal("-1"), None);
        assert_eq!(parse_decimal("1234567890"), None);
    }

    #[test]
    fn masks_and_networks_parse() {
        assert_eq!(parse_mask("0x8001"), Some(0x8001));
        assert_eq!(parse_mask("65535"), Some(u16::MAX));
        for bad in ["", "0x", "0x10000", "65536", "0xg", "-1"] {
            assert_eq!(parse_mask(bad), None, "{bad:?}");
        }
        let list = parse_allow_list("192.168.1.0/24,10.0.0.9").unwrap();
        assert!(list.allows([192, 168, 1, 77]) && list.allows([10, 0, 0, 9]) && !list.allows([10, 0, 0, 8]));
        assert!(parse_allow_list("0.0.0.0/0").unwrap().allows([8, 8, 8, 8]));
        let nine = "1.0.0.1,1.0.0.2,1.0.0.3,1.0.0.4,1.0.0.5,1.0.0.6,1.0.0.7,1.0.0.8,1.0.0.9";
        for bad in ["", "10.0.0.0/33", "10.0.0.0/8,", ",10.0.0.0/8", "10.0.0", nine] {
            assert_eq!(parse_allow_list(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn the_boards_config_follows_the_environment_or_defaults() {
        // CI builds without these variables: the defaults of docs/data-map.md hold.
        if option_env!("MODBUS_WATCHDOG_MS").is_none() {
            assert_eq!(CONFIG.watchdog, Watchdog::OFF);
        }
        if option_env!("MODBUS_ALLOW_CONNECT").is_none() && option_env!("MODBUS_ALLOW_WRITE").is_none() {
            assert_eq!(CONFIG.access, Access::OPEN);
        }
        if option_env!("MODBUS_UNIT_ID").is_none() && option_env!("MODBUS_WRITE_POLICY").is_none() {
            assert_eq!(CONFIG.policy, Config::DEFAULT.policy);
        }
        assert_eq!(CONFIG.port, crate::server::MODBUS_PORT);
    }
}
