//! One HTTP connection: arbitrary bytes from a client, cut into reads by
//! part of the input, to the JSON API with an in-memory backend
//! (firmware_fuzz::HttpInput).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::http(data));
