//! The value types of settings that are more than a number: the device
//! name, the network mode, the robot link's address. Each parses in `const`
//! context and shows itself as it parses.

use core::fmt;

use super::parse::{Invalid, ipv4, is, is_none, number_suffix};
use crate::text;

/// Longest device name (docs/settings.md; also a DNS label's limit).
pub const MAX_NAME_LEN: usize = 32;

/// The device name: 1-32 of `a-z 0-9 -`, not starting or ending with `-`;
/// a DNS label, so it works as DHCP hostname and mDNS name as it is.
/// [`Name::UNSET`] stands for the board's default, made from its MAC.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Name {
    bytes: [u8; MAX_NAME_LEN],
    len: u8,
}

impl Name {
    /// No name set: the device uses [`Name::from_mac`].
    pub const UNSET: Self = Self { bytes: [0; MAX_NAME_LEN], len: 0 };

    /// A name as the rule allows it; empty is [`Name::UNSET`] (the default).
    pub const fn parse(text: &str) -> Result<Self, Invalid> {
        let text = text.as_bytes();
        if text.is_empty() {
            return Ok(Self::UNSET);
        }
        if text.len() > MAX_NAME_LEN {
            return Err(Invalid);
        }
        if let [b'-', ..] | [.., b'-'] = text {
            return Err(Invalid);
        }
        let mut name = Self::UNSET;
        let mut rest = text;
        while let [byte, tail @ ..] = rest {
            if !matches!(byte, b'a'..=b'z' | b'0'..=b'9' | b'-') {
                return Err(Invalid);
            }
            name = name.push(*byte);
            rest = tail;
        }
        Ok(name)
    }

    /// `mbio-` and the last 3 bytes of `mac` in hex: the default name.
    pub const fn from_mac(mac: [u8; 6]) -> Self {
        let mut name = Self::UNSET.push(b'm').push(b'b').push(b'i').push(b'o').push(b'-');
        let [_, _, _, d, e, f] = mac;
        let tail = [d, e, f];
        let mut rest = tail.as_slice();
        while let [byte, more @ ..] = rest {
            name = name.push(text::hex_digit(*byte >> 4)).push(text::hex_digit(*byte & 0xf));
            rest = more;
        }
        name
    }

    /// This name, or the default for `mac` when none is set.
    pub const fn or_default(self, mac: [u8; 6]) -> Self {
        if self.len == 0 { Self::from_mac(mac) } else { self }
    }

    /// Appends a byte (dropped when full: only ever called within the limit).
    const fn push(mut self, byte: u8) -> Self {
        let len = self.len as usize;
        if len < MAX_NAME_LEN {
            let (_, tail) = self.bytes.split_at_mut(len);
            if let [slot, ..] = tail {
                *slot = byte;
            }
            self.len += 1;
        }
        self
    }

    /// The name as text (empty when unset).
    pub fn as_str(&self) -> &str {
        // Only ASCII is ever pushed.
        core::str::from_utf8(self.as_bytes()).unwrap_or_default()
    }

    /// The name's bytes, ASCII (none when unset): as a protocol sends it,
    /// with no check to run.
    pub fn as_bytes(&self) -> &[u8] {
        let (bytes, _) = self.bytes.split_at(usize::from(self.len).min(MAX_NAME_LEN));
        bytes
    }
}

impl fmt::Debug for Name {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Name({:?})", self.as_str())
    }
}

impl fmt::Display for Name {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Name {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "{=str}", self.as_str())
    }
}

/// How the device gets its address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NetMode {
    /// Ask DHCP; the static address (if any) is the fallback.
    Dhcp,
    /// The static address from the start.
    Static,
}

impl NetMode {
    /// `dhcp` or `static`.
    pub const fn parse(text: &str) -> Result<Self, Invalid> {
        if is(text, "dhcp") {
            Ok(Self::Dhcp)
        } else if is(text, "static") {
            Ok(Self::Static)
        } else {
            Err(Invalid)
        }
    }
}

impl NetMode {
    /// `dhcp` or `static`.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Dhcp => "dhcp",
            Self::Static => "static",
        }
    }
}

impl fmt::Display for NetMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The robot controller to mirror (docs/settings.md, `robot.link`): `IPv4[:port][/unit]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RobotLink {
    pub address: [u8; 4],
    /// 502 unless given.
    pub port: u16,
    /// 1 unless given.
    pub unit: u8,
}

impl RobotLink {
    /// `none` (or empty): no link.
    pub const fn parse_optional(text: &str) -> Result<Option<Self>, Invalid> {
        if is_none(text) {
            return Ok(None);
        }
        let Ok((rest, unit)) = number_suffix(text.as_bytes(), b'/', 0, 255, 1) else { return Err(Invalid) };
        let Ok((address, port)) = number_suffix(rest, b':', 1, 65535, 502) else { return Err(Invalid) };
        match ipv4(address) {
            Some(address) => Ok(Some(Self { address, port: port as u16, unit: unit as u8 })),
            None => Err(Invalid),
        }
    }
}

impl RobotLink {
    /// Writes `a.b.c.d:port/unit`.
    pub fn write_to(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        text::write_ipv4(out, self.address)?;
        out.write_str(":")?;
        text::write_decimal(out, self.port)?;
        out.write_str("/")?;
        text::write_decimal(out, self.unit)
    }
}

impl fmt::Display for RobotLink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write_to(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_the_rule() {
        assert_eq!(Name::parse("cell-4-io").unwrap().as_str(), "cell-4-io");
        assert_eq!(Name::parse(&"a".repeat(32)).unwrap().as_str().len(), 32);
        assert_eq!(Name::parse(""), Ok(Name::UNSET), "empty: back to the default");
        for bad in ["-io", "io-", "IO", "i_o", "i o", "ü", &"a".repeat(33)] {
            assert!(Name::parse(bad).is_err(), "{bad:?}");
        }
        assert_eq!(Name::from_mac([0x02, 0x4d, 0x42, 0x53, 0x49, 0x4d]).as_str(), "mbio-53494d");
        assert_eq!(Name::UNSET.or_default([0; 6]).as_str(), "mbio-000000");
        assert_eq!(Name::parse("x").unwrap().or_default([0; 6]).as_str(), "x");
        assert_eq!(Name::UNSET.to_string(), "");
    }

    #[test]
    fn modes_and_links_parse() {
        assert_eq!(NetMode::parse("dhcp"), Ok(NetMode::Dhcp));
        assert_eq!(NetMode::parse("static"), Ok(NetMode::Static));
        assert!(NetMode::parse("DHCP").is_err());
        let link = |text| RobotLink::parse_optional(text);
        assert_eq!(link("10.0.0.5"), Ok(Some(RobotLink { address: [10, 0, 0, 5], port: 502, unit: 1 })));
        assert_eq!(link("10.0.0.5:1502/7"), Ok(Some(RobotLink { address: [10, 0, 0, 5], port: 1502, unit: 7 })));
        assert_eq!(link("10.0.0.5/0"), Ok(Some(RobotLink { address: [10, 0, 0, 5], port: 502, unit: 0 })));
        assert_eq!(link("none"), Ok(None));
        for bad in ["10.0.0.5:", "10.0.0.5:0", "10.0.0.5:65536", "10.0.0.5/256", "host:502", "10.0.0.5/1:502"] {
            assert!(link(bad).is_err(), "{bad:?}");
        }
        assert_eq!(link("10.0.0.5:1502/7").unwrap().unwrap().to_string(), "10.0.0.5:1502/7");
    }
}
