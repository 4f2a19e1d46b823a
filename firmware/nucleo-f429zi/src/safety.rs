//! What keeps the device safe when the firmware goes wrong:
//!
//! - the independent watchdog (IWDG, its own 32 kHz LSI clock), fed by
//!   [`watchdog_task`]: if the executor stops running tasks for
//!   [`WATCHDOG_TIMEOUT_US`], the MCU resets;
//! - the HardFault handler (panics end there too, through panic-probe, and so
//!   does a stack overflow, which flip-link turns into a fault): every output
//!   off, the fault LED on, the fault logged, then the watchdog resets the MCU;
//! - the reset cause, read at boot, so a watchdog reset is logged and shown.

use core::sync::atomic::{AtomicU16, Ordering};

use embassy_stm32::Peri;
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::regs::Bsrr;
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_time::{Duration, Timer};

use adapter::io::ANALOG_CHANNELS;

/// Nominal watchdog timeout. The LSI runs at 17-47 kHz, so the real timeout
/// is 1.4-3.8 s; [`WATCHDOG_FEED`] stays well inside the shortest.
pub const WATCHDOG_TIMEOUT_US: u32 = 2_000_000;
/// How often [`watchdog_task`] feeds the watchdog.
pub const WATCHDOG_FEED: Duration = Duration::from_millis(250);

/// Why the MCU last reset (RCC_CSR).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum ResetCause {
    /// The independent watchdog: the firmware stalled or faulted.
    Watchdog,
    /// The window watchdog (unused by this firmware).
    WindowWatchdog,
    /// A software reset (`SYSRESETREQ`, as the debugger does after flashing).
    Software,
    /// Power-on or brown-out.
    PowerOn,
    /// The NRST pin (the board's reset button).
    Pin,
    /// Low-power management.
    LowPower,
    /// No flag set.
    Unknown,
}

impl ResetCause {
    /// As `/api/status` names it (`device.reset_reason`).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Watchdog => "watchdog",
            Self::WindowWatchdog => "window-watchdog",
            Self::Software => "software",
            Self::PowerOn => "power-on",
            Self::Pin => "reset-pin",
            Self::LowPower => "low-power",
            Self::Unknown => "unknown",
        }
    }
}

/// Reads and clears the reset flags. Checked in order of specificity: any
/// internal reset also pulls NRST, so the pin flag comes last.
pub fn take_reset_cause() -> ResetCause {
    let csr = pac::RCC.csr().read();
    pac::RCC.csr().modify(|w| w.set_rmvf(true));
    if csr.wdgrstf() {
        ResetCause::Watchdog
    } else if csr.wwdgrstf() {
        ResetCause::WindowWatchdog
    } else if csr.lpwrrstf() {
        ResetCause::LowPower
    } else if csr.porrstf() || csr.borrstf() {
        ResetCause::PowerOn
    } else if csr.sftrstf() {
        ResetCause::Software
    } else if csr.padrstf() {
        ResetCause::Pin
    } else {
        ResetCause::Unknown
    }
}

/// Starts the watchdog; it cannot be stopped again. It is frozen while a
/// debugger halts the core, so a breakpoint does not reset the board.
pub fn start_watchdog(iwdg: Peri<'static, IWDG>) -> IndependentWatchdog<'static, IWDG> {
    pac::DBGMCU.apb1fzr().modify(|w| w.set_iwdg(true));
    let mut watchdog = IndependentWatchdog::new(iwdg, WATCHDOG_TIMEOUT_US);
    watchdog.unleash();
    watchdog
}

/// Runs `future` to its end by polling it in a loop
/// (`embassy_futures::block_on`), feeding the watchdog before every poll:
/// for work done before the executor runs [`watchdog_task`] (the settings'
/// load at start, whose factory reset or format erases two 16 KiB sectors:
/// up to 1 s at x32, 1.6 s at x8, where the shortest watchdog period,
/// `WATCHDOG_TIMEOUT_US` at the LSI's fastest, 47 kHz, is 1.36 s).
/// `block_on` polls without pause,
/// and a poll of a flash operation returns at once while the flash is busy,
/// so the watchdog is fed every few microseconds. The future must not
/// wait on embassy-time's timers (their queue wants the executor's wakers).
#[cfg(feature = "http")]
pub fn block_on_fed<F: core::future::Future>(
    watchdog: &mut IndependentWatchdog<'static, IWDG>,
    future: F,
) -> F::Output {
    let mut future = core::pin::pin!(future);
    embassy_futures::block_on(core::future::poll_fn(|cx| {
        watchdog.pet();
        future.as_mut().poll(cx)
    }))
}

/// Feeds the watchdog for as long as the executor runs (with `update`:
/// and the image is not on trial past its limit, `update::keeps_feeding`).
#[embassy_executor::task]
pub async fn watchdog_task(mut watchdog: IndependentWatchdog<'static, IWDG>) -> ! {
    loop {
        #[cfg(feature = "update")]
        if !crate::update::keeps_feeding() {
            defmt::error!("update: not confirmed in time: the watchdog resets, the bootloader rolls back");
            core::future::pending::<()>().await;
        }
        watchdog.pet();
        Timer::after(WATCHDOG_FEED).await;
    }
}

/// GPIO ports A-I.
const PORTS: [pac::gpio::Gpio; 9] =
    [pac::GPIOA, pac::GPIOB, pac::GPIOC, pac::GPIOD, pac::GPIOE, pac::GPIOF, pac::GPIOG, pac::GPIOH, pac::GPIOI];

/// Per port, the output pins the fault handler turns off.
static OUTPUTS: [AtomicU16; PORTS.len()] = [const { AtomicU16::new(0) }; PORTS.len()];
/// The fault LED: port in the high byte, pin in the low byte (`u16::MAX`: none).
static FAULT_LED: AtomicU16 = AtomicU16::new(u16::MAX);

/// Records an output pin, so a fault turns it off.
pub fn register_output(port: u8, pin: u8) {
    if let Some(mask) = OUTPUTS.get(usize::from(port)) {
        mask.fetch_or(1u16.checked_shl(u32::from(pin)).unwrap_or(0), Ordering::Relaxed);
    }
}

/// Records the fault LED's pin.
pub fn register_fault_led(port: u8, pin: u8) {
    FAULT_LED.store(u16::from_be_bytes([port, pin]), Ordering::Relaxed);
}

/// Every output off, both analog outputs at 0, the fault LED on. Plain
/// register writes, safe from any context.
pub fn enter_safe_state() {
    for (port, mask) in PORTS.iter().zip(&OUTPUTS) {
        let mask = mask.load(Ordering::Relaxed);
        if mask != 0 {
            // The upper half of BSRR resets pins.
            port.bsrr().write_value(Bsrr(u32::from(mask) << 16));
        }
    }
    for channel in 0..ANALOG_CHANNELS {
        pac::DAC1.dhr12r(channel).write(|w| w.set_dhr(0));
    }
    let [port, pin] = FAULT_LED.load(Ordering::Relaxed).to_be_bytes();
    if let Some(port) = PORTS.get(usize::from(port)) {
        port.bsrr().write(|w| w.set_bs(usize::from(pin), true));
    }
}

/// A HardFault (a panic and a stack overflow end here too): safe state, log,
/// and wait for the watchdog to reset the MCU.
#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    enter_safe_state();
    defmt::error!(
        "HardFault at pc {=u32:#010x}, lr {=u32:#010x}: outputs off, the watchdog resets the MCU",
        frame.pc(),
        frame.lr()
    );
    loop {
        cortex_m::asm::nop();
    }
}
