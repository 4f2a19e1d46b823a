//! Log macros that go to defmt on the boards, to `log` on the host, or nowhere.
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
