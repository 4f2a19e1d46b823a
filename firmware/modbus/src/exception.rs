//! Exception codes (Modbus Application Protocol V1.1b3, section 7).

use core::fmt;

/// A Modbus exception: the protocol's own error vocabulary.
///
/// The PDU parser and the data map return it, so an error becomes a reply
/// with no mapping layer in between.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Exception {
    /// 01: the function code is not supported (V1.1b3, 7).
    IllegalFunction = 0x01,
    /// 02: an address in the request is outside the map or may not be used this way.
    IllegalDataAddress = 0x02,
    /// 03: a quantity, byte count, length or value is not allowed.
    IllegalDataValue = 0x03,
    /// 04: the server failed while executing a valid request.
    ServerDeviceFailure = 0x04,
    /// 0B: the addressed unit does not answer behind this server (gateway use).
    GatewayTargetDeviceFailedToRespond = 0x0B,
}

impl Exception {
    /// The exception code on the wire.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The exception with code `code`, if this server knows it.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0x01 => Some(Self::IllegalFunction),
            0x02 => Some(Self::IllegalDataAddress),
            0x03 => Some(Self::IllegalDataValue),
            0x04 => Some(Self::ServerDeviceFailure),
            0x0B => Some(Self::GatewayTargetDeviceFailedToRespond),
            _ => None,
        }
    }
}

impl fmt::Display for Exception {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let text = match self {
            Self::IllegalFunction => "illegal function",
            Self::IllegalDataAddress => "illegal data address",
            Self::IllegalDataValue => "illegal data value",
            Self::ServerDeviceFailure => "server device failure",
            Self::GatewayTargetDeviceFailedToRespond => "gateway target device failed to respond",
        };
        write!(f, "exception {:02x}: {}", self.code(), text)
    }
}

impl core::error::Error for Exception {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip() {
        for code in 0..=u8::MAX {
            if let Some(e) = Exception::from_code(code) {
                assert_eq!(e.code(), code);
            }
        }
        assert_eq!(Exception::from_code(0x0B).map(Exception::code), Some(0x0B));
        assert_eq!(Exception::from_code(0x05), None);
    }
}
