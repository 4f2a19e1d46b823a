//! The responder's log lines: to defmt (feature `defmt`), to `log`
//! (feature `log`), or nowhere.

macro_rules! info {
    ($($arg:tt)+) => {{
        #[cfg(feature = "defmt")]
        ::defmt::info!($($arg)+);
        #[cfg(all(feature = "log", not(feature = "defmt")))]
        ::log::info!($($arg)+);
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = format_args!($($arg)+);
    }};
}

macro_rules! warn {
    ($($arg:tt)+) => {{
        #[cfg(feature = "defmt")]
        ::defmt::warn!($($arg)+);
        #[cfg(all(feature = "log", not(feature = "defmt")))]
        ::log::warn!($($arg)+);
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = format_args!($($arg)+);
    }};
}
