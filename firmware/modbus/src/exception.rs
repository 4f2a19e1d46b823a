//! Exception codes (Modbus Application Protocol V1.1b3, section 7).

code_table! {
    /// A Modbus exception: the protocol's own error vocabulary.
    ///
    /// The PDU parser and the data map return it, so an error becomes a reply
    /// with no mapping layer in between. This server sends only the listed
    /// codes; `Unknown` holds any other code a peer sends.
    pub enum Exception: u8 {
        display: "exception",
        /// The function code is not supported.
        IllegalFunction = 0x01, "illegal function", section "7";
        /// An address in the request is outside the map or may not be used this way.
        IllegalDataAddress = 0x02, "illegal data address", section "7";
        /// A quantity, byte count, length or value is not allowed.
        IllegalDataValue = 0x03, "illegal data value", section "7";
        /// The server failed while executing a valid request.
        ServerDeviceFailure = 0x04, "server device failure", section "7";
        /// The addressed unit does not answer behind this server (gateway use).
        GatewayTargetDeviceFailedToRespond = 0x0B, "gateway target device failed to respond", section "7";
    }
}

impl core::error::Error for Exception {}

#[cfg(test)]
mod tests {
    use super::*;

    /// The codes this server knows, written here independently of the table.
    const LISTED: [u8; 5] = [0x01, 0x02, 0x03, 0x04, 0x0B];

    #[test]
    fn every_code_round_trips() {
        for code in 0..=u8::MAX {
            let exception = Exception::from(code);
            assert_eq!(u8::from(exception), code);
            assert_eq!(exception.code(), code);
        }
    }

    #[test]
    fn unlisted_codes_are_unknown() {
        for code in 0..=u8::MAX {
            let unknown = Exception::from(code) == Exception::Unknown(code);
            assert_eq!(unknown, !LISTED.contains(&code), "{code:#04x}");
        }
        assert_eq!(Exception::from(0x0B), Exception::GatewayTargetDeviceFailedToRespond);
        assert_eq!(Exception::from(0x05), Exception::Unknown(0x05));
    }

    #[test]
    fn display_texts() {
        let text = |code: u8| Exception::from(code).to_string();
        assert_eq!(text(0x01), "exception 01: illegal function");
        assert_eq!(text(0x02), "exception 02: illegal data address");
        assert_eq!(text(0x03), "exception 03: illegal data value");
        assert_eq!(text(0x04), "exception 04: server device failure");
        assert_eq!(text(0x0B), "exception 0b: gateway target device failed to respond");
        assert_eq!(text(0x0A), "exception 0a: unknown");
        assert_eq!(text(0xFF), "exception ff: unknown");
        assert_eq!(Exception::IllegalDataValue.name(), "illegal data value");
    }

    #[test]
    fn is_an_error() {
        fn error(e: impl core::error::Error + Copy + PartialEq) -> impl core::error::Error {
            e
        }
        assert_eq!(error(Exception::ServerDeviceFailure).to_string(), "exception 04: server device failure");
    }
}
