//! Whole frames in, whole frames out: every exception path, unit ids, echoes.

use super::*;
use crate::map::table::reg;
use test_support::fixtures::PYMODBUS;
use test_support::framer::adu;

fn answer(image: &mut Image, policy: &Policy, frame: &[u8]) -> Outcome {
    let mut reply = [0xa5u8; MAX_ADU_LEN];
    respond(frame, &mut reply, image, policy)
}

/// The reply to `pdu` sent as unit 1, transaction 0x1234, with its header checked.
fn reply_pdu(image: &mut Image, policy: &Policy, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let frame = adu(0x1234, 0, unit, pdu);
    let mut reply = [0xa5u8; MAX_ADU_LEN];
    let Outcome::Reply { len, .. } = respond(&frame, &mut reply, image, policy) else { panic!("no reply") };
    assert_eq!(&reply[..4], &[0x12, 0x34, 0x00, 0x00], "transaction id echoed, protocol 0");
    assert_eq!(usize::from(u16::from_be_bytes([reply[4], reply[5]])), len - 6, "length field");
    assert_eq!(reply[6], unit, "unit id echoed");
    assert_eq!(reply[len], 0xa5, "nothing written past the reply");
    reply[7..len].to_vec()
}

fn seed() -> Policy {
    Policy::default()
}

fn strict() -> Policy {
    Policy { write_policy: WritePolicy::Strict, ..Policy::default() }
}

#[test]
fn captured_requests_get_these_exact_replies() {
    let mut image = Image::new();
    image.set_controller_version(&crate::io::Version { major: 2, minor: 0x0110, patch: 9 });
    #[rustfmt::skip]
    let want: [&[u8]; 6] = [
        // 03, 6 bytes: registers 256-258 = the robot controller's version, 2.272.9.
        &[0x03, 0x06, 0x00, 0x02, 0x01, 0x10, 0x00, 0x09],
        // 01, 2 bytes: coils 16-25 all off.
        &[0x01, 0x02, 0x00, 0x00],
        // 05: echo.
        &[0x05, 0x00, 0x10, 0xff, 0x00],
        // 06: echo.
        &[0x06, 0x00, 0x80, 0x12, 0x34],
        // 0F: start 16, quantity 10.
        &[0x0f, 0x00, 0x10, 0x00, 0x0a],
        // 10: start 128, quantity 2.
        &[0x10, 0x00, 0x80, 0x00, 0x02],
    ];
    for (fixture, want) in PYMODBUS.iter().zip(want) {
        let mut reply = [0xa5u8; MAX_ADU_LEN];
        let Outcome::Reply { len, exception, .. } = respond(fixture.request, &mut reply, &mut image, &seed()) else {
            panic!("{}: no reply", fixture.name)
        };
        assert_eq!(exception, None, "{}", fixture.name);
        assert_eq!(&reply[..4], &fixture.request[..4], "{}: transaction and protocol id", fixture.name);
        assert_eq!(reply[6], fixture.request[6], "{}: unit id", fixture.name);
        assert_eq!(&reply[7..len], want, "{}", fixture.name);
    }
    // The writes landed: coils 16-25 = 1,0,1,1,0,0,0,0,1,1; registers 128-129.
    assert_eq!(image.register(reg::DIGITAL_OUTPUTS), 0b11_0000_1101);
    assert_eq!((image.register(128), image.register(129)), (0x000a, 0x0102));
    // pymodbus's server answered the writes with the same bytes we do.
    for fixture in &PYMODBUS[2..] {
        let mut reply = [0u8; MAX_ADU_LEN];
        let Outcome::Reply { len, .. } = respond(fixture.request, &mut reply, &mut Image::new(), &seed()) else {
            panic!()
        };
        assert_eq!(&reply[..len], fixture.reply, "{}", fixture.name);
    }
}

#[test]
fn illegal_function() {
    let mut image = Image::new();
    for code in [0x00u8, 0x02, 0x04, 0x07, 0x08, 0x11, 0x16, 0x17, 0x2b, 0x41, 0x7f] {
        assert_eq!(reply_pdu(&mut image, &seed(), 1, &[code, 0, 0, 0, 1]), [code | 0x80, 0x01], "{code:#04x}");
        assert_eq!(reply_pdu(&mut image, &seed(), 1, &[code]), [code | 0x80, 0x01], "{code:#04x} alone");
    }
    // A request that carries the exception bit is not a request.
    assert_eq!(reply_pdu(&mut image, &seed(), 1, &[0x83, 0, 0, 0, 1]), [0x83, 0x01]);
}

