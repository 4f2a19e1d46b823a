//! What the device answers, and the bytes of the answer: its records
//! (RFC 6762 and RFC 6763), which of them a query asks for ([`plan`]), and
//! the response written from a [`Plan`] ([`emit`]).
//!
//! The device owns these names and records (`NAME` is the device name):
//!
//! | owner | record | TTL |
//! |---|---|---|
//! | `NAME.local` | A: the address; NSEC: no other type (no AAAA) | 120 s |
//! | `_services._dns-sd._udp.local` | PTR `_modbus._tcp.local`, PTR `_http._tcp.local` | 4500 s |
//! | `_modbus._tcp.local`, `_http._tcp.local` | PTR `NAME._modbus._tcp.local`, ... | 4500 s |
//! | `NAME._modbus._tcp.local`, `NAME._http._tcp.local` | SRV (port, target `NAME.local`) 120 s; TXT `name=`, `model=`, `version=` 4500 s | |
//!
//! The `_http` ones exist only when the device serves HTTP. TTLs are RFC
//! 6762 section 10's; A, NSEC, SRV and TXT are the device's alone, so they
//! carry the cache-flush bit; the PTRs are shared.

use super::wire::{self, Message, Name, Writer, class, flags, rtype};
use crate::HostName;

/// TTL of the records tied to the host: A, NSEC, SRV (RFC 6762 section 10).
pub const HOST_TTL_S: u32 = 120;
/// TTL of the other records: PTR, TXT.
pub const OTHER_TTL_S: u32 = 4500;
/// Largest TTL in a response to a legacy (not port 5353) query (RFC 6762 section 6.7).
pub const LEGACY_TTL_S: u32 = 10;
/// The model is cut to this many bytes in TXT (the boards' are shorter).
pub const MAX_MODEL_LEN: usize = 24;
/// The largest response: every record, the longest name, the longest
/// model, and a legacy query's question echoed (a test checks it).
pub const MAX_RESPONSE_LEN: usize = 512;

/// A service the device advertises (DNS-SD, RFC 6763).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Service {
    /// `_modbus._tcp`: the Modbus TCP server.
    Modbus,
    /// `_http._tcp`: the device's page and API.
    Http,
}

impl Service {
    const ALL: [Self; 2] = [Self::Modbus, Self::Http];

    const fn index(self) -> u16 {
        match self {
            Self::Modbus => 0,
            Self::Http => 1,
        }
    }

    /// The service's label (RFC 6335's service name with `_`).
    const fn label(self) -> &'static [u8] {
        match self {
            Self::Modbus => b"_modbus",
            Self::Http => b"_http",
        }
    }
}

/// What the device advertises besides its name and address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Services {
    /// The board, in TXT `model=` (cut to [`MAX_MODEL_LEN`]).
    pub model: &'static str,
    /// The firmware version, in TXT `version=` (`0.1.0`).
    pub version: &'static str,
    pub modbus_port: u16,
    /// `None`: no HTTP, and no `_http._tcp`.
    pub http_port: Option<u16>,
}

impl Services {
    /// The port of `service`, if the device offers it.
    pub fn port(&self, service: Service) -> Option<u16> {
        match service {
            Service::Modbus => Some(self.modbus_port),
            Service::Http => self.http_port,
        }
    }
}

/// Everything a response says: the name, the address and the services.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    pub name: HostName,
    pub address: [u8; 4],
    pub services: Services,
}

/// One record of the device's (the table above).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Record {
    /// `NAME.local` A.
    Address,
    /// `NAME.local` NSEC: A is the only type (RFC 6762 section 6.1).
    NoOtherAddress,
    /// `_services._dns-sd._udp.local` PTR to the service's type (RFC 6763 section 9).
    ServiceType(Service),
    /// The service type's PTR to the device's instance.
    Instance(Service),
    /// The instance's SRV.
    Port(Service),
    /// The instance's TXT.
    Text(Service),
}

