//! The responder against real queries (written by python-zeroconf 0.154's
//! own encoder, each byte annotated), its responses read back by an
//! independent parser (simple-dns), and the wire reader against hostile
//! names.

use embassy_time::{Duration, Instant};
use simple_dns::Packet;
use simple_dns::rdata::RData;

use super::responder::{Domain, Legacy, Record, Records, emit, plan, response_len};
use super::wire::{Error, Message, Name};
use super::*;

/// hal-sim's identity: MAC 02:4d:42:53:49:4d, at 198.18.0.2, HTTP on.
fn identity() -> Identity {
    Identity {
        name: HostName::new(b"mbio-53494d"),
        address: [198, 18, 0, 2],
        services: Services { model: "hal-sim", version: "0.1.0", modbus_port: 502, http_port: Some(80) },
    }
}

fn without_http() -> Identity {
    let mut identity = identity();
    identity.services.http_port = None;
    identity
}

fn hex(text: &str) -> Vec<u8> {
    let text: String = text.split_whitespace().collect();
    (0..text.len()).step_by(2).map(|i| u8::from_str_radix(&text[i..i + 2], 16).unwrap()).collect()
}

/// zeroconf browsing `_modbus._tcp.local.` PTR: id 0, flags 0 (a query),
/// one question: `_modbus._tcp.local`, type PTR (000c), class IN with the
/// QU bit (8001).
fn browse() -> Vec<u8> {
    hex("0000 0000 0001 0000 0000 0000 07 5f6d6f64627573 04 5f746370 05 6c6f63616c 00 000c 8001")
}

/// Fixtures as zeroconf wrote them (hex; see each comment).
mod fixture {
    /// A and AAAA of `mbio-53494d.local.`: the second question's name is a
    /// pointer to the first (`c00c`).
    pub const ADDRESS: &str =
        "0000 0000 0002 0000 0000 0000 0b6d62696f2d353334393464 056c6f63616c 00 0001 0001 c00c 001c 0001";
    /// SRV and TXT of the Modbus instance, then A of the host: `mbio-53494d`
    /// then a pointer to `local` inside the first name (`c025`).
    pub const INFO: &str = "0000 0000 0003 0000 0000 0000 0b6d62696f2d353334393464 075f6d6f64627573 045f746370 056c6f63616c 00 0021 0001 c00c 0010 0001 0b6d62696f2d353334393464 c025 0001 0001";
    /// `_services._dns-sd._udp.local.` PTR.
    pub const TYPES: &str =
        "0000 0000 0001 0000 0000 0000 095f7365727669636573 075f646e732d7364 045f756470 056c6f63616c 00 000c 0001";
    /// `_http._tcp.local.` PTR with one known answer (another device's
    /// `printer._http._tcp.local`, TTL 4500).
    pub const KNOWN: &str = "0000 0000 0001 0001 0000 0000 055f68747470 045f746370 056c6f63616c 00 000c 0001 c00c 000c 0001 00001194 000a 077072696e746572 c00c";
    /// A of `MBIO-53494D.local.` in capitals, id 0x1234 (as a legacy
    /// resolver sends it: from another port than 5353).
    pub const LEGACY: &str = "1234 0000 0001 0000 0000 0000 0b4d42494f2d353334393444 056c6f63616c 00 0001 0001";
}

/// A record as `owner TYPE data ttl [flush]`.
fn describe(record: &simple_dns::ResourceRecord<'_>) -> String {
    let data = match &record.rdata {
        RData::A(a) => format!("A {}", std::net::Ipv4Addr::from(a.address)),
        RData::PTR(ptr) => format!("PTR {}", ptr.0),
        RData::SRV(srv) => format!("SRV {} {} {} {}", srv.priority, srv.weight, srv.port, srv.target),
        RData::TXT(txt) => {
            let mut strings: Vec<String> = txt
                .iter_raw()
                .map(|(k, v)| {
                    format!("{}={}", String::from_utf8_lossy(k), String::from_utf8_lossy(v.unwrap_or_default()))
                })
                .collect();
            strings.sort();
            format!("TXT {}", strings.join(" "))
        }
        RData::NSEC(nsec) => {
            let maps: Vec<String> =
                nsec.type_bit_maps.iter().map(|m| format!("{}:{:02x?}", m.window_block, m.bitmap)).collect();
            format!("NSEC {} {}", nsec.next_name, maps.join(" "))
        }
        other => format!("{other:?}"),
    };
    format!("{} {} {}{}", record.name, data, record.ttl, if record.cache_flush { " flush" } else { "" })
}

