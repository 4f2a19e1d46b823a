//! The process image: every holding register's value, and the coil views of them.
//!
//! Reads and writes are checked against [`super::table`] in the order of the
//! Application Protocol's state diagrams (address, then value), and a multiple
//! write is checked in full before anything changes.

use super::table::{self, COILS, CoilView, Encoding, Permission, REGISTER_COUNT, REGISTERS, Update, reg, rows_in};
use crate::modbus::Exception;

/// What a master may write (docs/data-map.md, decision 3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WritePolicy {
    /// Writes to read-only points are acknowledged; the point's source
    /// overwrites them at its next update (at most 100 ms later).
    #[default]
    Seed,
    /// A write that touches a read-only point is exception 02.
    Strict,
}

/// What an accepted write changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Written {
    /// A point that drives hardware (outputs, analog types) was written:
    /// the board must apply [`Image::outputs`](crate::io::Outputs).
    pub outputs: bool,
}

/// The values behind the map. Coils are views of registers, never stored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    registers: [u16; REGISTER_COUNT],
}

impl Default for Image {
    fn default() -> Self {
        Self::new()
    }
}

/// `first..=last` of a request, checked against the end of a space (exception 02).
fn span(start: u16, quantity: usize, count: usize) -> Result<(u16, u16), Exception> {
    let end = usize::from(start).checked_add(quantity).filter(|&end| quantity > 0 && end <= count);
    let last = end.and_then(|end| u16::try_from(end - 1).ok()).ok_or(Exception::IllegalDataAddress)?;
    Ok((start, last))
}

/// The part of a row's run that lies in `first..=last`.
fn overlap(row: (u16, u16), first: u16, last: u16) -> core::ops::RangeInclusive<u16> {
    row.0.max(first)..=row.1.min(last)
}

/// Exception 02 for an address a write may not touch under `policy`.
fn check_writable(access: Permission, policy: WritePolicy) -> Result<(), Exception> {
    match (access, policy) {
        (Permission::Reserved, _) | (Permission::Read, WritePolicy::Strict) => Err(Exception::IllegalDataAddress),
        _ => Ok(()),
    }
}

/// Whether writing a point with this access and update class drives hardware.
fn drives_outputs(access: Permission, update: Update) -> bool {
    access.writable() && update != Update::Master
}

impl Image {
    /// An image at power-up: all zeros, robot NOT READY, versions unset.
    #[allow(clippy::indexing_slicing, reason = "constant index, checked at compile time")]
    pub const fn new() -> Self {
        let mut registers = [0; REGISTER_COUNT];
        registers[reg::ROBOT_STATE as usize] = table::ROBOT_NOT_READY;
        Self { registers }
    }

    /// The value of register `address` (0 outside the map).
    pub fn register(&self, address: u16) -> u16 {
        self.registers.get(usize::from(address)).copied().unwrap_or(0)
    }

    /// The state of coil `address` (off outside the map).
    pub fn coil(&self, address: u16) -> bool {
        table::coil_row(address).is_some_and(|row| self.view(row.view, address - row.first))
    }

    fn view(&self, view: CoilView, offset: u16) -> bool {
        match view {
            CoilView::Reserved => false,
            CoilView::Bit { register, bit } => {
                let bit = u32::from(bit) + u32::from(offset);
                self.register(register).checked_shr(bit).is_some_and(|v| v & 1 != 0)
            }
            CoilView::NonZero { register } => self.register(register) != 0,
            CoilView::Equals { register, on, .. } => self.register(register) == on,
        }
    }

    /// Sets a register from its source (pins, robot, boot); bypasses the
    /// policy. Reserved addresses are left alone: they always read 0.
    pub fn set_register(&mut self, address: u16, value: u16) {
        let reserved = table::register_row(address).is_none_or(|row| row.access == Permission::Reserved);
        if let Some(slot) = self.registers.get_mut(usize::from(address)).filter(|_| !reserved) {
            *slot = value;
        }
    }

    /// Sets consecutive registers from a source.
    pub fn set_registers(&mut self, start: u16, values: &[u16]) {
        for (address, &value) in (start..=u16::MAX).zip(values) {
            self.set_register(address, value);
        }
    }

    /// FC 03: writes `quantity` registers from `start`, big-endian, into `out`.
    pub fn read_registers(&self, start: u16, quantity: u16, out: &mut [u8]) -> Result<usize, Exception> {
        let (first, last) = span(start, usize::from(quantity), REGISTER_COUNT)?;
        let values = self.registers.get(usize::from(first)..=usize::from(last)).ok_or(Exception::IllegalDataAddress)?;
        let out = out.get_mut(..values.len() * 2).ok_or(Exception::ServerDeviceFailure)?;
        // Two registers a step: the boards build this crate at opt-level
        // "z", which does not unroll the loop, and FC 03 x 125 spends most
        // of its handler's time here (BENCHMARKS.md).
        let (pairs, odd) = values.as_chunks::<2>();
        let (out_pairs, out_odd) = out.as_chunks_mut::<4>();
        for (dst, &[a, b]) in out_pairs.iter_mut().zip(pairs) {
            *dst = (u32::from(a.swap_bytes()) | u32::from(b.swap_bytes()) << 16).to_le_bytes();
        }
        if let ([value], Some(dst)) = (odd, out_odd.first_chunk_mut::<2>()) {
            *dst = value.to_be_bytes();
        }
        Ok(values.len() * 2)
    }

