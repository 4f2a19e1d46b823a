//! Text to values, in `const` context: the same functions check a board's
//! build-time variables (at compile time), hal-sim's command line and, later,
//! the HTTP API and the flash store (at run time).
//!
//! Each returns [`Invalid`] for a text it does not take (the settings table
//! holds the rule to tell the user), never panics, and reads its input by
//! pattern, so no index can go out of bounds.

use core::fmt;

use crate::access::{AllowList, Network, Rights, Role, Roles};
use crate::text;

pub use crate::text::Invalid;

/// A decimal number of at most 9 digits.
pub const fn decimal(text: &str) -> Option<u64> {
    decimal_bytes(text.as_bytes())
}

/// [`decimal`] over bytes.
pub const fn decimal_bytes(bytes: &[u8]) -> Option<u64> {
    if bytes.is_empty() || bytes.len() > 9 {
        return None;
    }
    let mut rest = bytes;
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

/// A decimal number in `min..=max`.
pub const fn number_in(text: &str, min: u64, max: u64) -> Result<u64, Invalid> {
    match decimal(text) {
        Some(value) if value >= min && value <= max => Ok(value),
        _ => Err(Invalid),
    }
}

/// A bit mask at most `max`: decimal, or hexadecimal after `0x`.
pub const fn mask(text: &str, max: u16) -> Result<u16, Invalid> {
    let value = match text.as_bytes() {
        [b'0', b'x' | b'X', hex @ ..] => hex_bytes(hex),
        _ => decimal(text),
    };
    match value {
        Some(value) if value <= max as u64 => Ok(value as u16),
        _ => Err(Invalid),
    }
}

/// At most 4 hexadecimal digits.
const fn hex_bytes(digits: &[u8]) -> Option<u64> {
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

/// Whether `text` is exactly `word`.
pub const fn is(text: &str, word: &str) -> bool {
    let (mut a, mut b) = (text.as_bytes(), word.as_bytes());
    loop {
        match (a, b) {
            ([], []) => return true,
            ([x, a_tail @ ..], [y, b_tail @ ..]) if *x == *y => {
                a = a_tail;
                b = b_tail;
            }
            _ => return false,
        }
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

/// `text` split at its first `separator` into what comes before and the
/// number after it, which must be in `min..=max`; without a separator, all
/// of `text` and `default`. (`10.0.0.0/8` is `(b"10.0.0.0", 8)` at `/`.)
pub const fn number_suffix(
    text: &[u8],
    separator: u8,
    min: u64,
    max: u64,
    default: u64,
) -> Result<(&[u8], u64), Invalid> {
    match split_once(text, separator) {
        Some((head, number)) => match decimal_bytes(number) {
            Some(value) if value >= min && value <= max => Ok((head, value)),
            _ => Err(Invalid),
        },
        None => Ok((text, default)),
    }
}

/// Dotted-quad IPv4 address, such as `192.168.1.50`. An octet with a
/// leading zero (`198.018.0.1`) is refused: many parsers read it as octal,
/// so it would not name the same address everywhere.
pub const fn ipv4(text: &[u8]) -> Option<[u8; 4]> {
    let mut rest = text;
    let mut address = 0u32;
    let mut octets = 0;
    loop {
        let (octet, tail, last) = match split_once(rest, b'.') {
            Some((octet, tail)) => (octet, tail, false),
            None => (rest, &[] as &[u8], true),
        };
        if let [b'0', _, ..] = octet {
            return None;
        }
        let value = match decimal_bytes(octet) {
            Some(value) if value <= 255 && octet.len() <= 3 => value,
            _ => return None,
        };
        address = (address << 8) | value as u32;
        octets += 1;
        if last {
            return if octets == 4 { Some(address.to_be_bytes()) } else { None };
        }
        if octets == 4 {
            return None;
        }
        rest = tail;
    }
}

/// An IPv4 address, as a setting shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ipv4(pub [u8; 4]);

impl Ipv4 {
    /// `192.168.1.1`.
    pub const fn parse(text: &str) -> Result<Self, Invalid> {
        match ipv4(text.as_bytes()) {
            Some(address) => Ok(Self(address)),
            None => Err(Invalid),
        }
    }

    /// `none` (or empty) is no address; otherwise as [`Self::parse`].
    pub const fn parse_optional(text: &str) -> Result<Option<Self>, Invalid> {
        if is_none(text) {
            return Ok(None);
        }
        match Self::parse(text) {
            Ok(address) => Ok(Some(address)),
            Err(e) => Err(e),
        }
    }
}

impl Ipv4 {
    /// Writes the address as [`Self::parse`] takes it.
    pub fn write_to(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        text::write_ipv4(out, self.0)
    }
}

impl fmt::Display for Ipv4 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write_to(f)
    }
}

/// Whether a text means "no value": `none` or nothing.
pub const fn is_none(text: &str) -> bool {
    text.is_empty() || is(text, "none")
}

/// An interface address with its prefix length, such as `192.168.1.50/24`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cidr {
    pub address: [u8; 4],
    /// 1..=32.
    pub prefix_len: u8,
}

impl Cidr {
    /// `none` (or empty) is no address; else a unicast `a.b.c.d/n` with n in
    /// 1..=32 (a bare address is a /24).
    pub const fn parse_optional(text: &str) -> Result<Option<Self>, Invalid> {
        if is_none(text) {
            return Ok(None);
        }
        let (address, prefix_len) = match number_suffix(text.as_bytes(), b'/', 1, 32, 24) {
            Ok(parts) => parts,
            Err(e) => return Err(e),
        };
        match ipv4(address) {
            Some(address) if is_unicast(address) => Ok(Some(Self { address, prefix_len: prefix_len as u8 })),
            _ => Err(Invalid),
        }
    }

    /// Whether `address` lies in this interface's network.
    pub const fn contains(&self, address: [u8; 4]) -> bool {
        match Network::new(self.address, self.prefix_len) {
            Some(network) => network.contains(address),
            None => false,
        }
    }
}

impl Cidr {
    /// Writes `a.b.c.d/n`.
    pub fn write_to(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        text::write_ipv4(out, self.address)?;
        out.write_str("/")?;
        text::write_decimal(out, self.prefix_len)
    }
}

impl fmt::Display for Cidr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write_to(f)
    }
}

