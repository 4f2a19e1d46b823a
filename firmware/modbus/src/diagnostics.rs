//! Diagnostics (function 08): its sub-functions (Modbus Application Protocol
//! V1.1b3, 6.8 and 6.8.1).
//!
//! ```text
//! request and normal response: | 08 | sub-function (2) | data (N) |
//! ```
//!
//! The spec names them for a serial line; a Modbus TCP server maps the
//! counters to its own (the adapter: `docs/data-map.md`).

code_table! {
    /// A Diagnostics sub-function (V1.1b3, 6.8.1). The sub-functions this
    /// server does not implement are `Unknown`, and answered with exception 01.
    pub enum Diagnostic: u16 {
        display: "diagnostic",
        /// Data: any; the response echoes the request.
        ReturnQueryData = 0x00, "return query data", section "6.8.1";
        /// Data: 0x0000; the response echoes the request.
        ClearCounters = 0x0A, "clear counters and diagnostic register", section "6.8.1";
        /// Data: 0x0000; the response carries the count.
        ReturnBusMessageCount = 0x0B, "return bus message count", section "6.8.1";
        ReturnBusCommunicationErrorCount = 0x0C, "return bus communication error count", section "6.8.1";
        ReturnBusExceptionErrorCount = 0x0D, "return bus exception error count", section "6.8.1";
        ReturnServerMessageCount = 0x0E, "return server message count", section "6.8.1";
        ReturnServerNoResponseCount = 0x0F, "return server no response count", section "6.8.1";
        ReturnBusCharacterOverrunCount = 0x12, "return bus character overrun count", section "6.8.1";
    }
}

/// The data field of every sub-function here but Return Query Data (6.8.1).
pub const ZERO_DATA: [u8; 2] = [0x00, 0x00];
/// Bytes before the data: function code and sub-function.
pub const HEADER_LEN: usize = 3;

impl Diagnostic {
    /// Whether the sub-function returns a counter (0B-0F, 12): its response
    /// data is the count, two bytes.
    pub const fn is_counter(self) -> bool {
        matches!(
            self,
            Self::ReturnBusMessageCount
                | Self::ReturnBusCommunicationErrorCount
                | Self::ReturnBusExceptionErrorCount
                | Self::ReturnServerMessageCount
                | Self::ReturnServerNoResponseCount
                | Self::ReturnBusCharacterOverrunCount
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sub-functions this server implements, written here independently of the table.
    const LISTED: [u16; 8] = [0x00, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x12];

    #[test]
    fn every_code_round_trips_and_only_the_listed_are_known() {
        for code in (0..=0x40).chain([0x0100, 0x0a00, 0x8000, 0xffff]) {
            let sub = Diagnostic::from(code);
            assert_eq!(u16::from(sub), code);
            assert_eq!(sub == Diagnostic::Unknown(code), !LISTED.contains(&code), "{code:#06x}");
        }
    }

    #[test]
    fn counters_are_the_return_count_sub_functions() {
        let counters: Vec<u16> = LISTED.into_iter().filter(|&c| Diagnostic::from(c).is_counter()).collect();
        assert_eq!(counters, [0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x12]);
        assert!(!Diagnostic::Unknown(0x10).is_counter());
    }

    #[test]
    fn display_texts() {
        assert_eq!(Diagnostic::ReturnQueryData.to_string(), "diagnostic 00: return query data");
        assert_eq!(Diagnostic::from(0x12).to_string(), "diagnostic 12: return bus character overrun count");
        assert_eq!(Diagnostic::from(0x0100).to_string(), "diagnostic 100: unknown");
    }
}
