//! Access control: which clients may connect, and what each may do.
//!
//! Plain Modbus has no authentication; an I/O adapter's answer is an
//! allow-list of client networks. A client outside the `connect` list is
//! refused at once (the connection is reset); a client outside the `write`
//! list may read, and its write functions (05, 06, 0F, 10) get exception 01.
//! `None` means everyone, which is the default (the map's source table lets
//! any master connect and write).
//!
//! What a session may do is its [`Rights`]: the allow-lists give a client
//! [`Rights::ReadWrite`] or [`Rights::Read`].

use core::fmt;

/// Most networks in one allow-list.
pub const MAX_ALLOWED_NETWORKS: usize = 8;

/// An IPv4 network: an address and a prefix length (0..=32).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Network {
    address: [u8; 4],
    prefix_len: u8,
}

impl Network {
    /// The network `address/prefix_len`; `None` for a prefix over 32.
    pub const fn new(address: [u8; 4], prefix_len: u8) -> Option<Self> {
        if prefix_len > 32 { None } else { Some(Self { address, prefix_len }) }
    }

    /// Whether `address` lies in this network.
    pub const fn contains(&self, address: [u8; 4]) -> bool {
        let mask = match self.prefix_len {
            0 => 0,
            n => u32::MAX << (32 - n as u32),
        };
        u32::from_be_bytes(self.address) & mask == u32::from_be_bytes(address) & mask
    }
}

impl Network {
    /// Writes `a.b.c.d/n`.
    pub fn write_to(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        crate::text::write_ipv4(out, self.address)?;
        out.write_str("/")?;
        crate::text::write_decimal(out, self.prefix_len)
    }
}

impl fmt::Display for Network {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write_to(f)
    }
}

/// Up to [`MAX_ALLOWED_NETWORKS`] networks. Built in `const` context, so a
/// board's build-time settings can hold one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AllowList {
    networks: [Network; MAX_ALLOWED_NETWORKS],
    len: usize,
}

impl AllowList {
    /// A list that allows no one.
    pub const EMPTY: Self =
        Self { networks: [Network { address: [0; 4], prefix_len: 32 }; MAX_ALLOWED_NETWORKS], len: 0 };

    /// The list with `network` added; `None` when it is full.
    #[must_use]
    #[allow(
        clippy::indexing_slicing,
        reason = "len < MAX_ALLOWED_NETWORKS is checked first; const fn cannot use get_mut"
    )]
    pub const fn with(mut self, network: Network) -> Option<Self> {
        if self.len >= MAX_ALLOWED_NETWORKS {
            return None;
        }
        self.networks[self.len] = network;
        self.len += 1;
        Some(self)
    }

    /// The networks in the list.
    pub fn networks(&self) -> &[Network] {
        // `with` keeps len <= MAX_ALLOWED_NETWORKS; were it not, the list
        // would allow no one (fail closed), never someone it should not.
        self.networks.split_at_checked(self.len).map_or(&[], |(networks, _)| networks)
    }

    /// Whether `address` lies in one of the networks.
    pub fn allows(&self, address: [u8; 4]) -> bool {
        self.networks().iter().any(|network| network.contains(address))
    }
}

impl fmt::Display for AllowList {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, network) in self.networks().iter().enumerate() {
            if i > 0 {
                f.write_str(",")?;
            }
            write!(f, "{network}")?;
        }
        Ok(())
    }
}

/// What a session's requests may do. A request its rights do not cover is
/// answered with exception 01 (Illegal Function), as a function the client
/// may not use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rights {
    /// Reads, identification and diagnostics; no write function and no
    /// Clear Counters ([`crate::modbus::pdu::is_write`]).
    Read,
    /// Everything the map allows.
    #[default]
    ReadWrite,
}

impl Rights {
    /// Whether a request is covered: `write` for one that asks for a change.
    pub const fn allow(self, write: bool) -> bool {
        match self {
            Self::Read => !write,
            Self::ReadWrite => true,
        }
    }

    /// The rights both grant (a server-wide limit and a session's own).
    #[must_use]
    pub fn and(self, other: Self) -> Self {
        self.min(other)
    }

    /// The name the API and the settings use: `read`, `read_write`.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Read => "read",
            Self::ReadWrite => "read_write",
        }
    }
}

/// Most roles the Modbus/TCP Security port tells apart (a plant names a
/// few: an operator, a viewer, a historian).
pub const MAX_ROLES: usize = 4;
/// The longest role name, in bytes.
pub const MAX_ROLE_LEN: usize = 24;

/// A role name: 1 to [`MAX_ROLE_LEN`] printable ASCII characters other
/// than `,` and `=` (the settings' separators), compared byte for byte
/// with the role a client certificate carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Role {
    bytes: [u8; MAX_ROLE_LEN],
    len: u8,
}