/// Whether a device may take `address`: not 0.0.0.0, loopback, multicast or broadcast.
pub const fn is_unicast(address: [u8; 4]) -> bool {
    !matches!(address, [0, 0, 0, 0] | [127, ..] | [224..=239, ..] | [255, 255, 255, 255])
}

/// A network of an allow-list: `address/prefix` (prefix 0..=32) or a bare address (a /32).
pub const fn network(text: &[u8]) -> Option<Network> {
    let Ok((address, prefix)) = number_suffix(text, b'/', 0, 32, 32) else { return None };
    match ipv4(address) {
        Some(address) => Network::new(address, prefix as u8),
        None => None,
    }
}

/// An allow-list: `any` (everyone), or up to 8 comma-separated networks.
/// An empty list is refused, not read as `any`: an operator who clears the
/// field must not open the device to everyone without saying so.
pub const fn allow_list(text: &str) -> Result<Option<AllowList>, Invalid> {
    if text.is_empty() {
        return Err(Invalid);
    }
    if is(text, "any") {
        return Ok(None);
    }
    let mut list = AllowList::EMPTY;
    let mut rest = text.as_bytes();
    loop {
        let (item, tail, last) = match split_once(rest, b',') {
            Some((item, tail)) => (item, tail, false),
            None => (rest, &[] as &[u8], true),
        };
        let Some(network) = network(item) else { return Err(Invalid) };
        list = match list.with(network) {
            Some(list) => list,
            None => return Err(Invalid),
        };
        if last {
            return Ok(Some(list));
        }
        rest = tail;
    }
}

/// `read_write` or `read`.
const fn rights(text: &[u8]) -> Option<Rights> {
    if bytes_are(text, b"read_write") {
        Some(Rights::ReadWrite)
    } else if bytes_are(text, b"read") {
        Some(Rights::Read)
    } else {
        None
    }
}

const fn bytes_are(text: &[u8], word: &[u8]) -> bool {
    match (core::str::from_utf8(text), core::str::from_utf8(word)) {
        (Ok(text), Ok(word)) => is(text, word),
        _ => false,
    }
}

/// The Modbus/TCP Security roles: `none` (no client gets a session), or up
/// to [`crate::access::MAX_ROLES`] comma-separated `role=rights`, each role
/// named once (`operator=read_write,viewer=read`). An empty list is
/// refused, as an allow-list's is: `none` must be written out.
pub const fn roles(text: &str) -> Result<Roles, Invalid> {
    if text.is_empty() {
        return Err(Invalid);
    }
    if is(text, "none") {
        return Ok(Roles::EMPTY);
    }
    let mut roles = Roles::EMPTY;
    let mut rest = text.as_bytes();
    loop {
        let (item, tail, last) = match split_once(rest, b',') {
            Some((item, tail)) => (item, tail, false),
            None => (rest, &[] as &[u8], true),
        };
        let Some((name, granted)) = split_once(item, b'=') else { return Err(Invalid) };
        let (Some(role), Some(granted)) = (Role::new(name), rights(granted)) else { return Err(Invalid) };
        roles = match roles.with(role, granted) {
            Some(roles) => roles,
            None => return Err(Invalid),
        };
        if last {
            return Ok(roles);
        }
        rest = tail;
    }
}

