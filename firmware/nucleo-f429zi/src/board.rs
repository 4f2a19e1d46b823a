//! NUCLEO-F429ZI (STM32F429ZI, LAN8742A PHY over RMII): the real I/O adapter.
//!
//! - [`init`]: clocks ([`clock`]: 180 MHz from the ST-LINK's 8 MHz MCO, HSE
//!   bypass, or 168 MHz from the HSI without it), the chip's traps stepped
//!   around ([`silicon`]), the watchdog, the pins, the ADC and DAC, and the
//!   Ethernet MAC + PHY ([`phy`]).
//! - [`net`]: the MAC address from the unique ID, DHCP with a static fallback
//!   ([`settings`]), link loss and link return.
//! - [`pins`]: the 44 digital points, the analog points and the input edges
//!   (EXTI for the 16 ControlBox inputs, timer input capture for the 6 tool
//!   inputs: the chip has only 16 EXTI lines).
//! - [`leds`]: link, Modbus traffic and fault on LD1-LD3.
//! - [`safety`]: the independent watchdog, the HardFault handler, the reset cause.
//! - [`flash`] (feature `http`): the settings flash, bank 2's sectors 12 and 13, outside the image.
//! - [`button`] (feature `http`): factory reset by the user button held at power-up.
//!
//! The pin table with header positions is in `docs/nucleo-f429zi.md`.

use embassy_executor::{SpawnError, Spawner};
use embassy_net::Stack;
use embassy_stm32::adc::{Adc, AdcChannel};
use embassy_stm32::dac::Dac;
use embassy_stm32::eth::{Ethernet, Sma};
use embassy_stm32::exti::{ExtiInput, TriggerEdge};
use embassy_stm32::gpio::{Level, Output, Pin, Speed};
use embassy_stm32::peripherals::{IWDG, RNG, TIM3, TIM4};
use embassy_stm32::rng::Rng;
use embassy_stm32::timer::{Ch1, Ch2, Ch3, Ch4};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, eth, rng};
use static_cell::StaticCell;

use crate::pins::{self, CaptureTimer, Edges, INPUT_PULL, output};
use crate::{ModbusServer, clock, leds, net, phy, safety, silicon};
#[cfg(feature = "http")]
use crate::{button, flash};
use adapter::device::Device;

bind_interrupts!(
    /// Every interrupt the board uses, bound to its handler.
    pub struct Irqs {
        ETH => eth::InterruptHandler;
        #[cfg(feature = "http")]
        FLASH => embassy_stm32::flash::InterruptHandler;
        HASH_RNG => rng::InterruptHandler<RNG>;
        EXTI0 => pins::EdgeInterrupt;
        EXTI1 => pins::EdgeInterrupt;
        EXTI2 => pins::EdgeInterrupt;
        EXTI3 => pins::EdgeInterrupt;
        EXTI4 => pins::EdgeInterrupt;
        EXTI9_5 => pins::EdgeInterrupt;
        EXTI15_10 => pins::EdgeInterrupt;
        TIM3 => pins::CaptureInterrupt<TIM3>;
        TIM4 => pins::CaptureInterrupt<TIM4>;
    }
);

/// Everything [`init`] brings up, handed to the binary.
pub struct Board {
    /// The Ethernet MAC and PHY, for `embassy_net::new`.
    pub ethernet: net::Device,
    /// The MAC address in use (from the unique ID).
    pub mac: [u8; 6],
    /// A seed for the network stack (TCP sequence numbers, DHCP ids), from the RNG.
    pub seed: u64,
    /// The outputs, for `Device::new`.
    pub outputs: &'static pins::Outputs,
    /// The inputs for the 100 ms refresh (debounced digital levels, the ADC).
    pub inputs: pins::Inputs,
    /// What the board's own tasks run on; see [`spawn`].
    pub tasks: Tasks,
    /// The flash the settings are saved in (memory.x's `SETTINGS`).
    #[cfg(feature = "http")]
    pub flash: flash::Partitions,
    /// The user button was held at power-up ([`button`]): erase the settings first.
    #[cfg(feature = "http")]
    pub factory_reset: bool,
    /// The user button, for its short presses once running ([`button::watch`]).
    #[cfg(feature = "http")]
    pub button: embassy_stm32::gpio::Input<'static>,
    /// Why the MCU last reset.
    #[cfg(feature = "http")]
    pub reset: safety::ResetCause,
    /// The RNG, kept for the admin password's salts.
    #[cfg(feature = "http")]
    pub rng: Rng<'static, RNG>,
}