impl Record {
    /// Every record, in the order a response lists them.
    pub const ALL: [Self; 10] = [
        Self::Address,
        Self::NoOtherAddress,
        Self::ServiceType(Service::Modbus),
        Self::ServiceType(Service::Http),
        Self::Instance(Service::Modbus),
        Self::Instance(Service::Http),
        Self::Port(Service::Modbus),
        Self::Port(Service::Http),
        Self::Text(Service::Modbus),
        Self::Text(Service::Http),
    ];

    /// Its bit in [`Records`].
    const fn bit(self) -> u16 {
        1 << match self {
            Self::Address => 0,
            Self::NoOtherAddress => 1,
            Self::ServiceType(s) => 2 + s.index(),
            Self::Instance(s) => 4 + s.index(),
            Self::Port(s) => 6 + s.index(),
            Self::Text(s) => 8 + s.index(),
        }
    }

    /// The service it belongs to, if any.
    const fn service(self) -> Option<Service> {
        match self {
            Self::Address | Self::NoOtherAddress => None,
            Self::ServiceType(s) | Self::Instance(s) | Self::Port(s) | Self::Text(s) => Some(s),
        }
    }

    /// Whether the device alone owns it (cache flush), not a shared PTR.
    pub const fn is_unique(self) -> bool {
        !matches!(self, Self::ServiceType(_) | Self::Instance(_))
    }

    /// Whether it changes with the device name (a rename says goodbye to it).
    pub const fn has_name(self) -> bool {
        !matches!(self, Self::ServiceType(_))
    }

    const fn rtype(self) -> u16 {
        match self {
            Self::Address => rtype::A,
            Self::NoOtherAddress => rtype::NSEC,
            Self::ServiceType(_) | Self::Instance(_) => rtype::PTR,
            Self::Port(_) => rtype::SRV,
            Self::Text(_) => rtype::TXT,
        }
    }

    const fn ttl_s(self) -> u32 {
        match self {
            Self::Address | Self::NoOtherAddress | Self::Port(_) => HOST_TTL_S,
            Self::ServiceType(_) | Self::Instance(_) | Self::Text(_) => OTHER_TTL_S,
        }
    }

    const fn owner(self) -> Domain {
        match self {
            Self::Address | Self::NoOtherAddress => Domain::Host,
            Self::ServiceType(_) => Domain::ServiceTypes,
            Self::Instance(s) => Domain::Type(s),
            Self::Port(s) | Self::Text(s) => Domain::Instance(s),
        }
    }
}

/// A set of [`Record`]s.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Records(u16);

impl Records {
    pub const NONE: Self = Self(0);

    /// Every record `identity` has (no `_http` ones without HTTP).
    pub fn all(identity: &Identity) -> Self {
        Record::ALL.iter().filter(|r| exists(identity, **r)).fold(Self::NONE, |set, r| set.with(*r))
    }

    pub const fn with(self, record: Record) -> Self {
        Self(self.0 | record.bit())
    }

    pub const fn contains(self, record: Record) -> bool {
        self.0 & record.bit() != 0
    }

    pub const fn union(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }

    pub const fn minus(self, other: Self) -> Self {
        Self(self.0 & !other.0)
    }

    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// How many records.
    pub const fn len(self) -> u16 {
        self.0.count_ones() as u16
    }

    /// The records, in [`Record::ALL`]'s order.
    pub fn iter(self) -> impl Iterator<Item = Record> {
        Record::ALL.into_iter().filter(move |r| self.contains(*r))
    }

    /// Whether one of them is shared (a PTR), which RFC 6762 section 6
    /// asks to answer after a short random delay.
    pub fn has_shared(self) -> bool {
        self.iter().any(|r| !r.is_unique())
    }
}

fn exists(identity: &Identity, record: Record) -> bool {
    record.service().is_none_or(|s| identity.services.port(s).is_some())
}

/// A legacy query (RFC 6762 section 6.7): from a port other than 5353,
/// answered by unicast, with its id and its question repeated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Legacy {
    pub id: u16,
    /// The question repeated: its owner (one of the device's names) and type.
    pub owner: Domain,
    pub qtype: u16,
}

