//! Numbers and addresses as text, written without `core::fmt`'s
//! formatting machinery (`write!` and `{}` cost the board images about
//! 3 KiB of flash: `core::fmt::write`, the `Formatter`'s padding and each
//! integer type's `Display`). What the settings and the HTTP API show goes
//! through here; `Display` impls stay for logs and tests, and call here too.

use core::fmt;

/// A text that is not a valid value of its type (every parser of the
/// crate's values returns it: names, addresses, settings).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Invalid;

/// The longest `u64` in decimal.
pub const MAX_DIGITS: usize = 20;

/// An unsigned integer of any width, as [`decimal`] takes it.
pub trait Unsigned: Copy {
    fn widen(self) -> u64;
}

macro_rules! unsigned {
    ($($ty:ty),*) => {$(
        impl Unsigned for $ty {
            fn widen(self) -> u64 {
                self as u64
            }
        }
    )*};
}

unsigned!(u8, u16, u32, u64, usize);

/// `value` in decimal, in `buf`.
#[inline]
pub fn decimal(value: impl Unsigned, buf: &mut [u8; MAX_DIGITS]) -> &str {
    decimal_u64(value.widen(), buf)
}

/// [`decimal`], once for every width.
fn decimal_u64(mut value: u64, buf: &mut [u8; MAX_DIGITS]) -> &str {
    let mut start = MAX_DIGITS;
    for slot in buf.iter_mut().rev() {
        *slot = b'0' + (value % 10) as u8;
        start -= 1;
        value /= 10;
        if value == 0 {
            break;
        }
    }
    let digits = buf.get(start..).unwrap_or_default();
    core::str::from_utf8(digits).unwrap_or_default()
}

/// Writes `value` in decimal.
pub fn write_decimal(out: &mut dyn fmt::Write, value: impl Unsigned) -> fmt::Result {
    out.write_str(decimal(value, &mut [0; MAX_DIGITS]))
}

/// Writes a version as `major.minor.patch`.
pub fn write_version(out: &mut dyn fmt::Write, version: crate::io::Version) -> fmt::Result {
    for (i, part) in version.registers().into_iter().enumerate() {
        if i > 0 {
            out.write_str(".")?;
        }
        write_decimal(out, part)?;
    }
    Ok(())
}

/// Writes `a.b.c.d`.
pub fn write_ipv4(out: &mut dyn fmt::Write, address: [u8; 4]) -> fmt::Result {
    for (i, octet) in address.into_iter().enumerate() {
        if i > 0 {
            out.write_str(".")?;
        }
        write_decimal(out, octet)?;
    }
    Ok(())
}

/// Writes a MAC address as `02:4d:42:53:49:4d`.
pub fn write_mac(out: &mut dyn fmt::Write, mac: [u8; 6]) -> fmt::Result {
    let mut text = [b':'; 17];
    for (byte, digits) in mac.into_iter().zip(text.chunks_mut(3)) {
        if let [high, low, ..] = digits {
            *high = hex_digit(byte >> 4);
            *low = hex_digit(byte & 0xf);
        }
    }
    out.write_str(core::str::from_utf8(&text).unwrap_or_default())
}

/// The lower-case hex digit of `nibble` (0..=15).
pub const fn hex_digit(nibble: u8) -> u8 {
    if nibble < 10 { b'0' + nibble } else { b'a' + (nibble - 10) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_read_as_display_writes_them() {
        let mut buf = [0; MAX_DIGITS];
        for value in [0, 1, 9, 10, 99, 100, 65_535, 4_294_967_295, u64::MAX - 1, u64::MAX] {
            assert_eq!(decimal(value, &mut buf), value.to_string());
        }
        assert_eq!(decimal(255u8, &mut buf), "255");
        assert_eq!(decimal(usize::MAX, &mut buf), usize::MAX.to_string());
        let mut text = String::new();
        write_ipv4(&mut text, [198, 18, 0, 255]).unwrap();
        assert_eq!(text, "198.18.0.255");
        text.clear();
        write_mac(&mut text, [0x02, 0x4d, 0x42, 0x53, 0x49, 0xaf]).unwrap();
        assert_eq!(text, "02:4d:42:53:49:af");
    }
}
