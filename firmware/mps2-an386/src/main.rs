//! The adapter on QEMU's `mps2-an386` board (docs/qemu.md): the LAN9118 on
//! embassy-net, the Modbus listeners, the 100 ms refresh with no robot, and
//! digital outputs 1 and 2 on the FPGA user LEDs; with the `http` feature
//! (on by default) the settings saved in the PSRAM region and the HTTP API
//! on port 80 ([`platform`]).
//!
//! Address: the adapter's network policy with the settings in force (the
//! saved ones, or this board's factory settings [`SETTINGS`]): DHCP (slirp
//! gives 10.0.2.15); with no answer within 5 s, 198.18.0.2/24 (the TAP
//! test bench, RFC 2544's range).
#![no_std]
#![no_main]

use adapter::device::{self, Device};
use adapter::server::{self, SOCKET_POOL, Server, SlotId};
use adapter::settings::{Cidr, NetMode, NetworkSettings, Settings};
#[cfg(feature = "http")]
use adapter::{http::Controller, storage::Store};
use defmt_semihosting as _;
use embassy_executor::Spawner;
use embassy_net::{Runner, Stack, StackResources};
mod board;
#[cfg(feature = "http")]
mod platform;
mod runtime;
mod systick;

use adapter::io::NoRobot;
use board::{Leds, Mmio, RamInputs};
use lan9118::Lan9118;
use static_cell::StaticCell;

/// Sockets the stack holds: the Modbus listeners, DHCP's, and the HTTP listeners.
const SOCKETS: usize = SOCKET_POOL + 1 + HTTP_SOCKETS;
#[cfg(feature = "http")]
const HTTP_SOCKETS: usize = adapter::http::MAX_HTTP_CONNECTIONS;
#[cfg(not(feature = "http"))]
const HTTP_SOCKETS: usize = 0;

/// The factory settings: DHCP with the test bench's address as the
/// fallback after 5 s, then the build's variables (a bad value stops the build).
pub const SETTINGS: Settings = Settings {
    network: NetworkSettings {
        mode: NetMode::Dhcp,
        address: Some(Cidr { address: [198, 18, 0, 2], prefix_len: 24 }),
        gateway: None,
        dhcp_timeout_s: 5,
    },
    ..Settings::DEFAULT
}
.with_build_env();

/// The Modbus server over the device.
type ModbusServer = Server<'static, Device<'static>>;

/// The board, as Read Device Identification (ModelName) and `/api/status` name it.
const MODEL: &str = "mps2-an386";

/// The HTTP API over the settings store and this board.
#[cfg(feature = "http")]
type Api = adapter::http::Http<'static, Controller<'static, platform::SettingsFlash, platform::Mps2>>;

static LEDS: Leds = Leds;

#[cortex_m_rt::entry]
fn main() -> ! {
    defmt::info!("firmware {} on mps2-an386", env!("CARGO_PKG_VERSION"));
    let ethernet = match board::init() {
        Some(Ok(ethernet)) => ethernet,
        Some(Err(e)) => fail("LAN9118", e),
        None => fail("board", "initialised twice"),
    };
    let mac = ethernet.mac();
    defmt::info!("LAN9118 up, MAC {=[u8]:02x}", mac);

    // The settings in force: the saved ones (the factory settings when
    // none are saved or they cannot be taken whole), or without the
    // store the factory settings.
    #[cfg(feature = "http")]
    let (store, loaded) = load_settings();
    #[cfg(feature = "http")]
    let settings: &'static Settings = {
        static IN_FORCE: StaticCell<Settings> = StaticCell::new();
        IN_FORCE.init(loaded.settings)
    };
    #[cfg(not(feature = "http"))]
    let settings: &'static Settings = &SETTINGS;

    static RESOURCES: StaticCell<StackResources<SOCKETS>> = StaticCell::new();
    // No entropy source on this board: the seed only varies TCP's initial
    // sequence numbers and ports between boards, so the MAC will do.
    let [a, b, c, d, e, f] = mac;
    let seed = u64::from_le_bytes([a, b, c, d, e, f, 0x4d, 0x42]);
    let config = adapter::net::initial_config(&settings.network);
    let (stack, runner) = embassy_net::new(ethernet, config, RESOURCES.init(StackResources::new()), seed);

    static DEVICE: StaticCell<Device<'static>> = StaticCell::new();
    let device: &'static Device<'static> = DEVICE.init(Device::new(settings.watchdog(), MODEL, &LEDS));
    device.drive_outputs();
    static SERVER: StaticCell<ModbusServer> = StaticCell::new();
    let server: &'static ModbusServer = SERVER.init(Server::new(settings.server_config(mac), device));

    #[cfg(feature = "http")]
    let api: &'static Api = {
        let platform = platform::Mps2::new(stack, mac, settings.network.mode);
        static CONTROLLER: StaticCell<Controller<'static, platform::SettingsFlash, platform::Mps2>> = StaticCell::new();
        let controller = CONTROLLER.init(Controller::new(server, platform, store, &loaded));
        static API: StaticCell<Api> = StaticCell::new();
        API.init(adapter::http::Http::new(controller))
    };

    runtime::run(|spawner| {
        let spawned = spawn_all(
            spawner,
            stack,
            runner,
            &settings.network,
            device,
            server,
            #[cfg(feature = "http")]
            api,
        );
        if let Err(e) = spawned {
            fail("spawn", e)
        }
    })
}