/// Answers `query` as the listener would (from port 5353 unless `legacy`),
/// and reads the response back with simple-dns: (answers, additionals).
fn respond(query: &[u8], legacy: bool, identity: &Identity) -> Option<(Vec<String>, Vec<String>)> {
    let plan = plan(query, legacy, identity)?;
    let bytes = response(&plan, identity);
    let packet = Packet::parse(&bytes).unwrap_or_else(|e| panic!("{e}: {bytes:02x?}"));
    assert!(packet.has_flags(simple_dns::PacketFlag::RESPONSE | simple_dns::PacketFlag::AUTHORITATIVE_ANSWER));
    Some((packet.answers.iter().map(describe).collect(), packet.additional_records.iter().map(describe).collect()))
}

/// The response's bytes, written into a buffer filled with 0xa5 first (a
/// byte left unwritten shows) and measured the same as written.
fn response(plan: &Plan, identity: &Identity) -> Vec<u8> {
    let mut buffer = [0xa5u8; MAX_RESPONSE_LEN];
    let len = emit(plan, identity, &mut buffer).unwrap();
    assert_eq!(len, response_len(plan, identity));
    buffer[..len].to_vec()
}

const A: &str = "mbio-53494d.local A 198.18.0.2 120 flush";
const NSEC: &str = "mbio-53494d.local NSEC mbio-53494d.local 0:[40] 120 flush";
const MODBUS_PTR: &str = "_modbus._tcp.local PTR mbio-53494d._modbus._tcp.local 4500";
const MODBUS_SRV: &str = "mbio-53494d._modbus._tcp.local SRV 0 0 502 mbio-53494d.local 120 flush";
const MODBUS_TXT: &str = "mbio-53494d._modbus._tcp.local TXT model=hal-sim name=mbio-53494d version=0.1.0 4500 flush";

fn strings(records: &[&str]) -> Vec<String> {
    records.iter().map(|r| r.to_string()).collect()
}

#[test]
fn a_browse_gets_the_instance_with_its_port_text_and_address() {
    let (answers, additionals) = respond(&browse(), false, &identity()).unwrap();
    assert_eq!(answers, strings(&[MODBUS_PTR]));
    assert_eq!(additionals, strings(&[A, NSEC, MODBUS_SRV, MODBUS_TXT]));
}

#[test]
fn the_address_question_gets_a_and_the_nsec_that_says_there_is_no_aaaa() {
    let (answers, additionals) = respond(&hex(fixture::ADDRESS), false, &identity()).unwrap();
    assert_eq!(answers, strings(&[A, NSEC]));
    assert!(additionals.is_empty());
    // AAAA alone: the NSEC alone.
    let mut aaaa = hex(fixture::ADDRESS);
    aaaa[5] = 1; // one question: the first, made AAAA
    let at = aaaa.len() - 10; // its type, after "mbio-53494d.local"
    aaaa[at..at + 2].copy_from_slice(&[0x00, 0x1c]);
    aaaa.truncate(at + 4);
    let (answers, _) = respond(&aaaa, false, &identity()).unwrap();
    assert_eq!(answers, strings(&[NSEC]));
}

#[test]
fn names_through_compression_pointers_are_answered() {
    let (answers, additionals) = respond(&hex(fixture::INFO), false, &identity()).unwrap();
    assert_eq!(answers, strings(&[A, MODBUS_SRV, MODBUS_TXT]));
    assert_eq!(additionals, strings(&[NSEC]));
}

#[test]
fn the_service_types_are_listed_and_http_only_when_served() {
    let types = hex(fixture::TYPES);
    let (answers, _) = respond(&types, false, &identity()).unwrap();
    assert_eq!(
        answers,
        strings(&[
            "_services._dns-sd._udp.local PTR _modbus._tcp.local 4500",
            "_services._dns-sd._udp.local PTR _http._tcp.local 4500"
        ])
    );
    let (answers, _) = respond(&types, false, &without_http()).unwrap();
    assert_eq!(answers, strings(&["_services._dns-sd._udp.local PTR _modbus._tcp.local 4500"]));
    assert_eq!(respond(&hex(fixture::KNOWN), false, &without_http()), None, "no _http without HTTP");
}

