//! The process image against docs/data-map.md, address by address.
//!
//! `SPEC_REGISTERS` and `SPEC_COILS` are written from docs/data-map.md by hand,
//! independently of `table.rs`, so a wrong row in the table fails here
//! instead of agreeing with itself.

use super::*;
use crate::map::table::{coil, reg};

/// `R`: read-only (source-backed), `W`: write-only, `RW`, `-`: reserved.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Spec {
    R,
    W,
    RW,
    Gap,
}
use Spec::{Gap, R, RW, W};

#[rustfmt::skip]
const SPEC_REGISTERS: &[(u16, u16, Spec)] = &[
    (0, 0, R), (1, 1, RW), (2, 3, Gap), (4, 4, R), (5, 5, RW), (6, 6, R), (7, 7, RW), (8, 15, Gap),
    (16, 19, W), (20, 20, Gap), (21, 21, R), (22, 22, W), (23, 127, Gap), (128, 255, RW),
    (256, 264, R), (265, 269, Gap), (270, 275, R), (276, 279, Gap), (280, 285, R), (286, 289, Gap),
    (290, 295, R), (296, 299, Gap), (300, 305, R), (306, 309, Gap), (310, 315, R), (316, 399, Gap),
    (400, 405, R), (406, 409, Gap), (410, 415, R), (416, 419, Gap), (420, 425, R), (426, 429, Gap),
    (430, 435, R),
];

#[rustfmt::skip]
const SPEC_COILS: &[(u16, u16, Spec)] = &[
    (0, 15, R), (16, 31, RW), (32, 37, R), (38, 43, RW), (44, 259, Gap), (260, 265, R),
];

fn spec(table: &[(u16, u16, Spec)], address: u16) -> Spec {
    table.iter().find(|(first, last, _)| (*first..=*last).contains(&address)).map(|row| row.2).unwrap()
}

fn write_register(image: &mut Image, address: u16, value: u16, policy: WritePolicy) -> Result<Written, Exception> {
    image.write_registers(address, &value.to_be_bytes(), policy)
}

fn write_coil(image: &mut Image, address: u16, on: bool, policy: WritePolicy) -> Result<Written, Exception> {
    image.write_coils(address, 1, &[u8::from(on)], policy)
}

fn read_register(image: &Image, address: u16) -> Result<u16, Exception> {
    let mut out = [0u8; 2];
    image.read_registers(address, 1, &mut out)?;
    Ok(u16::from_be_bytes(out))
}

fn read_coil(image: &Image, address: u16) -> Result<bool, Exception> {
    let mut out = [0xa5u8; 1];
    image.read_coils(address, 1, &mut out)?;
    assert_eq!(out[0] & !1, 0, "padding bits are zero");
    Ok(out[0] == 1)
}

/// A value each register accepts that is not 0 (so a write shows), or 0
/// where nothing else is guaranteed valid.
fn valid_nonzero(address: u16) -> u16 {
    match address {
        reg::ANALOG_INPUT_1_TYPE | reg::ANALOG_INPUT_2_TYPE | reg::ANALOG_OUTPUT_1_TYPE | reg::ANALOG_OUTPUT_2_TYPE => {
            1
        }
        reg::ANALOG_INPUT_1 | reg::ANALOG_INPUT_2 | reg::ANALOG_OUTPUT_1 | reg::ANALOG_OUTPUT_2 => 1234,
        reg::TOOL_INPUTS | reg::TOOL_OUTPUTS => 0b10_1010,
        reg::ROBOT_STATE => 6,
        reg::SAFETY_STOP => 2,
        260..=264 => 1,
        _ => 0xbeef,
    }
}

#[test]
fn the_table_matches_data_map_md() {
    for address in 0..=reg::LAST {
        let row = table::register_row(address).unwrap();
        let want = match spec(SPEC_REGISTERS, address) {
            R => Permission::Read,
            W => Permission::Write,
            RW => Permission::ReadWrite,
            Gap => Permission::Reserved,
        };
        assert_eq!(row.access, want, "register {address}");
    }
    for address in 0..=coil::LAST {
        let row = table::coil_row(address).unwrap();
        let want = match spec(SPEC_COILS, address) {
            R => Permission::Read,
            RW => Permission::ReadWrite,
            Gap => Permission::Reserved,
            W => panic!("docs/data-map.md has no write-only coils"),
        };
        assert_eq!(row.access, want, "coil {address}");
    }
}

