//! The NUCLEO-F429ZI image: Modbus TCP on port 502 over the board's Ethernet,
//! and with the `http` feature (on by default) the settings saved in flash
//! and the HTTP API on port 80 ([`http`]); with `mdns` (on by default) the
//! mDNS responder.
//!
//! Build and flash: `cargo nucleo` (see `docs/nucleo-f429zi.md`). The
//! factory settings are the defaults of `adapter::settings`, changed by the
//! build-time variables (`MODBUS_*`, `NET_*`, ...; docs/reliability.md);
//! the settings saved on the device override them.
#![no_std]
#![no_main]

mod board;
#[cfg(feature = "http")]
mod button;
mod clock;
#[cfg(feature = "http")]
mod flash;
#[cfg(feature = "http")]
mod http;
mod leds;
mod net;
mod phy;
mod pins;
mod safety;
// Its erase parallelism is for the flash driver, which only `http` has.
#[cfg_attr(not(feature = "http"), expect(dead_code))]
mod silicon;
#[cfg(feature = "tls")]
mod tls;
#[cfg(feature = "update")]
mod update;

use adapter::settings::Settings;
use defmt::unwrap;
use defmt_rtt as _;
use embassy_executor::Spawner;
use m4_mem as _; // its copy, move and fill routines instead of compiler-builtins' (BENCHMARKS.md)
use panic_probe as _;

adapter::program! {
    driver: net::Device,
    inputs: pins::Inputs,
    robot: BoardRobot,
    flash: flash::SettingsFlash,
    platform: http::Nucleo,
}

/// The factory settings: the defaults with the build's variables applied
/// (a bad value stops the build).
pub const SETTINGS: Settings = Settings::DEFAULT.with_build_env();

// `MODBUS_PORT` may not take the API's port (the API refuses it at run time).
#[cfg(feature = "http")]
const _: () = assert!(SETTINGS.modbus.port != adapter::http::HTTP_PORT, "MODBUS_PORT must not be the HTTP port");

/// The board, as Read Device Identification (ModelName), `/api/status` and mDNS's TXT name it.
pub const MODEL: &str = "nucleo-f429zi";

#[cfg(not(feature = "sim-robot"))]
type BoardRobot = adapter::io::NoRobot;
#[cfg(feature = "sim-robot")]
type BoardRobot = sim_robot::SimRobot;

/// The board's own robot source: NOT READY and zeros, or the simulated robot
/// for demos (the robot link, `robot-link`, wins over it while set).
const fn robot() -> BoardRobot {
    #[cfg(not(feature = "sim-robot"))]
    return adapter::io::NoRobot;
    #[cfg(feature = "sim-robot")]
    return sim_robot::SimRobot::new(sim_robot::Mode::Demo);
}

#[cortex_m_rt::entry]
fn main() -> ! {
    // The whole free stack painted, for its high-water mark (stack_task).
    cortex_m_support::stack::paint(usize::MAX);
    // The executor loop measures the CPU load (cortex_m_support).
    cortex_m_support::run(
        |spawner| spawner.spawn(unwrap!(start(spawner))),
        |from, to| adapter::cpu_load::CPU_LOAD.slept(from, to),
    )
}

