//! The mDNS responder: arbitrary bytes as a query, answered as the device
//! (`mdns::responder`), the response read back by an independent
//! DNS parser (simple-dns).
//!
//! The input ([`MdnsInput`]):
//!
//! ```text
//! | flags (1) | name length (1) | the query's bytes |
//! ```
//!
//! Flags bit 0: the query came from a port other than 5353 (legacy
//! unicast); bit 1: no HTTP. The device name is the first 1-32 bytes of
//! [`NAMES`] (`name length` modulo 32, plus 1).
//!
//! What is checked:
//!
//! - Reading the query and planning the answer never panic; a response
//!   fits `MAX_RESPONSE_LEN`, and writing it takes exactly the bytes
//!   measuring it said.
//! - simple-dns reads the response whole: a response, authoritative, id 0
//!   (legacy: the query's, with one question repeated), as many answers
//!   and additionals as the header says, every record owned by one of the
//!   device's names and carrying the device's data (address, ports, TXT),
//!   TTLs of RFC 6762 (legacy: at most 10 s, no cache-flush bit).
//! - When simple-dns reads the query too, and the library's own reader
//!   reads every question, the device answers exactly when a question (the
//!   first alone, for a legacy query) asks a type of one of its names, by
//!   a model written here from the records' table.

use adapter::mdns::responder::{self, emit, plan, response_len};
use adapter::mdns::wire::Message;
use adapter::mdns::{HostName, Identity, MAX_RESPONSE_LEN, Services};
use adapter::settings::Name;
use simple_dns::rdata::RData;
use simple_dns::{OPCODE, Packet, PacketFlag};

/// Flags bit 0: a legacy query.
pub const MDNS_LEGACY: u8 = 1;
/// Flags bit 1: no HTTP.
pub const MDNS_NO_HTTP: u8 = 2;
/// The device names the input picks from: a prefix of this.
pub const NAMES: &str = "mbio-53494d-0123456789abcdefghij";

/// A fuzz input, split.
#[derive(Clone, Copy, Debug)]
pub struct MdnsInput<'a> {
    pub flags: u8,
    pub name_len: u8,
    pub query: &'a [u8],
}

impl<'a> MdnsInput<'a> {
    pub fn parse(data: &'a [u8]) -> Self {
        match data {
            [flags, name_len, query @ ..] => Self { flags: *flags, name_len: *name_len, query },
            [flags] => Self { flags: *flags, name_len: 10, query: &[] },
            [] => Self { flags: 0, name_len: 10, query: &[] },
        }
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        [&[self.flags, self.name_len][..], self.query].concat()
    }

    fn identity(&self) -> Identity {
        let len = usize::from(self.name_len) % 32 + 1;
        let name = NAMES[..len].trim_end_matches('-');
        let name = if name.is_empty() { "m" } else { name };
        Identity {
            name: HostName::new(Name::parse(name).expect("a valid name").as_bytes()),
            address: [198, 18, 0, 2],
            services: Services {
                model: "fuzz-board",
                version: "1.22.333",
                modbus_port: 502,
                http_port: (self.flags & MDNS_NO_HTTP == 0).then_some(8080),
            },
        }
    }
}

/// Answers the query and checks the response (see the module).
pub fn mdns(data: &[u8]) {
    let input = MdnsInput::parse(data);
    let identity = input.identity();
    let legacy = input.flags & MDNS_LEGACY != 0;
    let planned = plan(input.query, legacy, &identity);
    check_model(input.query, legacy, &identity, planned.is_some());
    let Some(plan) = planned else { return };

    let len = response_len(&plan, &identity);
    assert!(len <= MAX_RESPONSE_LEN, "a response of {len} bytes");
    let mut buffer = [0xa5u8; MAX_RESPONSE_LEN];
    assert_eq!(emit(&plan, &identity, &mut buffer), Ok(len));
    let response = &buffer[..len];
    let packet = Packet::parse(response)
        .unwrap_or_else(|e| panic!("simple-dns cannot read the response ({e}): {response:02x?}"));
    assert!(packet.has_flags(PacketFlag::RESPONSE | PacketFlag::AUTHORITATIVE_ANSWER));
    let query_id = u16::from_be_bytes([input.query[0], input.query[1]]);
    assert_eq!(packet.id(), if legacy { query_id } else { 0 });
    assert_eq!(packet.questions.len(), usize::from(legacy));
    assert_eq!(packet.answers.len(), usize::from(plan.answers.len()));
    assert_eq!(packet.additional_records.len(), usize::from(plan.additionals.len()));
    assert!(!packet.answers.is_empty());

    let name = identity.name.as_str();
    let host = format!("{name}.local");
    for question in &packet.questions {
        assert!(owner_of(&question.qname.to_string(), &identity).is_some(), "{question:?}");
    }
    for record in packet.answers.iter().chain(&packet.additional_records) {
        let owner = record.name.to_string();
        assert!(owner_of(&owner, &identity).is_some(), "a record of another name: {owner}");
        let (ttl, unique) = match &record.rdata {
            RData::A(a) => {
                assert_eq!(owner, host);
                assert_eq!(a.address.to_be_bytes(), identity.address);
                (responder::HOST_TTL_S, true)
            }
            RData::NSEC(nsec) => {
                assert_eq!((owner.as_str(), nsec.next_name.to_string()), (host.as_str(), host.clone()));
                (responder::HOST_TTL_S, true)
            }
            RData::PTR(ptr) => {
                let target = ptr.0.to_string();
                let types = ["_modbus._tcp.local", "_http._tcp.local"];
                let instance = target.strip_prefix(&format!("{name}.")).unwrap_or_default();
                assert!(
                    (owner == "_services._dns-sd._udp.local" && types.contains(&target.as_str()))
                        || (types.contains(&owner.as_str()) && instance == owner),
                    "{owner} PTR {target}"
                );
                (responder::OTHER_TTL_S, false)
            }
            RData::SRV(srv) => {
                let port = if owner.ends_with("._modbus._tcp.local") { 502 } else { 8080 };
                assert_eq!((srv.port, srv.target.to_string()), (port, host.clone()), "{owner}");
                (responder::HOST_TTL_S, true)
            }
            RData::TXT(txt) => {
                let attributes = txt.attributes();
                assert_eq!(attributes.len(), 3, "{attributes:?}");
                assert_eq!(attributes["name"].as_deref(), Some(name));
                assert_eq!(attributes["model"].as_deref(), Some("fuzz-board"));
                assert_eq!(attributes["version"].as_deref(), Some("1.22.333"));
                (responder::OTHER_TTL_S, true)
            }
            other => panic!("a record the device does not have: {other:?}"),
        };
        let ttl = if legacy { ttl.min(responder::LEGACY_TTL_S) } else { ttl };
        assert_eq!(record.ttl, ttl, "{owner}");
        assert_eq!(record.cache_flush, unique && !legacy, "{owner}");
    }
}

