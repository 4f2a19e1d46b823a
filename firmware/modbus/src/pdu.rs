//! Protocol data units: requests and responses of the function codes this
//! server implements (Modbus Application Protocol V1.1b3, section 6): the
//! six of the map, Diagnostics (08) and Read Device Identification (2B/0E).
//!
//! Parsing follows the per-function state diagrams: an unknown function code,
//! Diagnostics sub-function or MEI type is exception 01; a quantity, byte
//! count, coil value, read device id code, data field or PDU length that is
//! not allowed is exception 03. Address checks (exception 02, and an unknown
//! object id of Read Device Identification) need the data map or the
//! device's objects and happen when the request is executed.

use core::fmt;

use super::diagnostics::{self, Diagnostic};
use super::identification::{self, MORE_FOLLOWS, Objects, ReadDeviceIdCode};
use super::mbap::MAX_PDU_LEN;
use super::{Exception, be_u16, put_be_u16};

code_table! {
    /// A function code (V1.1b3, 5.1). The codes this server does not
    /// implement are `Unknown`, and answered with exception 01.
    pub enum FunctionCode: u8 {
        display: "function",
        ReadCoils = 0x01, "read coils", section "6.1";
        ReadHoldingRegisters = 0x03, "read holding registers", section "6.3";
        WriteSingleCoil = 0x05, "write single coil", section "6.5";
        WriteSingleRegister = 0x06, "write single register", section "6.6";
        /// Implemented sub-functions: [`Diagnostic`].
        Diagnostics = 0x08, "diagnostics", section "6.8";
        WriteMultipleCoils = 0x0F, "write multiple coils", section "6.11";
        WriteMultipleRegisters = 0x10, "write multiple registers", section "6.12";
        /// Implemented for MEI type 0E, Read Device Identification (6.21), alone.
        EncapsulatedInterfaceTransport = 0x2B, "encapsulated interface transport", section "6.19";
    }
}

/// The one mapping from a message to its function code: [`Request`] and
/// [`Response`] name their variants after their function. Extra arms cover
/// variants that are not named after one.
macro_rules! function_of {
    ($message:expr $(, $other:pat => $value:expr)* $(,)?) => {
        match $message {
            Self::ReadCoils { .. } => FunctionCode::ReadCoils,
            Self::ReadHoldingRegisters { .. } => FunctionCode::ReadHoldingRegisters,
            Self::WriteSingleCoil { .. } => FunctionCode::WriteSingleCoil,
            Self::WriteSingleRegister { .. } => FunctionCode::WriteSingleRegister,
            Self::WriteMultipleCoils { .. } => FunctionCode::WriteMultipleCoils,
            Self::WriteMultipleRegisters { .. } => FunctionCode::WriteMultipleRegisters,
            Self::Diagnostics { .. } => FunctionCode::Diagnostics,
            Self::ReadDeviceIdentification { .. } => FunctionCode::EncapsulatedInterfaceTransport,
            $( $other => $value, )*
        }
    };
}

impl FunctionCode {
    /// Whether the function changes the map (05, 06, 0F, 10).
    pub const fn is_write(self) -> bool {
        matches!(
            self,
            Self::WriteSingleCoil | Self::WriteSingleRegister | Self::WriteMultipleCoils | Self::WriteMultipleRegisters
        )
    }
}

/// Whether the request PDU `pdu` asks the server to change something: a
/// write function ([`FunctionCode::is_write`]) or Diagnostics' Clear
/// Counters. Read from the function code and sub-function alone, before any
/// other check, so that a client that may not change things is refused
/// first, whatever else is wrong with its request.
pub fn is_write(pdu: &[u8]) -> bool {
    match pdu.first().map(|&code| FunctionCode::from(code)) {
        Some(FunctionCode::Diagnostics) => be_u16(pdu, 1).map(Diagnostic::from) == Some(Diagnostic::ClearCounters),
        Some(function) => function.is_write(),
        None => false,
    }
}

/// The bit that marks an exception response's function code.
pub const EXCEPTION_FLAG: u8 = 0x80;
/// Read Coils: most coils in one request (6.1).
pub const MAX_READ_COILS: u16 = 2000;
/// Read Holding Registers: most registers in one request (6.3).
pub const MAX_READ_REGISTERS: u16 = 125;
/// Write Multiple Coils: most coils in one request (6.11).
pub const MAX_WRITE_COILS: u16 = 1968;
/// Write Multiple Registers: most registers in one request (6.12).
pub const MAX_WRITE_REGISTERS: u16 = 123;
/// Write Single Coil: the value that turns a coil on (6.5).
pub const COIL_ON: u16 = 0xFF00;
/// Write Single Coil: the value that turns a coil off (6.5).
pub const COIL_OFF: u16 = 0x0000;

/// Bytes that hold `quantity` packed coils.
pub const fn coil_bytes(quantity: u16) -> usize {
    (quantity as usize).div_ceil(8)
}

/// The two 16-bit fields that are the whole data of a fixed-length PDU.
fn fixed(data: &[u8]) -> Option<(u16, u16)> {
    match *data {
        [a, b, c, d] => Some((u16::from_be_bytes([a, b]), u16::from_be_bytes([c, d]))),
        _ => None,
    }
}

/// `quantity` if it is within `1..=max`.
fn quantity_in(quantity: u16, max: u16) -> Option<u16> {
    (1..=max).contains(&quantity).then_some(quantity)
}

/// A Write Single Coil value: [`COIL_ON`] or [`COIL_OFF`], nothing else (6.5).
fn coil_value(value: u16) -> Option<bool> {
    match value {
        COIL_ON => Some(true),
        COIL_OFF => Some(false),
        _ => None,
    }
}

