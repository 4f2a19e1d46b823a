//! A certificate's validity times (RFC 5280 4.1.2.5): UTCTime
//! `YYMMDDHHMMSSZ` through 2049, GeneralizedTime `YYYYMMDDHHMMSSZ` after.

use core::fmt;

use crate::Error;
use crate::der::{Tlv, tag};

/// A UTC time to the second. Ordered as time is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Time {
    pub year: u16,
    pub month: u8,
    pub day: u8,
    pub hour: u8,
    pub minute: u8,
    pub second: u8,
}

impl Time {
    /// Reads a UTCTime or GeneralizedTime element, in the one form each
    /// may take in a certificate (seconds, `Z`, no fraction).
    pub fn parse(tlv: Tlv<'_>) -> Result<Self, Error> {
        let (year, rest) = match (tlv.tag, tlv.value) {
            (tag::UTC_TIME, [y0, y1, rest @ ..]) if rest.len() == 11 => {
                let yy = u16::from(digits([*y0, *y1])?);
                // RFC 5280: 50-99 are 1950-1999, 00-49 are 2000-2049.
                (if yy >= 50 { 1900 + yy } else { 2000 + yy }, rest)
            }
            (tag::GENERALIZED_TIME, [c0, c1, y0, y1, rest @ ..]) if rest.len() == 11 => {
                (u16::from(digits([*c0, *c1])?) * 100 + u16::from(digits([*y0, *y1])?), rest)
            }
            _ => return Err(Error::Malformed),
        };
        let [m0, m1, d0, d1, h0, h1, n0, n1, s0, s1, b'Z'] = *rest else { return Err(Error::Malformed) };
        let time = Self {
            year,
            month: digits([m0, m1])?,
            day: digits([d0, d1])?,
            hour: digits([h0, h1])?,
            minute: digits([n0, n1])?,
            second: digits([s0, s1])?,
        };
        let valid = (1..=12).contains(&time.month)
            && (1..=31).contains(&time.day)
            && time.hour < 24
            && time.minute < 60
            && time.second < 60;
        if valid { Ok(time) } else { Err(Error::Malformed) }
    }
}

/// Two ASCII digits as a number.
fn digits(pair: [u8; 2]) -> Result<u8, Error> {
    match pair {
        [a @ b'0'..=b'9', b @ b'0'..=b'9'] => Ok((a - b'0') * 10 + (b - b'0')),
        _ => Err(Error::Malformed),
    }
}

impl fmt::Display for Time {
    /// ISO 8601: `2026-11-27T12:41:52Z`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}Z",
            self.year, self.month, self.day, self.hour, self.minute, self.second
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::string::ToString;

    fn time(tag: u8, text: &str) -> Result<Time, Error> {
        Time::parse(Tlv { tag, value: text.as_bytes(), whole: &[] })
    }

    #[test]
    fn both_forms_read_and_order_as_time() {
        let utc = time(tag::UTC_TIME, "261127124152Z").unwrap();
        assert_eq!(utc.to_string(), "2026-11-27T12:41:52Z");
        assert_eq!(time(tag::UTC_TIME, "991231235959Z").unwrap().year, 1999);
        assert_eq!(time(tag::UTC_TIME, "491231235959Z").unwrap().year, 2049);
        let generalized = time(tag::GENERALIZED_TIME, "20500101000000Z").unwrap();
        assert_eq!(generalized.to_string(), "2050-01-01T00:00:00Z");
        assert!(utc < generalized);
        assert!(time(tag::UTC_TIME, "261127124153Z").unwrap() > utc);
    }

    #[test]
    fn other_forms_are_refused() {
        for (tag, text) in [
            (tag::UTC_TIME, "2611271241Z"),
            (tag::UTC_TIME, "261127124152"),
            (tag::UTC_TIME, "261127124152+0100"),
            (tag::UTC_TIME, "261327124152Z"),
            (tag::UTC_TIME, "261100124152Z"),
            (tag::UTC_TIME, "261127244152Z"),
            (tag::UTC_TIME, "26112712415aZ"),
            (tag::GENERALIZED_TIME, "261127124152Z"),
            (tag::GENERALIZED_TIME, "20261127124152.5Z"),
            (tag::UTF8_STRING, "261127124152Z"),
        ] {
            assert_eq!(time(tag, text), Err(Error::Malformed), "{text}");
        }
    }
}
