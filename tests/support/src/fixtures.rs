//! Real Modbus TCP bytes, captured from the pymodbus 3.16.1 client talking to
//! a pymodbus server through a logging proxy (`tests/fixtures/capture.py`,
//! raw log in `tests/fixtures/pymodbus.txt`). Used by the codec tests, the
//! benchmarks and as the fuzzer's seed corpus: [`PYMODBUS`] for the six
//! function codes of the map, [`PYMODBUS_DEVICE`] for Read Device
//! Identification and Diagnostics.

/// A request as a client sent it, and the reply the pymodbus server gave.
#[derive(Clone, Copy, Debug)]
pub struct Fixture {
    pub name: &'static str,
    pub request: &'static [u8],
    pub reply: &'static [u8],
}

#[rustfmt::skip]
pub static PYMODBUS: [Fixture; 6] = [
    Fixture {
        name: "read_holding_registers(256, count=3)",
        request: &[
            0x00, 0x01, // transaction id 1
            0x00, 0x00, // protocol id 0
            0x00, 0x06, // length 6: unit id + 5 PDU bytes
            0x01,       // unit id 1
            0x03,       // FC 03 read holding registers
            0x01, 0x00, // start address 256
            0x00, 0x03, // quantity 3
        ],
        reply: &[
            0x00, 0x01, 0x00, 0x00, // transaction 1, protocol 0
            0x00, 0x09, // length 9
            0x01,       // unit id 1
            0x03,       // FC 03
            0x06,       // byte count 6
            0x00, 0x00, 0x00, 0x00, 0x00, 0x00, // three registers, all 0 on that server
        ],
    },
    Fixture {
        name: "read_coils(16, count=10)",
        request: &[
            0x00, 0x02, 0x00, 0x00, // transaction 2, protocol 0
            0x00, 0x06, // length 6
            0x01,       // unit id 1
            0x01,       // FC 01 read coils
            0x00, 0x10, // start address 16
            0x00, 0x0a, // quantity 10
        ],
        reply: &[
            0x00, 0x02, 0x00, 0x00, 0x00, 0x05, 0x01, // header, length 5, unit 1
            0x01,       // FC 01
            0x02,       // byte count 2 (10 coils)
            0x00, 0x00, // coil states, LSB first
        ],
    },
    Fixture {
        name: "write_coil(16, True)",
        request: &[
            0x00, 0x03, 0x00, 0x00, 0x00, 0x06, 0x01, // transaction 3, length 6, unit 1
            0x05,       // FC 05 write single coil
            0x00, 0x10, // address 16
            0xff, 0x00, // 0xFF00 = on
        ],
        reply: &[
            0x00, 0x03, 0x00, 0x00, 0x00, 0x06, 0x01, // echo of the request
            0x05, 0x00, 0x10, 0xff, 0x00,
        ],
    },
    Fixture {
        name: "write_register(128, 0x1234)",
        request: &[
            0x00, 0x04, 0x00, 0x00, 0x00, 0x06, 0x01, // transaction 4, length 6, unit 1
            0x06,       // FC 06 write single register
            0x00, 0x80, // address 128
            0x12, 0x34, // value 0x1234
        ],
        reply: &[
            0x00, 0x04, 0x00, 0x00, 0x00, 0x06, 0x01, // echo of the request
            0x06, 0x00, 0x80, 0x12, 0x34,
        ],
    },
    Fixture {
        name: "write_coils(16, [1,0,1,1,0,0,0,0,1,1])",
        request: &[
            0x00, 0x05, 0x00, 0x00, // transaction 5, protocol 0
            0x00, 0x09, // length 9
            0x01,       // unit id 1
            0x0f,       // FC 0F write multiple coils
            0x00, 0x10, // start address 16
            0x00, 0x0a, // quantity 10
            0x02,       // byte count 2
            0x0d,       // coils 16-23: 1,0,1,1,0,0,0,0 (LSB first)
            0x03,       // coils 24-25: 1,1
        ],
        reply: &[
            0x00, 0x05, 0x00, 0x00, 0x00, 0x06, 0x01, // header, length 6, unit 1
            0x0f, 0x00, 0x10, 0x00, 0x0a, // FC 0F, start 16, quantity 10
        ],
    },
    Fixture {
        name: "write_registers(128, [0x000a, 0x0102])",
        request: &[
            0x00, 0x06, 0x00, 0x00, // transaction 6, protocol 0
            0x00, 0x0b, // length 11
            0x01,       // unit id 1
            0x10,       // FC 10 write multiple registers
            0x00, 0x80, // start address 128
            0x00, 0x02, // quantity 2
            0x04,       // byte count 4
            0x00, 0x0a, // register 128 = 10
            0x01, 0x02, // register 129 = 0x0102
        ],
        reply: &[
            0x00, 0x06, 0x00, 0x00, 0x00, 0x06, 0x01, // header, length 6, unit 1
            0x10, 0x00, 0x80, 0x00, 0x02, // FC 10, start 128, quantity 2
        ],
    },
];

