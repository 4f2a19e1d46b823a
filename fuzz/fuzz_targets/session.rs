//! A whole session: arbitrary bytes from a client, cut into reads by part of
//! the input, under a policy from the input (firmware_fuzz::SessionInput).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::session(data));
