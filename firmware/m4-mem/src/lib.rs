//! `__aeabi_memcpy`, `__aeabi_memmove`, `__aeabi_memset` and
//! `__aeabi_memclr` (each with its `4` and `8` forms) for the Cortex-M4:
//! what the compiler calls for every copy or fill it does not inline, which
//! at the images' opt-level `"z"` is nearly every one, down to a 6-byte MAC
//! address.
//!
//! compiler-builtins' routines, which the images would otherwise take, are
//! written for any ARM core, so they never load a word from an address that
//! is not a multiple of four: short and misaligned copies go a byte at a
//! time, after their checks. In one Modbus request (FC 03 x 10) the images
//! made 18 copies that cost 1 056 instructions with them, and cost 493 with
//! these (BENCHMARKS.md); the images are also about 3 KiB smaller, as
//! compiler-builtins' `memmove` alone is 1.5 KiB. ARMv7-M loads and stores
//! words and halfwords at any address in normal memory (only
//! `LDM`/`STM`/`LDRD`/`STRD` must be aligned, and the core traps unaligned
//! accesses only when `CCR.UNALIGN_TRP` is set, which no image here does).
//! So these move two words a round whatever the alignment, then a word, a
//! halfword and a byte as the length says: a copy of `n` bytes takes
//! 14 + 6 x (n / 8) instructions, a fill 14 + 4 x (n / 8).
//!
//! - `memcpy`: forwards.
//! - `memmove`: forwards when the destination is below the source or past
//!   its end (then forwards is right), else backwards from the end, loading
//!   each pair of words before storing it, so no byte is overwritten before
//!   it is read.
//! - `memset`, `memclr` (`memset` with 0): the byte spread over a word.
//!
//! compiler-builtins defines its routines as weak symbols, so a board that
//! links this crate (`use m4_mem as _;`) gets these instead. They are
//! never used on device memory: the drivers read and write registers and
//! FIFOs with volatile word accesses of their own.
//!
//! Tested on the core they are for: `mps2-an386`'s `mem-selftest` binary
//! (its feature `mem-selftest`) runs every length from 0 to 80 bytes and
//! some long ones at every alignment through every entry point: copies,
//! moves over every overlap of up to 9 bytes either way, and fills, and
//! checks each byte and the bytes around it; `tests/tests/qemu.rs` runs it
//! in QEMU.
//!
//! On any other target this crate is empty.

#![no_std]

// The AAPCS lets these clobber r0-r3, r12 and the flags; they return
// nothing. Copies: r0 = destination, r1 = source, r2 = length in bytes.
// memmove is in memcpy's section: it ends in memcpy when forwards is right.
#[cfg(all(target_arch = "arm", target_os = "none"))]
core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    ".section .text.m4_mem_copy,\"ax\",%progbits",
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
    //
    ".global __aeabi_memmove",
    ".global __aeabi_memmove4",
    ".global __aeabi_memmove8",
    ".type __aeabi_memmove,%function",
    ".type __aeabi_memmove4,%function",
    ".type __aeabi_memmove8,%function",
    ".thumb_func",
    "__aeabi_memmove:",
    ".thumb_func",
    "__aeabi_memmove4:",
    ".thumb_func",
    "__aeabi_memmove8:",
    // destination - source, unsigned, is at least the length when the
    // destination is below the source (it wraps) or past the source's end.
    "    subs   r3, r0, r1",
    "    cmp    r3, r2",
    "    bhs    __aeabi_memcpy",
    // Backwards, from the ends.
    "    add    r0, r0, r2",
    "    add    r1, r1, r2",
    "    subs   r2, r2, #8",
    "    blo    4f",
    "3:",
    "    ldr    r3, [r1, #-4]!",
    "    ldr    r12, [r1, #-4]!",
    "    str    r3, [r0, #-4]!",
    "    str    r12, [r0, #-4]!",
    "    subs   r2, r2, #8",
    "    bhs    3b",
    "4:",
    "    lsls   r12, r2, #30",
    "    itt    cs",
    "    ldrcs  r3, [r1, #-4]!",
    "    strcs  r3, [r0, #-4]!",
    "    itt    mi",
    "    ldrhmi r3, [r1, #-2]!",
    "    strhmi r3, [r0, #-2]!",
    "    lsls   r12, r2, #31",
    "    itt    mi",
    "    ldrbmi r3, [r1, #-1]",
    "    strbmi r3, [r0, #-1]",
    "    bx     lr",
    ".size __aeabi_memmove, . - __aeabi_memmove",
    ".size __aeabi_memmove4, . - __aeabi_memmove4",
    ".size __aeabi_memmove8, . - __aeabi_memmove8",
);

// Fills: r0 = destination, r1 = length in bytes, r2 = the byte (memset;
// the RTABI's order, not C's); memclr is memset with 0.
#[cfg(all(target_arch = "arm", target_os = "none"))]
core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    ".section .text.m4_mem_fill,\"ax\",%progbits",
    ".global __aeabi_memclr",
    ".global __aeabi_memclr4",
    ".global __aeabi_memclr8",
    ".global __aeabi_memset",
    ".global __aeabi_memset4",
    ".global __aeabi_memset8",
    ".type __aeabi_memclr,%function",
    ".type __aeabi_memclr4,%function",
    ".type __aeabi_memclr8,%function",
    ".type __aeabi_memset,%function",
    ".type __aeabi_memset4,%function",
    ".type __aeabi_memset8,%function",
    ".thumb_func",
    "__aeabi_memclr:",
    ".thumb_func",
    "__aeabi_memclr4:",
    ".thumb_func",
    "__aeabi_memclr8:",
    "    movs   r2, #0",
    ".thumb_func",
    "__aeabi_memset:",
    ".thumb_func",
    "__aeabi_memset4:",
    ".thumb_func",
    "__aeabi_memset8:",
    // The byte in all four of a word's bytes.
    "    uxtb   r2, r2",
    "    orr    r2, r2, r2, lsl #8",
    "    orr    r2, r2, r2, lsl #16",
    "    subs   r1, r1, #8",
    "    blo    6f",
    "5:",
    "    str    r2, [r0], #4",
    "    str    r2, [r0], #4",
    "    subs   r1, r1, #8",
    "    bhs    5b",
    "6:",
    "    lsls   r12, r1, #30",
    "    it     cs",
    "    strcs  r2, [r0], #4",
    "    it     mi",
    "    strhmi r2, [r0], #2",
    "    lsls   r12, r1, #31",
    "    it     mi",
    "    strbmi r2, [r0]",
    "    bx     lr",
    ".size __aeabi_memclr, . - __aeabi_memclr",
    ".size __aeabi_memclr4, . - __aeabi_memclr4",
    ".size __aeabi_memclr8, . - __aeabi_memclr8",
    ".size __aeabi_memset, . - __aeabi_memset",
    ".size __aeabi_memset4, . - __aeabi_memset4",
    ".size __aeabi_memset8, . - __aeabi_memset8",
);