/// Read Device Identification (2B/0E) and Diagnostics (08) from the same
/// capture, after [`PYMODBUS`]. The replies are the pymodbus server's, with
/// the identity `capture.py` gives it (its conformity level is 0x83, and it
/// leaves out an object with an empty value, here VendorUrl).
#[rustfmt::skip]
pub static PYMODBUS_DEVICE: [Fixture; 6] = [
    Fixture {
        name: "read_device_information(read_code=1, object_id=0)",
        request: &[
            0x00, 0x07, 0x00, 0x00, // transaction 7, protocol 0
            0x00, 0x05, // length 5: unit id + 4 PDU bytes
            0x01,       // unit id 1
            0x2b,       // FC 2B encapsulated interface transport
            0x0e,       // MEI type 0E read device identification
            0x01,       // read device id code 01: basic, stream
            0x00,       // from object 0
        ],
        reply: &[
            0x00, 0x07, 0x00, 0x00, 0x00, 0x1e, 0x01, // header, length 30, unit 1
            0x2b, 0x0e, 0x01, // FC 2B, MEI type 0E, code 01
            0x83,       // conformity level: extended, stream and individual access
            0x00,       // more follows: no
            0x00,       // next object id: 0
            0x03,       // 3 objects
            0x00, 0x08, b'p', b'y', b'm', b'o', b'd', b'b', b'u', b's', // 0 VendorName
            0x01, 0x02, b'P', b'M',                                     // 1 ProductCode
            0x02, 0x06, b'3', b'.', b'1', b'6', b'.', b'1',             // 2 MajorMinorRevision
        ],
    },
    Fixture {
        name: "read_device_information(read_code=2, object_id=0)",
        request: &[
            0x00, 0x08, 0x00, 0x00, 0x00, 0x05, 0x01, // transaction 8, length 5, unit 1
            0x2b, 0x0e, 0x02, // FC 2B, MEI type 0E, code 02: regular, stream
            0x00,       // from object 0
        ],
        reply: &[
            0x00, 0x08, 0x00, 0x00, 0x00, 0x39, 0x01, // header, length 57, unit 1
            0x2b, 0x0e, 0x02, 0x83, // FC 2B, MEI type 0E, code 02, conformity 0x83
            0x00, 0x00, // no more follows, next object id 0
            0x06,       // 6 objects (no VendorUrl: its value is empty)
            0x00, 0x08, b'p', b'y', b'm', b'o', b'd', b'b', b'u', b's', // 0 VendorName
            0x01, 0x02, b'P', b'M',                                     // 1 ProductCode
            0x02, 0x06, b'3', b'.', b'1', b'6', b'.', b'1',             // 2 MajorMinorRevision
            0x04, 0x06, b's', b'e', b'r', b'v', b'e', b'r',             // 4 ProductName
            0x05, 0x07, b'c', b'a', b'p', b't', b'u', b'r', b'e',       // 5 ModelName
            0x06, 0x08, b'f', b'i', b'x', b't', b'u', b'r', b'e', b's', // 6 UserApplicationName
        ],
    },
    Fixture {
        name: "read_device_information(read_code=4, object_id=5)",
        request: &[
            0x00, 0x09, 0x00, 0x00, 0x00, 0x05, 0x01, // transaction 9, length 5, unit 1
            0x2b, 0x0e, 0x04, // FC 2B, MEI type 0E, code 04: one object
            0x05,       // object 5: ModelName
        ],
        reply: &[
            0x00, 0x09, 0x00, 0x00, 0x00, 0x11, 0x01, // header, length 17, unit 1
            0x2b, 0x0e, 0x04, 0x83, // FC 2B, MEI type 0E, code 04, conformity 0x83
            0x00, 0x00, // no more follows, next object id 0
            0x01,       // 1 object
            0x05, 0x07, b'c', b'a', b'p', b't', b'u', b'r', b'e', // 5 ModelName
        ],
    },
    Fixture {
        name: "diag_query_data(b'\\x12\\x34')",
        request: &[
            0x00, 0x0a, 0x00, 0x00, 0x00, 0x06, 0x01, // transaction 10, length 6, unit 1
            0x08,       // FC 08 diagnostics
            0x00, 0x00, // sub-function 0000: return query data
            0x12, 0x34, // data
        ],
        reply: &[
            0x00, 0x0a, 0x00, 0x00, 0x00, 0x06, 0x01, // echo of the request
            0x08, 0x00, 0x00, 0x12, 0x34,
        ],
    },
    Fixture {
        name: "diag_clear_counters()",
        request: &[
            0x00, 0x0b, 0x00, 0x00, 0x00, 0x06, 0x01, // transaction 11, length 6, unit 1
            0x08,       // FC 08 diagnostics
            0x00, 0x0a, // sub-function 000A: clear counters and diagnostic register
            0x00, 0x00, // data 0000
        ],
        reply: &[
            0x00, 0x0b, 0x00, 0x00, 0x00, 0x06, 0x01, // echo of the request
            0x08, 0x00, 0x0a, 0x00, 0x00,
        ],
    },
    Fixture {
        name: "diag_read_bus_message_count()",
        request: &[
            0x00, 0x0c, 0x00, 0x00, 0x00, 0x06, 0x01, // transaction 12, length 6, unit 1
            0x08,       // FC 08 diagnostics
            0x00, 0x0b, // sub-function 000B: return bus message count
            0x00, 0x00, // data 0000
        ],
        reply: &[
            0x00, 0x0c, 0x00, 0x00, 0x00, 0x06, 0x01, // header, length 6, unit 1
            0x08, 0x00, 0x0b, // FC 08, sub-function 000B
            0x00, 0x00, // count 0 (the pymodbus server does not count)
        ],
    },
];

#[cfg(test)]
mod tests {
    use super::*;

    /// Every fixture is the capture log's bytes, in the log's order.
    #[test]
    fn the_fixtures_are_the_captured_bytes() {
        let log = include_str!("../../fixtures/pymodbus.txt");
        let lines: Vec<(&str, Vec<u8>)> = log
            .lines()
            .filter(|line| !line.starts_with('#'))
            .map(|line| {
                let (tag, hex) = line.split_once(' ').unwrap();
                let bytes = (0..hex.len()).step_by(2).map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap());
                (tag, bytes.collect())
            })
            .collect();
        let fixtures: Vec<&Fixture> = PYMODBUS.iter().chain(&PYMODBUS_DEVICE).collect();
        assert_eq!(lines.len(), 2 * fixtures.len());
        for (fixture, pair) in fixtures.iter().zip(lines.chunks(2)) {
            assert_eq!(pair[0], ("request", fixture.request.to_vec()), "{}", fixture.name);
            assert_eq!(pair[1], ("reply", fixture.reply.to_vec()), "{}", fixture.name);
        }
    }
}
