//! The NUCLEO-F429ZI image: Modbus TCP on port 502 over the board's Ethernet,
//! and with the `http` feature (on by default) the settings saved in flash
//! and the HTTP API on port 80 ([`http`]).
//!
//! Build and flash: `cargo nucleo` (see `docs/nucleo-f429zi.md`). The
//! factory settings are the defaults of `adapter::settings`, changed by the
//! build-time variables (`MODBUS_*`, `NET_*`, ...; docs/reliability.md);
//! the settings saved on the device override them.
#![no_std]
#![no_main]

mod board;
#[cfg(feature = "http")]
mod flash;
#[cfg(feature = "http")]
mod http;
mod leds;
mod net;
mod pins;
mod safety;

use adapter::device::{self, Device};
use adapter::server::{self, SOCKET_POOL, Server, SlotId};
use adapter::settings::Settings;
use defmt::unwrap;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_net::Stack;
use panic_probe as _;
use static_cell::StaticCell;

/// The factory settings: the defaults with the build's variables applied
/// (a bad value stops the build).
pub const SETTINGS: Settings = Settings::DEFAULT.with_build_env();

/// The Modbus server over the device.
pub type ModbusServer = Server<'static, Device<'static>>;

/// The board, as Read Device Identification (ModelName) and `/api/status` name it.
pub const MODEL: &str = "nucleo-f429zi";

#[cfg(not(feature = "sim-robot"))]
type BoardRobot = adapter::io::NoRobot;
#[cfg(feature = "sim-robot")]
type BoardRobot = sim_robot::SimRobot;

/// No robot link on this board: NOT READY and zeros, or the simulated robot for demos.
const fn robot() -> BoardRobot {
    #[cfg(not(feature = "sim-robot"))]
    return adapter::io::NoRobot;
    #[cfg(feature = "sim-robot")]
    return sim_robot::SimRobot::new(sim_robot::Mode::Demo);
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let board = board::init();

    // The settings in force: the saved ones (the factory settings when none
    // are saved or they cannot be taken whole), or without the store the
    // factory settings.
    #[cfg(feature = "http")]
    let (store, loaded) = http::load(board.settings).await;
    #[cfg(feature = "http")]
    let settings: &'static Settings = {
        static IN_FORCE: StaticCell<Settings> = StaticCell::new();
        IN_FORCE.init(loaded.settings)
    };
    #[cfg(not(feature = "http"))]
    let settings: &'static Settings = &SETTINGS;

    static DEVICE: StaticCell<Device<'static>> = StaticCell::new();
    let device = &*DEVICE.init(Device::new(settings.watchdog(), MODEL, board.outputs));
    device.drive_outputs();
    static SERVER: StaticCell<ModbusServer> = StaticCell::new();
    let server = &*SERVER.init(Server::new(settings.server_config(board.mac), device));

    let config = adapter::net::initial_config(&settings.network);
    let (stack, runner) = embassy_net::new(board.ethernet, config, net::resources(), board.seed);

    // Every task pool is sized for exactly these spawns; a failure is a build
    // mistake, and its panic ends in the fault handler (outputs off, reset).
    unwrap!(board::spawn(
        spawner,
        board.tasks,
        runner,
        stack,
        #[cfg(feature = "http")]
        &settings.network,
        device,
        server
    ));
    for slot in 0..SOCKET_POOL {
        spawner.spawn(unwrap!(modbus_task(stack, server, slot)));
    }
    spawner.spawn(unwrap!(refresh_task(device, board.inputs)));
    #[cfg(feature = "http")]
    {
        let platform = http::Nucleo::new(stack, board.mac, settings, board.rng);
        let api = http::api(server, platform, store, &loaded);
        for _ in 0..adapter::http::MAX_HTTP_CONNECTIONS {
            spawner.spawn(unwrap!(http_task(stack, api)));
        }
        defmt::info!("HTTP API on port {}", adapter::http::HTTP_PORT);
    }
    let config = server.config();
    defmt::info!("serving Modbus TCP on port {}, {} sessions", config.port, config.max_connections);
}

/// The 100 ms refresh of the inputs, the analog readings and the robot data.
#[embassy_executor::task]
async fn refresh_task(device: &'static Device<'static>, mut inputs: pins::Inputs) -> ! {
    let mut robot = robot();
    device::refresh_loop(device, &mut inputs, &mut robot).await
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
    adapter::http::listen(stack, api, adapter::http::HTTP_PORT).await
}
