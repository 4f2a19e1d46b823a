//! The NUCLEO's build-time settings and its pure arithmetic: the IP
//! configuration read from environment variables at compile time, the MAC
//! address derived from the chip's unique ID, and the analog scaling.
//!
//! Nothing here touches the hardware, so the host tests build this file on
//! its own (`board/mod.rs` includes it under `cfg(test)`).
//!
//! | variable | default | meaning |
//! |---|---|---|
//! | `NUCLEO_DHCP` | `on` | `on`: ask DHCP first; `off`: use `NUCLEO_IP` at once |
//! | `NUCLEO_IP` | `192.168.1.50/24` | the static address (the fallback when DHCP is on) |
//! | `NUCLEO_GATEWAY` | none | default gateway of the static address |
//! | `NUCLEO_DHCP_TIMEOUT_S` | `10` | seconds without a lease before the fallback applies (1..=3600) |
//!
//! A malformed value stops the build with a message naming the variable.

use crate::io::AnalogType;

/// Whether the board asks DHCP for its address (`NUCLEO_DHCP`).
pub const DHCP: bool = match option_env!("NUCLEO_DHCP") {
    None => true,
    Some(text) => match parse_switch(text) {
        Some(on) => on,
        None => invalid("NUCLEO_DHCP must be `on` or `off`"),
    },
};

/// The static address and prefix length (`NUCLEO_IP`).
pub const STATIC_IP: ([u8; 4], u8) = match parse_cidr(match option_env!("NUCLEO_IP") {
    Some(text) => text,
    None => "192.168.1.50/24",
}) {
    Some(cidr) => cidr,
    None => invalid("NUCLEO_IP must look like 192.168.1.50/24"),
};

/// The static configuration's default gateway (`NUCLEO_GATEWAY`; unset or empty: none).
pub const GATEWAY: Option<[u8; 4]> = match option_env!("NUCLEO_GATEWAY") {
    None => None,
    Some(text) if text.is_empty() => None,
    Some(text) => match parse_ipv4(text) {
        Some(address) => Some(address),
        None => invalid("NUCLEO_GATEWAY must look like 192.168.1.1"),
    },
};

/// Seconds without a DHCP lease before the static address applies (`NUCLEO_DHCP_TIMEOUT_S`).
pub const DHCP_TIMEOUT_S: u64 = match option_env!("NUCLEO_DHCP_TIMEOUT_S") {
    None => 10,
    Some(text) => match parse_decimal(text) {
        Some(seconds) if seconds >= 1 && seconds <= 3600 => seconds,
        _ => invalid("NUCLEO_DHCP_TIMEOUT_S must be 1..=3600"),
    },
};