#[test]
fn every_register_under_both_policies() {
    for address in 0..=reg::LAST {
        let value = valid_nonzero(address);
        for policy in [WritePolicy::Seed, WritePolicy::Strict] {
            let mut image = Image::new();
            let before = image.clone();
            let result = write_register(&mut image, address, value, policy);
            let accepted = !matches!((spec(SPEC_REGISTERS, address), policy), (Gap, _) | (R, WritePolicy::Strict));
            if accepted {
                assert!(result.is_ok(), "register {address} {policy:?}: {result:?}");
                assert_eq!(read_register(&image, address), Ok(value), "register {address} reads back");
            } else {
                assert_eq!(result, Err(Exception::IllegalDataAddress), "register {address} {policy:?}");
                assert_eq!(image, before, "a refused write changes nothing");
                let expect = if address == reg::ROBOT_STATE { table::ROBOT_NOT_READY } else { 0 };
                assert_eq!(read_register(&image, address), Ok(expect));
            }
        }
    }
}

#[test]
fn every_coil_under_both_policies() {
    for address in 0..=coil::LAST {
        for policy in [WritePolicy::Seed, WritePolicy::Strict] {
            let mut image = Image::new();
            let before = image.clone();
            let result = write_coil(&mut image, address, true, policy);
            let accepted = !matches!((spec(SPEC_COILS, address), policy), (Gap, _) | (R, WritePolicy::Strict));
            if accepted {
                assert!(result.is_ok(), "coil {address} {policy:?}: {result:?}");
                assert_eq!(read_coil(&image, address), Ok(true), "coil {address} reads back on");
                assert!(write_coil(&mut image, address, false, policy).is_ok());
                assert_eq!(read_coil(&image, address), Ok(false), "coil {address} reads back off");
            } else {
                assert_eq!(result, Err(Exception::IllegalDataAddress), "coil {address} {policy:?}");
                assert_eq!(image, before);
                assert_eq!(read_coil(&image, address), Ok(false));
            }
        }
    }
}

#[test]
fn reserved_addresses_read_zero_even_in_a_block() {
    let mut image = Image::new();
    for address in 0..=reg::LAST {
        image.set_register(address, 0xffff);
    }
    image.set_register(reg::SAFETY_STOP, 2); // coil 265 is "register 262 == 2"
    let mut out = [0u8; 250];
    for start in (0..=reg::LAST).step_by(125) {
        let quantity = 125.min(reg::LAST + 1 - start);
        let len = image.read_registers(start, quantity, &mut out).unwrap();
        for (i, pair) in out[..len].chunks(2).enumerate() {
            let address = start + i as u16;
            let value = u16::from_be_bytes([pair[0], pair[1]]);
            if spec(SPEC_REGISTERS, address) == Gap {
                assert_eq!(value, 0, "reserved register {address}");
            }
        }
    }
    let mut coils = [0u8; 34];
    assert_eq!(image.read_coils(0, 266, &mut coils), Ok(34));
    for address in 0..=coil::LAST {
        let on = coils[usize::from(address / 8)] >> (address % 8) & 1 == 1;
        assert_eq!(on, spec(SPEC_COILS, address) != Gap, "coil {address}");
    }
    assert_eq!(coils[33] >> 2, 0, "bits past the last coil are padding");
}

#[test]
fn coil_and_register_views_agree() {
    // (first coil, register, pins)
    for (first, register, pins) in [(0u16, reg::DIGITAL_INPUTS, 16u16), (16, 1, 16), (32, 21, 6), (38, 22, 6)] {
        for pin in 0..pins {
            let mut image = Image::new();
            image.set_register(register, 1 << pin);
            for c in first..first + pins {
                assert_eq!(image.coil(c), c == first + pin, "register {register} bit {pin} vs coil {c}");
            }
            let mut image = Image::new();
            write_coil(&mut image, first + pin, true, WritePolicy::Seed).unwrap();
            assert_eq!(
                image.register(register),
                1 << pin,
                "coil {} sets bit {pin} of register {register}",
                first + pin
            );
        }
    }
    // Robot flags: coil 260-264 = register != 0; coil 262 and 265 both from register 262.
    let mut image = Image::new();
    for (safety, c262, c265) in [(0u16, false, false), (1, true, false), (2, true, true)] {
        image.set_register(reg::SAFETY_STOP, safety);
        assert_eq!((image.coil(coil::SAFETY_STOP), image.coil(coil::SAFETY_STOP_RECOVERY)), (c262, c265));
    }
    for (register, c) in [(260, 260), (261, 261), (263, 263), (264, 264)] {
        image.set_register(register, 1);
        assert!(image.coil(c));
        image.set_register(register, 0);
        assert!(!image.coil(c));
    }
    // Under `seed`, writing the recovery coil off leaves "safety stopped" on.
    image.set_register(reg::SAFETY_STOP, 2);
    write_coil(&mut image, coil::SAFETY_STOP_RECOVERY, false, WritePolicy::Seed).unwrap();
    assert_eq!(image.register(reg::SAFETY_STOP), 1);
}