/// Which of the device's names `name` (as simple-dns prints it) is, and the
/// types asked of it that the device answers.
fn owner_of(name: &str, identity: &Identity) -> Option<&'static [u16]> {
    const ANY: u16 = 255;
    let device = identity.name.as_str();
    let name = name.to_ascii_lowercase();
    let http = identity.services.http_port.is_some();
    if name == format!("{device}.local") {
        return Some(&[1, 28, 47, ANY]);
    }
    if name == "_services._dns-sd._udp.local" {
        return Some(&[12, ANY]);
    }
    for (service, offered) in [("_modbus", true), ("_http", http)] {
        if !offered {
            continue;
        }
        if name == format!("{service}._tcp.local") {
            return Some(&[12, ANY]);
        }
        if name == format!("{device}.{service}._tcp.local") {
            return Some(&[33, 16, ANY]);
        }
    }
    None
}

/// Whether the device answers, against the model, when both readers read the query.
fn check_model(query: &[u8], legacy: bool, identity: &Identity, answered: bool) {
    let Ok(message) = Message::new_checked(query) else {
        assert!(!answered);
        return;
    };
    if message.questions().any(|q| q.is_err()) {
        return;
    }
    let Ok(packet) = Packet::parse(query) else { return };
    if packet.questions.len() != usize::from(message.question_count()) {
        return;
    }
    let is_query = !packet.has_flags(PacketFlag::RESPONSE) && packet.opcode() == OPCODE::StandardQuery;
    let questions = if legacy { &packet.questions[..packet.questions.len().min(1)] } else { &packet.questions[..] };
    let expected = is_query
        && questions.iter().any(|question| {
            let class = u16::from(question.qclass) & 0x7fff;
            let qtype = u16::from(question.qtype);
            (class == 1 || class == 255)
                && owner_of(&question.qname.to_string(), identity).is_some_and(|types| types.contains(&qtype))
        });
    assert_eq!(answered, expected, "questions {:?}", packet.questions);
}

/// Seeds: queries as python-zeroconf 0.154 writes them (the library's
/// mDNS tests hold the same bytes, annotated), for a few flags.
pub fn seeds() -> Vec<Vec<u8>> {
    let queries: [&str; 6] = [
        // _modbus._tcp.local PTR, QU
        "000000000001000000000000075f6d6f64627573045f746370056c6f63616c00000c8001",
        // mbio-53494d.local A and AAAA (a pointer)
        "0000000000020000000000000b6d62696f2d353334393464056c6f63616c0000010001c00c001c0001",
        // SRV and TXT of the instance, A of the host (pointers)
        "0000000000030000000000000b6d62696f2d353334393464075f6d6f64627573045f746370056c6f63616c0000210001c00c001000010b6d62696f2d353334393464c02500010001",
        // _services._dns-sd._udp.local PTR
        "000000000001000000000000095f7365727669636573075f646e732d7364045f756470056c6f63616c00000c0001",
        // _http._tcp.local PTR with a known answer
        "000000000001000100000000055f68747470045f746370056c6f63616c00000c0001c00c000c000100001194000a077072696e746572c00c",
        // MBIO-53494D.local A, id 0x1234
        "1234000000010000000000000b4d42494f2d353334393444056c6f63616c0000010001",
    ];
    let mut seeds = Vec::new();
    for query in queries {
        let bytes: Vec<u8> =
            (0..query.len()).step_by(2).map(|i| u8::from_str_radix(&query[i..i + 2], 16).unwrap()).collect();
        for flags in [0, MDNS_LEGACY, MDNS_NO_HTTP] {
            seeds.push(MdnsInput { flags, name_len: 10, query: &bytes }.to_bytes());
        }
    }
    seeds
}
