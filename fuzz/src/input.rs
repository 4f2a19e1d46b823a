//! How the fuzz targets read their bytes. Every byte string is a valid input
//! (missing header bytes read as 0), and [`SessionInput::to_bytes`] and
//! [`HandlerInput::to_bytes`] write the seeds.

use adapter::server::{Policy, Rights};

use crate::check::write_policy;

/// Bit 0 of the flags: answer only `unit_id` (and 0, 0xFF).
pub const UNIT_FILTER: u8 = 1 << 0;
/// Bit 1: the `strict` write policy (else `seed`).
pub const STRICT: u8 = 1 << 1;
/// Bit 2: every read is `Pending` once before it returns data.
pub const STALL_READS: u8 = 1 << 2;
/// Bit 3: every write is `Pending` once, then takes only part of the bytes.
pub const PARTIAL_WRITES: u8 = 1 << 3;
/// Bit 4: the client may not write (its write functions get exception 01).
pub const READ_ONLY: u8 = 1 << 4;
/// At most this many cut sizes (the low 4 bits of the count byte).
pub const MAX_CUTS: usize = 15;

/// The session target's input:
///
/// ```text
/// | flags (1) | unit id (1) | n (1, low 4 bits) | n cut sizes | the client's byte stream |
/// ```
///
/// Reads take the cut sizes in turn (0: as much as the buffer holds); with
/// [`PARTIAL_WRITES`], writes take `1 + cut % 16` bytes, in turn.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SessionInput<'a> {
    pub flags: u8,
    pub unit_id: u8,
    pub cuts: &'a [u8],
    pub stream: &'a [u8],
}

impl<'a> SessionInput<'a> {
    pub fn parse(data: &'a [u8]) -> Self {
        let byte = |i: usize| data.get(i).copied().unwrap_or(0);
        let rest = data.get(3..).unwrap_or(&[]);
        let (cuts, stream) = rest.split_at(usize::from(byte(2) & 0x0f).min(rest.len()));
        Self { flags: byte(0), unit_id: byte(1), cuts, stream }
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        assert!(self.cuts.len() <= MAX_CUTS);
        let mut out = vec![self.flags, self.unit_id, self.cuts.len() as u8];
        out.extend_from_slice(self.cuts);
        out.extend_from_slice(self.stream);
        out
    }

    pub fn policy(&self) -> Policy {
        policy(self.flags, self.unit_id)
    }
}

/// The handler target's input: records, each answered in turn on one map.
///
/// ```text
/// | flags (1) | unit id (1) | len (1) | len bytes | len (1) | len bytes | ...
/// ```
///
/// A record is given to the handler as it is, whatever its length field says.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct HandlerInput<'a> {
    pub flags: u8,
    pub unit_id: u8,
    pub records: &'a [u8],
}

impl<'a> HandlerInput<'a> {
    pub fn parse(data: &'a [u8]) -> Self {
        let byte = |i: usize| data.get(i).copied().unwrap_or(0);
        Self { flags: byte(0), unit_id: byte(1), records: data.get(2..).unwrap_or(&[]) }
    }

    /// Writes an input whose records are `frames`.
    pub fn encode(flags: u8, unit_id: u8, frames: &[&[u8]]) -> Vec<u8> {
        let mut out = vec![flags, unit_id];
        for frame in frames {
            out.push(u8::try_from(frame.len()).expect("a record of at most 255 bytes"));
            out.extend_from_slice(frame);
        }
        out
    }

    pub fn policy(&self) -> Policy {
        policy(self.flags, self.unit_id)
    }

    /// The records (the last one may be shorter than its length byte says).
    pub fn frames(&self) -> impl Iterator<Item = &'a [u8]> {
        let mut rest = self.records;
        std::iter::from_fn(move || {
            let (&len, tail) = rest.split_first()?;
            let (frame, next) = tail.split_at(usize::from(len).min(tail.len()));
            rest = next;
            Some(frame)
        })
    }
}

/// The http target's flags. Bit 0: an admin password is set ([`PASSWORD`]).
pub const HTTP_PASSWORD_SET: u8 = 1 << 0;
/// Bit 1: the client is outside `modbus.allow_write`.
pub const HTTP_OUTSIDE: u8 = 1 << 1;
/// Bit 2: every read is `Pending` once before it returns data.
pub const HTTP_STALL_READS: u8 = 1 << 2;
/// Bit 3: every write is `Pending` once, then takes only part of the bytes.
pub const HTTP_PARTIAL_WRITES: u8 = 1 << 3;
/// Bit 4: the backend fails to save (500: nothing changes).
pub const HTTP_SAVE_FAILS: u8 = 1 << 4;
/// Bit 5: the client keeps its side open after its bytes (the request
/// deadline ends a request left incomplete).
pub const HTTP_KEEP_OPEN: u8 = 1 << 5;
/// Bit 6: the connection is served as HTTPS serves one (`serve_kept`):
/// request after request, the stream holding any number of them.
pub const HTTP_KEPT: u8 = 1 << 6;

/// The admin password when [`HTTP_PASSWORD_SET`].
pub const PASSWORD: &str = "s3cret-pass";

/// The http target's input:
///
/// ```text
/// | flags (1) | n (1, low 4 bits) | n cut sizes | the client's byte stream |
/// ```
///
/// Reads take the cut sizes in turn (0: as much as the buffer holds); with
/// [`HTTP_PARTIAL_WRITES`], writes take `1 + cut % 16` bytes, in turn.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct HttpInput<'a> {
    pub flags: u8,
    pub cuts: &'a [u8],
    pub stream: &'a [u8],
}

impl<'a> HttpInput<'a> {
    pub fn parse(data: &'a [u8]) -> Self {
        let byte = |i: usize| data.get(i).copied().unwrap_or(0);
        let rest = data.get(2..).unwrap_or(&[]);
        let (cuts, stream) = rest.split_at(usize::from(byte(1) & 0x0f).min(rest.len()));
        Self { flags: byte(0), cuts, stream }
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        assert!(self.cuts.len() <= MAX_CUTS);
        let mut out = vec![self.flags, self.cuts.len() as u8];
        out.extend_from_slice(self.cuts);
        out.extend_from_slice(self.stream);
        out
    }
}

fn policy(flags: u8, unit_id: u8) -> Policy {
    Policy {
        unit_id: (flags & UNIT_FILTER != 0).then_some(unit_id),
        write_policy: write_policy(flags & STRICT != 0),
        rights: if flags & READ_ONLY != 0 { Rights::Read } else { Rights::ReadWrite },
    }
}
