//! One request frame in, one reply frame out: parse, execute, emit.
//!
//! Synchronous and allocation-free; the session calls it with the image
//! locked. This is the per-request cost the benchmarks measure.
//!
//! The map's six functions read and write the image; Read Device
//! Identification answers from the [`Identity`]; Diagnostics echoes, or
//! reads or clears the counters.

use super::Stats;
use super::identity::Identity;
use crate::access::Rights;
use crate::map::{Image, WritePolicy, Written};
use crate::modbus::diagnostics::Diagnostic;
use crate::modbus::mbap::{self, Frame, Header, MAX_ADU_LEN};
use crate::modbus::pdu::{self, EXCEPTION_FLAG};
use crate::modbus::{Exception, FunctionCode, Request, Response};

/// How requests are answered.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Policy {
    /// `None`: answer every unit id. `Some(id)`: answer `id`, 0 and 0xFF, and
    /// reply exception 0B to any other.
    pub unit_id: Option<u8>,
    pub write_policy: WritePolicy,
    /// What the client may do. With [`Rights::Read`] its write functions
    /// (05, 06, 0F, 10) and Diagnostics' Clear Counters ([`pdu::is_write`])
    /// get exception 01, as functions it is not allowed (see [`crate::access`]).
    pub rights: Rights,
}

/// What a request is answered from besides the image: who the device is
/// (Read Device Identification) and its counters (Diagnostics).
#[derive(Clone, Copy, Debug)]
pub struct Context<'a> {
    pub identity: Identity<'a>,
    pub stats: &'a Stats,
}

/// Unit ids a configured server always answers (broadcast-ish 0, and 0xFF,
/// the Implementation Guide's "not significant" id for TCP).
pub const ALWAYS_ANSWERED_UNITS: [u8; 2] = [0x00, 0xFF];

/// What became of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Outcome {
    /// Send the first `len` bytes of the reply buffer. `write`: the request
    /// asks for a change ([`pdu::is_write`]), whether or not it was refused.
    Reply { len: usize, function: FunctionCode, write: bool, written: Written, exception: Option<Exception> },
    /// The protocol id is not Modbus: no reply, the connection carries on.
    Discard { protocol_id: u16 },
    /// The bytes are not one whole frame (its length field and the buffer
    /// disagree). A session never passes such bytes; were it to, it closes
    /// the connection rather than answer what the bytes do not hold.
    NotWhole,
}

/// Answers the request `frame` (exactly one whole MBAP frame) into `reply`.
pub fn respond(
    frame: &[u8],
    reply: &mut [u8; MAX_ADU_LEN],
    image: &mut Image,
    policy: &Policy,
    context: &Context<'_>,
) -> Outcome {
    let request = Frame::new_unchecked(frame);
    let Ok(pdu) = request.pdu() else { return Outcome::NotWhole };
    let header = Header::parse(&request);
    if header.protocol_id != mbap::MODBUS_PROTOCOL_ID {
        return Outcome::Discard { protocol_id: header.protocol_id };
    }
    let code = pdu.first().copied().unwrap_or(0);
    let function = FunctionCode::from(code);
    let write = pdu::is_write(pdu);
    let mut out = Frame::new_unchecked(&mut reply[..]);
    let result = match policy.unit_id {
        Some(id) if header.unit_id != id && !ALWAYS_ANSWERED_UNITS.contains(&header.unit_id) => {
            Err(Exception::GatewayTargetDeviceFailedToRespond)
        }
        _ if !policy.rights.allow(write) => Err(Exception::IllegalFunction),
        _ => execute(pdu, out.payload_mut(), image, policy.write_policy, context),
    };
    let (pdu_len, written, exception) = match result {
        Ok((len, written)) => (len, written, None),
        Err(exception) => {
            let function = code & !EXCEPTION_FLAG;
            let len = Response::Exception { function, exception }.emit(out.payload_mut()).unwrap_or(0);
            (len, Written::default(), Some(exception))
        }
    };
    let len = header.emit(&mut out, pdu_len).unwrap_or(0);
    Outcome::Reply { len, function, write, written, exception }
}