/// `on` or `off`.
pub const fn on_off(text: &str) -> Result<bool, Invalid> {
    if is(text, "on") {
        Ok(true)
    } else if is(text, "off") {
        Ok(false)
    } else {
        Err(Invalid)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roles_parse_whole_or_not_at_all() {
        assert_eq!(roles("operator=read_write,viewer=read"), Ok(Roles::DEFAULT));
        assert_eq!(roles("none"), Ok(Roles::EMPTY));
        let one = roles("historian=read").unwrap();
        assert_eq!((one.rights(b"historian"), one.rights(b"operator")), (Some(Rights::Read), None));
        for bad in [
            "",
            ",",
            "operator",
            "operator=",
            "=read",
            "operator=write",
            "operator=read_write,",
            "operator=read,operator=read_write",
            "a=read,b=read,c=read,d=read,e=read",
            "oper ator=read",
            "operator=READ",
        ] {
            assert_eq!(roles(bad), Err(Invalid), "{bad:?}");
        }
        assert_eq!(
            (on_off("on"), on_off("off"), on_off("ON"), on_off("")),
            (Ok(true), Ok(false), Err(Invalid), Err(Invalid))
        );
    }

    #[test]
    fn addresses_parse() {
        assert_eq!(ipv4(b"192.168.1.50"), Some([192, 168, 1, 50]));
        assert_eq!(ipv4(b"0.0.0.0"), Some([0, 0, 0, 0]));
        assert_eq!(ipv4(b"255.255.255.255"), Some([255; 4]));
        for bad in
            ["", "1.2.3", "1.2.3.4.5", "256.1.1.1", "1..2.3", "1.2.3.", ".1.2.3", "a.b.c.d", "1.2.3.4 ", "0001.2.3.4"]
        {
            assert_eq!(ipv4(bad.as_bytes()), None, "{bad:?}");
        }
        // A leading zero (octal to many parsers) in any octet: refused.
        for octal in ["198.018.0.1", "010.0.0.1", "1.2.3.04", "1.2.00.4", "00.0.0.0"] {
            assert_eq!(ipv4(octal.as_bytes()), None, "{octal:?}");
        }
        assert_eq!(ipv4(b"10.0.0.100"), Some([10, 0, 0, 100]), "a zero that is not leading");
    }

    #[test]
    fn prefixes_parse() {
        let cidr = |text| Cidr::parse_optional(text);
        assert_eq!(cidr("10.0.0.7/8"), Ok(Some(Cidr { address: [10, 0, 0, 7], prefix_len: 8 })));
        assert_eq!(cidr("198.18.0.2"), Ok(Some(Cidr { address: [198, 18, 0, 2], prefix_len: 24 })));
        assert_eq!(cidr("none"), Ok(None));
        for bad in ["10.0.0.7/", "10.0.0.7/0", "10.0.0.7/33", "/24", "10.0.0.7/2x", "nothing", "0.0.0.0/8", "224.0.0.1"]
        {
            assert!(cidr(bad).is_err(), "{bad:?}");
        }
        assert!(Cidr { address: [10, 0, 0, 7], prefix_len: 8 }.contains([10, 9, 9, 9]));
        assert!(!Cidr { address: [10, 0, 0, 7], prefix_len: 8 }.contains([11, 0, 0, 7]));
    }

    #[test]
    fn numbers_and_words_parse() {
        assert_eq!(decimal("10"), Some(10));
        assert_eq!(decimal(""), None);
        assert_eq!(decimal("-1"), None);
        assert_eq!(decimal("1234567890"), None);
        assert_eq!(number_in("5", 5, 600), Ok(5));
        assert_eq!(number_in("601", 5, 600), Err(Invalid));
        assert!(is("dhcp", "dhcp") && !is("dhcp", "dhc") && !is("dhc", "dhcp"));
    }

    #[test]
    fn masks_and_networks_parse() {
        assert_eq!(mask("0x8001", u16::MAX), Ok(0x8001));
        assert_eq!(mask("65535", u16::MAX), Ok(u16::MAX));
        assert_eq!(mask("0x40", 0x3f), Err(Invalid));
        for bad in ["", "0x", "0x10000", "65536", "0xg", "-1"] {
            assert_eq!(mask(bad, u16::MAX), Err(Invalid), "{bad:?}");
        }
        let list = allow_list("192.168.1.0/24,10.0.0.9").unwrap().unwrap();
        assert!(list.allows([192, 168, 1, 77]) && list.allows([10, 0, 0, 9]) && !list.allows([10, 0, 0, 8]));
        assert!(allow_list("0.0.0.0/0").unwrap().unwrap().allows([8, 8, 8, 8]));
        assert_eq!(allow_list("any"), Ok(None));
        assert_eq!(allow_list(""), Err(Invalid), "empty is not any: it must be written out");
        assert!(allow_list("10.0.0.07").is_err(), "a leading zero");
        let nine = "1.0.0.1,1.0.0.2,1.0.0.3,1.0.0.4,1.0.0.5,1.0.0.6,1.0.0.7,1.0.0.8,1.0.0.9";
        for bad in ["10.0.0.0/33", "10.0.0.0/8,", ",10.0.0.0/8", "10.0.0", nine] {
            assert!(allow_list(bad).is_err(), "{bad:?}");
        }
    }
}
