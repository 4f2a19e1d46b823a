//! What the fuzz targets share: the layout of a fuzz input, an in-memory
//! connection for a session, and the checks every reply must pass.
//!
//! Each target is a few lines around one function here ([`session`],
//! [`handler`], [`codec`], [`store`], [`http`], [`mdns`]), so the same checks also run as
//! plain tests over the seed inputs (`cargo test` in this workspace).
//!
//! The checks are those of the library's session property test
//! (`firmware/adapter/src/server/session/properties.rs`), against the same
//! reference (test-support's framer and reply checks, written from the
//! specification): any stream, cut into reads of any size, is framed by the
//! MBAP length field only, every Modbus frame gets exactly one well-formed
//! reply in order, and the map (and the pins) change only through
//! acknowledged writes.

pub mod certificate;
pub mod check;
pub mod connection;
mod http;
pub mod input;
pub mod mdns;
pub mod reply;
pub mod storage;
pub mod tls;

use core::pin::pin;
use core::task::Poll;

use adapter::device::{Device, Watchdog};
use adapter::map::Image;
use adapter::server::{self, Config, Context, Counters, Error, Identity, Outcome, Policy, Server, Stats, handler};
use modbus::mbap::{self, MAX_ADU_LEN};
use modbus::{Exception, Request, Response};
use test_support::duplex::poll_once;
use test_support::framer::{self, Next, split_replies};
use test_support::reply::Answer;

use check::Pins;
pub use http::http;
pub use input::{HandlerInput, HttpInput, SessionInput};
pub use mdns::{MdnsInput, mdns};
pub use storage::{StoreInput, record, store};

/// The server's configuration as the tests set it: no idle timeout (the mock
/// clock never moves, but a session must not depend on that), the policy
/// under test, the device name [`NAME`].
fn config(policy: Policy) -> Config {
    let name = adapter::settings::Name::parse(NAME).unwrap_or(adapter::settings::Name::UNSET);
    Config { policy, idle_timeout: None, name, ..Config::DEFAULT }
}

/// The board the targets' devices say they are (Read Device Identification).
pub const MODEL: &str = "fuzz-board";
/// Their device name.
pub const NAME: &str = "fuzz-4";

/// Bound on polls of one session: every `Pending` must come from the
/// connection, which stalls at most once per read or write.
const MAX_POLLS: usize = 1 << 20;

