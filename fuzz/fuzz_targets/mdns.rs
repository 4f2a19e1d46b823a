//! The mDNS responder: arbitrary bytes as a query (firmware_fuzz::mdns).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::mdns(data));
