//! The codec: arbitrary bytes as a request PDU, a response PDU and an MBAP
//! stream; parse and emit round-trip, framing as the specification says.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| firmware_fuzz::codec(data));