/// What a response holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plan {
    pub answers: Records,
    /// Records that save the querier its next question (RFC 6763 section 12).
    pub additionals: Records,
    pub legacy: Option<Legacy>,
    /// Every TTL 0: the records are gone (RFC 6762 section 10.1).
    pub goodbye: bool,
}

impl Plan {
    /// An unsolicited response with every record (RFC 6762 section 8.3).
    pub fn announcement(identity: &Identity) -> Self {
        Self { answers: Records::all(identity), additionals: Records::NONE, legacy: None, goodbye: false }
    }

    /// Every record the device name is in, with TTL 0: sent before a rename.
    pub fn goodbye(identity: &Identity) -> Self {
        let answers = Records::all(identity).iter().filter(|r| r.has_name()).fold(Records::NONE, Records::with);
        Self { answers, additionals: Records::NONE, legacy: None, goodbye: true }
    }
}

/// The names the device writes, each one label then its parent's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Domain {
    Local,
    Tcp,
    Udp,
    DnsSd,
    /// `_services._dns-sd._udp.local`.
    ServiceTypes,
    /// `NAME.local`.
    Host,
    /// `_modbus._tcp.local`, `_http._tcp.local`.
    Type(Service),
    /// `NAME._modbus._tcp.local`, `NAME._http._tcp.local`.
    Instance(Service),
}

impl Domain {
    /// How many there are: the compression table's size.
    const COUNT: usize = 10;

    const fn index(self) -> usize {
        match self {
            Self::Local => 0,
            Self::Tcp => 1,
            Self::Udp => 2,
            Self::DnsSd => 3,
            Self::ServiceTypes => 4,
            Self::Host => 5,
            Self::Type(Service::Modbus) => 6,
            Self::Type(Service::Http) => 7,
            Self::Instance(Service::Modbus) => 8,
            Self::Instance(Service::Http) => 9,
        }
    }

    fn label(self, name: &HostName) -> &[u8] {
        match self {
            Self::Local => b"local",
            Self::Tcp => b"_tcp",
            Self::Udp => b"_udp",
            Self::DnsSd => b"_dns-sd",
            Self::ServiceTypes => b"_services",
            Self::Host | Self::Instance(_) => name.as_bytes(),
            Self::Type(s) => s.label(),
        }
    }

    const fn parent(self) -> Option<Self> {
        match self {
            Self::Local => None,
            Self::Tcp | Self::Udp | Self::Host => Some(Self::Local),
            Self::DnsSd => Some(Self::Udp),
            Self::ServiceTypes => Some(Self::DnsSd),
            Self::Type(_) => Some(Self::Tcp),
            Self::Instance(s) => Some(Self::Type(s)),
        }
    }

    /// Which of the device's names `name` is, if any (ASCII case ignored).
    fn of(name: &Name<'_>, identity: &Identity) -> Option<Self> {
        let own = identity.name.as_bytes();
        if name.is(&[own, b"local"]) {
            return Some(Self::Host);
        }
        if name.is(&[b"_services", b"_dns-sd", b"_udp", b"local"]) {
            return Some(Self::ServiceTypes);
        }
        Service::ALL.into_iter().filter(|s| identity.services.port(*s).is_some()).find_map(|s| {
            if name.is(&[s.label(), b"_tcp", b"local"]) {
                Some(Self::Type(s))
            } else if name.is(&[own, s.label(), b"_tcp", b"local"]) {
                Some(Self::Instance(s))
            } else {
                None
            }
        })
    }
}

