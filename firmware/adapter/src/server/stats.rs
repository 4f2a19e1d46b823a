//! Diagnostics counters (as an I/O adapter's web page or WAGO's diagnostics
//! show them): what the server has seen since start-up, or since a master
//! cleared them (Diagnostics 08/000A).
//!
//! Counted with relaxed atomics, so any task may count without a lock and a
//! reader gets each counter exact (the set is not one atomic snapshot, nor
//! is a clear).
//!
//! Diagnostics (function 08) reads the serial-line counters of the Modbus
//! specification (6.8.1) as these, by [`Counters::diagnostic`]
//! (docs/data-map.md, *Diagnostics*):
//!
//! | sub-function | serial-line counter | here |
//! |---|---|---|
//! | 0B | bus messages | `requests` + `bad_protocol`: every whole frame |
//! | 0C | bus communication errors | `bad_length`: streams lost to a bad length field |
//! | 0D | bus exception errors | `bad_function` + `bad_address` + `bad_value` + `refused_writes` + `other_unit` |
//! | 0E | server messages | `requests` - `other_unit`: the Modbus frames for this unit |
//! | 0F | server no response | `bad_protocol`: frames skipped unanswered |
//! | 12 | bus character overrun | `evictions`: sessions closed because every one was taken |
//!
//! Each is sent as its low 16 bits, as a 16-bit counter would wrap.

use core::fmt;
use core::sync::atomic::{AtomicU32, Ordering};

use crate::modbus::Exception;
use crate::modbus::diagnostics::Diagnostic;

