//! The NUCLEO's I/O points: 16 + 6 digital outputs, 16 + 6 digital inputs
//! pushed as events, 2 analog inputs (ADC1) and 2 analog outputs (DAC).
//!
//! # Input edges and debounce
//!
//! Every input has an edge interrupt: the ControlBox inputs on EXTI lines
//! 0-15 (one line each; the chip has no more), the tool inputs on timer input
//! capture channels (TIM4 CH1-4, TIM3 CH1-2, both edges, a 2.8 µs glitch
//! filter). An interrupt masks the line that fired and wakes [`edge_task`],
//! which samples every input and pushes any change into the image at once.
//! Then it waits [`DEBOUNCE`] before it re-arms the lines and samples again:
//! a bouncing contact yields its first change at once and its settled level
//! at most [`DEBOUNCE`] later, never a burst of changes. An edge on another
//! input inside that window is reported at its end. A glitch that is gone by
//! the time the task samples (a few µs) changes nothing.
//!
//! The debounced levels are also what the 100 ms refresh re-asserts
//! ([`Inputs`]), and the task re-samples every [`RESAMPLE`] in case an edge
//! interrupt was ever lost, so the image cannot keep a stale level.
//!
//! # Levels
//!
//! A digital point is on when its pin is high (3.3 V). Inputs have a pull-down,
//! so an open input reads off. Analog values use the map's encoding (mV or µA)
//! scaled by [`FRONT_END`]; the mode pins tell the external
//! front end which type the master selected (high = voltage, low = current).

use core::cell::RefCell;
use core::marker::PhantomData;
use core::sync::atomic::{AtomicU32, Ordering};

use embassy_stm32::Peri;
use embassy_stm32::adc::{Adc, AnyAdcChannel, SampleTime};
use embassy_stm32::dac::{DacChannel, Value};
use embassy_stm32::exti::ExtiInput;
use embassy_stm32::gpio::{AfType, AnyPin, Flex, Level, Output, Pin, Pull, Speed};
use embassy_stm32::interrupt::typelevel::{Binding, Handler, Interrupt};
use embassy_stm32::mode::Blocking;
use embassy_stm32::pac;
use embassy_stm32::pac::exti::regs::Lines;
use embassy_stm32::pac::timer::regs::SrGp16;
use embassy_stm32::pac::timer::vals::FilterValue;
use embassy_stm32::peripherals::{ADC1, TIM3, TIM4};
use embassy_stm32::timer::low_level::{InputCaptureMode, InputTISelection, Timer};
use embassy_stm32::timer::{GeneralInstance4Channel, TimerChannel, TimerPin};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Timer as Delay, with_timeout};

use crate::safety;
use adapter::analog::FrontEnd;
use adapter::io::{self, ANALOG_CHANNELS, AnalogType};

/// The analog front end: ADC and DAC at VDDA = VREF+ = 3.3 V, 12 bits; the
/// external front end maps 3.0 V at the pin to the top of each range (10 V
/// or 20 mA), leaving headroom below the reference.
pub const FRONT_END: FrontEnd = FrontEnd { vref_mv: 3300, full_scale_mv: 3000, code_max: 4095 };
use adapter::device::Device;

/// ControlBox digital inputs and outputs.
pub const DIGITAL_POINTS: usize = 16;
/// Tool digital inputs and outputs.
pub const TOOL_POINTS: usize = 6;
/// Contact debounce: after an edge, further edges are ignored this long and
/// the inputs are then sampled again.
pub const DEBOUNCE: Duration = Duration::from_millis(5);
/// Safety net: the inputs are re-sampled this often even without an edge.
pub const RESAMPLE: Duration = Duration::from_millis(100);
/// The inputs' pull resistor: an open input reads off.
pub const INPUT_PULL: Pull = Pull::Down;
/// ADC samples averaged per analog reading.
pub const ADC_SAMPLES: u32 = 8;
/// ADC sample time: 144 cycles of the 22.5 MHz ADC clock (6.4 µs) per sample.
const ADC_SAMPLE_TIME: SampleTime = SampleTime::CYCLES144;
/// The EXTI lines of the ControlBox inputs: all 16.
const EXTI_LINES: u32 = 0xffff;
/// CC1IF..CC4IF in a timer's SR (and CC1IE..CC4IE in its DIER).
const CAPTURE_FLAGS: u32 = 0b1_1110;
/// CC1OF..CC4OF in a timer's SR: an edge came before the last was handled.
const OVERCAPTURE_FLAGS: u32 = CAPTURE_FLAGS << 8;