/// The settings store over the PSRAM region, and what it holds. A load
/// that found something wrong is a warning: the factory settings stand in
/// for what cannot be read, and `/api/status` reports the storage not ok.
#[cfg(feature = "http")]
fn load_settings() -> (Store<platform::SettingsFlash>, adapter::storage::Loaded) {
    let Some(flash) = platform::settings_flash() else { fail("settings region", "taken twice") };
    let range = 0..u32::try_from(flash.capacity()).unwrap_or(0);
    let mut store = match Store::new(flash, range) {
        Ok(store) => store,
        Err(e) => fail("settings store", e),
    };
    // The flash is RAM: every operation completes at once, no executor needed.
    let loaded = embassy_futures::block_on(store.load(&SETTINGS));
    if let Some(error) = loaded.error {
        defmt::warn!("settings: {}", error);
    }
    defmt::info!("settings: {} records; storage ok: {}", loaded.status.records, loaded.status.ok);
    (store, loaded)
}

fn spawn_all(
    spawner: Spawner,
    stack: Stack<'static>,
    runner: Runner<'static, Lan9118<Mmio>>,
    network: &'static NetworkSettings,
    device: &'static Device<'static>,
    server: &'static ModbusServer,
    #[cfg(feature = "http")] api: &'static Api,
) -> Result<(), embassy_executor::SpawnError> {
    spawner.spawn(net_task(runner)?);
    spawner.spawn(link_task(stack, network, server)?);
    spawner.spawn(refresh_task(device)?);
    for slot in 0..SOCKET_POOL {
        spawner.spawn(modbus_task(stack, server, slot)?);
    }
    #[cfg(feature = "http")]
    {
        for _ in 0..adapter::http::MAX_HTTP_CONNECTIONS {
            spawner.spawn(http_task(stack, api)?);
        }
        spawner.spawn(locate_task()?);
        defmt::info!("HTTP API on port {}", adapter::http::HTTP_PORT);
    }
    Ok(())
}

fn fail(what: &str, error: impl defmt::Format) -> ! {
    defmt::error!("{=str} failed: {}", what, error);
    runtime::exit(runtime::EXIT_FAULT)
}

#[embassy_executor::task]
async fn net_task(mut runner: Runner<'static, Lan9118<Mmio>>) -> ! {
    runner.run().await
}

/// Follows the link with the adapter's network policy.
#[embassy_executor::task]
async fn link_task(stack: Stack<'static>, network: &'static NetworkSettings, server: &'static ModbusServer) -> ! {
    adapter::net::run(stack, network, server).await
}

#[embassy_executor::task]
async fn refresh_task(device: &'static Device<'static>) -> ! {
    device::refresh_loop(device, &mut RamInputs::default(), &mut NoRobot).await
}

/// One Modbus listener per socket; its buffers live in the task's static storage.
#[embassy_executor::task(pool_size = SOCKET_POOL)]
async fn modbus_task(stack: Stack<'static>, server: &'static ModbusServer, slot: SlotId) -> ! {
    server::listen(stack, server, slot).await
}

/// One HTTP listener per connection; its buffers live in the task's static storage.
#[cfg(feature = "http")]
#[embassy_executor::task(pool_size = adapter::http::MAX_HTTP_CONNECTIONS)]
async fn http_task(stack: Stack<'static>, api: &'static Api) -> ! {
    adapter::http::listen(stack, api, adapter::http::HTTP_PORT).await
}

/// Blinks LED1 for `POST /api/locate`.
#[cfg(feature = "http")]
#[embassy_executor::task]
async fn locate_task() -> ! {
    platform::locate_loop().await
}
