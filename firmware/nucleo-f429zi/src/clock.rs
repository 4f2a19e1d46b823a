//! The clocks, and what happens without the ST-LINK's 8 MHz.
//!
//! The board as delivered feeds OSC_IN from the ST-LINK's MCO, 8 MHz (HSE
//! bypass, UM1974). Without it (the ST-LINK cut off or unpowered, its MCO
//! bridge open), embassy-stm32 0.6's clock setup would wait for HSERDY
//! forever (rcc/f247.rs), before the watchdog runs: a board that hangs
//! dark. So [`probe`] turns HSE on in bypass and waits for it for at least
//! [`HSE_TIMEOUT_MS`], before `embassy_stm32::init`; [`config`] then sets
//! the tree from what came:
//!
//! | source | PLL | SYSCLK, AHB | APB1 | APB2 | PLL Q (RNG) |
//! |---|---|---|---|---|---|
//! | HSE, 8 MHz | / 4 x 180 / 2 | 180 MHz | 45 MHz | 90 MHz | 45 MHz |
//! | HSI, 16 MHz (fallback) | / 8 x 168 / 2 | 168 MHz | 42 MHz | 84 MHz | 42 MHz |
//!
//! The fallback runs below 180 MHz on purpose: the HSI is an RC oscillator
//! that drifts with temperature, where the ST-LINK's clock is a crystal's,
//! and 168 MHz keeps the core under its 180 MHz maximum with a margin.
//! Both feed the PLL 2 MHz, RM0090's recommended VCO input (PLLM: "2 MHz to
//! limit PLL jitter"). Ethernet does not depend on either: the RMII
//! reference clock is the PHY's own 50 MHz. The fallback is logged and
//! shown on LD3 ([`crate::leds`]).

use embassy_stm32::pac;
use embassy_stm32::rcc::{
    AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv, PllSource, Sysclk,
};
use embassy_stm32::time::Hertz;

/// How long [`probe`] waits for HSE, at least.
pub const HSE_TIMEOUT_MS: u32 = 100;

/// The clock at reset and until `embassy_stm32::init`: the HSI, 16 MHz
/// (the bootloader leaves it so too).
const RESET_CLOCK_HZ: u32 = 16_000_000;

/// Where the PLL's input comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Source {
    /// The ST-LINK's 8 MHz MCO on OSC_IN (HSE bypass): the board as delivered.
    Hse,
    /// The internal 16 MHz RC: no clock came on OSC_IN.
    Hsi,
}

/// One clock tree: the PLL's input and its dividers.
struct Plan {
    input: u32,
    m: PllPreDiv,
    n: PllMul,
    p: PllPDiv,
    q: PllQDiv,
}

impl Plan {
    const fn vco_input(&self) -> u32 {
        self.input / self.m.to_bits() as u32
    }
    const fn vco(&self) -> u32 {
        self.vco_input() * self.n.to_bits() as u32
    }
    /// SYSCLK and AHB (PLLP is encoded: 0 is / 2, 1 is / 4, ...).
    const fn sysclk(&self) -> u32 {
        self.vco() / ((self.p.to_bits() as u32 + 1) * 2)
    }
    /// The RNG's clock (PLL48CLK).
    const fn pll48(&self) -> u32 {
        self.vco() / self.q.to_bits() as u32
    }
    /// Within the chip's limits (RM0090 RCC_PLLCFGR; the datasheet's
    /// maxima, which embassy also asserts at run time), APB1 at / 4 and
    /// APB2 at / 2.
    const fn fits(&self) -> bool {
        self.vco_input() == 2_000_000
            && self.vco() >= 100_000_000
            && self.vco() <= 432_000_000
            && self.sysclk() <= 180_000_000
            && self.pll48() <= 48_000_000
            && self.sysclk() / 4 <= 45_000_000
            && self.sysclk() / 2 <= 90_000_000
    }
}

/// From the ST-LINK's 8 MHz.
const FROM_HSE: Plan =
    Plan { input: 8_000_000, m: PllPreDiv::DIV4, n: PllMul::MUL180, p: PllPDiv::DIV2, q: PllQDiv::DIV8 };
/// From the HSI's 16 MHz.
const FROM_HSI: Plan =
    Plan { input: 16_000_000, m: PllPreDiv::DIV8, n: PllMul::MUL168, p: PllPDiv::DIV2, q: PllQDiv::DIV8 };

const _: () = {
    assert!(FROM_HSE.fits() && FROM_HSE.sysclk() == 180_000_000 && FROM_HSE.pll48() == 45_000_000);
    assert!(FROM_HSI.fits() && FROM_HSI.sysclk() == 168_000_000 && FROM_HSI.pll48() == 42_000_000);
};

const fn plan(source: Source) -> &'static Plan {
    match source {
        Source::Hse => &FROM_HSE,
        Source::Hsi => &FROM_HSI,
    }
}

/// The core clock from `source`.
pub const fn sysclk(source: Source) -> Hertz {
    Hertz(plan(source).sysclk())
}

/// Whether the ST-LINK's clock is there: HSE on in bypass, HSERDY awaited
/// for at least [`HSE_TIMEOUT_MS`] (RM0090 RCC_CR), then off again if it
/// did not come. Runs at the reset clock, before `embassy_stm32::init`.
/// When it came, HSE is left on and embassy's own wait ends at once.
pub fn probe() -> Source {
    const POLLS: u32 = HSE_TIMEOUT_MS;
    // One poll a millisecond: `delay` waits at least so many cycles.
    const CYCLES_PER_POLL: u32 = RESET_CLOCK_HZ / 1000;
    let cr = pac::RCC.cr();
    // HSEBYP may be written only while HSE is off (RM0090 RCC_CR); it is
    // off from reset, and the bootloader leaves it off.
    cr.modify(|w| w.set_hseon(false));
    cr.modify(|w| w.set_hsebyp(true));
    cr.modify(|w| w.set_hseon(true));
    for _ in 0..POLLS {
        if cr.read().hserdy() {
            return Source::Hse;
        }
        cortex_m::asm::delay(CYCLES_PER_POLL);
    }
    cr.modify(|w| w.set_hseon(false));
    cr.modify(|w| w.set_hsebyp(false));
    Source::Hsi
}

/// The clock configuration from `source`. Without HSE, `rcc.hse` is
/// `None`: embassy then turns HSE off and waits on nothing but the HSI
/// and the PLL (rcc/f247.rs).
pub fn config(source: Source) -> embassy_stm32::Config {
    let plan = plan(source);
    let mut config = embassy_stm32::Config::default();
    match source {
        Source::Hse => {
            config.rcc.hse = Some(Hse { freq: Hertz(plan.input), mode: HseMode::Bypass });
            config.rcc.pll_src = PllSource::HSE;
        }
        Source::Hsi => config.rcc.pll_src = PllSource::HSI,
    }
    config.rcc.pll = Some(Pll { prediv: plan.m, mul: plan.n, divp: Some(plan.p), divq: Some(plan.q), divr: None });
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.sys = Sysclk::PLL1_P;
    config
}
