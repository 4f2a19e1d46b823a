//! The TLS server of port 802: a client's bytes, cut into reads by part of
//! the input, to a session of the device's configuration (firmware_fuzz::tls).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::tls::tls(data));