#[test]
fn illegal_data_value_comes_before_illegal_data_address() {
    let mut image = Image::new();
    // (request PDU, exception) — addresses far outside the map, so 03 must win over 02.
    #[rustfmt::skip]
    let cases: &[(&[u8], u8)] = &[
        (&[0x01, 0xff, 0xff, 0x00, 0x00], 0x03),        // quantity 0
        (&[0x01, 0xff, 0xff, 0x07, 0xd1], 0x03),        // quantity 2001
        (&[0x03, 0xff, 0xff, 0x00, 0x00], 0x03),        // quantity 0
        (&[0x03, 0xff, 0xff, 0x00, 0x7e], 0x03),        // quantity 126
        (&[0x05, 0xff, 0xff, 0x00, 0x01], 0x03),        // value not 0xFF00/0x0000
        (&[0x0f, 0xff, 0xff, 0x00, 0x09, 0x01, 0xff], 0x03), // 9 coils in 1 byte
        (&[0x0f, 0xff, 0xff, 0x07, 0xb1, 0xf7], 0x03),  // quantity 1969
        (&[0x10, 0xff, 0xff, 0x00, 0x01, 0x01, 0x00], 0x03), // byte count 1 for 1 register
        (&[0x10, 0xff, 0xff, 0x00, 0x7c, 0xf8], 0x03),  // quantity 124
        (&[0x03, 0x00, 0x00, 0x00], 0x03),              // a field cut short
        (&[0x06, 0x00, 0x80, 0x00, 0x01, 0x00], 0x03),  // a byte too many
        // Now valid quantities at bad addresses: 02.
        (&[0x01, 0x01, 0x0a, 0x00, 0x01], 0x02),        // coil 266
        (&[0x01, 0x00, 0x00, 0x07, 0xd0], 0x02),        // 2000 coils from 0
        (&[0x03, 0x01, 0xb4, 0x00, 0x01], 0x02),        // register 436
        (&[0x03, 0x01, 0x39, 0x00, 0x7d], 0x02),        // 313 + 125 > 436
        (&[0x05, 0x00, 0x2c, 0xff, 0x00], 0x02),        // reserved coil 44
        (&[0x06, 0x00, 0x02, 0x00, 0x01], 0x02),        // reserved register 2
        (&[0x0f, 0x01, 0x09, 0x00, 0x02, 0x01, 0x03], 0x02), // coils 265-266
        (&[0x10, 0x00, 0x7f, 0x00, 0x01, 0x02, 0x00, 0x01], 0x02), // reserved register 127
        // Valid addresses, values the map refuses: 03.
        (&[0x06, 0x00, 0x10, 0x4e, 0x21], 0x03),        // analog output 20 001 µA
        (&[0x06, 0x00, 0x11, 0x00, 0x02], 0x03),        // analog type 2
        (&[0x06, 0x00, 0x16, 0x00, 0x40], 0x03),        // tool output 7 does not exist
    ];
    for (pdu, code) in cases {
        let before = image.clone();
        assert_eq!(reply_pdu(&mut image, &seed(), 1, pdu), [pdu[0] | 0x80, *code], "{pdu:02x?}");
        assert_eq!(image, before, "{pdu:02x?}: an exception changes nothing");
    }
}

#[test]
fn strict_policy_refuses_read_only_points_and_seed_accepts_them() {
    for (pdu, echo_len) in [(&[0x06u8, 0x01, 0x00, 0x00, 0x09][..], 5), (&[0x05, 0x00, 0x00, 0xff, 0x00][..], 5)] {
        let mut image = Image::new();
        assert_eq!(reply_pdu(&mut image, &strict(), 1, pdu), [pdu[0] | 0x80, 0x02]);
        assert_eq!(image, Image::new());
        assert_eq!(reply_pdu(&mut image, &seed(), 1, pdu).len(), echo_len);
        assert_ne!(image, Image::new());
    }
    let mut image = Image::new();
    let write = [0x10, 0x00, 0xff, 0x00, 0x02, 0x04, 0, 1, 0, 2]; // registers 255 (RW) and 256 (R)
    assert_eq!(reply_pdu(&mut image, &strict(), 1, &write), [0x90, 0x02]);
    assert_eq!(image.register(255), 0, "all or nothing");
    assert_eq!(reply_pdu(&mut image, &seed(), 1, &write), [0x10, 0x00, 0xff, 0x00, 0x02]);
    assert_eq!((image.register(255), image.register(256)), (1, 2));
}

