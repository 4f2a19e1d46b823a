//! The device's name: a DNS label, so DHCP's hostname option, mDNS and
//! Read Device Identification send it as it is. Low in the crate, as the
//! server, the settings and the discovery all name the device by it.

use core::fmt;

use crate::text::{self, Invalid};

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
}
