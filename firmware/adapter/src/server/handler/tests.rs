//! Whole frames in, whole frames out: every exception path, unit ids, echoes.

use super::*;
use crate::access::Rights;
use crate::map::table::reg;
use crate::server::identity;
use crate::settings::Name;
use test_support::fixtures::PYMODBUS;
use test_support::framer::adu;

/// The device these tests answer as. Its counters stay 0 (the handler
/// never counts; the device does): a test of Diagnostics sets its own.
const IDENTITY: Identity<'static> = Identity { model: "test-board", name: &PRESS_4, previous_firmware: None };
const PRESS_4: Name = match Name::parse("press-4") {
    Ok(name) => name,
    Err(_) => Name::UNSET,
};
static STATS: Stats = Stats::new();

fn context() -> Context<'static> {
    Context { identity: IDENTITY, stats: &STATS }
}

fn answer(image: &mut Image, policy: &Policy, frame: &[u8]) -> Outcome {
    let mut reply = [0xa5u8; MAX_ADU_LEN];
    respond(frame, &mut reply, image, policy, &context())
}

/// The reply to `pdu` sent as unit 1, transaction 0x1234, with its header checked.
fn reply_pdu(image: &mut Image, policy: &Policy, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let frame = adu(0x1234, 0, unit, pdu);
    let mut reply = [0xa5u8; MAX_ADU_LEN];
    let Outcome::Reply { len, .. } = respond(&frame, &mut reply, image, policy, &context()) else { panic!("no reply") };
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
        let Outcome::Reply { len, exception, .. } =
            respond(fixture.request, &mut reply, &mut image, &seed(), &context())
        else {
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
        let Outcome::Reply { len, .. } = respond(fixture.request, &mut reply, &mut Image::new(), &seed(), &context())
        else {
            panic!()
        };
        assert_eq!(&reply[..len], fixture.reply, "{}", fixture.name);
    }
}