    /// FC 01: packs `quantity` coils from `start` into `out`, LSB first.
    pub fn read_coils(&self, start: u16, quantity: u16, out: &mut [u8]) -> Result<usize, Exception> {
        let (first, last) = span(start, usize::from(quantity), table::COIL_COUNT)?;
        let out = out.get_mut(..crate::modbus::pdu::coil_bytes(quantity)).ok_or(Exception::ServerDeviceFailure)?;
        out.fill(0);
        for row in rows_in(&COILS, first, last, |r| (r.first, r.last)) {
            for address in overlap((row.first, row.last), first, last) {
                let index = usize::from(address - first);
                if self.view(row.view, address - row.first)
                    && let Some(byte) = out.get_mut(index / 8)
                {
                    *byte |= 1 << (index % 8);
                }
            }
        }
        Ok(out.len())
    }

    /// FC 06 and FC 10: writes big-endian `values` from `start`, all or nothing.
    pub fn write_registers(&mut self, start: u16, values: &[u8], policy: WritePolicy) -> Result<Written, Exception> {
        let (values, []) = values.as_chunks::<2>() else { return Err(Exception::IllegalDataValue) };
        let (first, last) = span(start, values.len(), REGISTER_COUNT)?;
        let rows = rows_in(&REGISTERS, first, last, |r| (r.first, r.last));
        let value_at = |address: u16| {
            address.checked_sub(first).and_then(|i| values.get(usize::from(i))).map(|v| u16::from_be_bytes(*v))
        };

        let mut written = Written::default();
        for row in rows {
            check_writable(row.access, policy)?;
            written.outputs |= drives_outputs(row.access, row.update);
        }
        let mut analog_type_written = false;
        for row in rows.iter().filter(|row| !row.encoding.accepts_all()) {
            analog_type_written |= row.encoding == Encoding::AnalogType;
            for address in overlap((row.first, row.last), first, last) {
                let value = value_at(address).unwrap_or(0);
                let analog_type = match row.encoding {
                    Encoding::Analog { type_register } => {
                        value_at(type_register).unwrap_or_else(|| self.register(type_register))
                    }
                    _ => 0,
                };
                if !row.encoding.accepts(value, analog_type) {
                    return Err(Exception::IllegalDataValue);
                }
            }
        }

        if analog_type_written {
            // A range change that does not also set the value starts the point at 0,
            // so an old value never lands outside the new range.
            for row in &REGISTERS {
                if let Encoding::Analog { type_register } = row.encoding {
                    let retyped = value_at(type_register).is_some_and(|t| t != self.register(type_register));
                    if retyped && value_at(row.first).is_none() {
                        self.set_register(row.first, 0);
                    }
                }
            }
        }
        let dst =
            self.registers.get_mut(usize::from(first)..=usize::from(last)).ok_or(Exception::IllegalDataAddress)?;
        for (dst, value) in dst.iter_mut().zip(values) {
            *dst = u16::from_be_bytes(*value);
        }
        Ok(written)
    }

    /// FC 05 and FC 0F: writes `quantity` packed coils from `start`, all or nothing.
    pub fn write_coils(
        &mut self,
        start: u16,
        quantity: u16,
        values: &[u8],
        policy: WritePolicy,
    ) -> Result<Written, Exception> {
        let (first, last) = span(start, usize::from(quantity), table::COIL_COUNT)?;
        if values.len() < crate::modbus::pdu::coil_bytes(quantity) {
            return Err(Exception::IllegalDataValue);
        }
        let rows = rows_in(&COILS, first, last, |r| (r.first, r.last));
        let mut written = Written::default();
        for row in rows {
            check_writable(row.access, policy)?;
            written.outputs |= drives_outputs(row.access, row.update);
        }
        // Coil views produce only values their registers accept: nothing can fail now.
        let mut bits = values.iter().flat_map(|byte| (0..8).map(move |bit| byte >> bit & 1 != 0));
        for row in rows {
            for address in overlap((row.first, row.last), first, last) {
                let Some(on) = bits.next() else { break };
                self.write_view(row.view, address - row.first, on);
            }
        }
        Ok(written)
    }

    fn write_view(&mut self, view: CoilView, offset: u16, on: bool) {
        let (register, value) = match view {
            CoilView::Reserved => return,
            CoilView::Bit { register, bit } => {
                let mask = 1u16.checked_shl(u32::from(bit) + u32::from(offset)).unwrap_or(0);
                let old = self.register(register);
                (register, if on { old | mask } else { old & !mask })
            }
            CoilView::NonZero { register } => {
                let old = self.register(register);
                (
                    register,
                    if !on {
                        0
                    } else if old == 0 {
                        1
                    } else {
                        old
                    },
                )
            }
            CoilView::Equals { register, on: value_on, off } => {
                let old = self.register(register);
                (
                    register,
                    if on {
                        value_on
                    } else if old == value_on {
                        off
                    } else {
                        old
                    },
                )
            }
        };
        self.set_register(register, value);
    }
}

#[cfg(test)]
mod tests;
