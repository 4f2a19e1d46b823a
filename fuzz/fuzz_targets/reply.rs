//! The robot link's reply check: arbitrary bytes as the reply to a Read
//! Holding Registers request; accepted exactly when the specification says.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::reply::reply(data));