#[test]
fn http_is_advertised_with_its_port() {
    let (answers, additionals) = respond(&hex(fixture::KNOWN), false, &identity()).unwrap();
    assert_eq!(answers, strings(&["_http._tcp.local PTR mbio-53494d._http._tcp.local 4500"]));
    assert!(additionals.contains(&"mbio-53494d._http._tcp.local SRV 0 0 80 mbio-53494d.local 120 flush".to_string()));
    let mut other = identity();
    other.services.http_port = Some(8080);
    let (_, additionals) = respond(&hex(fixture::KNOWN), false, &other).unwrap();
    assert!(additionals.iter().any(|r| r.contains("SRV 0 0 8080 ")), "{additionals:?}");
}

#[test]
fn a_legacy_query_gets_its_id_and_question_back_and_short_ttls_by_unicast() {
    let query = hex(fixture::LEGACY);
    let identity = identity();
    let plan = plan(&query, true, &identity).unwrap();
    assert_eq!(plan.legacy, Some(Legacy { id: 0x1234, owner: Domain::Host, qtype: 1 }));
    let bytes = response(&plan, &identity);
    let packet = Packet::parse(&bytes).unwrap();
    assert_eq!(packet.id(), 0x1234);
    assert_eq!(packet.questions.len(), 1);
    assert_eq!(packet.questions[0].qname.to_string(), "mbio-53494d.local");
    let answers: Vec<String> = packet.answers.iter().map(describe).collect();
    let additionals: Vec<String> = packet.additional_records.iter().map(describe).collect();
    assert_eq!(answers, ["mbio-53494d.local A 198.18.0.2 10"]);
    assert_eq!(additionals, ["mbio-53494d.local NSEC mbio-53494d.local 0:[40] 10"]);
    // The same query from port 5353 is a multicast one: id 0, no question, full TTLs.
    let (answers, additionals) = respond(&query, false, &identity).unwrap();
    assert_eq!((answers, additionals), (strings(&[A]), strings(&[NSEC])));
}

#[test]
fn names_match_without_regard_to_case_and_others_get_nothing() {
    assert!(respond(&hex(fixture::LEGACY), false, &identity()).is_some(), "MBIO-53494D.local");
    let mut other = identity();
    other.name = HostName::new(b"press-7");
    for query in [browse(), hex(fixture::TYPES)] {
        assert!(respond(&query, false, &other).is_some(), "not about the name");
    }
    for query in [hex(fixture::ADDRESS), hex(fixture::INFO), hex(fixture::LEGACY)] {
        assert_eq!(respond(&query, false, &other), None, "another device's name");
    }
}

#[test]
fn responses_and_classes_other_than_in_or_any_are_not_answered() {
    let mut response = browse();
    response[2] = 0x84; // QR and AA: a response
    assert_eq!(plan(&response, false, &identity()), None);
    let mut chaos = browse();
    let len = chaos.len();
    chaos[len - 1] = 3; // class CH
    assert_eq!(plan(&chaos, false, &identity()), None);
    let mut any = browse();
    any[len - 2..].copy_from_slice(&[0x00, 0xff]);
    assert!(plan(&any, false, &identity()).is_some());
}

#[test]
fn an_announcement_has_every_record_and_a_goodbye_the_named_ones_at_ttl_0() {
    let identity = identity();
    let packet_of = |plan: &Plan| {
        let bytes = response(plan, &identity);
        let packet = Packet::parse(&bytes).unwrap();
        assert!(packet.questions.is_empty() && packet.additional_records.is_empty());
        packet.answers.iter().map(describe).collect::<Vec<_>>()
    };
    let announced = packet_of(&Plan::announcement(&identity));
    assert_eq!(announced.len(), 10);
    for record in [A, NSEC, MODBUS_PTR, MODBUS_SRV, MODBUS_TXT] {
        assert!(announced.contains(&record.to_string()), "{record} in {announced:#?}");
    }
    assert!(announced.contains(
        &"mbio-53494d._http._tcp.local TXT model=hal-sim name=mbio-53494d version=0.1.0 4500 flush".to_string()
    ));
    let goodbye = packet_of(&Plan::goodbye(&identity));
    assert_eq!(goodbye.len(), 8, "all but the service types: {goodbye:#?}");
    assert!(goodbye.iter().all(|r| r.contains(" 0") && !r.starts_with("_services")), "{goodbye:#?}");
    assert_eq!(Plan::announcement(&without_http()).answers.len(), 6);
}

