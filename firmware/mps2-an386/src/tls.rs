//! TLS on QEMU's mps2-an386 (feature `tls`, docs/tls.md): the arena, and
//! the entropy the generator is seeded from.
//!
//! **This board has no entropy source.** The AN386 image has no TRNG; what
//! varies from one start to the next under QEMU is the host's timing, read
//! here as SysTick's current count between busy waits, with the MAC. That
//! makes keys hard to guess from outside but not secret in the sense TLS
//! needs: the QEMU image's TLS is for smoke tests of the protocol, never
//! for protecting anything. The NUCLEO draws from the STM32's RNG.

use adapter::program::TLS_ARENA_LEN;
use cortex_m::peripheral::SYST;
use static_cell::ConstStaticCell;

/// The TLS arena: Mbed TLS's only memory handed out at run time (in .bss).
static ARENA: ConstStaticCell<[u8; TLS_ARENA_LEN]> = ConstStaticCell::new([0; TLS_ARENA_LEN]);

/// The arena, once (`None` after).
pub fn arena() -> Option<&'static mut [u8]> {
    ARENA.try_take().map(|arena| arena.as_mut_slice())
}

/// Timing jitter under QEMU: SysTick's count after each of a few hundred
/// short busy waits, folded into the buffer. Not a real entropy source
/// (module docs).
pub fn entropy(buf: &mut [u8]) -> bool {
    let mut state: u32 = 0x6d62_696f;
    for byte in buf.iter_mut() {
        for _ in 0..8 {
            for _ in 0..(state & 0x3f) + 16 {
                cortex_m::asm::nop();
            }
            state = state.rotate_left(5) ^ SYST::get_current();
        }
        *byte = (state ^ (state >> 11) ^ (state >> 23)) as u8;
    }
    true
}
