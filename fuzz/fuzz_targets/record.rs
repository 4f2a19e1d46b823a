//! The settings record decoder alone: arbitrary bytes as a stored settings
//! record (firmware_fuzz::record).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::record(data));