/// Set by the edge interrupts, awaited by [`edge_task`].
static EDGE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// A push-pull output, off, registered for the fault handler's safe state.
/// (One copy for every pin: outlined, it keeps bring-up small.)
#[inline(never)]
pub fn output(pin: Peri<'static, AnyPin>) -> Output<'static> {
    safety::register_output(pin.port(), pin.pin());
    Output::new(pin, Level::Low, Speed::Low)
}

/// What [`Outputs`] drives.
pub struct OutputPins {
    pub digital: [Output<'static>; DIGITAL_POINTS],
    pub tool: [Output<'static>; TOOL_POINTS],
    /// The front end's mode for each analog input: high = voltage, low = current.
    pub analog_input_mode: [Output<'static>; ANALOG_CHANNELS],
    /// The front end's mode for each analog output: high = voltage, low = current.
    pub analog_output_mode: [Output<'static>; ANALOG_CHANNELS],
    /// DAC channel 1 (PA4) and 2 (PA5).
    pub dac: [DacChannel<'static, Blocking>; ANALOG_CHANNELS],
}

impl core::fmt::Debug for OutputPins {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("OutputPins").finish_non_exhaustive()
    }
}

/// The board's outputs, driven the moment a master's write lands.
pub struct Outputs {
    pins: Mutex<CriticalSectionRawMutex, RefCell<OutputPins>>,
}

impl core::fmt::Debug for Outputs {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Outputs").finish_non_exhaustive()
    }
}

impl Outputs {
    /// Takes the pins (all off) and turns off the DAC's output buffers: the
    /// outputs then swing rail to rail into the front end's high-impedance
    /// amplifier, instead of stopping 0.2 V short of 0 V and VDDA.
    pub fn new(mut pins: OutputPins) -> Self {
        for (index, dac) in pins.dac.iter_mut().enumerate() {
            dac.set(Value::Bit12Right(0));
            pac::DAC1.cr().modify(|w| w.set_boff(index, true));
        }
        Self { pins: Mutex::new(RefCell::new(pins)) }
    }
}

/// `true` for a set bit `n` of `mask`.
fn bit(mask: u16, n: usize) -> Level {
    Level::from(mask.checked_shr(n as u32).unwrap_or(0) & 1 == 1)
}

impl io::OutputPins for Outputs {
    fn drive(&self, outputs: &io::Outputs) {
        self.pins.lock(|pins| {
            let Ok(mut pins) = pins.try_borrow_mut() else { return };
            let pins = &mut *pins;
            for (n, pin) in pins.digital.iter_mut().enumerate() {
                pin.set_level(bit(outputs.digital, n));
            }
            for (n, pin) in pins.tool.iter_mut().enumerate() {
                pin.set_level(bit(u16::from(outputs.tool), n));
            }
            for (pin, kind) in pins.analog_input_mode.iter_mut().zip(outputs.analog_input_types) {
                pin.set_level(Level::from(kind == AnalogType::Voltage));
            }
            let analog = pins.analog_output_mode.iter_mut().zip(pins.dac.iter_mut()).zip(outputs.analog);
            for ((mode, dac), output) in analog {
                let voltage = Level::from(output.kind == AnalogType::Voltage);
                if mode.get_output_level() != voltage {
                    // A new type: zero the output before the front end switches stages.
                    dac.set(Value::Bit12Right(0));
                    mode.set_level(voltage);
                }
                dac.set(Value::Bit12Right(FRONT_END.to_code(output.value, output.kind)));
            }
        });
    }
}

/// A timer whose channels capture the tool inputs' edges.
pub struct CaptureTimer<T: GeneralInstance4Channel> {
    timer: Timer<'static, T>,
}

impl<T: GeneralInstance4Channel> core::fmt::Debug for CaptureTimer<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CaptureTimer").finish_non_exhaustive()
    }
}

impl<T: GeneralInstance4Channel> CaptureTimer<T> {
    /// Clocks the timer and enables its interrupt (bound to [`CaptureInterrupt`]).
    pub fn new(tim: Peri<'static, T>, _irq: impl Binding<T::CaptureCompareInterrupt, CaptureInterrupt<T>>) -> Self {
        let timer = Timer::new(tim);
        timer.start();
        T::CaptureCompareInterrupt::unpend();
        // SAFETY: the handler bound to this interrupt only touches this timer's flags and `EDGE`.
        unsafe { T::CaptureCompareInterrupt::enable() };
        Self { timer }
    }

    /// Routes `pin` to channel `C` and captures both of its edges.
    pub fn pin<C: TimerChannel>(&self, pin: Peri<'static, impl TimerPin<T, C>>) -> Flex<'static> {
        let af = pin.af_num();
        let mut flex = Flex::new(pin);
        flex.set_as_af_unchecked(af, AfType::input(INPUT_PULL));
        let channel = C::CHANNEL;
        let timer = &self.timer;
        timer.set_input_ti_selection(channel, InputTISelection::Normal);
        // fSAMPLING = fDTS / 32, 8 samples: pulses under 2.8 µs (90 MHz timer clock) are ignored.
        timer.set_input_capture_filter(channel, FilterValue::FDTS_DIV32_N8);
        timer.set_input_capture_mode(channel, InputCaptureMode::BothEdges);
        timer.set_input_capture_prescaler(channel, 0);
        timer.enable_channel(channel, true);
        timer.enable_input_interrupt(channel, true);
        flex
    }

    /// Clears the channels' pending edges and enables their interrupts again.
    fn rearm(&self) {
        let regs = self.timer.regs_gp16();
        let channels = regs.ccer().read().0;
        // CCxE sit at bits 0, 4, 8, 12; the flags at bits 1..=4.
        let enabled = (0..4u32).filter(|n| channels & (1 << (4 * n)) != 0).fold(0u32, |mask, n| mask | (2 << n));
        cortex_m::interrupt::free(|_| {
            regs.sr().write_value(SrGp16(!(enabled | (enabled << 8))));
            regs.dier().modify(|w| w.0 |= enabled);
        });
    }
}

/// Interrupt handler for a capture timer: masks the channels that fired,
/// clears their flags and wakes [`edge_task`].
#[derive(Debug)]
pub struct CaptureInterrupt<T> {
    _timer: PhantomData<T>,
}

impl<T: GeneralInstance4Channel> Handler<T::CaptureCompareInterrupt> for CaptureInterrupt<T> {
    unsafe fn on_interrupt() {
        // SAFETY: `T::regs()` is this timer's register block, general-purpose layout.
        let regs = unsafe { pac::timer::TimGp16::from_ptr(T::regs()) };
        let fired = regs.sr().read().0 & regs.dier().read().0 & CAPTURE_FLAGS;
        regs.dier().modify(|w| w.0 &= !fired);
        // SR bits are cleared by writing 0; writing 1 leaves them.
        regs.sr().write_value(SrGp16(!(fired | ((fired << 8) & OVERCAPTURE_FLAGS))));
        EDGE.signal(());
    }
}

/// Interrupt handler for the EXTI lines: masks the lines that fired, clears
/// them and wakes [`edge_task`].
#[derive(Debug)]
pub struct EdgeInterrupt;

impl<I: Interrupt> Handler<I> for EdgeInterrupt {
    unsafe fn on_interrupt() {
        let exti = pac::EXTI;
        let fired = exti.pr(0).read().0 & exti.imr(0).read().0 & EXTI_LINES;
        exti.imr(0).modify(|w| w.0 &= !fired);
        // PR bits are cleared by writing 1.
        exti.pr(0).write_value(Lines(fired));
        EDGE.signal(());
    }
}

/// The input pins and their debounced levels, shared by [`edge_task`] and
/// the 100 ms refresh ([`Inputs`]).
pub struct Edges {
    digital: [ExtiInput<'static, Blocking>; DIGITAL_POINTS],
    tool: [Flex<'static>; TOOL_POINTS],
    tim4: CaptureTimer<TIM4>,
    tim3: CaptureTimer<TIM3>,
    /// Debounced levels: bits 0-15 ControlBox inputs, bits 16-21 tool inputs.
    debounced: AtomicU32,
}

impl core::fmt::Debug for Edges {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Edges").field("debounced", &self.debounced).finish_non_exhaustive()
    }
}

impl Edges {
    pub fn new(
        digital: [ExtiInput<'static, Blocking>; DIGITAL_POINTS],
        tool: [Flex<'static>; TOOL_POINTS],
        tim4: CaptureTimer<TIM4>,
        tim3: CaptureTimer<TIM3>,
    ) -> Self {
        let edges = Self { digital, tool, tim4, tim3, debounced: AtomicU32::new(0) };
        edges.debounced.store(edges.sample(), Ordering::Relaxed);
        edges
    }

    /// The pins' levels now: bits 0-15 ControlBox inputs, bits 16-21 tool inputs.
    fn sample(&self) -> u32 {
        let digital = self.digital.iter().map(ExtiInput::is_high);
        let tool = self.tool.iter().map(Flex::is_high);
        digital.chain(tool).enumerate().fold(0, |mask, (n, high)| mask | (u32::from(high) << n))
    }

    /// Every edge interrupt armed again, with nothing pending.
    fn rearm(&self) {
        cortex_m::interrupt::free(|_| {
            let exti = pac::EXTI;
            exti.pr(0).write_value(Lines(EXTI_LINES));
            exti.imr(0).modify(|w| w.0 |= EXTI_LINES);
        });
        self.tim4.rearm();
        self.tim3.rearm();
    }

    /// The debounced ControlBox and tool inputs.
    pub fn debounced(&self) -> (u16, u8) {
        split(self.debounced.load(Ordering::Relaxed))
    }

    /// Samples the pins and pushes what changed since the last push.
    fn update(&self, shared: &Device<'_>) {
        let now = self.sample();
        let before = self.debounced.swap(now, Ordering::Relaxed);
        let (digital, tool) = split(now);
        let (digital_before, tool_before) = split(before);
        if digital != digital_before {
            shared.set_digital_inputs(digital);
        }
        if tool != tool_before {
            shared.set_tool_inputs(tool);
        }
    }
}

/// Bits 0-15 and 16-21 of a sample.
fn split(levels: u32) -> (u16, u8) {
    let [a, b, c, _] = levels.to_le_bytes();
    (u16::from_le_bytes([a, b]), c & 0x3f)
}

/// Pushes input edges into the image as they happen (see the module docs).
#[embassy_executor::task]
pub async fn edge_task(edges: &'static Edges, shared: &'static Device<'static>) -> ! {
    loop {
        EDGE.reset();
        edges.rearm();
        // Sampled after arming: an edge before this is seen here, one after it fires.
        edges.update(shared);
        if with_timeout(RESAMPLE, EDGE.wait()).await.is_ok() {
            // The edge, at once; then the lock-out.
            edges.update(shared);
            Delay::after(DEBOUNCE).await;
        }
    }
}

/// The inputs as the 100 ms refresh samples them: debounced digital levels and the ADC.
pub struct Inputs {
    edges: &'static Edges,
    adc: Adc<'static, ADC1>,
    channels: [AnyAdcChannel<'static, ADC1>; ANALOG_CHANNELS],
}

impl core::fmt::Debug for Inputs {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Inputs").field("edges", &self.edges).finish_non_exhaustive()
    }
}

impl Inputs {
    pub fn new(
        edges: &'static Edges,
        adc: Adc<'static, ADC1>,
        channels: [AnyAdcChannel<'static, ADC1>; ANALOG_CHANNELS],
    ) -> Self {
        Self { edges, adc, channels }
    }
}

impl io::InputPins for Inputs {
    fn digital(&mut self) -> u16 {
        self.edges.debounced().0
    }

    fn tool(&mut self) -> u8 {
        self.edges.debounced().1
    }

    fn analog(&mut self, channel: usize, kind: AnalogType) -> u16 {
        let Some(pin) = self.channels.get_mut(channel) else { return 0 };
        let sum: u32 = (0..ADC_SAMPLES).map(|_| u32::from(self.adc.blocking_read(pin, ADC_SAMPLE_TIME))).sum();
        let code = u16::try_from(sum / ADC_SAMPLES).unwrap_or(u16::MAX);
        FRONT_END.to_value(code, kind)
    }
}