#[test]
fn ranges_end_where_the_spaces_end() {
    let image = Image::new();
    let mut out = [0u8; 250];
    assert!(image.read_registers(reg::LAST, 1, &mut out).is_ok());
    assert!(image.read_registers(reg::LAST + 1 - 125, 125, &mut out).is_ok());
    for (start, quantity) in
        [(reg::LAST, 2), (reg::LAST + 1, 1), (reg::LAST + 2 - 125, 125), (u16::MAX, 1), (u16::MAX, 125)]
    {
        assert_eq!(
            image.read_registers(start, quantity, &mut out),
            Err(Exception::IllegalDataAddress),
            "{start}+{quantity}"
        );
    }
    assert!(image.read_coils(coil::LAST, 1, &mut out).is_ok());
    assert!(image.read_coils(0, 266, &mut out).is_ok());
    for (start, quantity) in [(coil::LAST, 2), (coil::LAST + 1, 1), (0, 267), (0, 2000), (u16::MAX, 2000)] {
        assert_eq!(
            image.read_coils(start, quantity, &mut out),
            Err(Exception::IllegalDataAddress),
            "{start}+{quantity}"
        );
    }
    let mut image = Image::new();
    assert_eq!(write_register(&mut image, reg::LAST + 1, 0, WritePolicy::Seed), Err(Exception::IllegalDataAddress));
    assert_eq!(write_coil(&mut image, coil::LAST + 1, true, WritePolicy::Seed), Err(Exception::IllegalDataAddress));
}

#[test]
fn multiple_writes_are_all_or_nothing() {
    let mut image = Image::new();
    let ones = |n: usize| [0x00u8, 0x01].repeat(n);
    // 128..=255 are writable; 256 is read-only: strict refuses the whole block.
    let before = image.clone();
    assert_eq!(image.write_registers(200, &ones(57), WritePolicy::Strict), Err(Exception::IllegalDataAddress));
    assert_eq!(image, before);
    // A reserved address at the end of a coil block (44): nothing is written.
    assert_eq!(image.write_coils(38, 7, &[0x7f], WritePolicy::Seed), Err(Exception::IllegalDataAddress));
    assert_eq!(image, before);
    // A bad analog value after good ones: nothing is written.
    let values: Vec<u8> = [7u16, 1, 1, 30_000].iter().flat_map(|v| v.to_be_bytes()).collect();
    assert_eq!(image.write_registers(4, &values, WritePolicy::Seed), Err(Exception::IllegalDataValue));
    assert_eq!(image, before);
    // The whole block is fine: all of it lands.
    assert!(image.write_registers(128, &ones(123), WritePolicy::Strict).is_ok());
    assert!((128..251).all(|a| image.register(a) == 1));
    assert!(image.write_coils(16, 16, &[0xff, 0xff], WritePolicy::Strict).is_ok());
    assert_eq!(image.register(reg::DIGITAL_OUTPUTS), 0xffff);
}

#[test]
fn analog_values_follow_their_type() {
    let mut image = Image::new();
    let strict = WritePolicy::Strict;
    // Current (type 0, the default): 0..=20 000 µA.
    assert!(write_register(&mut image, reg::ANALOG_OUTPUT_1, 20_000, strict).is_ok());
    assert_eq!(write_register(&mut image, reg::ANALOG_OUTPUT_1, 20_001, strict), Err(Exception::IllegalDataValue));
    assert_eq!(image.register(reg::ANALOG_OUTPUT_1), 20_000);
    // Changing the type alone starts the value at 0: 20 000 would be 20 V.
    assert!(write_register(&mut image, reg::ANALOG_OUTPUT_1_TYPE, 1, strict).is_ok());
    assert_eq!(image.register(reg::ANALOG_OUTPUT_1), 0);
    assert!(write_register(&mut image, reg::ANALOG_OUTPUT_1, 10_000, strict).is_ok());
    assert_eq!(write_register(&mut image, reg::ANALOG_OUTPUT_1, 10_001, strict), Err(Exception::IllegalDataValue));
    // Type and value in one write: the value is checked against the new type.
    let pair = |value: u16, kind: u16| [value.to_be_bytes(), kind.to_be_bytes()].concat();
    assert_eq!(image.write_registers(reg::ANALOG_OUTPUT_2, &pair(15_000, 1), strict), Err(Exception::IllegalDataValue));
    assert!(image.write_registers(reg::ANALOG_OUTPUT_2, &pair(15_000, 0), strict).is_ok());
    assert_eq!(image.register(reg::ANALOG_OUTPUT_2), 15_000);
    // Only 0 and 1 are types.
    for register in [5, 7, 17, 19] {
        assert_eq!(write_register(&mut image, register, 2, strict), Err(Exception::IllegalDataValue), "{register}");
    }
    // Writing the same type again keeps the value.
    assert!(write_register(&mut image, reg::ANALOG_OUTPUT_2_TYPE, 0, strict).is_ok());
    assert_eq!(image.register(reg::ANALOG_OUTPUT_2), 15_000);
    // A block over both outputs and their types.
    let block: Vec<u8> = [9_000u16, 1, 19_000, 0].iter().flat_map(|v| v.to_be_bytes()).collect();
    assert!(image.write_registers(16, &block, strict).is_ok());
    assert_eq!([16, 17, 18, 19].map(|a| image.register(a)), [9_000, 1, 19_000, 0]);
}

