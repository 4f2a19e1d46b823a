//! Arm MPS2 with the AN386 FPGA image (Cortex-M4F at 25 MHz), as QEMU's
//! `mps2-an386` machine models it: the image's test bench.
//!
//! | what | where |
//! |---|---|
//! | code (ZBT SSRAM1, writable in QEMU) | `0x0000_0000`, 4 MiB (`memory.x`) |
//! | data, stack (ZBT SSRAM2/3) | `0x2000_0000`, 4 MiB |
//! | settings (PSRAM, file-backed by the QEMU scripts) | `0x2100_0000`, 64 KiB ([`settings_region`]) |
//! | FPGA IO `LED0` (2 user LEDs) | `0x4002_8000` |
//! | LAN9118 Ethernet | `0x4020_0000`, NVIC IRQ 13 |
//!
//! Digital outputs 1 and 2 drive the two FPGA user LEDs ([`Leds`]); while
//! the HTTP API's locate runs, LED1 blinks instead of showing output 2
//! ([`locate`]: QEMU models two user LEDs and both are outputs). QEMU's
//! GPIO blocks are placeholders (reads 0, writes dropped), so every other
//! point lives only in the process image: the inputs read 0 ([`RamInputs`]).
//!
//! [`lan9118`] is plain logic and builds (and is tested) on the host; the
//! rest needs the `mps2-an386` feature and the Cortex-M target.

pub use self::hw::*;

/// The core clock (QEMU's `mps2-an386` SYSCLK).
pub const CPU_HZ: u32 = 25_000_000;
/// The LAN9118's register window.
pub const LAN9118_BASE: usize = 0x4020_0000;
/// The LAN9118's NVIC interrupt line.
pub const LAN9118_IRQ: u16 = 13;
/// The FPGA IO block's `LED0` register: bit n lights user LED n.
pub const FPGAIO_LED0: usize = 0x4002_8000;
/// The digital outputs (bit n = output n + 1) that have an LED: outputs 1 and 2.
pub const LED_OUTPUTS: u16 = 0b11;

/// Inputs with no pin behind them: they hold what is stored here (0).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RamInputs {
    pub digital: u16,
    pub tool: u8,
    pub analog: [u16; adapter::io::ANALOG_CHANNELS],
}

impl adapter::io::InputPins for RamInputs {
    fn digital(&mut self) -> u16 {
        self.digital
    }

    fn tool(&mut self) -> u8 {
        self.tool
    }

    fn analog(&mut self, channel: usize, kind: adapter::io::AnalogType) -> u16 {
        self.analog.get(channel).copied().unwrap_or(0).min(kind.max())
    }
}

mod hw {
    use core::ptr;
    #[cfg(feature = "http")]
    use core::sync::atomic::{AtomicBool, Ordering};
    use core::task::Waker;

    use cortex_m::interrupt::InterruptNumber;
    use cortex_m::peripheral::NVIC;
    use embassy_sync::waitqueue::AtomicWaker;

    use super::{FPGAIO_LED0, LAN9118_BASE, LAN9118_IRQ, LED_OUTPUTS};
    use crate::{runtime, systick};
    use adapter::io::{OutputPins, Outputs};
    use lan9118::{self, Lan9118};

    /// Woken by the LAN9118's interrupt.
    static ETHERNET_WAKER: AtomicWaker = AtomicWaker::new();

    #[derive(Clone, Copy)]
    struct Irq(u16);

    // SAFETY: `Irq` only ever holds a line this board has (the LAN9118's, or
    // one reported by the NVIC itself).
    unsafe impl InterruptNumber for Irq {
        fn number(self) -> u16 {
            self.0
        }
    }

    /// Brings the board up, once (later calls return `None`): the 1 kHz
    /// time base, then the LAN9118, reset and configured.
    pub fn init() -> Option<Result<Lan9118<Mmio>, lan9118::Error>> {
        let peripherals = cortex_m::Peripherals::take()?;
        systick::start(peripherals.SYST);
        Some(Lan9118::new(Mmio { _private: () }))
    }

    /// Set once [`settings_region`] has handed the region out.
    #[cfg(feature = "http")]
    static SETTINGS_TAKEN: AtomicBool = AtomicBool::new(false);

