//! The value types of settings that are more than a number: the network
//! mode, the robot link's address (the device name is [`crate::name`]'s). Each parses in `const`
//! context and shows itself as it parses.

use core::fmt;

use super::parse::{Invalid, ipv4, is, is_none, number_suffix};
use crate::text;

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
