//! embassy-time driver on SysTick: one interrupt per millisecond
//! (embassy-time's `tick-hz-1_000`), a 64-bit tick count that never wraps in
//! practice, and embassy-time-queue-utils' timer queue woken from the tick.

use core::cell::RefCell;
use core::task::Waker;

use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

use crate::board::CPU_HZ;

/// SysTick interrupts per second; must equal embassy-time's tick rate.
const TICK_HZ: u32 = 1_000;
const _: () = assert!(TICK_HZ as u64 == embassy_time_driver::TICK_HZ, "enable embassy-time/tick-hz-1_000");

struct State {
    /// Ticks since [`start`].
    now: u64,
    /// The tick at which the queue next needs looking at (`u64::MAX`: never).
    alarm: u64,
    queue: Queue,
}

struct SysTickDriver {
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    state: Mutex::new(RefCell::new(State { now: 0, alarm: u64::MAX, queue: Queue::new() })),
});

impl Driver for SysTickDriver {
    fn now(&self) -> u64 {
        self.state.lock(|state| state.borrow().now)
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        self.state.lock(|state| {
            let mut state = state.borrow_mut();
            let state = &mut *state;
            if state.queue.schedule_wake(at, waker) {
                // Wakes what is already due and returns the next deadline.
                state.alarm = state.queue.next_expiration(state.now);
            }
        });
    }
}

/// Starts the 1 kHz tick from the core clock.
pub fn start(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(CPU_HZ / TICK_HZ - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

#[cortex_m_rt::exception]
fn SysTick() {
    DRIVER.state.lock(|state| {
        let mut state = state.borrow_mut();
        let state = &mut *state;
        state.now += 1;
        if state.now >= state.alarm {
            state.alarm = state.queue.next_expiration(state.now);
        }
    });
}
