//! The on-target test of `m4-memcpy`: every length from 0 to [`MAX_LEN`]
//! bytes and some long ones, at every pair of source and destination
//! offsets modulo 8, through each of the three entry points the compiler
//! calls. Each copy is checked byte by byte, and so are the bytes around
//! the destination, which must be untouched. Runs in QEMU's mps2-an386
//! (`tests/tests/qemu.rs`); prints what it checked, or the first
//! copy that went wrong, and exits through semihosting: 0 when every copy
//! was right.

#![no_std]
#![no_main]

use cortex_m_rt::{ExceptionFrame, entry, exception};
use m4_memcpy as _;
use semihosting::println;
use semihosting::process::exit;

unsafe extern "C" {
    fn __aeabi_memcpy(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memcpy4(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memcpy8(dest: *mut u8, src: *const u8, n: usize);
}

/// Every length up to this is tried at every alignment.
const MAX_LEN: usize = 80;
/// The longest copy tried.
const LONGEST: usize = 1029;
/// Longer lengths, tried at every alignment too: whole rounds and tails.
const LONG_LENS: [usize; 5] = [255, 256, 257, 511, LONGEST];
/// Bytes before and after the destination that must stay as they were.
const GUARD: usize = 16;
/// Room for the longest copy at the largest offset, with its guards.
const BUF_LEN: usize = LONGEST + 8 + 2 * GUARD;
/// What the destination holds before a copy: no source byte is this.
const UNTOUCHED: u8 = 0xEE;
/// QEMU's exit status when a copy went wrong, and after a fault.
const EXIT_WRONG: i32 = 1;
const EXIT_FAULT: i32 = 102;

/// A buffer at an address that is a multiple of 8, so that an offset is
/// the alignment.
#[repr(C, align(8))]
struct Buf([u8; BUF_LEN]);

type CopyFn = unsafe extern "C" fn(*mut u8, *const u8, usize);

#[entry]
fn main() -> ! {
    let entries: [(&str, CopyFn, usize); 3] = [
        ("__aeabi_memcpy", __aeabi_memcpy, 1),
        ("__aeabi_memcpy4", __aeabi_memcpy4, 4),
        ("__aeabi_memcpy8", __aeabi_memcpy8, 8),
    ];
    // The three are one routine here; compiler-builtins' are three.
    if entries.iter().any(|&(_, f, _)| f as usize != entries[0].1 as usize) {
        println!("memcpy-selftest: the entry points are not m4-memcpy's");
        exit(EXIT_WRONG);
    }
    let mut src = Buf([0; BUF_LEN]);
    let mut dst = Buf([0; BUF_LEN]);
    for (i, byte) in src.0.iter_mut().enumerate() {
        // 1..=127 in a sequence that does not repeat within 127 bytes.
        *byte = (i * 29 % 127) as u8 + 1;
    }
    let mut copies = 0u32;
    for (name, copy, align) in entries {
        for len in (0..=MAX_LEN).chain(LONG_LENS) {
            for src_off in (0..8).step_by(align) {
                for dst_off in (0..8).step_by(align) {
                    let at = GUARD + dst_off;
                    dst.0.fill(UNTOUCHED);
                    // SAFETY: both ranges lie inside their buffers (BUF_LEN
                    // holds the longest length at the largest offset past the
                    // guard) and the buffers do not overlap.
                    unsafe { copy(dst.0.as_mut_ptr().add(at), src.0.as_ptr().add(src_off), len) };
                    if let Some(i) = first_wrong(&dst.0, &src.0, at, src_off, len) {
                        println!(
                            "memcpy-selftest: {name}({len} bytes, source offset {src_off}, destination offset \
                             {dst_off}) is wrong at destination byte {i} (relative to the copy's start: {})",
                            i as isize - at as isize
                        );
                        exit(EXIT_WRONG);
                    }
                    copies += 1;
                }
            }
        }
    }
    println!("memcpy-selftest: {copies} copies right, lengths 0-{MAX_LEN} and {LONG_LENS:?} at every alignment");
    exit(0)
}

/// The first byte of `dst` that is not what copying `len` bytes of `src`
/// from `src_off` to `at` should have left. (The copy is an external call
/// given the buffers' addresses: the compiler reads them again after it.)
fn first_wrong(dst: &[u8; BUF_LEN], src: &[u8; BUF_LEN], at: usize, src_off: usize, len: usize) -> Option<usize> {
    dst.iter().enumerate().position(|(i, &got)| {
        let want = if (at..at + len).contains(&i) { src.get(src_off + i - at).copied() } else { Some(UNTOUCHED) };
        want != Some(got)
    })
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    println!("memcpy-selftest: HardFault at pc {:#010x}", frame.pc());
    exit(EXIT_FAULT)
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    println!("memcpy-selftest: panicked");
    exit(EXIT_FAULT)
}