/// A request PDU. Multiple writes borrow their values from the frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Request<'a> {
    /// Read `quantity` coils from `start`.
    ReadCoils { start: u16, quantity: u16 },
    /// Read `quantity` holding registers from `start`.
    ReadHoldingRegisters { start: u16, quantity: u16 },
    /// Set one coil.
    WriteSingleCoil { address: u16, value: bool },
    /// Set one holding register.
    WriteSingleRegister { address: u16, value: u16 },
    /// Set `quantity` coils from `start`; `values` packs them LSB first.
    WriteMultipleCoils { start: u16, quantity: u16, values: &'a [u8] },
    /// Set `quantity` registers from `start`; `values` holds them big-endian.
    WriteMultipleRegisters { start: u16, quantity: u16, values: &'a [u8] },
    /// Diagnostics: `data` is any for Return Query Data, and
    /// [`diagnostics::ZERO_DATA`] for every other sub-function.
    Diagnostics { sub_function: Diagnostic, data: &'a [u8] },
    /// Read Device Identification: the objects `code` names, from `object_id`.
    ReadDeviceIdentification { code: ReadDeviceIdCode, object_id: u8 },
}

impl<'a> Request<'a> {
    /// Parses a request PDU (function code and data).
    pub fn parse(pdu: &'a [u8]) -> Result<Self, Exception> {
        let (&code, data) = pdu.split_first().ok_or(Exception::IllegalFunction)?;
        // The map's functions start with two 16-bit fields. Whatever a known
        // function's data does not allow is exception 03; an unknown
        // sub-function or MEI type is 01, as an unknown function is.
        let request = match FunctionCode::from(code) {
            FunctionCode::ReadCoils => fixed(data).and_then(|(start, quantity)| {
                Some(Self::ReadCoils { start, quantity: quantity_in(quantity, MAX_READ_COILS)? })
            }),
            FunctionCode::ReadHoldingRegisters => fixed(data).and_then(|(start, quantity)| {
                Some(Self::ReadHoldingRegisters { start, quantity: quantity_in(quantity, MAX_READ_REGISTERS)? })
            }),
            FunctionCode::WriteSingleCoil => fixed(data)
                .and_then(|(address, value)| Some(Self::WriteSingleCoil { address, value: coil_value(value)? })),
            FunctionCode::WriteSingleRegister => {
                fixed(data).map(|(address, value)| Self::WriteSingleRegister { address, value })
            }
            FunctionCode::WriteMultipleCoils => Self::multiple(data).and_then(|(start, quantity, values)| {
                let quantity = quantity_in(quantity, MAX_WRITE_COILS)?;
                (values.len() == coil_bytes(quantity)).then_some(Self::WriteMultipleCoils { start, quantity, values })
            }),
            FunctionCode::WriteMultipleRegisters => Self::multiple(data).and_then(|(start, quantity, values)| {
                let quantity = quantity_in(quantity, MAX_WRITE_REGISTERS)?;
                (values.len() == 2 * usize::from(quantity)).then_some(Self::WriteMultipleRegisters {
                    start,
                    quantity,
                    values,
                })
            }),
            FunctionCode::Diagnostics => {
                let (sub_function, data) = match data.split_at_checked(2) {
                    Some((&[hi, lo], data)) => (Diagnostic::from(u16::from_be_bytes([hi, lo])), data),
                    _ => return Err(Exception::IllegalDataValue),
                };
                match sub_function {
                    Diagnostic::Unknown(_) => return Err(Exception::IllegalFunction),
                    // "Any" data, as long as no ADU is longer than 260 bytes (V1.1b3, 4.1):
                    // the bytes might not come from a frame, and the echo must fit one.
                    Diagnostic::ReturnQueryData => {
                        (pdu.len() <= MAX_PDU_LEN).then_some(Self::Diagnostics { sub_function, data })
                    }
                    _ => (data == diagnostics::ZERO_DATA).then_some(Self::Diagnostics { sub_function, data }),
                }
            }
            FunctionCode::EncapsulatedInterfaceTransport => match *data {
                [identification::MEI_TYPE, ref fields @ ..] => match *fields {
                    [code, object_id] => match ReadDeviceIdCode::from(code) {
                        ReadDeviceIdCode::Unknown(_) => None,
                        code => Some(Self::ReadDeviceIdentification { code, object_id }),
                    },
                    _ => None,
                },
                _ => return Err(Exception::IllegalFunction),
            },
            FunctionCode::Unknown(_) => return Err(Exception::IllegalFunction),
        };
        request.ok_or(Exception::IllegalDataValue)
    }

    /// `start | quantity | byte count | values`, with the byte count matching
    /// the bytes that follow it.
    fn multiple(data: &'a [u8]) -> Option<(u16, u16, &'a [u8])> {
        let start = be_u16(data, 0)?;
        let quantity = be_u16(data, 2)?;
        let (&count, values) = data.get(4..)?.split_first()?;
        (values.len() == usize::from(count)).then_some((start, quantity, values))
    }

    /// The function code of this request.
    pub fn function(&self) -> FunctionCode {
        function_of!(self)
    }

    /// Whether this request changes the map.
    pub fn is_write(&self) -> bool {
        self.function().is_write()
    }

    /// Bytes that [`Request::emit`] writes.
    pub fn buffer_len(&self) -> usize {
        match self {
            Self::WriteMultipleCoils { values, .. } | Self::WriteMultipleRegisters { values, .. } => 6 + values.len(),
            Self::Diagnostics { data, .. } => diagnostics::HEADER_LEN + data.len(),
            Self::ReadDeviceIdentification { .. } => 4,
            _ => 5,
        }
    }

    /// Writes the PDU into `buf`; returns its length, or `None` if `buf` is
    /// shorter than [`Request::buffer_len`] or a value list is too long to count.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        let len = self.buffer_len();
        let out = buf.get_mut(..len)?;
        let (a, b) = match *self {
            Self::Diagnostics { sub_function, data } => {
                let (head, rest) = out.split_at_mut_checked(diagnostics::HEADER_LEN)?;
                let [hi, lo] = sub_function.code().to_be_bytes();
                head.copy_from_slice(&[self.function().into(), hi, lo]);
                rest.copy_from_slice(data);
                return Some(len);
            }
            Self::ReadDeviceIdentification { code, object_id } => {
                let function = self.function().into();
                out.copy_from_slice(&[function, identification::MEI_TYPE, code.into(), object_id]);
                return Some(len);
            }
            Self::ReadCoils { start, quantity }
            | Self::ReadHoldingRegisters { start, quantity }
            | Self::WriteMultipleCoils { start, quantity, .. }
            | Self::WriteMultipleRegisters { start, quantity, .. } => (start, quantity),
            Self::WriteSingleCoil { address, value } => (address, if value { COIL_ON } else { COIL_OFF }),
            Self::WriteSingleRegister { address, value } => (address, value),
        };
        if let Self::WriteMultipleCoils { values, .. } | Self::WriteMultipleRegisters { values, .. } = self {
            let count = u8::try_from(values.len()).ok()?;
            *out.get_mut(5)? = count;
            out.get_mut(6..)?.copy_from_slice(values);
        }
        *out.first_mut()? = self.function().into();
        put_be_u16(out, 1, a);
        put_be_u16(out, 3, b);
        Some(len)
    }
}

/// A response PDU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Response<'a> {
    /// Coil states, packed LSB first, padded with zeros.
    ReadCoils { values: &'a [u8] },
    /// Register values, big-endian.
    ReadHoldingRegisters { values: &'a [u8] },
    /// Echo of a single coil write.
    WriteSingleCoil { address: u16, value: bool },
    /// Echo of a single register write.
    WriteSingleRegister { address: u16, value: u16 },
    /// Acknowledges a multiple coil write.
    WriteMultipleCoils { start: u16, quantity: u16 },
    /// Acknowledges a multiple register write.
    WriteMultipleRegisters { start: u16, quantity: u16 },
    /// Diagnostics: Return Query Data and Clear Counters echo the request;
    /// a counter's `data` is its count, big-endian.
    Diagnostics { sub_function: Diagnostic, data: &'a [u8] },
    /// Read Device Identification: objects of `code`, and where they go on
    /// in a next response if more follow (`next_object_id`).
    ReadDeviceIdentification {
        code: ReadDeviceIdCode,
        conformity: u8,
        next_object_id: Option<u8>,
        objects: Objects<'a>,
    },
    /// Function code (without the exception flag) and the exception.
    Exception { function: u8, exception: Exception },
}

/// A response PDU that is not one this server could have sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Malformed;

impl fmt::Display for Malformed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("malformed response PDU")
    }
}

impl core::error::Error for Malformed {}

impl<'a> Response<'a> {
    /// Parses a response PDU (a client's side; used by tests and tools).
    /// None is longer than an ADU holds ([`MAX_PDU_LEN`]).
    pub fn parse(pdu: &'a [u8]) -> Result<Self, Malformed> {
        if pdu.len() > MAX_PDU_LEN {
            return Err(Malformed);
        }
        let (&code, data) = pdu.split_first().ok_or(Malformed)?;
        if code & EXCEPTION_FLAG != 0 {
            // This server sends only the exceptions it knows.
            let [exception] = *data else { return Err(Malformed) };
            return match Exception::from(exception) {
                Exception::Unknown(_) => Err(Malformed),
                exception => Ok(Self::Exception { function: code & !EXCEPTION_FLAG, exception }),
            };
        }
        let counted = || match data.split_first() {
            Some((&count, values)) if values.len() == usize::from(count) => Ok(values),
            _ => Err(Malformed),
        };
        let fields = || fixed(data).ok_or(Malformed);
        match FunctionCode::from(code) {
            FunctionCode::ReadCoils => Ok(Self::ReadCoils { values: counted()? }),
            FunctionCode::ReadHoldingRegisters => {
                let values = counted()?;
                if values.len() % 2 != 0 {
                    return Err(Malformed);
                }
                Ok(Self::ReadHoldingRegisters { values })
            }
            FunctionCode::WriteSingleCoil => {
                let (address, value) = fields()?;
                Ok(Self::WriteSingleCoil { address, value: coil_value(value).ok_or(Malformed)? })
            }
            FunctionCode::WriteSingleRegister => {
                let (address, value) = fields()?;
                Ok(Self::WriteSingleRegister { address, value })
            }
            FunctionCode::WriteMultipleCoils => {
                let (start, quantity) = fields()?;
                Ok(Self::WriteMultipleCoils { start, quantity })
            }
            FunctionCode::WriteMultipleRegisters => {
                let (start, quantity) = fields()?;
                Ok(Self::WriteMultipleRegisters { start, quantity })
            }
            FunctionCode::Diagnostics => {
                let (&[hi, lo], data) = data.split_at_checked(2).ok_or(Malformed)? else { return Err(Malformed) };
                let sub_function = Diagnostic::from(u16::from_be_bytes([hi, lo]));
                let allowed = match sub_function {
                    Diagnostic::Unknown(_) => false,
                    Diagnostic::ReturnQueryData => true,
                    Diagnostic::ClearCounters => data == diagnostics::ZERO_DATA,
                    _ => data.len() == 2,
                };
                allowed.then_some(Self::Diagnostics { sub_function, data }).ok_or(Malformed)
            }
            FunctionCode::EncapsulatedInterfaceTransport => {
                let (&[mei, code, conformity, more, next, count], objects) =
                    data.split_at_checked(identification::HEADER_LEN - 1).ok_or(Malformed)?
                else {
                    return Err(Malformed);
                };
                if mei != identification::MEI_TYPE {
                    return Err(Malformed);
                }
                let code = match ReadDeviceIdCode::from(code) {
                    ReadDeviceIdCode::Unknown(_) => return Err(Malformed),
                    code => code,
                };
                let next_object_id = match (more, next) {
                    (MORE_FOLLOWS, next) => Some(next),
                    (0x00, 0x00) => None,
                    _ => return Err(Malformed),
                };
                let objects = Objects::parse(count, objects).ok_or(Malformed)?;
                Ok(Self::ReadDeviceIdentification { code, conformity, next_object_id, objects })
            }
            FunctionCode::Unknown(_) => Err(Malformed),
        }
    }

    /// Bytes that [`Response::emit`] writes.
    pub fn buffer_len(&self) -> usize {
        match self {
            Self::ReadCoils { values } | Self::ReadHoldingRegisters { values } => 2 + values.len(),
            Self::Exception { .. } => 2,
            Self::Diagnostics { data, .. } => diagnostics::HEADER_LEN + data.len(),
            Self::ReadDeviceIdentification { objects, .. } => identification::HEADER_LEN + objects.as_bytes().len(),
            _ => 5,
        }
    }

    /// Writes the PDU into `buf`; returns its length, or `None` if it does not fit.
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        // Every response is a head of at most 7 bytes (the function code
        // and fixed fields), then the bytes it carries: one copy of each.
        let code = self.code();
        let (head, head_len, rest): ([u8; 7], usize, &[u8]) = match *self {
            Self::ReadCoils { values } | Self::ReadHoldingRegisters { values } => {
                ([code, u8::try_from(values.len()).ok()?, 0, 0, 0, 0, 0], 2, values)
            }
            Self::Exception { exception, .. } => ([code, exception.code(), 0, 0, 0, 0, 0], 2, &[]),
            Self::WriteSingleCoil { address, value } => {
                fixed_head(code, address, if value { COIL_ON } else { COIL_OFF })
            }
            Self::WriteSingleRegister { address: a, value: b }
            | Self::WriteMultipleCoils { start: a, quantity: b }
            | Self::WriteMultipleRegisters { start: a, quantity: b } => fixed_head(code, a, b),
            Self::Diagnostics { sub_function, data } => {
                let [hi, lo] = sub_function.code().to_be_bytes();
                ([code, hi, lo, 0, 0, 0, 0], diagnostics::HEADER_LEN, data)
            }
            Self::ReadDeviceIdentification { code: read, conformity, next_object_id, objects } => {
                let (more, next) = next_object_id.map_or((0x00, 0x00), |next| (MORE_FOLLOWS, next));
                let head = [code, identification::MEI_TYPE, read.code(), conformity, more, next, objects.count()];
                (head, identification::HEADER_LEN, objects.as_bytes())
            }
        };
        let len = head_len.checked_add(rest.len())?;
        let (out_head, out_rest) = buf.get_mut(..len)?.split_at_mut_checked(head_len)?;
        out_head.copy_from_slice(head.get(..head_len)?);
        out_rest.copy_from_slice(rest);
        Some(len)
    }

    /// The function code byte on the wire.
    fn code(&self) -> u8 {
        function_of!(self, Self::Exception { function, .. } => return function | EXCEPTION_FLAG).code()
    }
}

