//! `__aeabi_memcpy` (and its `4` and `8` forms) for the Cortex-M4: what the
//! compiler calls for every copy it does not inline, which at the images'
//! opt-level `"z"` is nearly every copy, down to a 6-byte MAC address.
//!
//! compiler-builtins' routine, which the images would otherwise take, is
//! written for any ARM core, so it never loads a word from an address that
//! is not a multiple of four: short and misaligned copies go a byte at a
//! time, after its checks. In one Modbus request (FC 03 x 10) the images
//! made 18 copies that cost 1 056 instructions with it, and cost 493 with
//! this one (BENCHMARKS.md). ARMv7-M loads and stores words and halfwords
//! at any address in normal memory (only `LDM`/`STM`/`LDRD`/`STRD` must be
//! aligned, and the core traps unaligned accesses only when
//! `CCR.UNALIGN_TRP` is set, which no image here does). So this one copies
//! two words a round whatever the alignment, then a word, a halfword and a
//! byte as the length says: `n` bytes take 14 + 6 x (n / 8) instructions.
//!
//! compiler-builtins defines its routines as weak symbols, so a board that
//! links this crate (`use m4_memcpy as _;`) gets these instead. They are
//! never used on device memory: the drivers read and write registers and
//! FIFOs with volatile word accesses of their own.
//!
//! Tested on the core it is for: `mps2-an386`'s `memcpy-selftest` binary
//! (its feature `memcpy-selftest`) copies every length from 0 to 80 bytes
//! (and some long ones) at every pair of source and destination alignments
//! and checks each byte and the bytes around it; `tests/tests/qemu.rs` runs
//! it in QEMU.
//!
//! On any other target this crate is empty.

#![no_std]

// The AAPCS lets these clobber r0-r3, r12 and the flags; they return nothing.
// r0 = destination, r1 = source, r2 = length in bytes.
#[cfg(all(target_arch = "arm", target_os = "none"))]
core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    ".section .text.__aeabi_memcpy,\"ax\",%progbits",
    ".global __aeabi_memcpy",
    ".global __aeabi_memcpy4",
    ".global __aeabi_memcpy8",
    ".type __aeabi_memcpy,%function",
    ".type __aeabi_memcpy4,%function",
    ".type __aeabi_memcpy8,%function",
    ".thumb_func",
    "__aeabi_memcpy:",
    ".thumb_func",
    "__aeabi_memcpy4:",
    ".thumb_func",
    "__aeabi_memcpy8:",
    // Eight bytes a round while at least eight are left.
    "    subs   r2, r2, #8",
    "    blo    2f",
    "1:",
    "    ldr    r3, [r1], #4",
    "    ldr    r12, [r1], #4",
    "    str    r3, [r0], #4",
    "    str    r12, [r0], #4",
    "    subs   r2, r2, #8",
    "    bhs    1b",
    // r2 is now (bytes left) - 8, whose low three bits are the bytes left (0-7):
    // bit 2 (a word) into C and bit 1 (a halfword) into N.
    "2:",
    "    lsls   r12, r2, #30",
    "    itt    cs",
    "    ldrcs  r3, [r1], #4",
    "    strcs  r3, [r0], #4",
    "    itt    mi",
    "    ldrhmi r3, [r1], #2",
    "    strhmi r3, [r0], #2",
    // Bit 0 (a byte) into N.
    "    lsls   r12, r2, #31",
    "    itt    mi",
    "    ldrbmi r3, [r1]",
    "    strbmi r3, [r0]",
    "    bx     lr",
    ".size __aeabi_memcpy, . - __aeabi_memcpy",
    ".size __aeabi_memcpy4, . - __aeabi_memcpy4",
    ".size __aeabi_memcpy8, . - __aeabi_memcpy8",
);