#[test]
fn the_largest_response_fits_max_response_len() {
    let mut identity = identity();
    identity.name = HostName::new("z".repeat(MAX_NAME_LEN).as_bytes());
    identity.services.model = "a-model-name-that-is-longer-than-any-board-has";
    identity.services.version = "65535.65535.65535";
    let every = Records::all(&identity);
    let mut plans = vec![Plan::announcement(&identity)];
    for owner in [Domain::Host, Domain::Instance(Service::Http)] {
        let legacy = Some(Legacy { id: 1, owner, qtype: 255 });
        plans.push(Plan { answers: every, additionals: Records::NONE, legacy, goodbye: false });
    }
    for plan in &plans {
        let len = response_len(plan, &identity);
        assert!(len <= MAX_RESPONSE_LEN, "{len} bytes");
        let bytes = response(plan, &identity);
        let packet = Packet::parse(&bytes).unwrap();
        let text = packet.answers.iter().find(|r| matches!(r.rdata, RData::TXT(_))).map(describe).unwrap();
        assert!(text.contains("model=a-model-name-that-is-lon "), "cut to MAX_MODEL_LEN: {text}");
        assert!(text.contains("version=65535.65535.65535"), "{text}");
    }
    println!("largest response: {} bytes", plans.iter().map(|p| response_len(p, &identity)).max().unwrap());
}

#[test]
fn every_prefix_of_every_fixture_is_ignored_or_answered_never_a_panic() {
    let fixtures = [browse(), hex(fixture::ADDRESS), hex(fixture::INFO), hex(fixture::TYPES), hex(fixture::KNOWN)];
    for query in fixtures {
        for len in 0..=query.len() {
            let prefix = &query[..len];
            let answered = plan(prefix, false, &identity()).is_some();
            // The questions end exactly where the query does (KNOWN's answer aside).
            if answered {
                let message = Message::new_checked(prefix).unwrap();
                assert!(message.questions().all(|q| q.is_ok()), "{len} of {query:02x?}");
            }
        }
        assert!(plan(&query, false, &identity()).is_some());
    }
}

#[test]
fn hostile_names_are_errors() {
    let header = hex("0000 0000 0001 0000 0000 0000");
    let question = |name: &[u8]| {
        let mut query = header.clone();
        query.extend_from_slice(name);
        query.extend_from_slice(&[0, 1, 0, 1]);
        query
    };
    fn first(query: &[u8]) -> Result<(), Error> {
        Message::new_checked(query).unwrap().questions().next().unwrap().map(|_| ())
    }
    // A pointer to itself, and one forwards.
    assert_eq!(first(&question(&[0xc0, 12])), Err(Error::BadPointer));
    assert_eq!(first(&question(&[0xc0, 20])), Err(Error::BadPointer));
    // Two pointers chasing each other: label "a" at 12, pointer at 14 to 12 (before its run: allowed
    // once), and the run that starts at 12 ends in that same pointer: a loop.
    assert_eq!(first(&question(&[1, b'a', 0xc0, 12])), Err(Error::BadPointer));
    // Reserved label types 01 and 10.
    assert_eq!(first(&question(&[0x40, 0])), Err(Error::BadLabel));
    assert_eq!(first(&question(&[0x80, 0])), Err(Error::BadLabel));
    // A label past the end, a missing end byte, a missing type.
    assert_eq!(first(&question(&[5, b'a'])[..15]), Err(Error::Truncated));
    assert_eq!(first(&[header.as_slice(), &[1, b'a']].concat()), Err(Error::Truncated));
    assert_eq!(first(&[header.as_slice(), &[0, 0, 1]].concat()), Err(Error::Truncated));
    // 256 bytes of name: too long (63-byte labels, each 64 on the wire).
    let mut long = Vec::new();
    for _ in 0..4 {
        long.push(63);
        long.extend_from_slice(&[b'x'; 63]);
    }
    long.push(0);
    assert_eq!(first(&question(&long)), Err(Error::NameTooLong));
    long.drain(..64);
    assert!(first(&question(&long)).is_ok(), "192 bytes are fine");
    // Pointer chains: each to the one before, as deep as allowed, then one more.
    let chain = |hops: usize| {
        let mut query = header.clone();
        query.extend_from_slice(&[1, b'a', 0]); // the name at 12
        let mut at = 12;
        for _ in 0..hops {
            let here = query.len();
            query.extend_from_slice(&[0xc0, at as u8]);
            at = here;
        }
        // The question: a pointer to the last link.
        let mut message = query[..12].to_vec();
        message[5] = 1;
        let start = query.len();
        query.extend_from_slice(&[0xc0, at as u8, 0, 1, 0, 1]);
        let _ = message;
        (query, start)
    };
    for (hops, ok) in [(wire::MAX_POINTER_HOPS - 1, true), (wire::MAX_POINTER_HOPS, false)] {
        let (query, start) = chain(hops);
        let read = Name::read(&query, start);
        assert_eq!(read.is_ok(), ok, "{hops} pointers before the question's own");
        if let Ok((name, end)) = read {
            assert_eq!(end, start + 2);
            assert!(name.is(&[b"A"]));
        }
    }
}