#[test]
fn encoded_points_refuse_values_outside_their_encoding() {
    let mut image = Image::new();
    let seed = WritePolicy::Seed;
    assert_eq!(write_register(&mut image, reg::TOOL_OUTPUTS, 0b100_0000, seed), Err(Exception::IllegalDataValue));
    assert!(write_register(&mut image, reg::TOOL_OUTPUTS, 0b11_1111, seed).is_ok());
    assert!((38..=43).all(|c| image.coil(c)));
    assert!(write_register(&mut image, reg::DIGITAL_OUTPUTS, 0xffff, seed).is_ok());
    // Read-only points written under `seed` still take only values they can hold.
    assert_eq!(write_register(&mut image, reg::ROBOT_STATE, 11, seed), Err(Exception::IllegalDataValue));
    assert!(write_register(&mut image, reg::ROBOT_STATE, 15, seed).is_ok());
    assert_eq!(write_register(&mut image, reg::SAFETY_STOP, 3, seed), Err(Exception::IllegalDataValue));
    assert_eq!(write_register(&mut image, reg::SERVO_ON, 2, seed), Err(Exception::IllegalDataValue));
    assert!(write_register(&mut image, reg::JOINT_POSITION, (-900i16) as u16, seed).is_ok());
}

#[test]
fn writes_say_whether_outputs_must_be_driven() {
    let mut image = Image::new();
    let seed = WritePolicy::Seed;
    let drives = |r: Result<Written, Exception>| r.unwrap().outputs;
    assert!(drives(write_coil(&mut image, 16, true, seed)));
    assert!(drives(write_coil(&mut image, 43, true, seed)));
    assert!(drives(write_register(&mut image, reg::DIGITAL_OUTPUTS, 3, seed)));
    assert!(drives(write_register(&mut image, reg::ANALOG_OUTPUT_2, 5, seed)));
    assert!(drives(write_register(&mut image, reg::ANALOG_INPUT_1_TYPE, 1, seed)), "the input front end's mode");
    assert!(!drives(write_register(&mut image, 128, 5, seed)));
    assert!(!drives(write_register(&mut image, reg::DIGITAL_INPUTS, 5, seed)));
    assert!(!drives(write_coil(&mut image, 0, true, seed)));
}

#[test]
fn power_up_state() {
    let image = Image::new();
    assert_eq!(image.register(reg::ROBOT_STATE), table::ROBOT_NOT_READY);
    assert!((0..=reg::LAST).filter(|&a| a != reg::ROBOT_STATE).all(|a| image.register(a) == 0));
    assert!((0..=coil::LAST).all(|c| !image.coil(c)));
}

#[test]
fn a_block_reads_each_register_big_endian_in_order_for_odd_and_even_counts() {
    let mut image = Image::new();
    let stored = |address: u16| 0x0102u16.wrapping_mul(address).wrapping_add(0x5a0f);
    for address in 0..=reg::LAST {
        image.set_register(address, stored(address));
    }
    let mut out = [0u8; 250];
    for quantity in [1u16, 2, 3, 4, 10, 124, 125] {
        for start in [0, 1, 2, reg::LAST + 1 - quantity] {
            let len = image.read_registers(start, quantity, &mut out).unwrap();
            assert_eq!(len, usize::from(quantity) * 2);
            for (i, pair) in out[..len].chunks(2).enumerate() {
                let address = start + i as u16;
                // A reserved address reads 0 whatever was set.
                let expected = if spec(SPEC_REGISTERS, address) == Gap { 0 } else { stored(address) };
                assert_eq!(
                    u16::from_be_bytes([pair[0], pair[1]]),
                    expected,
                    "register {address} of {start}+{quantity}"
                );
            }
        }
    }
}