impl Role {
    /// `text` as a role name; `None` if it breaks the rule.
    #[allow(
        clippy::indexing_slicing,
        reason = "i < text.len() <= MAX_ROLE_LEN is checked first; const fn cannot use get_mut"
    )]
    pub const fn new(text: &[u8]) -> Option<Self> {
        if text.is_empty() || text.len() > MAX_ROLE_LEN {
            return None;
        }
        let mut bytes = [0; MAX_ROLE_LEN];
        let mut i = 0;
        while i < text.len() {
            let byte = text[i];
            if !byte.is_ascii_graphic() || byte == b',' || byte == b'=' {
                return None;
            }
            bytes[i] = byte;
            i += 1;
        }
        Some(Self { bytes, len: text.len() as u8 })
    }

    /// Whether both name the same role (the bytes past `len` are zero).
    const fn same(&self, other: &Self) -> bool {
        let mut i = 0;
        while i < MAX_ROLE_LEN {
            #[allow(clippy::indexing_slicing, reason = "i < MAX_ROLE_LEN, both arrays' length")]
            if self.bytes[i] != other.bytes[i] {
                return false;
            }
            i += 1;
        }
        self.len == other.len
    }

    /// The name's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

/// The roles a Modbus/TCP Security client may hold and the [`Rights`] each
/// gives: up to [`MAX_ROLES`], each named once. A role not in the list gets
/// no session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Roles {
    roles: [(Role, Rights); MAX_ROLES],
    len: usize,
}

impl Roles {
    /// No role: no client gets a session.
    pub const EMPTY: Self =
        Self { roles: [(Role { bytes: [0; MAX_ROLE_LEN], len: 0 }, Rights::Read); MAX_ROLES], len: 0 };

    /// `operator` reads and writes, `viewer` reads.
    #[allow(clippy::unwrap_used, reason = "const: the names keep the rule, or the build fails")]
    pub const DEFAULT: Self = {
        let operator = Role::new(b"operator").unwrap();
        let viewer = Role::new(b"viewer").unwrap();
        Self::EMPTY.with(operator, Rights::ReadWrite).unwrap().with(viewer, Rights::Read).unwrap()
    };

    /// The list with `role` giving `rights` added; `None` when it is full
    /// or names `role` already.
    #[must_use]
    #[allow(
        clippy::indexing_slicing,
        reason = "i < len <= MAX_ROLES is checked first; const fn cannot use get or get_mut"
    )]
    pub const fn with(mut self, role: Role, rights: Rights) -> Option<Self> {
        if self.len >= MAX_ROLES {
            return None;
        }
        let mut i = 0;
        while i < self.len {
            let (known, _) = self.roles[i];
            if known.same(&role) {
                return None;
            }
            i += 1;
        }
        self.roles[self.len] = (role, rights);
        self.len += 1;
        Some(self)
    }

    /// The roles and their rights, in the order given.
    pub fn iter(&self) -> impl Iterator<Item = (&Role, Rights)> {
        self.roles.get(..self.len).unwrap_or(&[]).iter().map(|(role, rights)| (role, *rights))
    }

    /// The rights `role` (a certificate's, as its bytes) gives; `None`: no session.
    pub fn rights(&self, role: &[u8]) -> Option<Rights> {
        self.iter().find(|(known, _)| known.as_bytes() == role).map(|(_, rights)| rights)
    }

    /// Writes `role=rights,...` as the settings parse it.
    pub fn write_to(&self, out: &mut dyn fmt::Write) -> fmt::Result {
        for (i, (role, rights)) in self.iter().enumerate() {
            if i > 0 {
                out.write_str(",")?;
            }
            // A role is printable ASCII by construction.
            out.write_str(core::str::from_utf8(role.as_bytes()).unwrap_or(""))?;
            out.write_str("=")?;
            out.write_str(rights.name())?;
        }
        Ok(())
    }
}

/// Who may connect and who may write. `None`: everyone.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Access {
    /// Clients that may connect; others are refused at once.
    pub connect: Option<AllowList>,
    /// Clients that may write; others get exception 01 on write functions.
    pub write: Option<AllowList>,
}

impl Access {
    /// Everyone may connect and write.
    pub const OPEN: Self = Self { connect: None, write: None };

    /// Whether a client at `address` may connect.
    pub fn may_connect(&self, address: [u8; 4]) -> bool {
        self.connect.is_none_or(|list| list.allows(address))
    }

    /// Whether a client at `address` may write.
    pub fn may_write(&self, address: [u8; 4]) -> bool {
        self.write.is_none_or(|list| list.allows(address))
    }

