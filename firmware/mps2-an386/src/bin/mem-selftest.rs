//! The on-target test of `m4-mem`, through every entry point the compiler
//! calls: copies, moves and fills of every length from 0 to [`MAX_LEN`]
//! bytes and some long ones, at every offset modulo 8 (the `4` and `8`
//! forms at the offsets they promise); moves over every overlap of up to
//! [`MAX_SHIFT`] bytes either way. After each call the whole buffer is
//! checked against what it must hold, the bytes around the destination
//! included. Runs in QEMU's mps2-an386 (`tests/tests/qemu.rs`); prints how
//! many calls were right, or the first that was not, and exits through
//! semihosting: 0 when every call was right.

#![no_std]
#![no_main]
#![allow(clippy::indexing_slicing, reason = "a test program: an index out of range ends it as failed (exit 102)")]

use core::ptr::{read_volatile, write_volatile};

use cortex_m_rt::{ExceptionFrame, entry, exception};
use m4_mem as _;
use semihosting::println;
use semihosting::process::exit;

unsafe extern "C" {
    fn __aeabi_memcpy(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memcpy4(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memcpy8(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memmove(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memmove4(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memmove8(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memset(dest: *mut u8, n: usize, c: i32);
    fn __aeabi_memset4(dest: *mut u8, n: usize, c: i32);
    fn __aeabi_memset8(dest: *mut u8, n: usize, c: i32);
    fn __aeabi_memclr(dest: *mut u8, n: usize);
    fn __aeabi_memclr4(dest: *mut u8, n: usize);
    fn __aeabi_memclr8(dest: *mut u8, n: usize);
}

/// Every length up to this is tried at every offset.
const MAX_LEN: usize = 80;
/// The longest length tried.
const LONGEST: usize = 1029;
/// Longer lengths, tried at every offset too: whole rounds and tails.
const LONG_LENS: [usize; 5] = [255, 256, 257, 511, LONGEST];
/// Moves are tried with the destination this many bytes before and after
/// the source, and everything between.
const MAX_SHIFT: usize = 9;
/// Bytes before and after the destination that must stay as they were.
const GUARD: usize = 16;
/// Room for the longest call at the largest offset and shift, with guards.
const BUF_LEN: usize = LONGEST + 8 + 2 * MAX_SHIFT + 2 * GUARD;
/// What a buffer holds where nothing may be written: no pattern byte and
/// no fill byte is this.
const UNTOUCHED: u8 = 0xEE;
/// Fill bytes tried with memset (memclr tries 0).
const FILLS: [u8; 2] = [0x5A, 0xFF];
/// QEMU's exit status when a call went wrong, and after a fault.
const EXIT_WRONG: i32 = 1;
const EXIT_FAULT: i32 = 102;

/// A buffer at an address that is a multiple of 8, so that an offset is
/// the alignment.
#[repr(C, align(8))]
struct Buf([u8; BUF_LEN]);

type CopyFn = unsafe extern "C" fn(*mut u8, *const u8, usize);
type SetFn = unsafe extern "C" fn(*mut u8, usize, i32);
type ClrFn = unsafe extern "C" fn(*mut u8, usize);

/// Every length tried.
fn lengths() -> impl Iterator<Item = usize> {
    (0..=MAX_LEN).chain(LONG_LENS)
}

/// Byte `i` of the pattern: 1..=127, not repeating within 127 bytes.
fn pattern(i: usize) -> u8 {
    (i * 29 % 127) as u8 + 1
}

/// Sets every byte of `buf` to `byte(i)`, one volatile store at a time: what
/// a test writes as its reference must not go through the routines under
/// test (which a `fill` or a `copy_from_slice` would call).
fn fill_with(buf: &mut Buf, byte: impl Fn(usize) -> u8) {
    for (i, b) in buf.0.iter_mut().enumerate() {
        // SAFETY: a valid, exclusive reference.
        unsafe { write_volatile(b, byte(i)) };
    }
}

/// Byte `i` of `buf`, read with a volatile load.
fn byte_at(buf: &Buf, i: usize) -> u8 {
    // SAFETY: a valid reference to a byte of the buffer.
    unsafe { read_volatile(&buf.0[i]) }
}

#[entry]
fn main() -> ! {
    let copies: [(&str, CopyFn, usize); 3] =
        [("memcpy", __aeabi_memcpy, 1), ("memcpy4", __aeabi_memcpy4, 4), ("memcpy8", __aeabi_memcpy8, 8)];
    let moves: [(&str, CopyFn, usize); 3] =
        [("memmove", __aeabi_memmove, 1), ("memmove4", __aeabi_memmove4, 4), ("memmove8", __aeabi_memmove8, 8)];
    let sets: [(&str, SetFn, usize); 3] =
        [("memset", __aeabi_memset, 1), ("memset4", __aeabi_memset4, 4), ("memset8", __aeabi_memset8, 8)];
    let clrs: [(&str, ClrFn, usize); 3] =
        [("memclr", __aeabi_memclr, 1), ("memclr4", __aeabi_memclr4, 4), ("memclr8", __aeabi_memclr8, 8)];
    // Each family is one routine here; compiler-builtins' forms are separate functions.
    let one_routine = copies.iter().all(|c| c.1 as usize == copies[0].1 as usize)
        && moves.iter().all(|m| m.1 as usize == moves[0].1 as usize)
        && sets.iter().all(|s| s.1 as usize == sets[0].1 as usize)
        && clrs.iter().all(|c| c.1 as usize == clrs[0].1 as usize);
    if !one_routine {
        println!("mem-selftest: the entry points are not m4-mem's");
        exit(EXIT_WRONG);
    }

    let mut src = Buf([0; BUF_LEN]);
    let mut buf = Buf([0; BUF_LEN]);
    let mut want = Buf([0; BUF_LEN]);
    fill_with(&mut src, pattern);
    let mut calls = 0u32;

    // Copies between two buffers.
    for (name, copy, align) in copies {
        for len in lengths() {
            for src_off in (0..8).step_by(align) {
                for dst_off in (0..8).step_by(align) {
                    let at = GUARD + dst_off;
                    fill_with(&mut buf, |_| UNTOUCHED);
                    fill_with(&mut want, |i| {
                        if (at..at + len).contains(&i) { byte_at(&src, src_off + i - at) } else { UNTOUCHED }
                    });
                    // SAFETY: both ranges lie inside their buffers (BUF_LEN
                    // holds the longest length at the largest offset) and
                    // the buffers are distinct.
                    unsafe { copy(buf.0.as_mut_ptr().add(at), src.0.as_ptr().add(src_off), len) };
                    check(name, len, src_off as isize, dst_off, &buf, &want);
                    calls += 1;
                }
            }
        }
    }

    // Moves within one buffer: the destination `shift` bytes from the source.
    for (name, mv, align) in moves {
        for len in lengths() {
            for src_off in (0..8).step_by(align) {
                for shift in (-(MAX_SHIFT as isize)..=MAX_SHIFT as isize).filter(|s| s.rem_euclid(align as isize) == 0)
                {
                    let from = GUARD + MAX_SHIFT + src_off;
                    let to = from.wrapping_add_signed(shift);
                    let before = |i: usize| if (from..from + len).contains(&i) { pattern(i) } else { UNTOUCHED };
                    fill_with(&mut buf, before);
                    // The source's bytes at the destination; the rest as it was.
                    fill_with(
                        &mut want,
                        |i| if (to..to + len).contains(&i) { pattern(from + i - to) } else { before(i) },
                    );
                    // SAFETY: both ranges lie inside the buffer (BUF_LEN
                    // holds the longest length at the largest offset and
                    // shift); a move may overlap.
                    unsafe {
                        let base = buf.0.as_mut_ptr();
                        mv(base.add(to), base.add(from), len);
                    }
                    check(name, len, shift, src_off, &buf, &want);
                    calls += 1;
                }
            }
        }
    }

    // Fills: memset with each fill byte, memclr with 0.
    for (index, (name, set, align)) in sets.into_iter().enumerate() {
        let (clr_name, clr, _) = clrs[index];
        for len in lengths() {
            for dst_off in (0..8).step_by(align) {
                let at = GUARD + dst_off;
                for fill in FILLS.into_iter().map(Some).chain([None]) {
                    fill_with(&mut buf, |_| UNTOUCHED);
                    fill_with(&mut want, |i| if (at..at + len).contains(&i) { fill.unwrap_or(0) } else { UNTOUCHED });
                    // SAFETY: the range lies inside the buffer.
                    unsafe {
                        let dest = buf.0.as_mut_ptr().add(at);
                        match fill {
                            // The byte in the low eight bits, junk above them, as C's int may carry.
                            Some(byte) => set(dest, len, i32::from(byte) | 0x3700),
                            None => clr(dest, len),
                        }
                    }
                    check(if fill.is_some() { name } else { clr_name }, len, 0, dst_off, &buf, &want);
                    calls += 1;
                }
            }
        }
    }

    println!("mem-selftest: {calls} calls right: copies, moves and fills of 0-{MAX_LEN} and {LONG_LENS:?} bytes");
    exit(0)
}

/// Ends the test if `got` is not `want`, naming the call and the first
/// wrong byte. (The call was external and given the buffer's address: the
/// compiler reads the buffer again after it.)
fn check(name: &str, len: usize, source: isize, dest: usize, got: &Buf, want: &Buf) {
    if let Some(i) = (0..BUF_LEN).find(|&i| byte_at(got, i) != byte_at(want, i)) {
        println!(
            "mem-selftest: {name}({len} bytes, source offset or shift {source}, destination offset {dest}) is \
             wrong at byte {i} of the buffer: {:#04x}, not {:#04x}",
            byte_at(got, i),
            byte_at(want, i)
        );
        exit(EXIT_WRONG);
    }
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    println!("mem-selftest: HardFault at pc {:#010x}", frame.pc());
    exit(EXIT_FAULT)
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    println!("mem-selftest: panicked");
    exit(EXIT_FAULT)
}