/// The answers and additional records for one question about `owner`.
fn answer(owner: Domain, qtype: u16, identity: &Identity) -> (Records, Records) {
    let any = qtype == rtype::ANY;
    let host = Records::NONE.with(Record::Address).with(Record::NoOtherAddress);
    let pick = |record: Record| (any || qtype == record.rtype()) && exists(identity, record);
    let only = |records: &[Record]| records.iter().filter(|r| pick(**r)).fold(Records::NONE, |set, r| set.with(*r));
    match owner {
        Domain::Host if qtype == rtype::AAAA => (Records::NONE.with(Record::NoOtherAddress), Records::NONE),
        Domain::Host => {
            let answers = only(&[Record::Address, Record::NoOtherAddress]);
            // With the address, the NSEC that says there is no AAAA.
            let extra = if answers.contains(Record::Address) { host } else { Records::NONE };
            (answers, extra)
        }
        Domain::ServiceTypes => {
            (only(&[Record::ServiceType(Service::Modbus), Record::ServiceType(Service::Http)]), Records::NONE)
        }
        Domain::Type(s) => {
            let answers = only(&[Record::Instance(s)]);
            let extra = Records::NONE.with(Record::Port(s)).with(Record::Text(s)).union(host);
            (answers, if answers.is_empty() { Records::NONE } else { extra })
        }
        Domain::Instance(s) => {
            let answers = only(&[Record::Port(s), Record::Text(s)]);
            (answers, if answers.contains(Record::Port(s)) { host } else { Records::NONE })
        }
        Domain::Local | Domain::Tcp | Domain::Udp | Domain::DnsSd => (Records::NONE, Records::NONE),
    }
}

/// What to answer `query` with, for a device that is `identity`: `None`
/// when it asks nothing of the device's, is not a standard query, or a
/// question cannot be read. `legacy`: the query came from a port other than
/// 5353; then only its first question is answered, and repeated.
pub fn plan(query: &[u8], legacy: bool, identity: &Identity) -> Option<Plan> {
    let message = Message::new_checked(query).ok()?;
    if !message.is_query() {
        return None;
    }
    let mut answers = Records::NONE;
    let mut additionals = Records::NONE;
    let mut first = None;
    for question in message.questions() {
        let question = question.ok()?;
        let owner = Domain::of(&question.name, identity);
        if matches!(question.class, class::IN | class::ANY)
            && let Some(owner) = owner
        {
            let (more, extra) = answer(owner, question.qtype, identity);
            answers = answers.union(more);
            additionals = additionals.union(extra);
            if first.is_none() && !more.is_empty() {
                first = Some((owner, question.qtype));
            }
        }
        if legacy {
            break;
        }
    }
    if answers.is_empty() {
        return None;
    }
    let legacy = if legacy {
        let (owner, qtype) = first?;
        Some(Legacy { id: message.id(), owner, qtype })
    } else {
        None
    };
    Some(Plan { answers, additionals: additionals.minus(answers), legacy, goodbye: false })
}

/// Why [`emit`] wrote nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Full {
    /// Bytes the response takes.
    pub needed: usize,
}

/// The bytes of the response `plan` describes, for `identity`; `Full` when
/// `buffer` is shorter than it (then what is in `buffer` means nothing).
/// [`response_len`] measures it first.
pub fn emit(plan: &Plan, identity: &Identity, buffer: &mut [u8]) -> Result<usize, Full> {
    let mut out = Emitter { writer: Writer::new(buffer), offsets: [0; Domain::COUNT], identity };
    out.response(plan);
    if out.writer.fits() { Ok(out.writer.len()) } else { Err(Full { needed: out.writer.len() }) }
}

/// Bytes the response `plan` describes takes.
pub fn response_len(plan: &Plan, identity: &Identity) -> usize {
    match emit(plan, identity, &mut []) {
        Ok(len) | Err(Full { needed: len }) => len,
    }
}

struct Emitter<'a, 'b> {
    writer: Writer<'a>,
    /// Where each name was written first (0: not yet; no name starts at 0).
    offsets: [u16; Domain::COUNT],
    identity: &'b Identity,
}

