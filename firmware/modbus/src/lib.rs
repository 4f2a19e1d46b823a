//! The Modbus TCP wire format: bytes in, values out, and back. No I/O, no async.
//!
//! Contract (as smoltcp's `wire`): once a constructor's length check passes, no
//! accessor panics; `parse` never panics on any input; `emit` never panics on a
//! buffer of at least `buffer_len()` bytes.
#![cfg_attr(not(test), no_std)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

#[macro_use]
mod macros;

pub mod client;
pub mod diagnostics;
pub mod exception;
pub mod identification;
pub mod mbap;
pub mod pdu;

pub use exception::Exception;
pub use pdu::{FunctionCode, Request, Response};

/// Reads a big-endian `u16` at `offset`, or `None` past the end of `bytes`.
#[inline]
pub fn be_u16(bytes: &[u8], offset: usize) -> Option<u16> {
    match bytes.get(offset..offset.checked_add(2)?)? {
        [hi, lo] => Some(u16::from_be_bytes([*hi, *lo])),
        _ => None,
    }
}

/// Writes `value` big-endian at `offset`; bytes past the end of `bytes` are not written.
#[inline]
pub fn put_be_u16(bytes: &mut [u8], offset: usize, value: u16) {
    if let Some(dst) = bytes.get_mut(offset..offset.saturating_add(2)) {
        dst.copy_from_slice(&value.to_be_bytes());
    }
}
