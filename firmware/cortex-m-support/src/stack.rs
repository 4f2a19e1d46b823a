//! The stack's high-water mark, measured as the device runs: [`paint`] at
//! start fills the free stack with a pattern; [`used`] later finds the
//! deepest word that no longer holds it. Interrupts share the one stack
//! (MSP), so the mark covers them too.

use core::sync::atomic::{AtomicUsize, Ordering};

/// The pattern: a word the program is unlikely to leave on its stack.
const PAINT: u32 = 0x5afe_57ac;

/// Bytes left unpainted below the painting frame.
const MARGIN: usize = 64;

// cortex-m-rt's link.x: the stack's top (its initial SP) and its end (the
// end of the statics; the stack grows down to it).
unsafe extern "C" {
    static _stack_start: u32;
    static _stack_end: u32;
}

/// The painted region's start (0: not painted).
static BOTTOM: AtomicUsize = AtomicUsize::new(0);
/// The stack in use when it was painted (`main`'s frame and what called it).
static AT_PAINT: AtomicUsize = AtomicUsize::new(0);

fn top() -> usize {
    (&raw const _stack_start) as usize
}

/// Paints the free stack below the caller's frame, at most `limit` bytes
/// below the stack's top (or down to its end). Once, first thing in `main`.
pub fn paint(limit: usize) {
    let end = (&raw const _stack_end) as usize;
    let bottom = top().saturating_sub(limit).max(end).next_multiple_of(4);
    let sp = cortex_m::register::msp::read() as usize;
    let mut at = bottom;
    while at + 4 <= sp.saturating_sub(MARGIN) {
        // SAFETY: [bottom, sp - MARGIN) is stack below the current frame:
        // no live data, word aligned, inside RAM (between the statics' end
        // and the stack's top).
        unsafe { core::ptr::write_volatile(at as *mut u32, PAINT) };
        at += 4;
    }
    AT_PAINT.store(top().saturating_sub(sp), Ordering::Relaxed);
    BOTTOM.store(bottom, Ordering::Release);
}

/// The stack in use when [`paint`] ran: `main`'s frame, which lives as
/// long as the program, and what called it.
pub fn at_paint() -> usize {
    AT_PAINT.load(Ordering::Relaxed)
}

/// The most stack used since [`paint`], in bytes from the top (0 before
/// it); the painted region's size when the whole of it was used.
pub fn used() -> usize {
    let bottom = BOTTOM.load(Ordering::Acquire);
    if bottom == 0 {
        return 0;
    }
    let mut at = bottom;
    // SAFETY: reading the painted region, word by word, below the top.
    while at < top() && unsafe { core::ptr::read_volatile(at as *const u32) } == PAINT {
        at += 4;
    }
    top() - at
}

/// The painted region's size: the most [`used`] can tell.
pub fn measured() -> usize {
    top().saturating_sub(BOTTOM.load(Ordering::Acquire))
}

/// Looks at the mark once a second, forever, and calls `report` with it
/// (and [`at_paint`], and [`measured`]) each time it has risen: a board's
/// task logs it.
pub async fn watch(mut report: impl FnMut(usize, usize, usize)) -> ! {
    let mut reported = 0;
    loop {
        let now = used();
        if now > reported {
            reported = now;
            report(now, at_paint(), measured());
        }
        embassy_time::Timer::after_secs(1).await;
    }
}
