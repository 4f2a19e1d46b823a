//! Real Modbus TCP bytes, captured from the pymodbus 3.16.1 client talking to
//! a pymodbus server through a logging proxy (`tests/fixtures/capture.py`,
//! raw log in `tests/fixtures/pymodbus.txt`). Used by the codec tests, the
//! benchmarks and as the fuzzer's seed corpus.

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
