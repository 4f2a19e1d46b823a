//! Log macros that go to defmt on the boards, to `log` on the host, or
//! nowhere (crate-internal), and [`Ip`], for logging addresses.
//!
//! Arguments must implement both `defmt::Format` and `core::fmt::Display`
//! (or `Debug` for `{:?}`), since either backend may format them.
#![allow(unused_macros)]

macro_rules! log_with {
    ($level:ident, $($arg:tt)+) => {{
        #[cfg(feature = "defmt")]
        ::defmt::$level!($($arg)+);
        #[cfg(all(feature = "log", not(feature = "defmt")))]
        ::log::$level!($($arg)+);
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = format_args!($($arg)+);
    }};
}

macro_rules! debug { ($($arg:tt)+) => { log_with!(debug, $($arg)+) }; }
macro_rules! info { ($($arg:tt)+) => { log_with!(info, $($arg)+) }; }
macro_rules! warn { ($($arg:tt)+) => { log_with!(warn, $($arg)+) }; }

/// An IPv4 address as logs show it (`192.168.1.50`). defmt prints it octet
/// by octet on the host, so the boards do not carry `core::fmt`'s IP
/// printing, which smoltcp's own `Format` impls pull in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ip(pub [u8; 4]);

impl core::fmt::Display for Ip {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let [a, b, c, d] = self.0;
        write!(f, "{a}.{b}.{c}.{d}")
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Ip {
    fn format(&self, f: defmt::Formatter<'_>) {
        let [a, b, c, d] = self.0;
        defmt::write!(f, "{}.{}.{}.{}", a, b, c, d);
    }
}
