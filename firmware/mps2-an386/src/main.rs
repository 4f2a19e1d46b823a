//! The adapter on QEMU's `mps2-an386` board (docs/qemu.md): the LAN9118 on
//! embassy-net, the Modbus listeners, the 100 ms refresh with no robot, and
//! digital outputs 1 and 2 on the FPGA user LEDs; with the `http` feature
//! (on by default) the settings saved in the PSRAM region and the HTTP API
//! on port 80 ([`platform`]); with the `mdns` feature (on by default) the
//! mDNS responder (`NAME.local`, `_modbus._tcp`, `_http._tcp`).
//!
//! Address: the adapter's network policy with the settings in force (the
//! saved ones, or this board's factory settings [`SETTINGS`]): DHCP (slirp
//! gives 10.0.2.15); with no answer within 5 s, 198.18.0.2/24 (the TAP
//! test bench, RFC 2544's range).
#![no_std]
#![no_main]

use adapter::device::{self, Device};
use adapter::net::DeviceName;
use adapter::server::{self, SOCKET_POOL, Server, SlotId};
#[cfg(not(feature = "http"))]
use adapter::settings::Name;
use adapter::settings::{Cidr, NetMode, NetworkSettings, Settings};
#[cfg(feature = "http")]
use adapter::{control::Controller, storage::Store};
use defmt_semihosting as _;
use embassy_executor::Spawner;
use embassy_net::{Runner, Stack, StackResources};
use m4_mem as _; // its copy, move and fill routines instead of compiler-builtins' (BENCHMARKS.md)
mod board;
#[cfg(feature = "http")]
mod platform;
mod runtime;
mod systick;
#[cfg(feature = "update")]
mod update;
#[cfg(feature = "update")]
mod watchdog;

use adapter::io::NoRobot;
use board::{Leds, Mmio, RamInputs};
use lan9118::Lan9118;
use static_cell::StaticCell;

/// Sockets the stack holds (the Modbus listeners, DHCP's, HTTP's, mDNS's).
const SOCKETS: usize = adapter::program::STACK_SOCKETS;

/// The board, as Read Device Identification (ModelName), `/api/status` and mDNS's TXT name it.
pub const MODEL: &str = "mps2-an386";

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

// `MODBUS_PORT` may not take the API's port (the API refuses it at run time).
#[cfg(feature = "http")]
const _: () = assert!(SETTINGS.modbus.port != adapter::http::HTTP_PORT, "MODBUS_PORT must not be the HTTP port");

/// The Modbus server over the device.
type ModbusServer = Server<'static, Device<'static>>;

/// The settings service: the settings, the store and the password over this board.
#[cfg(feature = "http")]
type Control = Controller<'static, platform::SettingsFlash, platform::Mps2>;
/// The HTTP API over it.
#[cfg(feature = "http")]
type Api = adapter::http::Http<'static, platform::SettingsFlash, platform::Mps2>;

static LEDS: Leds = Leds;

/// The robot link (`robot-link`): the source of the robot's points while `robot.link` is set.
#[cfg(feature = "robot-link")]
static ROBOT_LINK: adapter::link::Link = adapter::link::Link::new();

