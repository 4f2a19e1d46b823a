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
#[cfg(feature = "http")]
mod flash;
#[cfg(feature = "http")]
mod http;
mod leds;
mod net;
mod pins;
mod safety;
#[cfg(feature = "update")]
mod update;

use adapter::device::{self, Device};
use adapter::net::DeviceName;
use adapter::server::{self, SOCKET_POOL, Server, SlotId};
#[cfg(not(feature = "http"))]
use adapter::settings::Name;
use adapter::settings::Settings;
use defmt::unwrap;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_net::Stack;
use m4_mem as _; // its copy, move and fill routines instead of compiler-builtins' (BENCHMARKS.md)
use panic_probe as _;
use static_cell::StaticCell;

/// The factory settings: the defaults with the build's variables applied
/// (a bad value stops the build).
pub const SETTINGS: Settings = Settings::DEFAULT.with_build_env();

// `MODBUS_PORT` may not take the API's port (the API refuses it at run time).
#[cfg(feature = "http")]
const _: () = assert!(SETTINGS.modbus.port != adapter::http::HTTP_PORT, "MODBUS_PORT must not be the HTTP port");

/// The board, as Read Device Identification (ModelName), `/api/status` and mDNS's TXT name it.
pub const MODEL: &str = "nucleo-f429zi";

/// The Modbus server over the device.
pub type ModbusServer = Server<'static, Device<'static>>;

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

/// The robot link (`robot-link`): the source of the robot's points while `robot.link` is set.
#[cfg(feature = "robot-link")]
pub static ROBOT_LINK: adapter::link::Link = adapter::link::Link::new();

#[cortex_m_rt::entry]
fn main() -> ! {
    // The executor loop measures the CPU load (cortex_m_support).
    cortex_m_support::run(
        |spawner| spawner.spawn(unwrap!(start(spawner))),
        |from, to| adapter::load::CPU_LOAD.slept(from, to),
    )
}

/// Brings the board up, loads the settings and starts every task.
#[embassy_executor::task]
async fn start(spawner: Spawner) {
    let board = board::init();

    // The settings in force: the saved ones (the factory settings when none
    // are saved or they cannot be taken whole), or without the store the
    // factory settings.
    // Loaded before any other task runs, by blocking: a task's future keeps
    // every local live across its `.await`s in static RAM for good (the
    // board's peripherals, the settings: 2 KiB), and nothing waits meanwhile.
    #[cfg(feature = "http")]
    let (store, loaded) = embassy_futures::block_on(http::load(board.flash.settings, board.factory_reset));
    #[cfg(feature = "http")]
    let settings: &'static Settings = {
        static IN_FORCE: StaticCell<Settings> = StaticCell::new();
        IN_FORCE.init(loaded.settings)
    };
    #[cfg(not(feature = "http"))]
    let settings: &'static Settings = &SETTINGS;

    #[cfg(feature = "robot-link")]
    ROBOT_LINK.configure(&settings.robot);
    static DEVICE: StaticCell<Device<'static>> = StaticCell::new();
    let device = &*DEVICE.init(Device::new(settings.watchdog(), MODEL, board.outputs));
    device.drive_outputs();
    static SERVER: StaticCell<ModbusServer> = StaticCell::new();
    let server = &*SERVER.init(Server::new(settings.server_config(board.mac), device));

    let name = settings.device.name.or_default(board.mac);
    let config = adapter::net::initial_config(&settings.network, &name);
    let (stack, runner) = embassy_net::new(board.ethernet, config, net::resources(), board.seed);

    #[cfg(feature = "http")]
    let api = {
        let platform = http::Nucleo::new(stack, board.mac, settings, board.reset, board.rng);
        http::api(server, platform, store, &loaded)
    };
    // The name in force: the settings' (the API may change it), or without
    // the store the factory name, fixed.
    #[cfg(feature = "http")]
    let names: &'static dyn DeviceName = api.control();
    #[cfg(not(feature = "http"))]
    let names: &'static dyn DeviceName = {
        static NAME: StaticCell<Name> = StaticCell::new();
        NAME.init(name)
    };

    // Every task pool is sized for exactly these spawns; a failure is a build
    // mistake, and its panic ends in the fault handler (outputs off, reset).
    unwrap!(board::spawn(spawner, board.tasks, runner, stack, device, server));
    // The link supervisor, on the settings in force (without the `http`
    // feature the factory settings, a constant: 40 bytes less).
    spawner.spawn(unwrap!(net::link_task(
        stack,
        #[cfg(feature = "http")]
        &settings.network,
        server,
        names
    )));
    for slot in 0..SOCKET_POOL {
        spawner.spawn(unwrap!(modbus_task(stack, server, slot)));
    }
    spawner.spawn(unwrap!(refresh_task(device, board.inputs)));
    #[cfg(feature = "robot-link")]
    spawner.spawn(unwrap!(robot_link_task(stack, device)));
    // Without an updater the confirmation only settles the trial flag, so
    // that the watchdog is fed (a reset every 30 s would not help).
    #[cfg(feature = "update")]
    {
        if !update::install(board.flash.dfu, board.flash.state) {
            defmt::error!("update: no updater: this image cannot confirm itself");
        }
        spawner.spawn(unwrap!(confirm_task(stack, device)));
    }
    #[cfg(feature = "http")]
    {
        for _ in 0..adapter::http::MAX_HTTP_CONNECTIONS {
            spawner.spawn(unwrap!(http_task(stack, api)));
        }
        defmt::info!("HTTP API on port {}", adapter::http::HTTP_PORT);
    }
    #[cfg(feature = "mdns")]
    {
        let services = adapter::program::mdns_services(MODEL, server.config().port);
        spawner.spawn(unwrap!(mdns_task(stack, names, services)));
    }
    let config = server.config();
    defmt::info!("serving Modbus TCP on port {}, {} sessions", config.port, config.max_connections);
}

