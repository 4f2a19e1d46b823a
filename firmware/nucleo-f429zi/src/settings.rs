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

use adapter::io::AnalogType;
use adapter::settings::{invalid, parse_cidr, parse_decimal, parse_ipv4, parse_switch};

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