#[test]
fn illegal_function() {
    let mut image = Image::new();
    // 07 and 11 are serial-line only; 2B here carries MEI type 00, or none.
    for code in [0x00u8, 0x02, 0x04, 0x07, 0x11, 0x16, 0x17, 0x2b, 0x41, 0x7f] {
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

// Read Device Identification (2B/0E).

/// `| id | length | value |` of object `id` holding `value`.
fn object(id: u8, value: &str) -> Vec<u8> {
    [&[id, value.len() as u8][..], value.as_bytes()].concat()
}

/// The objects this device answers with, in order (docs/data-map.md).
fn objects() -> [Vec<u8>; 7] {
    [
        object(0, "mbio"),
        object(1, "mbio-tcp-io"),
        object(2, crate::VERSION_TEXT),
        object(3, ""),
        object(4, "Modbus TCP I/O adapter"),
        object(5, "test-board"),
        object(6, "press-4"),
    ]
}

/// A response to read code `code`: conformity 0x82, nothing more follows,
/// the objects `ids`.
fn identification(code: u8, ids: &[usize]) -> Vec<u8> {
    let mut pdu = vec![0x2b, 0x0e, code, 0x82, 0x00, 0x00, ids.len() as u8];
    for &id in ids {
        pdu.extend(&objects()[id]);
    }
    pdu
}

#[test]
fn read_device_identification_streams_and_single_objects() {
    let mut image = Image::new();
    let ask = |image: &mut Image, code: u8, object_id: u8| reply_pdu(image, &seed(), 1, &[0x2b, 0x0e, code, object_id]);
    #[rustfmt::skip]
    let regular = [
        0x2b, 0x0e, 0x02,   // function, MEI type, read code 02: regular stream
        0x82,               // conformity: regular, stream and individual access
        0x00, 0x00,         // no more follows, next object id 0: the whole set fits
        0x07,               // seven objects
        0x00, 0x04, b'm', b'b', b'i', b'o',                                      // VendorName
        0x01, 0x0b, b'm', b'b', b'i', b'o', b'-', b't', b'c', b'p', b'-', b'i', b'o', // ProductCode
    ];
    let reply = ask(&mut image, 0x02, 0x00);
    assert_eq!(reply[..regular.len()], regular);
    assert_eq!(reply, identification(0x02, &[0, 1, 2, 3, 4, 5, 6]));
    // Basic: objects 0-2. A stream starts at its object id, when that is one of
    // the category's, and at 0 otherwise ("as if object 0 were pointed out").
    assert_eq!(ask(&mut image, 0x01, 0x00), identification(0x01, &[0, 1, 2]));
    assert_eq!(ask(&mut image, 0x01, 0x02), identification(0x01, &[2]));
    for outside in [0x03, 0x06, 0x07, 0x80, 0xff] {
        assert_eq!(ask(&mut image, 0x01, outside), identification(0x01, &[0, 1, 2]), "basic from {outside:#04x}");
    }
    assert_eq!(ask(&mut image, 0x02, 0x04), identification(0x02, &[4, 5, 6]));
    assert_eq!(ask(&mut image, 0x02, 0x06), identification(0x02, &[6]));
    for outside in [0x07, 0x7f, 0x80, 0xff] {
        let all = identification(0x02, &[0, 1, 2, 3, 4, 5, 6]);
        assert_eq!(ask(&mut image, 0x02, outside), all, "regular from {outside:#04x}");
    }
    // Code 04: one object, every one of them.
    for id in 0..=6u8 {
        assert_eq!(ask(&mut image, 0x04, id), identification(0x04, &[usize::from(id)]), "object {id}");
    }
    assert_eq!(image, Image::new(), "identification reads no point and changes none");
}

#[test]
fn read_device_identification_exceptions() {
    let mut image = Image::new();
    // 02: code 04 for an object the device does not have.
    for id in [0x07, 0x7f, 0x80, 0xff] {
        assert_eq!(reply_pdu(&mut image, &seed(), 1, &[0x2b, 0x0e, 0x04, id]), [0xab, 0x02], "object {id:#04x}");
    }
    // 03: a read code other than 01, 02, 04 (03 too: no extended objects), or a PDU of another length.
    for code in [0x00, 0x03, 0x05, 0x0e, 0xff] {
        assert_eq!(reply_pdu(&mut image, &seed(), 1, &[0x2b, 0x0e, code, 0x00]), [0xab, 0x03], "code {code:#04x}");
    }
    for pdu in
        [&[0x2b, 0x0e][..], &[0x2b, 0x0e, 0x01], &[0x2b, 0x0e, 0x01, 0x00, 0x00], &[0x2b, 0x0e, 0x04, 0x09, 0x00]]
    {
        assert_eq!(reply_pdu(&mut image, &seed(), 1, pdu), [0xab, 0x03], "{pdu:02x?}");
    }
    // 01: another MEI type (0D, CANopen General Reference), or none.
    for pdu in [&[0x2b, 0x0d, 0x01, 0x00][..], &[0x2b, 0x0d], &[0x2b]] {
        assert_eq!(reply_pdu(&mut image, &seed(), 1, pdu), [0xab, 0x01], "{pdu:02x?}");
    }
    // The unit id filter comes first; a read-only client may read it all.
    let filtered = Policy { unit_id: Some(5), ..seed() };
    assert_eq!(reply_pdu(&mut image, &filtered, 9, &[0x2b, 0x0e, 0x04, 0x09]), [0xab, 0x0b]);
    let read_only = Policy { rights: Rights::Read, ..seed() };
    assert_eq!(reply_pdu(&mut image, &read_only, 1, &[0x2b, 0x0e, 0x01, 0x00]), identification(0x01, &[0, 1, 2]));
}

#[test]
fn the_device_name_and_model_come_from_the_context_and_the_longest_fit_one_reply() {
    let mut image = Image::new();
    let long_name = Name::parse(&"a".repeat(crate::settings::MAX_NAME_LEN)).unwrap();
    let long_model = "m".repeat(identity::MAX_MODEL_LEN + 8);
    let stats = Stats::new();
    let context = Context {
        identity: Identity { model: &long_model, name: &long_name, previous_firmware: Some(b"65535.65535.65535") },
        stats: &stats,
    };
    let mut reply = [0xa5u8; MAX_ADU_LEN];
    let frame = adu(1, 0, 1, &[0x2b, 0x0e, 0x02, 0x00]);
    let Outcome::Reply { len, exception: None, .. } = respond(&frame, &mut reply, &mut image, &seed(), &context) else {
        panic!("no reply")
    };
    let pdu = &reply[7..len];
    assert_eq!(pdu.len(), identity::REGULAR_SET_MAX_LEN, "the longest regular set");
    assert!(pdu.len() <= mbap::MAX_PDU_LEN);
    assert_eq!(pdu[4..7], [0x00, 0x00, 0x07], "all seven objects, nothing more follows");
    let Ok(Response::ReadDeviceIdentification { objects, next_object_id: None, .. }) = Response::parse(pdu) else {
        panic!("{pdu:02x?}")
    };
    let values: Vec<(u8, &[u8])> = objects.iter().collect();
    assert_eq!(values[5], (5, "m".repeat(identity::MAX_MODEL_LEN).as_bytes()), "the model, cut to 32 bytes");
    assert_eq!(values[6], (6, long_name.as_bytes()));
    assert_eq!(long_name.as_bytes().len(), 32);
    assert_eq!(reply[len], 0xa5);
}

// Diagnostics (08).

/// The reply PDU to `pdu` with the counters `stats` and `policy`.
fn diagnose(stats: &Stats, policy: &Policy, pdu: &[u8]) -> (Vec<u8>, Outcome) {
    let context = Context { identity: IDENTITY, stats };
    let mut reply = [0xa5u8; MAX_ADU_LEN];
    let outcome = respond(&adu(7, 0, 1, pdu), &mut reply, &mut Image::new(), policy, &context);
    let Outcome::Reply { len, .. } = outcome else { panic!("no reply to {pdu:02x?}") };
    assert!(reply.get(len).is_none_or(|&after| after == 0xa5), "nothing written past the reply");
    (reply[7..len].to_vec(), outcome)
}

/// Counters with a distinct value each (requests above 16 bits).
fn counted() -> Stats {
    let stats = Stats::new();
    let set =
        |counter: &core::sync::atomic::AtomicU32, value| counter.store(value, core::sync::atomic::Ordering::Relaxed);
    set(&stats.requests, 0x1_0064); // 65 636
    set(&stats.bad_protocol, 3);
    set(&stats.bad_length, 5);
    set(&stats.bad_function, 7);
    set(&stats.bad_address, 11);
    set(&stats.bad_value, 13);
    set(&stats.refused_writes, 17);
    set(&stats.other_unit, 19);
    set(&stats.evictions, 23);
    set(&stats.timeouts, 29);
    set(&stats.refused_connections, 31);
    set(&stats.watchdog_trips, 37);
    stats
}

#[test]
fn diagnostics_counters_are_the_adapter_s_own() {
    let stats = counted();
    #[rustfmt::skip]
    let expected: [(u8, u16); 6] = [
        (0x0b, 0x0067),       // bus messages: requests + bad protocol ids, low 16 bits (65 639)
        (0x0c, 5),            // communication errors: bad length fields
        (0x0d, 7 + 11 + 13 + 17 + 19), // exceptions: every exception counter
        (0x0e, 0x0064 - 19),  // server messages: requests for this unit (65 617)
        (0x0f, 3),            // no response: frames skipped unanswered
        (0x12, 23),           // overrun: sessions evicted for lack of room
    ];
    for (sub, count) in expected {
        let [hi, lo] = count.to_be_bytes();
        let (reply, outcome) = diagnose(&stats, &seed(), &[0x08, 0x00, sub, 0x00, 0x00]);
        assert_eq!(reply, [0x08, 0x00, sub, hi, lo], "sub-function {sub:#04x}");
        assert!(matches!(outcome, Outcome::Reply { write: false, exception: None, .. }));
    }
    assert_eq!(stats.snapshot(), counted().snapshot(), "reading changes no counter");
}

#[test]
fn diagnostics_return_query_data_echoes_any_data() {
    let stats = Stats::new();
    for data in [&[][..], &[0x12], &[0x12, 0x34], &[0xa5; 250]] {
        let pdu = [&[0x08, 0x00, 0x00][..], data].concat();
        assert_eq!(diagnose(&stats, &seed(), &pdu).0, pdu, "{} bytes", data.len());
    }
    // The largest echo fills the largest ADU.
    let mut reply = [0u8; MAX_ADU_LEN];
    let pdu = [&[0x08, 0x00, 0x00][..], &[0x5a; 250]].concat();
    let outcome = respond(&adu(1, 0, 1, &pdu), &mut reply, &mut Image::new(), &seed(), &context());
    assert!(matches!(outcome, Outcome::Reply { len: MAX_ADU_LEN, exception: None, .. }));
}

#[test]
fn diagnostics_clear_counters_is_a_write() {
    let stats = counted();
    let clear = [0x08, 0x00, 0x0a, 0x00, 0x00];
    // A client that may not write: 01, and nothing cleared.
    let read_only = Policy { rights: Rights::Read, ..seed() };
    let (reply, outcome) = diagnose(&stats, &read_only, &clear);
    assert_eq!(reply, [0x88, 0x01]);
    assert!(matches!(outcome, Outcome::Reply { write: true, exception: Some(Exception::IllegalFunction), .. }));
    assert_eq!(stats.snapshot(), counted().snapshot());
    // Refused first, whatever else is wrong with it; its counters are readable.
    assert_eq!(diagnose(&stats, &read_only, &[0x08, 0x00, 0x0a, 0x12, 0x34]).0, [0x88, 0x01]);
    assert_eq!(diagnose(&stats, &read_only, &[0x08, 0x00, 0x0c, 0x00, 0x00]).0, [0x08, 0x00, 0x0c, 0x00, 0x05]);
    // Another unit: 0B, nothing cleared.
    let filtered = Policy { unit_id: Some(3), ..seed() };
    assert_eq!(diagnose(&stats, &filtered, &clear).0, [0x88, 0x0b]);
    assert_eq!(stats.snapshot(), counted().snapshot());
    // Anyone else: echoed, every counter 0.
    let (reply, outcome) = diagnose(&stats, &seed(), &clear);
    assert_eq!(reply, clear);
    assert!(matches!(
        outcome,
        Outcome::Reply { write: true, exception: None, written: Written { outputs: false }, .. }
    ));
    assert_eq!(stats.snapshot(), crate::server::Counters::default());
}

#[test]
fn diagnostics_exceptions() {
    let stats = counted();
    // 01: the sub-functions not implemented (01-04 and 10, 11, 13, 14 of 6.8.1 among them).
    for sub in [0x0001u16, 0x0002, 0x0003, 0x0004, 0x0010, 0x0011, 0x0013, 0x0014, 0x0015, 0x0100, 0xffff] {
        let [hi, lo] = sub.to_be_bytes();
        assert_eq!(diagnose(&stats, &seed(), &[0x08, hi, lo, 0x00, 0x00]).0, [0x88, 0x01], "{sub:#06x}");
    }
    // 03: a counter's or the clear's data other than 0000; no whole sub-function.
    for pdu in [
        &[0x08, 0x00, 0x0b, 0x00, 0x01][..],
        &[0x08, 0x00, 0x0b],
        &[0x08, 0x00, 0x0b, 0x00, 0x00, 0x00],
        &[0x08, 0x00, 0x0a, 0xff, 0x00],
        &[0x08, 0x00, 0x12, 0x00],
        &[0x08, 0x00],
        &[0x08],
    ] {
        assert_eq!(diagnose(&stats, &seed(), pdu).0, [0x88, 0x03], "{pdu:02x?}");
    }
    assert_eq!(stats.snapshot(), counted().snapshot(), "no exception clears a counter");
}

#[test]
fn every_prefix_of_the_device_requests_is_not_a_frame() {
    use test_support::fixtures::PYMODBUS_DEVICE;
    let mut image = Image::new();
    for fixture in &PYMODBUS_DEVICE {
        for cut in 0..fixture.request.len() {
            assert_eq!(answer(&mut image, &seed(), &fixture.request[..cut]), Outcome::NotWhole, "{}", fixture.name);
        }
        // Whole, each is answered (the counters here are 0, the identity ours).
        let Outcome::Reply { exception, .. } = answer(&mut image, &seed(), fixture.request) else { panic!() };
        assert_eq!(exception, None, "{}", fixture.name);
    }
    assert_eq!(image, Image::new());
}

#[test]
fn the_previous_firmware_is_the_extended_object_of_a_device_that_takes_updates() {
    use crate::modbus::identification::{Objects, ReadDeviceIdCode};
    let updating = Identity { previous_firmware: Some(b"0.1.0"), ..IDENTITY };
    let mut out = [0u8; 253];
    // The answer's header (code, conformity) and its objects' ids and values.
    let mut ask = |identity: &Identity<'_>, code: u8, object_id: u8| {
        let len = identity.respond(ReadDeviceIdCode::from(code), object_id, &mut out)?;
        let reply = &out[..len];
        let objects = Objects::parse(reply[6], &reply[7..]).unwrap();
        let objects: Vec<(u8, Vec<u8>)> = objects.iter().map(|(id, value)| (id, value.to_vec())).collect();
        Ok::<_, Exception>((reply[2], reply[3], objects))
    };
    let (code, conformity, objects) = ask(&updating, 0x03, 0x00).unwrap();
    assert_eq!((code, conformity), (0x03, 0x83), "extended, stream and individual access");
    let ids: Vec<u8> = objects.iter().map(|(id, _)| *id).collect();
    assert_eq!(ids, [0, 1, 2, 3, 4, 5, 6, 0x80], "the regular objects, then the private one");
    assert_eq!(objects[7].1, b"0.1.0");
    // From the private object, or one by one; a reserved id starts at 0.
    assert_eq!(ask(&updating, 0x03, 0x80).unwrap().2, [(0x80, b"0.1.0".to_vec())]);
    assert_eq!(ask(&updating, 0x04, 0x80).unwrap().2, [(0x80, b"0.1.0".to_vec())]);
    assert_eq!(ask(&updating, 0x03, 0x07).unwrap().2.len(), 8);
    assert_eq!(ask(&updating, 0x02, 0x00).unwrap().1, 0x83, "the conformity is the device's, whatever the code");
    // Unknown: an empty object.
    let unknown = Identity { previous_firmware: Some(b""), ..IDENTITY };
    assert_eq!(ask(&unknown, 0x04, 0x80).unwrap().2, [(0x80, Vec::new())]);
    // A device that takes no updates: no extended object, 03 refused as before.
    assert_eq!(ask(&IDENTITY, 0x03, 0x00), Err(Exception::IllegalDataValue));
    assert_eq!(ask(&IDENTITY, 0x04, 0x80), Err(Exception::IllegalDataAddress));
    assert_eq!(ask(&IDENTITY, 0x02, 0x00).unwrap().1, 0x82);
}
