//! The host's name as the responder announces it, and where it comes from.

use core::fmt;

/// The longest host name: a response with every record and the longest
/// name fits [`crate::MAX_RESPONSE_LEN`] (a test checks it).
pub const MAX_NAME_LEN: usize = 32;

/// The host's name, `NAME` in `NAME.local`: one DNS label of at most
/// [`MAX_NAME_LEN`] bytes, sent as it is (the program checks its rule;
/// an empty name announces nothing).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct HostName {
    bytes: [u8; MAX_NAME_LEN],
    len: u8,
}

impl HostName {
    /// The first [`MAX_NAME_LEN`] bytes of `label`.
    pub fn new(label: &[u8]) -> Self {
        let mut bytes = [0; MAX_NAME_LEN];
        let len = label.len().min(MAX_NAME_LEN);
        if let (Some(to), Some(from)) = (bytes.get_mut(..len), label.get(..len)) {
            to.copy_from_slice(from);
        }
        Self { bytes, len: len as u8 }
    }

    /// The name's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or_default()
    }

    /// The name as text (empty when it is not UTF-8).
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(self.as_bytes()).unwrap_or_default()
    }
}

impl fmt::Debug for HostName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("HostName").field(&self.as_str()).finish()
    }
}

impl fmt::Display for HostName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for HostName {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "{=str}", self.as_str())
    }
}

/// Where the responder reads the host's name, each time it looks: a
/// rename is announced (the old name's records withdrawn first).
pub trait NameSource {
    /// The name now.
    fn host_name(&self) -> HostName;
}

impl NameSource for HostName {
    fn host_name(&self) -> HostName {
        *self
    }
}