/// Drives a whole session over `data` (see [`SessionInput`]) and checks it.
pub fn session(data: &[u8]) {
    let input = SessionInput::parse(data);
    let policy = input.policy();
    let pins = Pins::default();
    let device = Device::new(Watchdog::OFF, MODEL, &pins);
    let server = Server::new(config(policy), &device);
    let (wire, mut end) = connection::connect(&input);
    let result = {
        let mut session = pin!(server::serve(&mut end, &server, 0));
        let mut polls = 0;
        loop {
            let before = wire.stalls();
            match poll_once(session.as_mut()) {
                Poll::Ready(result) => break result,
                Poll::Pending => {
                    assert!(wire.stalls() > before, "the session waits with all input there and nothing stalled");
                    polls += 1;
                    assert!(polls < MAX_POLLS, "the session never ends");
                }
            }
        }
    };

    let framed = framer::split(input.stream);
    match result {
        Ok(()) => assert_eq!(framed.bad_length, None, "a clean end after a bad length field"),
        Err(Error::BadLength(len)) => assert_eq!(framed.bad_length, Some(len), "BadLength({len}) on this stream"),
        Err(other) => panic!("the session ended with {other:?}"),
    }
    let requests = framed.requests();
    let replies = split_replies(&wire.take_replies());
    assert_eq!(replies.len(), requests.len(), "one reply per Modbus frame, none for others");

    // The model: a fresh server that sees only the acknowledged writes and
    // the reads. At each step it holds what the session's server should
    // hold, so it must give the very same reply. (Diagnostics' counters are
    // not the model server's: check::counters follows them, below.)
    let model_pins = Pins::default();
    let model_device = Device::new(Watchdog::OFF, MODEL, &model_pins);
    let model = Server::new(config(policy), &model_device);
    let scratch = Stats::new();
    let name = config(policy).name;
    let context =
        Context { identity: Identity { model: MODEL, name: &name, previous_firmware: None }, stats: &scratch };
    let mut expected = [0u8; MAX_ADU_LEN];
    for (request, reply) in requests.iter().zip(&replies) {
        let answer = check::reply(request, reply, &policy);
        if let Answer::Read | Answer::Write | Answer::Identification = answer {
            let outcome = model.respond(request, &mut expected);
            let Outcome::Reply { len, exception, .. } = outcome else { panic!("the model discarded {request:02x?}") };
            assert_eq!(exception, None, "replaying {request:02x?} on the model fails");
            assert_eq!(&expected[..len], reply, "the model answers {request:02x?} otherwise");
        } else if answer == Answer::Diagnostics {
            // A count, or their clear: check::counters follows the counters,
            // below. Return Query Data's echo is the model's too.
            if request[8..10] == [0, 0] {
                let outcome = model.respond(request, &mut expected);
                let Outcome::Reply { len, .. } = outcome else { panic!("the model discarded {request:02x?}") };
                assert_eq!(&expected[..len], reply, "the model echoes {request:02x?} otherwise");
            }
        } else {
            // Refused: the same refusal from the model, and nothing changed.
            let before = model_device.read(Clone::clone);
            let mut copy = before.clone();
            let outcome = handler::respond(request, &mut expected, &mut copy, &policy, &context);
            let Outcome::Reply { len, .. } = outcome else { panic!("the handler discarded {request:02x?}") };
            assert_eq!(&expected[..len], reply, "the model refuses {request:02x?} otherwise");
            assert_eq!(copy, before, "a refused request {request:02x?} changed the map");
        }
    }
    let image = device.read(Clone::clone);
    assert!(image == model_device.read(Clone::clone), "the map holds exactly the acknowledged writes");
    check::pins_follow_map(&pins, &image);
    let lost = framed.bad_length.is_some();
    let expected = check::counters(&framed.frames, &replies, lost, &policy);
    assert_eq!(scratch.snapshot(), Counters::default(), "a refused request touched the counters");
    assert_eq!(server.stats().snapshot(), expected, "the diagnostics counters");
}

