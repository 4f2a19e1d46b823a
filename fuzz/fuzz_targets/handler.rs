//! The request handler alone: records of arbitrary bytes answered in turn
//! on one map (firmware_fuzz::HandlerInput).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::handler(data));