/// The head of a fixed-length response: the code and two 16-bit fields.
fn fixed_head(code: u8, a: u16, b: u16) -> ([u8; 7], usize, &'static [u8]) {
    let ([a_hi, a_lo], [b_hi, b_lo]) = (a.to_be_bytes(), b.to_be_bytes());
    ([code, a_hi, a_lo, b_hi, b_lo, 0, 0], 5, &[])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mbap::{Frame, HEADER_LEN, MAX_PDU_LEN};
    use test_support::fixtures::{PYMODBUS, PYMODBUS_DEVICE};

    fn pdu(adu: &[u8]) -> &[u8] {
        &adu[HEADER_LEN..]
    }

    #[test]
    fn parses_captured_requests() {
        let parsed: Vec<_> = PYMODBUS.iter().map(|f| Request::parse(pdu(f.request)).unwrap()).collect();
        assert_eq!(
            parsed,
            [
                Request::ReadHoldingRegisters { start: 256, quantity: 3 },
                Request::ReadCoils { start: 16, quantity: 10 },
                Request::WriteSingleCoil { address: 16, value: true },
                Request::WriteSingleRegister { address: 128, value: 0x1234 },
                Request::WriteMultipleCoils { start: 16, quantity: 10, values: &[0x0d, 0x03] },
                Request::WriteMultipleRegisters { start: 128, quantity: 2, values: &[0x00, 0x0a, 0x01, 0x02] },
            ]
        );
    }

    #[test]
    fn requests_and_responses_round_trip() {
        for fixture in &PYMODBUS {
            let request = Request::parse(pdu(fixture.request)).unwrap();
            let mut buf = [0xa5u8; 300];
            let len = request.emit(&mut buf).unwrap();
            assert_eq!(len, request.buffer_len());
            assert_eq!(&buf[..len], pdu(fixture.request), "{}", fixture.name);
            assert_eq!(buf[len], 0xa5, "{}: nothing written past the PDU", fixture.name);

            let response = Response::parse(pdu(fixture.reply)).unwrap();
            let mut buf = [0xa5u8; 300];
            let len = response.emit(&mut buf).unwrap();
            assert_eq!(len, response.buffer_len());
            assert_eq!(&buf[..len], pdu(fixture.reply), "{}", fixture.name);
            assert_eq!(buf[len], 0xa5);
        }
    }

    #[test]
    fn every_prefix_of_every_fixture_is_incomplete_or_an_error() {
        for fixture in &PYMODBUS {
            for n in 0..fixture.request.len() {
                let prefix = &fixture.request[..n];
                assert!(Frame::new_checked(prefix).is_err(), "{} request prefix {n}", fixture.name);
                // The PDU layer alone rejects a cut PDU too.
                let cut = prefix.get(HEADER_LEN..).unwrap_or(&[]);
                assert!(Request::parse(cut).is_err(), "{} request PDU prefix {n}", fixture.name);
            }
            for n in 0..fixture.reply.len() {
                let prefix = &fixture.reply[..n];
                assert!(Frame::new_checked(prefix).is_err(), "{} reply prefix {n}", fixture.name);
                let cut = prefix.get(HEADER_LEN..).unwrap_or(&[]);
                assert!(Response::parse(cut).is_err(), "{} reply PDU prefix {n}", fixture.name);
            }
        }
    }

    #[test]
    fn unknown_and_exception_flagged_codes_are_illegal_function() {
        // 2B here carries MEI type 00, or none: only 0E is implemented.
        for code in [0x00, 0x02, 0x04, 0x07, 0x11, 0x2b, 0x7f, 0x81, 0x83, 0xff] {
            assert_eq!(Request::parse(&[code, 0, 0, 0, 1]), Err(Exception::IllegalFunction), "{code:#x}");
            assert_eq!(Request::parse(&[code]), Err(Exception::IllegalFunction));
        }
        assert_eq!(Request::parse(&[]), Err(Exception::IllegalFunction));
    }

    fn read(code: u8, quantity: u16) -> Result<Request<'static>, Exception> {
        let [hi, lo] = quantity.to_be_bytes();
        Request::parse(Box::leak(Box::new([code, 0, 0, hi, lo])))
    }

    #[test]
    fn read_quantity_limits() {
        for (code, max) in [(0x01, MAX_READ_COILS), (0x03, MAX_READ_REGISTERS)] {
            assert_eq!(read(code, 0), Err(Exception::IllegalDataValue));
            assert!(read(code, 1).is_ok());
            assert!(read(code, max).is_ok());
            assert_eq!(read(code, max + 1), Err(Exception::IllegalDataValue));
            assert_eq!(read(code, u16::MAX), Err(Exception::IllegalDataValue));
        }
    }

    fn write_coils(quantity: u16, count: usize) -> Result<Request<'static>, Exception> {
        let [hi, lo] = quantity.to_be_bytes();
        let mut pdu = vec![0x0f, 0, 0, hi, lo, count as u8];
        pdu.extend(std::iter::repeat_n(0u8, count));
        Request::parse(pdu.leak())
    }

    fn write_registers(quantity: u16, count: usize) -> Result<Request<'static>, Exception> {
        let [hi, lo] = quantity.to_be_bytes();
        let mut pdu = vec![0x10, 0, 0, hi, lo, count as u8];
        pdu.extend(std::iter::repeat_n(0u8, count));
        Request::parse(pdu.leak())
    }

    #[test]
    fn write_multiple_coils_limits() {
        assert_eq!(write_coils(0, 0), Err(Exception::IllegalDataValue));
        assert!(write_coils(1, 1).is_ok());
        assert!(write_coils(8, 1).is_ok());
        assert_eq!(write_coils(9, 1), Err(Exception::IllegalDataValue), "byte count must be ceil(q/8)");
        assert_eq!(write_coils(8, 2), Err(Exception::IllegalDataValue));
        assert!(write_coils(MAX_WRITE_COILS, 246).is_ok());
        assert_eq!(write_coils(MAX_WRITE_COILS + 1, 247), Err(Exception::IllegalDataValue));
    }

    #[test]
    fn write_multiple_registers_limits() {
        assert_eq!(write_registers(0, 0), Err(Exception::IllegalDataValue));
        assert!(write_registers(1, 2).is_ok());
        assert_eq!(write_registers(1, 1), Err(Exception::IllegalDataValue), "byte count must be 2q");
        assert!(write_registers(MAX_WRITE_REGISTERS, 246).is_ok());
        assert_eq!(write_registers(MAX_WRITE_REGISTERS + 1, 248), Err(Exception::IllegalDataValue));
    }

    #[test]
    fn byte_count_must_match_the_bytes_that_follow() {
        // Says 4 bytes, carries 2.
        assert_eq!(Request::parse(&[0x10, 0, 0, 0, 2, 4, 0, 1]), Err(Exception::IllegalDataValue));
        // Says 2 bytes, carries 3.
        assert_eq!(Request::parse(&[0x10, 0, 0, 0, 1, 2, 0, 1, 9]), Err(Exception::IllegalDataValue));
        // No byte count at all.
        assert_eq!(Request::parse(&[0x0f, 0, 0, 0, 1]), Err(Exception::IllegalDataValue));
    }

    #[test]
    fn single_coil_value_is_checked() {
        assert!(Request::parse(&[0x05, 0, 16, 0xff, 0x00]).is_ok());
        assert!(Request::parse(&[0x05, 0, 16, 0x00, 0x00]).is_ok());
        for bad in [[0x00, 0x01], [0xff, 0xff], [0x01, 0x00], [0xff, 0x01]] {
            assert_eq!(Request::parse(&[0x05, 0, 16, bad[0], bad[1]]), Err(Exception::IllegalDataValue));
        }
        // Checked before the address: even a far address gets 03 for a bad value.
        assert_eq!(Request::parse(&[0x05, 0xff, 0xff, 0x12, 0x34]), Err(Exception::IllegalDataValue));
    }

    #[test]
    fn fixed_length_pdus_must_be_exact() {
        for code in [0x01, 0x03, 0x05, 0x06] {
            assert_eq!(Request::parse(&[code, 0, 0, 0]), Err(Exception::IllegalDataValue));
            assert_eq!(Request::parse(&[code, 0, 0, 0, 1, 0]), Err(Exception::IllegalDataValue));
        }
    }

    #[test]
    fn exception_responses() {
        let mut buf = [0xa5u8; 4];
        let response = Response::Exception { function: 0x03, exception: Exception::IllegalDataAddress };
        assert_eq!(response.emit(&mut buf), Some(2));
        assert_eq!(buf, [0x83, 0x02, 0xa5, 0xa5]);
        assert_eq!(Response::parse(&buf[..2]), Ok(response));
        assert_eq!(Response::parse(&[0x83, 0x09]), Err(Malformed));
        assert_eq!(Response::parse(&[0x83]), Err(Malformed));
    }

    #[test]
    fn emit_refuses_short_buffers() {
        let request = Request::WriteMultipleRegisters { start: 0, quantity: 2, values: &[0, 1, 0, 2] };
        let mut short = [0u8; 9];
        assert_eq!(request.emit(&mut short), None);
        let response = Response::ReadHoldingRegisters { values: &[0; 250] };
        assert_eq!(response.emit(&mut [0u8; 251]), None);
        assert_eq!(response.emit(&mut [0u8; 252]), Some(252));
    }

    #[test]
    fn function_codes_round_trip() {
        for code in 0..=u8::MAX {
            let function = FunctionCode::from(code);
            assert_eq!(u8::from(function), code);
            assert_eq!(function.code(), code);
        }
    }

    #[test]
    fn unlisted_function_codes_are_unknown() {
        const LISTED: [u8; 8] = [0x01, 0x03, 0x05, 0x06, 0x08, 0x0F, 0x10, 0x2B];
        for code in 0..=u8::MAX {
            let unknown = FunctionCode::from(code) == FunctionCode::Unknown(code);
            assert_eq!(unknown, !LISTED.contains(&code), "{code:#04x}");
        }
        assert_eq!(FunctionCode::from(0x0F), FunctionCode::WriteMultipleCoils);
        assert_eq!(FunctionCode::from(0x83), FunctionCode::Unknown(0x83));
    }

    #[test]
    fn function_code_display_texts() {
        let text = |code: u8| FunctionCode::from(code).to_string();
        assert_eq!(text(0x01), "function 01: read coils");
        assert_eq!(text(0x03), "function 03: read holding registers");
        assert_eq!(text(0x05), "function 05: write single coil");
        assert_eq!(text(0x06), "function 06: write single register");
        assert_eq!(text(0x0F), "function 0f: write multiple coils");
        assert_eq!(text(0x10), "function 10: write multiple registers");
        assert_eq!(text(0x08), "function 08: diagnostics");
        assert_eq!(text(0x2B), "function 2b: encapsulated interface transport");
        assert_eq!(text(0x07), "function 07: unknown");
        assert_eq!(FunctionCode::WriteSingleCoil.name(), "write single coil");
    }

    #[test]
    fn messages_carry_their_function_code() {
        for fixture in &PYMODBUS {
            let request = Request::parse(pdu(fixture.request)).unwrap();
            assert_eq!(u8::from(request.function()), pdu(fixture.request)[0], "{}", fixture.name);
            let response = Response::parse(pdu(fixture.reply)).unwrap();
            assert_eq!(response.code(), pdu(fixture.reply)[0], "{}", fixture.name);
        }
        let refusal = Response::Exception { function: 0x2B, exception: Exception::IllegalFunction };
        assert_eq!(refusal.code(), 0xAB);
    }

    #[test]
    fn unknown_exception_codes_are_not_a_reply_of_this_server() {
        for code in [0x00, 0x05, 0x0A, 0x0C, 0xFF] {
            assert_eq!(Response::parse(&[0x83, code]), Err(Malformed), "{code:#04x}");
        }
        // But an unknown exception still emits as it is.
        let mut buf = [0xa5u8; 3];
        let response = Response::Exception { function: 0x03, exception: Exception::Unknown(0x0A) };
        assert_eq!(response.emit(&mut buf), Some(2));
        assert_eq!(buf, [0x83, 0x0A, 0xa5]);
    }

    #[test]
    fn parses_captured_device_requests() {
        let parsed: Vec<_> = PYMODBUS_DEVICE.iter().map(|f| Request::parse(pdu(f.request)).unwrap()).collect();
        use Diagnostic::{ClearCounters, ReturnBusMessageCount, ReturnQueryData};
        use ReadDeviceIdCode::{Basic, Regular, Specific};
        assert_eq!(
            parsed,
            [
                Request::ReadDeviceIdentification { code: Basic, object_id: 0 },
                Request::ReadDeviceIdentification { code: Regular, object_id: 0 },
                Request::ReadDeviceIdentification { code: Specific, object_id: 5 },
                Request::Diagnostics { sub_function: ReturnQueryData, data: &[0x12, 0x34] },
                Request::Diagnostics { sub_function: ClearCounters, data: &[0, 0] },
                Request::Diagnostics { sub_function: ReturnBusMessageCount, data: &[0, 0] },
            ]
        );
    }

    #[test]
    fn parses_captured_device_replies() {
        let reply = |i: usize| Response::parse(pdu(PYMODBUS_DEVICE[i].reply)).unwrap();
        let Response::ReadDeviceIdentification { code, conformity, next_object_id, objects } = reply(1) else {
            panic!("{:?}", reply(1))
        };
        assert_eq!((code, conformity, next_object_id, objects.count()), (ReadDeviceIdCode::Regular, 0x83, None, 6));
        let ids: Vec<u8> = objects.iter().map(|(id, _)| id).collect();
        assert_eq!(ids, [0, 1, 2, 4, 5, 6]);
        assert_eq!(objects.iter().nth(2), Some((2, &b"3.16.1"[..])));
        let data = [0x12, 0x34];
        assert_eq!(reply(3), Response::Diagnostics { sub_function: Diagnostic::ReturnQueryData, data: &data });
        let count = [0, 0];
        assert_eq!(reply(5), Response::Diagnostics { sub_function: Diagnostic::ReturnBusMessageCount, data: &count });
    }

    #[test]
    fn device_requests_and_replies_round_trip() {
        for fixture in &PYMODBUS_DEVICE {
            let request = Request::parse(pdu(fixture.request)).unwrap();
            assert_eq!(request.function().code(), pdu(fixture.request)[0]);
            assert!(!request.is_write(), "{}", fixture.name);
            let mut buf = [0xa5u8; 300];
            let len = request.emit(&mut buf).unwrap();
            assert_eq!(len, request.buffer_len());
            assert_eq!(&buf[..len], pdu(fixture.request), "{}", fixture.name);
            assert_eq!(buf[len], 0xa5, "{}: nothing written past the PDU", fixture.name);

            let response = Response::parse(pdu(fixture.reply)).unwrap();
            assert_eq!(response.code(), pdu(fixture.reply)[0]);
            let mut buf = [0xa5u8; 300];
            let len = response.emit(&mut buf).unwrap();
            assert_eq!(len, response.buffer_len());
            assert_eq!(&buf[..len], pdu(fixture.reply), "{}", fixture.name);
            assert_eq!(buf[len], 0xa5);
            assert_eq!(response.emit(&mut buf[..len - 1]), None, "{}: a short buffer", fixture.name);
        }
    }

    /// Return Query Data takes any data (6.8.1), so a cut one is a shorter
    /// query: the cut PDU parses as exactly the bytes it still holds.
    fn cut_query_data(cut: &[u8]) -> bool {
        matches!(cut, [0x08, 0x00, 0x00, data @ ..]
            if Request::parse(cut) == Ok(Request::Diagnostics { sub_function: Diagnostic::ReturnQueryData, data })
            && Response::parse(cut) == Ok(Response::Diagnostics { sub_function: Diagnostic::ReturnQueryData, data }))
    }

    #[test]
    fn every_prefix_of_every_device_fixture_is_incomplete_or_an_error() {
        for fixture in &PYMODBUS_DEVICE {
            for (message, bytes) in [("request", fixture.request), ("reply", fixture.reply)] {
                for n in 0..bytes.len() {
                    let prefix = &bytes[..n];
                    assert!(Frame::new_checked(prefix).is_err(), "{} {message} prefix {n}", fixture.name);
                    let cut = prefix.get(HEADER_LEN..).unwrap_or(&[]);
                    let refused =
                        if message == "request" { Request::parse(cut).is_err() } else { Response::parse(cut).is_err() };
                    assert!(refused || cut_query_data(cut), "{} {message} PDU prefix {n}: {cut:02x?}", fixture.name);
                }
            }
        }
    }

    #[test]
    fn diagnostics_sub_functions_and_their_data() {
        let request = |sub: u16, data: &[u8]| {
            let mut pdu = vec![0x08];
            pdu.extend(sub.to_be_bytes());
            pdu.extend(data);
            Request::parse(pdu.leak())
        };
        for sub in [0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x12] {
            let sub_function = Diagnostic::from(sub);
            assert_eq!(request(sub, &[0, 0]), Ok(Request::Diagnostics { sub_function, data: &[0, 0] }), "{sub:#x}");
            // Their data is 0x0000 and nothing else (6.8.1): 03.
            for data in [&[][..], &[0], &[0, 1], &[1, 0], &[0, 0, 0], &[0xff, 0xff]] {
                assert_eq!(request(sub, data), Err(Exception::IllegalDataValue), "{sub:#x} {data:02x?}");
            }
        }
        // Return Query Data echoes any data, none up to the largest PDU; not
        // beyond it (found by the codec fuzz target: an echo must fit a reply).
        for len in [0, 1, 2, 3, MAX_PDU_LEN - 3] {
            let data = vec![0x5a; len];
            let parsed = request(0x00, &data).unwrap();
            assert_eq!(parsed, Request::Diagnostics { sub_function: Diagnostic::ReturnQueryData, data: &data });
            assert_eq!(parsed.buffer_len(), 3 + len);
        }
        for len in [MAX_PDU_LEN - 2, 312] {
            assert_eq!(request(0x00, &vec![0; len]), Err(Exception::IllegalDataValue), "{len} bytes of data");
        }
        let longest = [&[0x08, 0x00, 0x00][..], &[0u8; MAX_PDU_LEN - 3]].concat();
        assert!(Response::parse(&longest).is_ok());
        let longer = [&longest[..], &[0]].concat();
        assert_eq!(Response::parse(&longer), Err(Malformed), "a reply no ADU holds");
        // Every other sub-function is not implemented: 01, whatever its data.
        for sub in [0x01, 0x02, 0x03, 0x04, 0x10, 0x11, 0x13, 0x14, 0x15, 0x0100, 0x0a00, 0xffff] {
            assert_eq!(request(sub, &[0, 0]), Err(Exception::IllegalFunction), "{sub:#06x}");
            assert_eq!(request(sub, &[]), Err(Exception::IllegalFunction), "{sub:#06x} without data");
        }
        // No whole sub-function: 03.
        assert_eq!(Request::parse(&[0x08]), Err(Exception::IllegalDataValue));
        assert_eq!(Request::parse(&[0x08, 0x00]), Err(Exception::IllegalDataValue));
    }

    #[test]
    fn read_device_identification_fields() {
        let request = |pdu: &'static [u8]| Request::parse(pdu);
        assert_eq!(
            request(&[0x2b, 0x0e, 0x02, 0x06]),
            Ok(Request::ReadDeviceIdentification { code: ReadDeviceIdCode::Regular, object_id: 6 })
        );
        // Any object id parses: which objects exist is the server's to say (02).
        for object_id in [0x00, 0x07, 0x7f, 0x80, 0xff] {
            let parsed = Request::parse(Box::leak(Box::new([0x2b, 0x0e, 0x04, object_id])));
            assert_eq!(parsed, Ok(Request::ReadDeviceIdentification { code: ReadDeviceIdCode::Specific, object_id }));
        }
        // Another MEI type (0D is CANopen's), or none: not implemented, 01.
        for pdu in [&[0x2b, 0x0d, 0x01, 0x00][..], &[0x2b, 0x00, 0x01, 0x00], &[0x2b, 0xff], &[0x2b]] {
            assert_eq!(Request::parse(pdu), Err(Exception::IllegalFunction), "{pdu:02x?}");
        }
        // A read device id code other than 01 to 04: 03. (03 parses: whether the
        // device has extended objects is the server's to say.)
        for code in [0x00, 0x05, 0x80, 0xff] {
            let pdu = Box::leak(Box::new([0x2b, 0x0e, code, 0x00]));
            assert_eq!(Request::parse(pdu), Err(Exception::IllegalDataValue), "code {code:#04x}");
        }
        // Exactly four bytes: 03 otherwise (the MEI type is checked first).
        assert_eq!(request(&[0x2b, 0x0e]), Err(Exception::IllegalDataValue));
        assert_eq!(request(&[0x2b, 0x0e, 0x01]), Err(Exception::IllegalDataValue));
        assert_eq!(request(&[0x2b, 0x0e, 0x01, 0x00, 0x00]), Err(Exception::IllegalDataValue));
        assert_eq!(request(&[0x2b, 0x0d, 0x01, 0x00, 0x00]), Err(Exception::IllegalFunction));
    }

    #[test]
    fn device_replies_this_server_could_not_have_sent_are_malformed() {
        #[rustfmt::skip]
        let malformed: [&[u8]; 13] = [
            &[0x08, 0x00, 0x01, 0x00, 0x00],        // an unknown sub-function
            &[0x08, 0x00, 0x0a, 0x00, 0x01],        // a clear that is not 0000
            &[0x08, 0x00, 0x0b, 0x00],              // a count of one byte
            &[0x08, 0x00, 0x0b, 0x00, 0x00, 0x00],  // and of three
            &[0x08, 0x00],                          // no whole sub-function
            &[0x2b, 0x0d, 0x01, 0x82, 0x00, 0x00, 0x00],       // another MEI type
            &[0x2b, 0x0e, 0x05, 0x82, 0x00, 0x00, 0x00],       // read device id code 05
            &[0x2b, 0x0e, 0x01, 0x82, 0x01, 0x00, 0x00],       // more follows neither 00 nor FF
            &[0x2b, 0x0e, 0x01, 0x82, 0x00, 0x03, 0x00],       // a next object id without more
            &[0x2b, 0x0e, 0x01, 0x82, 0x00, 0x00, 0x01],       // an object missing
            &[0x2b, 0x0e, 0x01, 0x82, 0x00, 0x00, 0x00, 0x00], // a byte left over
            &[0x2b, 0x0e, 0x01, 0x82, 0x00, 0x00, 0x01, 0x00, 0x02, b'a'], // a value cut short
            &[0x2b, 0x0e, 0x01, 0x82, 0x00, 0x00],             // no object count
        ];
        for pdu in malformed {
            assert_eq!(Response::parse(pdu), Err(Malformed), "{pdu:02x?}");
        }
        // More follows, from object 3, with no object in this one.
        let more = [0x2b, 0x0e, 0x02, 0x82, 0xff, 0x03, 0x00];
        let parsed = Response::parse(&more).unwrap();
        assert!(matches!(parsed, Response::ReadDeviceIdentification { next_object_id: Some(3), .. }));
        let mut buf = [0xa5u8; 8];
        assert_eq!(parsed.emit(&mut buf), Some(7));
        assert_eq!(buf[..7], more);
    }

    #[test]
    fn a_write_is_a_write_function_or_clear_counters() {
        for fixture in &PYMODBUS {
            assert_eq!(is_write(pdu(fixture.request)), fixture.request[7] != 0x01 && fixture.request[7] != 0x03);
        }
        assert!(is_write(&[0x08, 0x00, 0x0a, 0x00, 0x00]));
        assert!(is_write(&[0x08, 0x00, 0x0a]), "whatever its data");
        assert!(is_write(&[0x05]), "whatever its fields");
        for pdu in [&[0x08, 0x00, 0x00, 0x12][..], &[0x08, 0x00, 0x0b, 0, 0], &[0x08, 0x00], &[0x08], &[0x2b, 0x0e]] {
            assert!(!is_write(pdu), "{pdu:02x?}");
        }
        assert!(!is_write(&[]));
        assert!(!is_write(&[0x85, 0x00]), "an exception-flagged code is no write");
    }
}