/// Answers each record of `data` (see [`HandlerInput`]) with the handler
/// alone, on one image, and checks each answer.
pub fn handler(data: &[u8]) {
    let input = HandlerInput::parse(data);
    let policy = input.policy();
    let mut image = Image::new();
    // The handler counts nothing (the device does): Diagnostics reads 0s.
    let stats = Stats::new();
    let name = config(policy).name;
    let context = Context { identity: Identity { model: MODEL, name: &name, previous_firmware: None }, stats: &stats };
    let mut reply = [0xa5u8; MAX_ADU_LEN];
    for frame in input.frames() {
        let before = image.clone();
        let outcome = handler::respond(frame, &mut reply, &mut image, &policy, &context);
        let protocol_id = framer::protocol_id(frame).unwrap_or(0);
        let whole = matches!(framer::next(frame), Next::Frame(_));
        if !whole {
            assert_eq!(outcome, Outcome::NotWhole, "bytes that are not one whole frame");
            assert!(image == before, "bytes that are not a frame changed the map");
            continue;
        }
        let (len, exception) = match outcome {
            Outcome::Discard { protocol_id: said } => {
                assert_ne!(protocol_id, mbap::MODBUS_PROTOCOL_ID, "a Modbus frame discarded");
                assert_eq!(said, protocol_id);
                assert!(image == before, "a discarded frame changed the map");
                continue;
            }
            Outcome::Reply { len, exception, .. } => (len, exception),
            Outcome::NotWhole => panic!("a whole frame {frame:02x?} refused as not whole"),
        };
        assert_eq!(protocol_id, mbap::MODBUS_PROTOCOL_ID, "a reply to protocol id {protocol_id}");
        assert!((mbap::HEADER_LEN + 2..=MAX_ADU_LEN).contains(&len), "reply length {len}");
        let out = &reply[..len];
        assert_eq!(framer::length_field(out).map(usize::from), Some(len - 6), "the reply's length field");
        if frame.len() >= mbap::HEADER_LEN {
            assert_eq!(out[..2], frame[..2], "transaction id echoed");
            assert_eq!(out[6], frame[6], "unit id echoed");
        }
        // The PDU as the length field delimits it (the handler trusts it).
        let length = usize::from(framer::length_field(frame).unwrap_or(0));
        let function = frame.get(7..6 + length).and_then(<[u8]>::first).copied().unwrap_or(0);
        match exception {
            Some(e) => {
                assert_eq!(out[7..], [(function & 0x7f) | 0x80, e.code()], "exception reply");
                assert!(image == before, "a refused request changed the map");
            }
            None => {
                if matches!(function, 0x01 | 0x03 | 0x08 | 0x2b) {
                    assert!(image == before, "a read, a diagnostic or an identification changed the map");
                }
                if let [0x08, 0x00, 0x0b..=0x0f | 0x12, count @ ..] = &out[7..] {
                    assert_eq!(count, [0, 0], "a count from counters that count nothing: {out:02x?}");
                }
            }
        }
        // A frame whose length field covers exactly its bytes is a real
        // request: its reply passes the session's checks too.
        if framer::next(frame) == Next::Frame(frame.len()) {
            check::reply(frame, out, &policy);
        }
    }
}

/// Parses `data` as a request PDU, a response PDU and an MBAP stream, and
/// checks each against a few lines of the specification.
pub fn codec(data: &[u8]) {
    let mut buf = [0xa5u8; MAX_ADU_LEN + 8];
    let pdu = data;
    // What the codec implements (V1.1b3, 6.8.1 and 6.21): the six functions of
    // the map, Diagnostics' eight sub-functions, Read Device Identification
    // (2B with MEI type 0E). Anything else of theirs is 03.
    let diagnostic = |sub: u16| [0x00, 0x0a, 0x0b, 0x0c, 0x0d, 0x0e, 0x0f, 0x12].contains(&sub);
    let known = match pdu {
        [0x01 | 0x03 | 0x05 | 0x06 | 0x0f | 0x10, ..] => true,
        [0x08, hi, lo, ..] => diagnostic(u16::from_be_bytes([*hi, *lo])),
        [0x08, ..] => true,
        [0x2b, mei, ..] => *mei == 0x0e,
        _ => false,
    };
    match Request::parse(pdu) {
        Ok(request) => {
            assert!(known);
            assert_eq!(request.emit(&mut buf), Some(pdu.len()), "{request:?}");
            assert_eq!(&buf[..pdu.len()], pdu, "emit(parse(x)) == x");
            assert_eq!(request.buffer_len(), pdu.len());
        }
        Err(e) => {
            let allowed = if known { Exception::IllegalDataValue } else { Exception::IllegalFunction };
            assert_eq!(e, allowed, "parsing {pdu:02x?}");
        }
    }
    if let Ok(response) = Response::parse(pdu) {
        assert_eq!(response.emit(&mut buf), Some(pdu.len()), "{response:?}");
        assert_eq!(&buf[..pdu.len()], pdu, "emit(parse(x)) == x");
    }

    let framed = mbap::next_frame_len(pdu);
    let expected = match framer::next(pdu) {
        Next::Incomplete => Ok(None),
        Next::Frame(len) => Ok(Some(len)),
        Next::BadLength(length) => Err(mbap::Error::BadLength(length)),
    };
    assert_eq!(framed, expected, "framing {pdu:02x?}");
}
