//! Analog scaling for a linear front end: ADC and DAC codes to and from the
//! map's units (µA or mV, by the point's type). Boards give their
//! reference voltage and the pin voltage at full scale ([`FrontEnd`]).

use crate::io::AnalogType;

/// A linear analog front end: pin voltage 0..=`full_scale_mv` maps to the
/// whole range of a type (10 V or 20 mA); the converters span 0..=`vref_mv`
/// in codes 0..=`code_max`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrontEnd {
    /// The converters' reference voltage, in mV.
    pub vref_mv: u64,
    /// The pin voltage at the top of each range, in mV (headroom below `vref_mv`).
    pub full_scale_mv: u64,
    /// The converters' largest code.
    pub code_max: u64,
}

impl FrontEnd {
    /// An ADC reading in thousandths of `kind`'s unit, clamped to its range.
    pub const fn to_value(&self, code: u16, kind: AnalogType) -> u16 {
        let max = kind.max() as u64;
        let value = (code as u64 * self.vref_mv * max) / (self.code_max * self.full_scale_mv);
        if value > max { max as u16 } else { value as u16 }
    }

    /// The DAC code for an output `value` in thousandths of `kind`'s unit (clamped to its range).
    pub const fn to_code(&self, value: u16, kind: AnalogType) -> u16 {
        let max = kind.max() as u64;
        let value = if value as u64 > max { max } else { value as u64 };
        // Rounded to the nearest code.
        ((value * self.full_scale_mv * self.code_max + max * self.vref_mv / 2) / (max * self.vref_mv)) as u16
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The NUCLEO's: 3.3 V reference, 3.0 V at full scale, 12-bit converters.
    const NUCLEO: FrontEnd = FrontEnd { vref_mv: 3300, full_scale_mv: 3000, code_max: 4095 };

    #[test]
    fn adc_codes_scale_to_the_map() {
        let adc_to_value = |code, kind| NUCLEO.to_value(code, kind);
        assert_eq!(adc_to_value(0, AnalogType::Voltage), 0);
        // 3.0 V at the pin is the top of both ranges.
        let full = (NUCLEO.full_scale_mv * NUCLEO.code_max / NUCLEO.vref_mv) as u16; // 3722
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
        let value_to_dac = |value, kind| NUCLEO.to_code(value, kind);
        assert_eq!(value_to_dac(0, AnalogType::Voltage), 0);
        assert_eq!(value_to_dac(10_000, AnalogType::Voltage), 3723);
        assert_eq!(value_to_dac(20_000, AnalogType::Current), 3723);
        assert_eq!(value_to_dac(u16::MAX, AnalogType::Current), 3723);
        assert_eq!(value_to_dac(5_000, AnalogType::Voltage), 1861);
        // A round trip stays within one code's worth (< 3 mV / 6 µA).
        for value in (0..=10_000).step_by(250) {
            let back = NUCLEO.to_value(value_to_dac(value, AnalogType::Voltage), AnalogType::Voltage);
            assert!(back.abs_diff(value) <= 3, "{value} -> {back}");
        }
    }
}