/// The 100 ms refresh of the inputs, the analog readings and the robot data.
#[embassy_executor::task]
async fn refresh_task(device: &'static Device<'static>, mut inputs: pins::Inputs) -> ! {
    #[cfg(not(feature = "robot-link"))]
    let mut robot = robot();
    // The link wins over the board's own source while it is set.
    #[cfg(feature = "robot-link")]
    let mut robot = adapter::link::Gated::new(&ROBOT_LINK, robot());
    device::refresh_loop(device, &mut inputs, &mut robot).await
}

/// Polls the robot controller while `robot.link` is set.
#[cfg(feature = "robot-link")]
#[embassy_executor::task]
async fn robot_link_task(stack: embassy_net::Stack<'static>, device: &'static Device<'static>) -> ! {
    adapter::link::run(stack, device, &ROBOT_LINK).await
}

/// Answers mDNS queries for the name in force and the services.
#[cfg(feature = "mdns")]
#[embassy_executor::task]
async fn mdns_task(stack: Stack<'static>, names: &'static dyn DeviceName, services: adapter::mdns::Services) -> ! {
    adapter::mdns::run(stack, names, services).await
}

/// One Modbus listener per socket; its buffers live in the task's static storage.
#[embassy_executor::task(pool_size = SOCKET_POOL)]
async fn modbus_task(stack: Stack<'static>, server: &'static ModbusServer, slot: SlotId) -> ! {
    server::listen(stack, server, slot).await
}

/// One HTTP listener per connection; its buffers live in the task's static storage.
#[cfg(feature = "http")]
#[embassy_executor::task(pool_size = adapter::http::MAX_HTTP_CONNECTIONS)]
async fn http_task(stack: Stack<'static>, api: &'static http::Api) -> ! {
    adapter::http::listen(stack, api).await
}

/// Confirms this image once it serves, when it runs on trial after a swap.
#[cfg(feature = "update")]
#[embassy_executor::task]
async fn confirm_task(stack: Stack<'static>, device: &'static Device<'static>) {
    update::confirm_when_serving(stack, device).await
}