/// Brings the board up, loads the settings and starts every task.
#[embassy_executor::task]
async fn start(spawner: Spawner) {
    #[cfg_attr(not(feature = "http"), expect(unused_mut))]
    let mut board = board::init();

    // The settings in force: the saved ones (the factory settings when none
    // are saved or they cannot be taken whole), or without the store the
    // factory settings.
    // Loaded before any other task runs, by blocking: a task's future keeps
    // every local live across its `.await`s in static RAM for good (the
    // board's peripherals, the settings: 2 KiB), and nothing waits meanwhile.
    // The watchdog runs and its feeder task does not yet: the load feeds it
    // (a factory reset, or a format, erases two 16 KiB sectors: up to 1 s,
    // near the watchdog's shortest period, 1.36 s).
    #[cfg(feature = "http")]
    #[allow(unused_mut, reason = "the TLS identity's records are saved into it (tls)")]
    let (mut store, loaded) = board.tasks.block_on(http::load(board.flash.settings, board.factory_reset));
    #[cfg(feature = "http")]
    http::install_rng(board.rng);
    #[cfg(feature = "http")]
    let settings = loaded.settings;
    #[cfg(not(feature = "http"))]
    let settings = SETTINGS;
    // TLS: the identity from the store (made at the first start, from the
    // hardware RNG), the configurations of HTTPS and port 802 (docs/tls.md). Blocking, fed,
    // as the load: a new key's certificate and its two records take a
    // signature and two flash writes.
    #[cfg(feature = "tls")]
    let tls = {
        let address = settings.network.address.map(|cidr| cidr.address);
        let Some(arena) = tls::arena() else { defmt::panic!("the TLS arena, taken twice") };
        let started = adapter::identity::start(&mut store, &settings, board.mac, address, arena, http::entropy, None);
        board.tasks.block_on(started)
    };
    let (stack, runner, settings) = program::network(board.ethernet, settings, board.mac, board.seed);
    let program = program::build(Board {
        stack,
        settings,
        mac: board.mac,
        model: MODEL,
        outputs: board.outputs,
        #[cfg(feature = "http")]
        store,
        #[cfg(feature = "http")]
        loaded,
        #[cfg(feature = "http")]
        platform: http::Nucleo::new(stack, board.mac, settings, board.reset),
        #[cfg(feature = "http")]
        http_port: Some(adapter::http::HTTP_PORT),
        #[cfg(all(feature = "http", feature = "tls"))]
        https_port: Some(adapter::http::HTTPS_PORT),
        #[cfg(feature = "tls")]
        tls,
    });

    // Every task pool is sized for exactly these spawns; a failure is a build
    // mistake, and its panic ends in the fault handler (outputs off, reset).
    unwrap!(board::spawn(spawner, board.tasks, stack, program.device, program.server));
    spawner.spawn(unwrap!(stack_task()));
    unwrap!(program::spawn(spawner, program, runner, board.inputs, robot()));
    // Without an updater the confirmation only settles the trial flag, so
    // that the watchdog is fed (a reset every 30 s would not help).
    #[cfg(feature = "update")]
    {
        if !update::install(board.flash.dfu, board.flash.state) {
            defmt::error!("update: no updater: this image cannot confirm itself");
        }
        spawner.spawn(unwrap!(confirm_task(stack, program.device, &program.settings.network)));
    }
    #[cfg(feature = "http")]
    spawner.spawn(unwrap!(button_task(board.button, program.control)));
    let config = program.server.config();
    defmt::info!("serving Modbus TCP on port {}, {} sessions", config.port, config.max_connections);
}

/// The user button's short presses: the first password's window.
#[cfg(feature = "http")]
#[embassy_executor::task]
async fn button_task(button: embassy_stm32::gpio::Input<'static>, control: &'static Control) {
    button::watch(button, control).await
}

/// Confirms this image once it serves, when it runs on trial after a swap.
#[cfg(feature = "update")]
#[embassy_executor::task]
async fn confirm_task(
    stack: embassy_net::Stack<'static>,
    device: &'static adapter::device::Device<'static>,
    network: &'static adapter::settings::NetworkSettings,
) {
    update::confirm_when_serving(stack, device, network).await
}

/// Logs the stack's high-water mark each time it rises (looked at once a
/// second): what the SRAM left after the statics must hold, with 16 KiB to
/// spare (docs/sizes.md).
#[embassy_executor::task]
async fn stack_task() -> ! {
    cortex_m_support::stack::watch(|used, main, watched| {
        defmt::info!("stack: high-water {=usize} B (main's frame {=usize} B; {=usize} B watched)", used, main, watched)
    })
    .await
}
