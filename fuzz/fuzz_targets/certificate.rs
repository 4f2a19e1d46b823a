//! The certificate reader alone: arbitrary bytes as a client certificate's
//! DER (firmware_fuzz::certificate).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::certificate::certificate(data));