macro_rules! counters {
    ($( $(#[$doc:meta])* $name:ident ),* $(,)?) => {
        /// The live counters, shared by all tasks.
        #[derive(Debug, Default)]
        pub struct Stats {
            $( $(#[$doc])* pub $name: AtomicU32, )*
        }

        /// A copy of the counters at one moment.
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub struct Counters {
            $( $(#[$doc])* pub $name: u32, )*
        }

        impl Stats {
            /// All counters at 0.
            pub const fn new() -> Self {
                Self { $( $name: AtomicU32::new(0), )* }
            }

            /// Reads every counter.
            pub fn snapshot(&self) -> Counters {
                Counters { $( $name: self.$name.load(Ordering::Relaxed), )* }
            }

            /// Sets every counter to 0.
            pub fn clear(&self) {
                $( self.$name.store(0, Ordering::Relaxed); )*
            }
        }

        impl Counters {
            /// Calls `f` with each counter's name and value, in a fixed order.
            pub fn for_each(&self, mut f: impl FnMut(&'static str, u32)) {
                $( f(stringify!($name), self.$name); )*
            }
        }

        impl fmt::Display for Counters {
            /// `name=value` pairs separated by spaces, in a fixed order.
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                let mut sep = "";
                $(
                    write!(f, "{sep}{}={}", stringify!($name), self.$name)?;
                    sep = " ";
                )*
                let _ = sep;
                Ok(())
            }
        }
    };
}

counters! {
    /// Modbus frames received (protocol id 0), answered or not.
    requests,
    /// Frames with a protocol id other than 0, skipped.
    bad_protocol,
    /// Length fields outside 2..=254: the connection was closed.
    bad_length,
    /// Exception 01 for an unknown function code.
    bad_function,
    /// Exception 02.
    bad_address,
    /// Exception 03.
    bad_value,
    /// Exception 01 for a write, or a Clear Counters, from a client outside
    /// the write allow-list.
    refused_writes,
    /// Exception 0B: a unit id this server does not answer.
    other_unit,
    /// Sessions closed to make room for a new client.
    evictions,
    /// Sessions closed by the idle or the frame timeout.
    timeouts,
    /// Connections refused by the connect allow-list.
    refused_connections,
    /// Times the communication watchdog put the outputs in their safe state.
    watchdog_trips,
    /// Robot link: polls of the controller applied whole (docs/robot-link.md).
    robot_polls,
    /// Robot link: polls that failed (no connection, a timeout, an exception,
    /// a reply that makes no sense).
    robot_errors,
    /// Robot link: times it went down (3 failed polls in a row, or no connection).
    robot_link_downs,
    /// Modbus/TCP Security: sessions opened after a handshake (docs/tls.md).
    tls_sessions,
    /// Modbus/TCP Security: handshakes that failed (bad bytes, a timeout,
    /// no room in the arena).
    tls_failed,
    /// Modbus/TCP Security: clients refused for their certificate (none,
    /// not from the client CA) or its role (none, or not in `tls.roles`).
    tls_refused,
}

impl Stats {
    /// Adds one to `counter`.
    pub fn count(counter: &AtomicU32) {
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts an exception reply to `function` under its counter.
    pub(crate) fn count_exception(&self, exception: Exception, refused_write: bool) {
        let counter = match exception {
            Exception::IllegalFunction if refused_write => &self.refused_writes,
            Exception::IllegalFunction => &self.bad_function,
            Exception::IllegalDataAddress => &self.bad_address,
            Exception::IllegalDataValue => &self.bad_value,
            Exception::GatewayTargetDeviceFailedToRespond => &self.other_unit,
            Exception::ServerDeviceFailure | Exception::Unknown(_) => return,
        };
        Self::count(counter);
    }
}

impl Counters {
    /// The count Diagnostics' counter sub-function `sub_function` returns
    /// (the module's table), or `None` for a sub-function that returns none.
    pub fn diagnostic(&self, sub_function: Diagnostic) -> Option<u16> {
        let count = match sub_function {
            Diagnostic::ReturnBusMessageCount => self.requests.wrapping_add(self.bad_protocol),
            Diagnostic::ReturnBusCommunicationErrorCount => self.bad_length,
            Diagnostic::ReturnBusExceptionErrorCount => {
                [self.bad_function, self.bad_address, self.bad_value, self.refused_writes, self.other_unit]
                    .into_iter()
                    .fold(0, u32::wrapping_add)
            }
            Diagnostic::ReturnServerMessageCount => self.requests.saturating_sub(self.other_unit),
            Diagnostic::ReturnServerNoResponseCount => self.bad_protocol,
            Diagnostic::ReturnBusCharacterOverrunCount => self.evictions,
            Diagnostic::ReturnQueryData | Diagnostic::ClearCounters | Diagnostic::Unknown(_) => return None,
        };
        Some(count as u16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_reports() {
        let stats = Stats::new();
        Stats::count(&stats.requests);
        Stats::count(&stats.requests);
        stats.count_exception(Exception::IllegalFunction, false);
        stats.count_exception(Exception::IllegalFunction, true);
        stats.count_exception(Exception::IllegalDataAddress, false);
        stats.count_exception(Exception::IllegalDataValue, false);
        stats.count_exception(Exception::GatewayTargetDeviceFailedToRespond, false);
        let c = stats.snapshot();
        assert_eq!(
            (c.requests, c.bad_function, c.refused_writes, c.bad_address, c.bad_value, c.other_unit),
            (2, 1, 1, 1, 1, 1)
        );
        assert_eq!(
            c.to_string(),
            "requests=2 bad_protocol=0 bad_length=0 bad_function=1 bad_address=1 bad_value=1 refused_writes=1 \
             other_unit=1 evictions=0 timeouts=0 refused_connections=0 watchdog_trips=0 robot_polls=0 \
             robot_errors=0 robot_link_downs=0 tls_sessions=0 tls_failed=0 tls_refused=0"
        );
        let mut pairs = Vec::new();
        c.for_each(|name, value| pairs.push(format!("{name}={value}")));
        assert_eq!(pairs.join(" "), c.to_string(), "the same names and order");
    }

    #[test]
    fn clear_sets_every_counter_to_0() {
        let stats = Stats::new();
        let all = |stats: &Stats| {
            let mut values = Vec::new();
            stats.snapshot().for_each(|_, value| values.push(value));
            values
        };
        for (i, counter) in [
            &stats.requests,
            &stats.bad_protocol,
            &stats.bad_length,
            &stats.bad_function,
            &stats.bad_address,
            &stats.bad_value,
            &stats.refused_writes,
            &stats.other_unit,
            &stats.evictions,
            &stats.timeouts,
            &stats.refused_connections,
            &stats.watchdog_trips,
            &stats.robot_polls,
            &stats.robot_errors,
            &stats.robot_link_downs,
            &stats.tls_sessions,
            &stats.tls_failed,
            &stats.tls_refused,
        ]
        .into_iter()
        .enumerate()
        {
            counter.store(i as u32 + 1, Ordering::Relaxed);
        }
        assert!(all(&stats).iter().all(|&v| v > 0), "each counter set: {:?}", all(&stats));
        stats.clear();
        assert_eq!(all(&stats), [0; 18]);
    }

    #[test]
    fn diagnostic_counters_wrap_at_16_bits_and_never_underflow() {
        let c = Counters { requests: 0xffff, bad_protocol: 2, other_unit: 1, ..Counters::default() };
        assert_eq!(c.diagnostic(Diagnostic::ReturnBusMessageCount), Some(1), "0x1_0001 sent as its low 16 bits");
        assert_eq!(c.diagnostic(Diagnostic::ReturnServerMessageCount), Some(0xfffe));
        let odd = Counters { requests: 1, other_unit: 2, ..Counters::default() };
        assert_eq!(odd.diagnostic(Diagnostic::ReturnServerMessageCount), Some(0), "a reader between two counts");
        let wide = Counters { bad_function: u32::MAX, bad_value: 2, ..Counters::default() };
        assert_eq!(wide.diagnostic(Diagnostic::ReturnBusExceptionErrorCount), Some(1));
        for none in [Diagnostic::ReturnQueryData, Diagnostic::ClearCounters, Diagnostic::Unknown(0x10)] {
            assert_eq!(c.diagnostic(none), None, "{none}");
        }
    }
}