impl Emitter<'_, '_> {
    fn response(&mut self, plan: &Plan) {
        let id = plan.legacy.map_or(0, |legacy| legacy.id);
        self.writer.put_u16(id);
        self.writer.put_u16(flags::RESPONSE | flags::AUTHORITATIVE);
        self.writer.put_u16(u16::from(plan.legacy.is_some()));
        self.writer.put_u16(plan.answers.len());
        self.writer.put_u16(0);
        self.writer.put_u16(plan.additionals.len());
        if let Some(legacy) = plan.legacy {
            self.name(legacy.owner);
            self.writer.put_u16(legacy.qtype);
            self.writer.put_u16(class::IN);
        }
        for record in plan.answers.iter().chain(plan.additionals.iter()) {
            self.record(record, plan);
        }
    }

    /// A name: its labels until one already written, then a pointer there.
    fn name(&mut self, name: Domain) {
        let mut next = Some(name);
        while let Some(domain) = next {
            let written = self.offsets.get(domain.index()).copied().unwrap_or(0);
            if let Some(pointer) = wire::pointer(usize::from(written)).filter(|_| written != 0) {
                self.writer.put(&pointer);
                return;
            }
            if let (Some(slot), Ok(offset)) = (self.offsets.get_mut(domain.index()), u16::try_from(self.writer.len())) {
                *slot = offset;
            }
            let label = domain.label(&self.identity.name);
            self.writer.put_u8(label.len().min(wire::MAX_LABEL_LEN) as u8);
            self.writer.put(label.get(..wire::MAX_LABEL_LEN).unwrap_or(label));
            next = domain.parent();
        }
        self.writer.put_u8(0);
    }

    fn record(&mut self, record: Record, plan: &Plan) {
        let identity = self.identity;
        self.name(record.owner());
        self.writer.put_u16(record.rtype());
        let flush = record.is_unique() && plan.legacy.is_none();
        self.writer.put_u16(if flush { class::IN | class::TOP_BIT } else { class::IN });
        let ttl = match (plan.goodbye, plan.legacy) {
            (true, _) => 0,
            (false, Some(_)) => record.ttl_s().min(LEGACY_TTL_S),
            (false, None) => record.ttl_s(),
        };
        self.writer.put_u32(ttl);
        let length_at = self.writer.len();
        self.writer.put_u16(0);
        match record {
            Record::Address => self.writer.put(&identity.address),
            Record::NoOtherAddress => {
                // Next name: the owner itself; then window 0, one byte, type A's bit (RFC 4034 section 4.1.2).
                self.name(Domain::Host);
                self.writer.put(&[0, 1, 0x80 >> rtype::A]);
            }
            Record::ServiceType(s) => self.name(Domain::Type(s)),
            Record::Instance(s) => self.name(Domain::Instance(s)),
            Record::Port(s) => {
                // Priority 0, weight 0, the port, the host (RFC 2782).
                self.writer.put_u32(0);
                self.writer.put_u16(identity.services.port(s).unwrap_or(0));
                self.name(Domain::Host);
            }
            Record::Text(_) => self.text(),
        }
        let length = self.writer.len().saturating_sub(length_at + 2);
        self.writer.set_u16(length_at, u16::try_from(length).unwrap_or(u16::MAX));
    }

    /// TXT: `name=`, `model=` and `version=` (RFC 6763 section 6).
    fn text(&mut self) {
        let identity = self.identity;
        let name = identity.name.as_bytes();
        let model = identity.services.model.as_bytes();
        let model = model.get(..MAX_MODEL_LEN).unwrap_or(model);
        self.string(&[b"name=", name]);
        self.string(&[b"model=", model]);
        self.string(&[b"version=", identity.services.version.as_bytes()]);
    }

    /// One character string: a length byte, then `parts` (at most 255 bytes in all).
    fn string(&mut self, parts: &[&[u8]]) {
        let len: usize = parts.iter().map(|part| part.len()).sum();
        self.writer.put_u8(len.min(255) as u8);
        let mut left = 255;
        for part in parts {
            let part = part.get(..left).unwrap_or(part);
            self.writer.put(part);
            left -= part.len();
        }
    }
}