#[test]
fn unit_ids() {
    let read = [0x03, 0x00, 0x80, 0x00, 0x01];
    let mut image = Image::new();
    for unit in 0..=u8::MAX {
        assert_eq!(reply_pdu(&mut image, &seed(), unit, &read)[0], 0x03, "every unit id by default");
    }
    let configured = Policy { unit_id: Some(5), ..Policy::default() };
    for unit in 0..=u8::MAX {
        let reply = reply_pdu(&mut image, &configured, unit, &read);
        if [0, 5, 0xff].contains(&unit) {
            assert_eq!(reply[0], 0x03, "unit {unit}");
        } else {
            assert_eq!(reply, [0x83, 0x0b], "unit {unit}");
        }
    }
    // A write to another unit changes nothing.
    let before = image.clone();
    assert_eq!(reply_pdu(&mut image, &configured, 9, &[0x06, 0x00, 0x80, 0x00, 0x01]), [0x86, 0x0b]);
    assert_eq!(image, before);
}

#[test]
fn bytes_that_are_not_one_whole_frame_are_not_answered() {
    let mut image = Image::new();
    let frame = adu(1, 0, 1, &[0x06, 0x00, 0x80, 0x00, 0x01]);
    for cut in 0..frame.len() {
        assert_eq!(answer(&mut image, &seed(), &frame[..cut]), Outcome::NotWhole, "{cut} bytes");
    }
    let mut short_length = frame.clone();
    short_length[5] = 1; // a length field of 1: no function code
    assert_eq!(answer(&mut image, &seed(), &short_length), Outcome::NotWhole);
    assert_eq!(image, Image::new(), "nothing was written");
}

#[test]
fn a_foreign_protocol_id_gets_no_reply() {
    let mut image = Image::new();
    let mut frame = adu(1, 0, 1, &[0x06, 0x00, 0x80, 0x00, 0x01]);
    for protocol in [1u16, 0x0100, 0xffff] {
        frame[2..4].copy_from_slice(&protocol.to_be_bytes());
        assert_eq!(answer(&mut image, &seed(), &frame), Outcome::Discard { protocol_id: protocol });
        assert_eq!(image.register(128), 0, "and does nothing");
    }
}

#[test]
fn outcomes_report_exceptions_and_output_writes() {
    let mut image = Image::new();
    let outcome = answer(&mut image, &seed(), &adu(1, 0, 1, &[0x05, 0x00, 0x10, 0xff, 0x00]));
    assert!(matches!(outcome, Outcome::Reply { written: Written { outputs: true }, exception: None, .. }));
    let outcome = answer(&mut image, &seed(), &adu(1, 0, 1, &[0x06, 0x00, 0x80, 0x00, 0x01]));
    assert!(matches!(outcome, Outcome::Reply { written: Written { outputs: false }, exception: None, .. }));
    let outcome = answer(&mut image, &seed(), &adu(1, 0, 1, &[0x06, 0x00, 0x02, 0x00, 0x01]));
    assert!(matches!(outcome, Outcome::Reply { exception: Some(Exception::IllegalDataAddress), len: 9, .. }));
}

#[test]
fn the_largest_reads_fill_the_largest_replies() {
    let mut image = Image::new();
    let reply = reply_pdu(&mut image, &seed(), 1, &[0x03, 0x00, 0x80, 0x00, 0x7d]);
    assert_eq!((reply.len(), reply[1]), (252, 250));
    let reply = reply_pdu(&mut image, &seed(), 1, &[0x01, 0x00, 0x00, 0x01, 0x0a]);
    assert_eq!((reply.len(), reply[1]), (36, 34), "266 coils in 34 bytes");
}
