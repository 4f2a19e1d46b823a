//! The settings record: the whole [`Settings`] as text, one line per field.
//!
//! ```text
//! | version = 1 (1 byte) | "device.name=cell-4\n" | "network.mode=static\n" | ... |
//! ```
//!
//! After the version byte, UTF-8 lines `group.field=value`, each ending in
//! `\n`: every field of [`Field::ALL`], its value written by
//! [`Settings::show`] and read back by [`Settings::set`], so the record
//! follows the settings table and needs no format of its own. A record is
//! decoded starting from the factory settings (a field an older firmware did
//! not write keeps its factory value) and taken **whole or not at all**: a
//! malformed line, a value that breaks its field's rule, a field given
//! twice, or a whole that fails [`Settings::validate`] rejects the record.
//! A line whose key this firmware does not know (a newer firmware's
//! setting) is skipped and counted.
//!
//! The version changes only when the syntax does; adding a setting does not
//! need a new version (older firmware skips it, newer firmware fills it
//! from the factory settings when an older record lacks it).

use core::fmt;

use crate::settings::{Field, Settings};

/// This firmware's record format.
pub const VERSION: u8 = 1;

/// Longest settings record, version byte included. The longest settings of
/// today take 1008 bytes (eight networks in each allow-list, four roles of
/// 24 characters); the rest is room for settings to come.
pub const MAX_RECORD_LEN: usize = 1280;

/// Why a record was not taken (decoding), or could not be made (encoding).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordError {
    /// No version byte.
    Empty,
    /// A format this firmware does not read (a newer firmware's).
    Version(u8),
    /// Line `line` (1 is the first) is not `group.field=value` in UTF-8
    /// ending with a newline.
    Malformed {
        /// Its number, from 1.
        line: u16,
    },
    /// The field is given twice.
    Duplicate(Field),
    /// The field's value breaks its rule.
    Invalid(Field),
    /// The fields do not fit together ([`Settings::validate`]); the first
    /// field to fix.
    Inconsistent(Field),
    /// The settings take more than [`MAX_RECORD_LEN`] bytes, or more than
    /// the buffer given.
    TooLong,
}

impl fmt::Display for RecordError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Empty => f.write_str("empty record"),
            Self::Version(version) => write!(f, "record format {version}, this firmware reads {VERSION}"),
            Self::Malformed { line } => write!(f, "line {line} is not group.field=value"),
            Self::Duplicate(field) => write!(f, "{} given twice", field.key()),
            Self::Invalid(field) => write!(f, "{}: must be {}", field.key(), field.rule()),
            Self::Inconsistent(field) => write!(f, "{}: does not fit the other settings", field.key()),
            Self::TooLong => write!(f, "the settings take more than {MAX_RECORD_LEN} bytes"),
        }
    }
}

impl core::error::Error for RecordError {}

/// A record taken whole.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Decoded {
    /// The factory settings with the record's fields applied, validated.
    pub settings: Settings,
    /// Lines skipped because this firmware does not know their key.
    pub skipped: u32,
}

/// Writes `settings` as a record into `out`; returns its length.
pub fn encode(settings: &Settings, out: &mut [u8]) -> Result<usize, RecordError> {
    let limit = out.len().min(MAX_RECORD_LEN);
    let (out, _) = out.split_at_mut(limit);
    let mut writer = Writer { out, len: 0 };
    writer.push(&[VERSION])?;
    for &field in Field::ALL {
        writer.push(field.key().as_bytes())?;
        writer.push(b"=")?;
        let start = writer.len;
        settings.show(field, &mut writer).map_err(|fmt::Error| RecordError::TooLong)?;
        // A value that holds a newline would not read back as one line.
        let value = writer.out.get(start..writer.len).unwrap_or_default();
        if value.contains(&b'\n') {
            return Err(RecordError::Invalid(field));
        }
        writer.push(b"\n")?;
    }
    Ok(writer.len)
}

/// Reads a record over `factory`: the settings whole, or why not.
pub fn decode(record: &[u8], factory: &Settings) -> Result<Decoded, RecordError> {
    let Some((&version, text)) = record.split_first() else { return Err(RecordError::Empty) };
    if version != VERSION {
        return Err(RecordError::Version(version));
    }
    let mut settings = *factory;
    let mut seen = [false; Field::ALL.len()];
    let mut skipped = 0u32;
    let mut rest = text;
    let mut line_no = 0u16;
    while !rest.is_empty() {
        line_no = line_no.saturating_add(1);
        let malformed = RecordError::Malformed { line: line_no };
        let newline = rest.iter().position(|&b| b == b'\n').ok_or(malformed)?;
        let (line, tail) = rest.split_at(newline);
        rest = tail.get(1..).unwrap_or_default();
        let line = core::str::from_utf8(line).map_err(|_| malformed)?;
        let (key, value) = line.split_once('=').ok_or(malformed)?;
        if !is_key(key) {
            return Err(malformed);
        }
        let Some(index) = Field::ALL.iter().position(|field| field.key() == key) else {
            skipped = skipped.saturating_add(1);
            continue;
        };
        let (Some(&field), Some(seen)) = (Field::ALL.get(index), seen.get_mut(index)) else {
            return Err(malformed);
        };
        if core::mem::replace(seen, true) {
            return Err(RecordError::Duplicate(field));
        }
        settings.set(field, value).map_err(|_| RecordError::Invalid(field))?;
    }
    if let Err(errors) = settings.validate() {
        let field = errors.iter().next().map_or(Field::NetworkMode, |(field, _)| *field);
        return Err(RecordError::Inconsistent(field));
    }
    Ok(Decoded { settings, skipped })
}

/// `group.field`: two non-empty words of `a-z 0-9 _` around one dot.
fn is_key(key: &str) -> bool {
    let word = |w: &str| !w.is_empty() && w.bytes().all(|b| matches!(b, b'a'..=b'z' | b'0'..=b'9' | b'_'));
    key.split_once('.').is_some_and(|(group, name)| word(group) && word(name))
}

/// Appends to a byte slice; full is an error.
struct Writer<'a> {
    out: &'a mut [u8],
    len: usize,
}

impl Writer<'_> {
    fn push(&mut self, bytes: &[u8]) -> Result<(), RecordError> {
        let end = self.len.checked_add(bytes.len()).ok_or(RecordError::TooLong)?;
        self.out.get_mut(self.len..end).ok_or(RecordError::TooLong)?.copy_from_slice(bytes);
        self.len = end;
        Ok(())
    }
}

impl fmt::Write for Writer<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.push(s.as_bytes()).map_err(|_| fmt::Error)
    }
}

#[cfg(test)]
mod tests;
