//! The settings store: arbitrary bytes as a settings record and as the flash
//! image it loads from (firmware_fuzz::StoreInput).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::store(data));