/// Executes a request PDU against the image (or the context); writes the
/// response PDU into `out`.
fn execute(
    pdu: &[u8],
    out: &mut [u8],
    image: &mut Image,
    policy: WritePolicy,
    context: &Context<'_>,
) -> Result<(usize, Written), Exception> {
    let request = Request::parse(pdu)?;
    let nothing = Written::default();
    match request {
        Request::ReadCoils { start, quantity } => {
            let (head, values) = out.split_at_mut_checked(2).ok_or(Exception::ServerDeviceFailure)?;
            let len = image.read_coils(start, quantity, values)?;
            head.copy_from_slice(&[request.function().into(), byte_count(len)?]);
            Ok((2 + len, nothing))
        }
        Request::ReadHoldingRegisters { start, quantity } => {
            let (head, values) = out.split_at_mut_checked(2).ok_or(Exception::ServerDeviceFailure)?;
            let len = image.read_registers(start, quantity, values)?;
            head.copy_from_slice(&[request.function().into(), byte_count(len)?]);
            Ok((2 + len, nothing))
        }
        Request::WriteSingleCoil { address, value } => {
            let written = image.write_coils(address, 1, &[u8::from(value)], policy)?;
            Ok((echo(pdu, out)?, written))
        }
        Request::WriteSingleRegister { address, value } => {
            let written = image.write_registers(address, &value.to_be_bytes(), policy)?;
            Ok((echo(pdu, out)?, written))
        }
        Request::WriteMultipleCoils { start, quantity, values } => {
            let written = image.write_coils(start, quantity, values, policy)?;
            let len = Response::WriteMultipleCoils { start, quantity }.emit(out);
            Ok((len.ok_or(Exception::ServerDeviceFailure)?, written))
        }
        Request::WriteMultipleRegisters { start, quantity, values } => {
            let written = image.write_registers(start, values, policy)?;
            let len = Response::WriteMultipleRegisters { start, quantity }.emit(out);
            Ok((len.ok_or(Exception::ServerDeviceFailure)?, written))
        }
        Request::ReadDeviceIdentification { code, object_id } => {
            Ok((context.identity.respond(code, object_id, out)?, nothing))
        }
        Request::Diagnostics { sub_function: Diagnostic::ReturnQueryData, .. } => Ok((echo(pdu, out)?, nothing)),
        Request::Diagnostics { sub_function: Diagnostic::ClearCounters, .. } => {
            // The clear is answered, then counted as every request is: the
            // next read finds it alone (docs/data-map.md, *Diagnostics*).
            context.stats.clear();
            Ok((echo(pdu, out)?, nothing))
        }
        Request::Diagnostics { sub_function, .. } => {
            let count = context.stats.snapshot().diagnostic(sub_function).ok_or(Exception::IllegalFunction)?;
            let data = count.to_be_bytes();
            let len = Response::Diagnostics { sub_function, data: &data }.emit(out);
            Ok((len.ok_or(Exception::ServerDeviceFailure)?, nothing))
        }
    }
}

fn byte_count(len: usize) -> Result<u8, Exception> {
    u8::try_from(len).map_err(|_| Exception::ServerDeviceFailure)
}

/// A single write's reply is its request, byte for byte (V1.1b3, 6.5 and 6.6).
fn echo(pdu: &[u8], out: &mut [u8]) -> Result<usize, Exception> {
    let dst = out.get_mut(..pdu.len()).ok_or(Exception::ServerDeviceFailure)?;
    dst.copy_from_slice(pdu);
    Ok(pdu.len())
}

/// The largest reply: a 125-register read fits an ADU with room to spare.
const _: () = assert!(2 + 2 * pdu::MAX_READ_REGISTERS as usize <= mbap::MAX_PDU_LEN);

#[cfg(test)]
mod tests;