    /// The settings region, once (later calls return `None`): memory.x's
    /// `SETTINGS`, the first 64 KiB of the PSRAM at `0x2100_0000`, which the
    /// QEMU scripts map to a state file so that what is written here is
    /// there again at the next boot (docs/qemu.md). The settings store puts
    /// flash rules on it (erase to 0xFF, writes clear bits).
    ///
    /// A state file the scripts made reads 0xFF: erased flash, no settings.
    /// All zeros is RAM no file backs (QEMU started without the scripts'
    /// `memory-backend` options, or QEMU created the file itself): the store
    /// should take it as blank, not corrupt, erase it to 0xFF and log that
    /// the settings will not outlive QEMU unless it runs with a state file.
    #[cfg(feature = "http")]
    pub fn settings_region() -> Option<&'static mut [u8]> {
        // memory.x's symbols: the region's first byte and the byte after it.
        unsafe extern "C" {
            static mut __settings_start: u8;
            static __settings_end: u8;
        }
        if SETTINGS_TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        let start = &raw mut __settings_start;
        let len = (&raw const __settings_end as usize).saturating_sub(start as usize);
        // SAFETY: memory.x reserves [start, start + len) for the settings
        // alone (no section is placed there); it is RAM for as long as QEMU
        // runs, any byte pattern is a valid u8, and the flag above hands it
        // out once, so no other reference to it exists.
        Some(unsafe { core::slice::from_raw_parts_mut(start, len) })
    }

    /// The LAN9118's registers in the memory map, and its interrupt line.
    #[derive(Debug)]
    pub struct Mmio {
        _private: (),
    }

    impl lan9118::Interface for Mmio {
        fn read(&mut self, offset: u8) -> u32 {
            // SAFETY: the window is 256 bytes of 32-bit registers at
            // LAN9118_BASE; only `Mmio` (one instance) touches it.
            unsafe { ptr::read_volatile((LAN9118_BASE + usize::from(offset)) as *const u32) }
        }

        fn write(&mut self, offset: u8, value: u32) {
            // SAFETY: as for `read`.
            unsafe { ptr::write_volatile((LAN9118_BASE + usize::from(offset)) as *mut u32, value) }
        }

        fn arm(&mut self, waker: &Waker) {
            ETHERNET_WAKER.register(waker);
            // The line was still high when the handler returned, so the NVIC
            // latched the interrupt again; the driver has handled its events
            // since. Unmasked as it is, it would run the handler and poll the
            // stack once more for nothing (scripts/bench-mcu). The driver
            // reads the chip again after this, so a new event is not lost.
            NVIC::unpend(Irq(LAN9118_IRQ));
            // SAFETY: the handler only masks the line and wakes the waker;
            // no critical section depends on the line being masked.
            unsafe { NVIC::unmask(Irq(LAN9118_IRQ)) };
        }
    }

    /// Device interrupts (there is no PAC, so cortex-m-rt sends them all
    /// here). The LAN9118's line is masked and its waker woken: the driver
    /// reads the chip and unmasks the line when the stack polls it.
    #[cortex_m_rt::exception]
    unsafe fn DefaultHandler(irqn: i16) {
        let Ok(line) = u16::try_from(irqn) else { runtime::unexpected_exception(irqn) };
        NVIC::mask(Irq(line));
        if line == LAN9118_IRQ {
            ETHERNET_WAKER.wake();
        } else {
            defmt::warn!("masked unexpected interrupt {=u16}", line);
        }
    }

    /// Digital outputs 1 and 2 on the FPGA IO user LEDs.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct Leds;

    impl OutputPins for Leds {
        fn drive(&self, outputs: &Outputs) {
            let value = u32::from(outputs.digital & LED_OUTPUTS);
            #[cfg(feature = "http")]
            let value = super::locate::overlay(value);
            write_leds(value);
        }
    }

    /// Writes the FPGA IO `LED0` register.
    pub(super) fn write_leds(value: u32) {
        // SAFETY: LED0 is a plain read-write register of the FPGA IO block.
        unsafe { ptr::write_volatile(FPGAIO_LED0 as *mut u32, value) }
    }
}

/// Locate (the HTTP API's `POST /api/locate`) on LED1: both user LEDs are
/// outputs, so for the blink LED1 shows the blink instead of output 2, and
/// output 2 again once it ends (LED0 keeps showing output 1 throughout).
#[cfg(feature = "http")]
pub mod locate {
    use core::sync::atomic::{AtomicU8, AtomicU32, Ordering};

    /// The LED that blinks: LED1 (bit 1 of `LED0`).
    const LOCATE_LED: u32 = 0b10;
    /// Not locating.
    const OFF: u8 = 0;
    /// Locating, the LED dark.
    const DARK: u8 = 1;
    /// Locating, the LED lit.
    const LIT: u8 = 2;

    /// The outputs' LED bits as last driven.
    static OUTPUTS: AtomicU32 = AtomicU32::new(0);
    static STATE: AtomicU8 = AtomicU8::new(OFF);

    /// The register value for the outputs' LED bits `value`, locate shown
    /// over it; remembers `value` for [`show`].
    pub(super) fn overlay(value: u32) -> u32 {
        OUTPUTS.store(value, Ordering::Relaxed);
        apply(value, STATE.load(Ordering::Relaxed))
    }

    fn apply(value: u32, state: u8) -> u32 {
        match state {
            OFF => value,
            DARK => value & !LOCATE_LED,
            _ => value | LOCATE_LED,
        }
    }

    /// Shows the blink's phase (`Some(lit)`), or the outputs again (`None`).
    pub fn show(phase: Option<bool>) {
        let state = match phase {
            None => OFF,
            Some(false) => DARK,
            Some(true) => LIT,
        };
        // With interrupts masked: a Modbus write cannot drive the LEDs
        // between reading the outputs and writing the register.
        cortex_m::interrupt::free(|_| {
            STATE.store(state, Ordering::Relaxed);
            super::hw::write_leds(apply(OUTPUTS.load(Ordering::Relaxed), state));
        });
    }
}