#[cortex_m_rt::entry]
fn main() -> ! {
    defmt::info!("firmware {} on mps2-an386", adapter::VERSION_TEXT);
    let ethernet = match board::init() {
        Some(Ok(ethernet)) => ethernet,
        Some(Err(e)) => fail("LAN9118", e),
        None => fail("board", "initialised twice"),
    };
    let mac = ethernet.mac();
    defmt::info!("LAN9118 up, MAC {=[u8]:02x}", mac);
    // The mDNS group through the MAC's hash filter (other multicast stays out).
    #[cfg(feature = "mdns")]
    let ethernet = {
        let mut ethernet = ethernet;
        if let Err(e) = ethernet.accept_multicast(&[lan9118::ipv4_multicast_mac(adapter::mdns::GROUP)]) {
            fail("LAN9118 multicast filter", e)
        }
        ethernet
    };

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
    #[cfg(feature = "robot-link")]
    ROBOT_LINK.configure(&settings.robot);
    let name = settings.device.name.or_default(mac);
    let config = adapter::net::initial_config(&settings.network, &name);
    let (stack, runner) = embassy_net::new(ethernet, config, RESOURCES.init(StackResources::new()), seed);

    static DEVICE: StaticCell<Device<'static>> = StaticCell::new();
    let device: &'static Device<'static> = DEVICE.init(Device::new(settings.watchdog(), MODEL, &LEDS));
    device.drive_outputs();
    static SERVER: StaticCell<ModbusServer> = StaticCell::new();
    let server: &'static ModbusServer = SERVER.init(Server::new(settings.server_config(mac), device));

    #[cfg(feature = "http")]
    let (api, names): (&'static Api, &'static dyn DeviceName) = {
        let platform = platform::Mps2::new(stack, mac, settings.network.mode);
        let control = Controller::new(server, platform, store, &loaded);
        #[cfg(feature = "robot-link")]
        let control = control.with_robot_link(&ROBOT_LINK);
        static CONTROL: StaticCell<Control> = StaticCell::new();
        let control: &'static Control = CONTROL.init(control);
        static API: StaticCell<Api> = StaticCell::new();
        (API.init(adapter::http::Http::new(control, adapter::http::HTTP_PORT)), control)
    };
    // Without the settings store the name never changes.
    #[cfg(not(feature = "http"))]
    let names: &'static dyn DeviceName = {
        static NAME: StaticCell<Name> = StaticCell::new();
        NAME.init(name)
    };

    runtime::run(|spawner| {
        let shared = Shared {
            stack,
            settings,
            names,
            device,
            server,
            #[cfg(feature = "http")]
            api,
        };
        let spawned = spawn_all(spawner, runner, shared);
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

/// What the tasks share, all of it for the life of the program.
#[derive(Clone, Copy)]
struct Shared {
    stack: Stack<'static>,
    /// The settings in force at start.
    settings: &'static Settings,
    /// The device name in force (the API may change it).
    names: &'static dyn DeviceName,
    device: &'static Device<'static>,
    server: &'static ModbusServer,
    #[cfg(feature = "http")]
    api: &'static Api,
}

fn spawn_all(
    spawner: Spawner,
    runner: Runner<'static, Lan9118<Mmio>>,
    shared: Shared,
) -> Result<(), embassy_executor::SpawnError> {
    #[cfg(feature = "http")]
    let Shared { stack, settings, names, device, server, api } = shared;
    #[cfg(not(feature = "http"))]
    let Shared { stack, settings, names, device, server } = shared;
    spawner.spawn(net_task(runner)?);
    spawner.spawn(link_task(stack, &settings.network, server, names)?);
    #[cfg(feature = "mdns")]
    {
        let services = adapter::program::mdns_services(MODEL, server.config().port);
        spawner.spawn(mdns_task(stack, names, services)?);
    }
    spawner.spawn(refresh_task(device)?);
    #[cfg(feature = "robot-link")]
    spawner.spawn(robot_link_task(stack, device)?);
    for slot in 0..SOCKET_POOL {
        spawner.spawn(modbus_task(stack, server, slot)?);
    }
    // Without an updater the confirmation only settles the trial flag, so
    // that the watchdog is petted (a reset every 30 s would not help).
    #[cfg(feature = "update")]
    {
        if !update::install() {
            defmt::error!("update: no updater: this image cannot confirm itself");
        }
        spawner.spawn(confirm_task(stack, device)?);
    }
    #[cfg(feature = "update")]
    spawner.spawn(watchdog_task()?);
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

/// Follows the link with the adapter's network policy (DHCP's hostname: the name in force).
#[embassy_executor::task]
async fn link_task(
    stack: Stack<'static>,
    network: &'static NetworkSettings,
    server: &'static ModbusServer,
    names: &'static dyn DeviceName,
) -> ! {
    adapter::net::run(stack, network, server, names).await
}

/// Answers mDNS queries for the name in force and the services.
#[cfg(feature = "mdns")]
#[embassy_executor::task]
async fn mdns_task(stack: Stack<'static>, names: &'static dyn DeviceName, services: adapter::mdns::Services) -> ! {
    adapter::mdns::run(stack, names, services).await
}

#[embassy_executor::task]
async fn refresh_task(device: &'static Device<'static>) -> ! {
    #[cfg(not(feature = "robot-link"))]
    let mut robot = NoRobot;
    // The link wins while it is set; no robot otherwise.
    #[cfg(feature = "robot-link")]
    let mut robot = adapter::link::Gated::new(&ROBOT_LINK, NoRobot);
    device::refresh_loop(device, &mut RamInputs::default(), &mut robot).await
}

/// Polls the robot controller while `robot.link` is set.
#[cfg(feature = "robot-link")]
#[embassy_executor::task]
async fn robot_link_task(stack: Stack<'static>, device: &'static Device<'static>) -> ! {
    adapter::link::run(stack, device, &ROBOT_LINK).await
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
    adapter::http::listen(stack, api).await
}

/// Blinks LED1 for `POST /api/locate`.
#[cfg(feature = "http")]
#[embassy_executor::task]
async fn locate_task() -> ! {
    platform::locate_loop().await
}

/// Confirms this image once it serves, when it runs on trial after a swap.
#[cfg(feature = "update")]
#[embassy_executor::task]
async fn confirm_task(stack: Stack<'static>, device: &'static Device<'static>) {
    update::confirm_when_serving(stack, device).await
}

/// Pets the bootloader's watchdog, unless this image is on trial.
#[cfg(feature = "update")]
#[embassy_executor::task]
async fn watchdog_task() -> ! {
    update::pet_loop().await
}