/// Stops the build: a setting above is malformed. Only ever evaluated in a `const`.
#[allow(clippy::panic, reason = "evaluated at compile time only: a bad setting is a build error")]
const fn invalid<T>(message: &str) -> T {
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
const fn parse_decimal_bytes(bytes: &[u8]) -> Option<u64> {
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
const fn split_once(bytes: &[u8], separator: u8) -> Option<(&[u8], &[u8])> {
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

/// A locally administered, unicast MAC address from the chip's 96-bit unique
/// ID: `02` then 40 bits of the ID's FNV-1a hash. The same chip always gets
/// the same address; two chips collide with odds of about 1 in 10^12.
pub const fn mac_from_uid(uid: &[u8; 12]) -> [u8; 6] {
    const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut hash = FNV_OFFSET;
    let mut rest = uid.as_slice();
    while let [byte, tail @ ..] = rest {
        hash ^= *byte as u64;
        hash = hash.wrapping_mul(FNV_PRIME);
        rest = tail;
    }
    let [a, b, c, d, e, ..] = hash.to_be_bytes();
    // Bit 1 of the first octet: locally administered; bit 0 clear: unicast.
    [0x02, a, b, c, d, e]
}

/// Full scale of the ADC and the DAC: VDDA = VREF+ on the NUCLEO, in mV.
pub const VREF_MV: u64 = 3300;
/// The pin voltage, in mV, that the analog front end maps to the top of each
/// range (10 V or 20 mA), leaving headroom below [`VREF_MV`].
pub const FULL_SCALE_MV: u64 = 3000;
/// Largest code of the 12-bit ADC and DAC.
pub const CODE_MAX: u64 = 4095;

/// An ADC reading (0..=4095) in thousandths of `kind`'s unit, clamped to its range.
pub const fn adc_to_value(code: u16, kind: AnalogType) -> u16 {
    let max = kind.max() as u64;
    let value = (code as u64 * VREF_MV * max) / (CODE_MAX * FULL_SCALE_MV);
    if value > max { max as u16 } else { value as u16 }
}

/// The DAC code for an output `value` in thousandths of `kind`'s unit (clamped to its range).
pub const fn value_to_dac(value: u16, kind: AnalogType) -> u16 {
    let max = kind.max() as u64;
    let value = if value as u64 > max { max } else { value as u64 };
    // Rounded to the nearest code.
    ((value * FULL_SCALE_MV * CODE_MAX + max * VREF_MV / 2) / (max * VREF_MV)) as u16
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
    #[allow(clippy::assertions_on_constants, reason = "checks the values the build environment produced")]
    fn defaults_hold_without_environment() {
        // Whatever the build environment sets, it parsed; what it leaves unset has its default.
        assert!(STATIC_IP.1 >= 1 && STATIC_IP.1 <= 32);
        assert!((1..=3600).contains(&DHCP_TIMEOUT_S));
        if option_env!("NUCLEO_DHCP").is_none() {
            assert!(DHCP);
        }
        if option_env!("NUCLEO_IP").is_none() {
            assert_eq!(STATIC_IP, ([192, 168, 1, 50], 24));
        }
        if option_env!("NUCLEO_GATEWAY").is_none() {
            assert_eq!(GATEWAY, None);
        }
        if option_env!("NUCLEO_DHCP_TIMEOUT_S").is_none() {
            assert_eq!(DHCP_TIMEOUT_S, 10);
        }
    }

    #[test]
    fn the_mac_is_local_unicast_and_stable() {
        let uid = [0x33, 0x00, 0x2f, 0x00, 0x0d, 0x51, 0x33, 0x30, 0x34, 0x38, 0x37, 0x30];
        let mac = mac_from_uid(&uid);
        assert_eq!(mac[0], 0x02);
        assert_eq!(mac, mac_from_uid(&uid));
        let mut other = uid;
        other[11] ^= 1;
        assert_ne!(mac, mac_from_uid(&other));
    }

    #[test]
    fn adc_codes_scale_to_the_map() {
        assert_eq!(adc_to_value(0, AnalogType::Voltage), 0);
        // 3.0 V at the pin is the top of both ranges.
        let full = (FULL_SCALE_MV * CODE_MAX / VREF_MV) as u16; // 3722
        assert_eq!(adc_to_value(full + 1, AnalogType::Voltage), 10_000);
        assert!(adc_to_value(full, AnalogType::Voltage) >= 9_997);
        assert!(adc_to_value(full, AnalogType::Current) >= 19_994);
        // Above full scale: clamped.
        assert_eq!(adc_to_value(4095, AnalogType::Voltage), 10_000);
        assert_eq!(adc_to_value(4095, AnalogType::Current), 20_000);
        // Mid-scale: 1.5 V at the pin is 5 V / 10 mA.
        let mid = adc_to_value(1861, AnalogType::Voltage);
        assert!((4_995..=5_005).contains(&mid), "{mid}");
    }

    #[test]
    fn output_values_scale_to_dac_codes() {
        assert_eq!(value_to_dac(0, AnalogType::Voltage), 0);
        assert_eq!(value_to_dac(10_000, AnalogType::Voltage), 3723);
        assert_eq!(value_to_dac(20_000, AnalogType::Current), 3723);
        assert_eq!(value_to_dac(u16::MAX, AnalogType::Current), 3723);
        assert_eq!(value_to_dac(5_000, AnalogType::Voltage), 1861);
        // A round trip stays within one code's worth (< 3 mV / 6 µA).
        for value in (0..=10_000).step_by(250) {
            let back = adc_to_value(value_to_dac(value, AnalogType::Voltage), AnalogType::Voltage);
            assert!(back.abs_diff(value) <= 3, "{value} -> {back}");
        }
    }
}