    /// What a client at `address` that may connect may do.
    pub fn rights(&self, address: [u8; 4]) -> Rights {
        if self.may_write(address) { Rights::ReadWrite } else { Rights::Read }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn net(a: [u8; 4], p: u8) -> Network {
        Network::new(a, p).unwrap()
    }

    #[test]
    fn networks_contain_their_addresses() {
        let lan = net([192, 168, 1, 0], 24);
        assert!(lan.contains([192, 168, 1, 0]) && lan.contains([192, 168, 1, 255]));
        assert!(!lan.contains([192, 168, 2, 1]) && !lan.contains([10, 0, 0, 1]));
        let host = net([10, 0, 0, 5], 32);
        assert!(host.contains([10, 0, 0, 5]) && !host.contains([10, 0, 0, 4]));
        let all = net([1, 2, 3, 4], 0);
        assert!(all.contains([0, 0, 0, 0]) && all.contains([255, 255, 255, 255]));
        assert!(net([198, 18, 0, 0], 15).contains([198, 19, 255, 1]));
        assert!(!net([198, 18, 0, 0], 15).contains([198, 20, 0, 1]));
        assert_eq!(Network::new([0; 4], 33), None);
        assert_eq!(lan.to_string(), "192.168.1.0/24");
    }

    #[test]
    fn allow_lists() {
        let mut list = AllowList::EMPTY;
        assert!(!list.allows([10, 0, 0, 1]), "an empty list allows no one");
        for i in 0..MAX_ALLOWED_NETWORKS as u8 {
            list = list.with(net([10, i, 0, 0], 16)).unwrap();
        }
        assert_eq!(list.with(net([11, 0, 0, 0], 8)), None, "full");
        assert!(list.allows([10, 7, 1, 1]) && !list.allows([10, 8, 1, 1]));
        assert_eq!(list.networks().len(), MAX_ALLOWED_NETWORKS);
        let two = AllowList::EMPTY.with(net([10, 0, 0, 0], 8)).unwrap().with(net([192, 168, 0, 0], 16)).unwrap();
        assert_eq!(two.to_string(), "10.0.0.0/8,192.168.0.0/16");
    }

    #[test]
    fn access_defaults_to_open() {
        assert!(Access::OPEN.may_connect([1, 2, 3, 4]) && Access::OPEN.may_write([1, 2, 3, 4]));
        let readers = AllowList::EMPTY.with(net([198, 18, 0, 0], 24)).unwrap();
        let writer = AllowList::EMPTY.with(net([198, 18, 0, 9], 32)).unwrap();
        let access = Access { connect: Some(readers), write: Some(writer) };
        assert!(access.may_connect([198, 18, 0, 1]) && !access.may_write([198, 18, 0, 1]));
        assert!(access.may_connect([198, 18, 0, 9]) && access.may_write([198, 18, 0, 9]));
        assert!(!access.may_connect([198, 18, 1, 1]));
        assert_eq!((access.rights([198, 18, 0, 1]), access.rights([198, 18, 0, 9])), (Rights::Read, Rights::ReadWrite));
    }

    #[test]
    fn roles_map_a_certificate_role_to_rights_exactly() {
        let roles = Roles::DEFAULT;
        assert_eq!(roles.rights(b"operator"), Some(Rights::ReadWrite));
        assert_eq!(roles.rights(b"viewer"), Some(Rights::Read));
        for unknown in [&b"Operator"[..], b"operator ", b"", b"oper", b"operator\0"] {
            assert_eq!(roles.rights(unknown), None, "{unknown:?}");
        }
        let mut text = String::new();
        roles.write_to(&mut text).unwrap();
        assert_eq!(text, "operator=read_write,viewer=read");
        assert_eq!(Roles::EMPTY.rights(b"operator"), None);
    }

    #[test]
    fn role_names_keep_their_rule_and_are_named_once() {
        assert!(Role::new(b"historian-2").is_some());
        assert!(Role::new(&[b'r'; MAX_ROLE_LEN]).is_some());
        for bad in [&b""[..], &[b'r'; MAX_ROLE_LEN + 1], b"a b", b"a,b", b"a=b", "é".as_bytes(), b"a\n"] {
            assert_eq!(Role::new(bad), None, "{bad:?}");
        }
        let operator = Role::new(b"operator").unwrap();
        assert_eq!(Roles::DEFAULT.with(operator, Rights::Read), None, "named twice");
        let mut roles = Roles::EMPTY;
        for i in 0..MAX_ROLES as u8 {
            roles = roles.with(Role::new(&[b'a' + i]).unwrap(), Rights::Read).unwrap();
        }
        assert_eq!(roles.with(Role::new(b"z").unwrap(), Rights::Read), None, "full");
    }

    #[test]
    fn rights_cover_requests_and_combine_to_the_lesser() {
        assert!(Rights::ReadWrite.allow(true) && Rights::ReadWrite.allow(false));
        assert!(!Rights::Read.allow(true) && Rights::Read.allow(false));
        assert_eq!(Rights::ReadWrite.and(Rights::Read), Rights::Read);
        assert_eq!(Rights::Read.and(Rights::ReadWrite), Rights::Read);
        assert_eq!(Rights::ReadWrite.and(Rights::ReadWrite), Rights::ReadWrite);
        assert_eq!(Rights::default(), Rights::ReadWrite);
    }
}