impl core::fmt::Debug for Board {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Board").field("mac", &self.mac).finish_non_exhaustive()
    }
}

/// What the board's background tasks own.
pub struct Tasks {
    watchdog: IndependentWatchdog<'static, IWDG>,
    edges: &'static Edges,
    leds: leds::Leds,
}

impl core::fmt::Debug for Tasks {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Tasks").field("edges", &self.edges).finish_non_exhaustive()
    }
}

#[cfg(feature = "http")]
impl Tasks {
    /// Runs `future` to its end before the executor runs the other tasks,
    /// feeding the watchdog meanwhile ([`safety::block_on_fed`]): its
    /// feeder task is not running yet.
    pub fn block_on<F: core::future::Future>(&mut self, future: F) -> F::Output {
        safety::block_on_fed(&mut self.watchdog, future)
    }
}

/// Brings the board up: clocks, the flash accelerator, PA12, watchdog
/// (running from here on), outputs off, inputs with their edge
/// interrupts, ADC, DAC, RNG, Ethernet and the settings flash.
pub fn init() -> Board {
    // Before embassy's init, which would wait for HSE forever.
    let clock = clock::probe();
    let p = embassy_stm32::init(clock::config(clock));
    let prefetch = silicon::flash_accelerator_on();
    // Before anything reads bank 2 (the settings, the boot state, DFU).
    silicon::hold_pa12_low(p.PA12);
    let reset = safety::take_reset_cause();
    // REV_ID (ES0206, table 2): 0x1000 A, 0x1003 Y, 0x1007 1, 0x2001 3, 0x2003 5 or B.
    defmt::info!(
        "NUCLEO-F429ZI at {} MHz from {}, silicon REV_ID {=u16:#06x}, flash prefetch {=bool}; last reset: {=str}",
        clock::sysclk(clock).0 / 1_000_000,
        clock,
        silicon::revision(),
        prefetch,
        reset.name()
    );
    let clock_fallback = clock == clock::Source::Hsi;
    if clock_fallback {
        defmt::warn!(
            "clocks: no 8 MHz from the ST-LINK's MCO within {} ms: running on the internal RC (HSI); LD3 blinks",
            clock::HSE_TIMEOUT_MS
        );
    }

    // From here on a stall (in the rest of bring-up, or of the executor) resets the MCU.
    let watchdog = safety::start_watchdog(p.IWDG);

    safety::register_fault_led(p.PB14.port(), p.PB14.pin());
    let leds = leds::Leds {
        link: Output::new(p.PB0, Level::Low, Speed::Low),
        traffic: Output::new(p.PB7, Level::Low, Speed::Low),
        fault: Output::new(p.PB14, Level::Low, Speed::Low),
        watchdog_reset: reset == safety::ResetCause::Watchdog,
        clock_fallback,
    };
    // B1 pulls PC13 up to 3V3 when pressed (UM1974); the internal pull-down
    // keeps it low when released, beside the board's own.
    #[cfg(feature = "http")]
    let (watchdog, leds, factory_reset, button) = {
        let (mut watchdog, mut leds) = (watchdog, leds);
        let button = embassy_stm32::gpio::Input::new(p.PC13, embassy_stm32::gpio::Pull::Down);
        let held = button::factory_reset_held(&button, &mut watchdog, &mut leds);
        (watchdog, leds, held, button)
    };

    // Outputs first, all off.
    let (dac1, dac2) = Dac::new_blocking(p.DAC1, p.PA4, p.PA5).split();
    static OUTPUTS: StaticCell<pins::Outputs> = StaticCell::new();
    let outputs = &*OUTPUTS.init(pins::Outputs::new(pins::OutputPins {
        digital: [
            p.PF0.into(),
            p.PF1.into(),
            p.PF2.into(),
            p.PF3.into(),
            p.PF4.into(),
            p.PF5.into(),
            p.PF7.into(),
            p.PF8.into(),
            p.PF9.into(),
            p.PF10.into(),
            p.PF12.into(),
            p.PF13.into(),
            p.PF14.into(),
            p.PF15.into(),
            p.PG2.into(),
            p.PG3.into(),
        ]
        .map(output),
        tool: [p.PD0.into(), p.PD1.into(), p.PD2.into(), p.PD3.into(), p.PD4.into(), p.PD5.into()].map(output),
        analog_input_mode: [p.PD6.into(), p.PD7.into()].map(output),
        analog_output_mode: [p.PC8.into(), p.PC9.into()].map(output),
        dac: [dac1, dac2],
    }));

    // ControlBox inputs: EXTI line n - 1 for input n, both edges.
    let digital = [
        ExtiInput::new_blocking(p.PE0, p.EXTI0, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PG1, p.EXTI1, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE2, p.EXTI2, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE3, p.EXTI3, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE4, p.EXTI4, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE5, p.EXTI5, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE6, p.EXTI6, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE7, p.EXTI7, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE8, p.EXTI8, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE9, p.EXTI9, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE10, p.EXTI10, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE11, p.EXTI11, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE12, p.EXTI12, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE13, p.EXTI13, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE14, p.EXTI14, INPUT_PULL, TriggerEdge::Any),
        ExtiInput::new_blocking(p.PE15, p.EXTI15, INPUT_PULL, TriggerEdge::Any),
    ];
    // Tool inputs: timer input capture on both edges.
    let tim4 = CaptureTimer::new(p.TIM4, Irqs);
    let tim3 = CaptureTimer::new(p.TIM3, Irqs);
    let tool = [
        tim4.pin::<Ch1>(p.PD12),
        tim4.pin::<Ch2>(p.PD13),
        tim4.pin::<Ch3>(p.PD14),
        tim4.pin::<Ch4>(p.PD15),
        tim3.pin::<Ch1>(p.PC6),
        tim3.pin::<Ch2>(p.PC7),
    ];
    static EDGES: StaticCell<Edges> = StaticCell::new();
    let edges = &*EDGES.init(Edges::new(digital, tool, tim4, tim3));

    let inputs = pins::Inputs::new(edges, Adc::new(p.ADC1), [p.PA3.degrade_adc(), p.PC0.degrade_adc()]);

    let mut rng = Rng::new(p.RNG, Irqs);
    let seed = rng.next_u64();
    #[cfg(not(feature = "http"))]
    drop(rng);
    let mac = adapter::net::mac_from_uid(&embassy_stm32::uid::uid());
    defmt::info!("MAC {:02x}", mac);
    // RMII: REF_CLK PA1, CRS_DV PA7, RXD0 PC4, RXD1 PC5, TXD0 PG13, TXD1 PB13, TX_EN PG11; MDIO PA2, MDC PC1.
    let ethernet = Ethernet::new_with_phy(
        net::packets(),
        p.ETH,
        Irqs,
        p.PA1,
        p.PA7,
        p.PC4,
        p.PC5,
        p.PG13,
        p.PB13,
        p.PG11,
        mac,
        phy::Lan8742a::new(Sma::new(p.ETH_SMA, p.PA2, p.PC1)),
    );

    Board {
        ethernet,
        mac,
        seed,
        outputs,
        inputs,
        tasks: Tasks { watchdog, edges, leds },
        #[cfg(feature = "http")]
        flash: flash::partitions(p.FLASH),
        #[cfg(feature = "http")]
        factory_reset,
        #[cfg(feature = "http")]
        button,
        #[cfg(feature = "http")]
        reset,
        #[cfg(feature = "http")]
        rng,
    }
}

/// Spawns the board's own tasks: the watchdog feeder, the input edges and
/// the LEDs (the program's tasks are `program::spawn`'s).
pub fn spawn(
    spawner: Spawner,
    tasks: Tasks,
    stack: Stack<'static>,
    device: &'static Device<'static>,
    server: &'static ModbusServer,
) -> Result<(), SpawnError> {
    let Tasks { watchdog, edges, leds } = tasks;
    spawner.spawn(safety::watchdog_task(watchdog)?);
    spawner.spawn(pins::edge_task(edges, device)?);
    spawner.spawn(leds::led_task(leds, stack, server)?);
    Ok(())
}