#[test]
fn the_state_announces_twice_answers_and_says_goodbye_on_a_rename() {
    let mut state = State::new();
    let t0 = Instant::from_secs(100);
    assert_eq!(state.follow(None, t0), None);
    assert_eq!(state.announcement(t0), None, "nothing without an address");
    let identity = identity();
    assert_eq!(state.follow(Some(identity), t0), None);
    let first = state.announcement(t0).unwrap();
    assert_eq!(first.plan, Plan::announcement(&identity));
    assert_eq!(state.announcement(t0), None);
    assert_eq!(state.deadline(t0), t0 + ANNOUNCE_INTERVAL);
    assert!(state.announcement(t0 + ANNOUNCE_INTERVAL).is_some());
    assert_eq!(state.announcement(t0 + Duration::from_secs(60)), None, "two announcements");

    // Within a second of the announcement a query finds its records sent already.
    let from = embassy_net::IpEndpoint::new(embassy_net::IpAddress::v4(198, 18, 0, 1), PORT);
    let t1 = t0 + ANNOUNCE_INTERVAL;
    assert_eq!(state.answer(&browse(), from, t1 + Duration::from_millis(500)), None);
    let answer = state.answer(&browse(), from, t1 + MIN_REPEAT).unwrap();
    assert_eq!((answer.unicast, answer.plan.answers), (None, Records::NONE.with(Record::Instance(Service::Modbus))));
    // A legacy query is answered whatever was sent, by unicast.
    let legacy_from = embassy_net::IpEndpoint::new(embassy_net::IpAddress::v4(198, 18, 0, 1), 40000);
    let legacy = state.answer(&hex(fixture::LEGACY), legacy_from, t1 + MIN_REPEAT).unwrap();
    assert_eq!(legacy.unicast, Some(legacy_from));

    // A rename: a goodbye for the old name, then two announcements of the new.
    let mut renamed = identity;
    renamed.name = HostName::new(b"press-7");
    let t2 = t1 + Duration::from_secs(10);
    let goodbye = state.follow(Some(renamed), t2).unwrap();
    assert_eq!((goodbye.identity, goodbye.plan), (identity, Plan::goodbye(&identity)));
    assert_eq!(state.announcement(t2).unwrap().identity, renamed);
    // A new address alone: announced again, no goodbye (the cache-flush bit replaces the old A).
    let mut moved = renamed;
    moved.address = [198, 18, 0, 3];
    assert_eq!(state.follow(Some(moved), t2), None);
    assert_eq!(state.announcement(t2).unwrap().identity, moved);
}

#[test]
fn versions_are_written_in_decimal() {
    let mut identity = identity();
    identity.services.version = "10.0.7";
    let bytes = response(&Plan::announcement(&identity), &identity);
    assert!(bytes.windows(15).any(|w| w == b"\x0eversion=10.0.7"), "{bytes:02x?}");
}
