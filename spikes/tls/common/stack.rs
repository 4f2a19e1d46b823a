// Stack high-water of a closure on the M4: paint the 64 KiB below the
// current stack pointer, run it, find the deepest word it changed.
// (The painting runs outside the instruction-count window.)

const DEPTH: usize = 64 * 1024;
const PAINT: u32 = 0x5afe_c0de;
pub static mut DEEPEST: usize = 0;

#[inline(always)]
pub fn measured<R>(f: impl FnOnce() -> R) -> R {
    let sp = cortex_m::register::msp::read() as usize;
    let low = sp - DEPTH;
    // Leave 256 bytes under the current frame alone (this function's own).
    let top = sp - 256;
    let mut p = low;
    while p < top {
        // SAFETY: RAM below the stack pointer, unused by anything else here.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
    let r = f();
    let mut p = low;
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    unsafe {
        if sp - p > DEEPEST {
            DEEPEST = sp - p;
        }
    }
    r
}
