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

use adapter::io::NoRobot;
use adapter::settings::{Cidr, NetMode, NetworkSettings, Settings};
#[cfg(feature = "http")]
use adapter::storage::Store;
use defmt_semihosting as _;
use embassy_executor::Spawner;
use m4_mem as _; // its copy, move and fill routines instead of compiler-builtins' (BENCHMARKS.md)
mod board;
#[cfg(feature = "http")]
mod platform;
mod runtime;
mod systick;
#[cfg(feature = "tls")]
mod tls;
#[cfg(feature = "update")]
mod update;
#[cfg(feature = "update")]
mod watchdog;

use board::{Leds, Mmio, RamInputs};
use lan9118::Lan9118;

adapter::program! {
    driver: Lan9118<Mmio>,
    inputs: RamInputs,
    robot: NoRobot,
    flash: platform::SettingsFlash,
    platform: platform::Mps2,
}

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

static LEDS: Leds = Leds;

/// The stack painted at start, for its high-water mark: more than the
/// NUCLEO has for its stack, so the figure is the image's need.
const STACK_PAINTED: usize = 64 * 1024;

#[cortex_m_rt::entry]
fn main() -> ! {
    cortex_m_support::stack::paint(STACK_PAINTED);
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
    #[allow(unused_mut, reason = "the TLS identity's records are saved into it (tls)")]
    let (mut store, loaded) = load_settings();
    #[cfg(feature = "http")]
    let settings = loaded.settings;
    #[cfg(not(feature = "http"))]
    let settings = SETTINGS;
    // No entropy source on this board: the seed only varies TCP's initial
    // sequence numbers and ports between boards, so the MAC will do.
    let [a, b, c, d, e, f] = mac;
    let seed = u64::from_le_bytes([a, b, c, d, e, f, 0x4d, 0x42]);
    // TLS: the identity from the store (made at the first start), the
    // configurations of HTTPS and port 802 (docs/tls.md).
    #[cfg(feature = "tls")]
    let tls = {
        let address = settings.network.address.map(|cidr| cidr.address);
        let Some(arena) = tls::arena() else { fail("TLS arena", "taken twice") };
        let started = adapter::identity::start(&mut store, &settings, mac, address, [arena], tls::entropy, None);
        embassy_futures::block_on(started)
    };
    let (stack, runner, settings) = program::network(ethernet, settings, mac, seed);
    let program = program::build(Board {
        stack,
        settings,
        mac,
        model: MODEL,
        outputs: &LEDS,
        #[cfg(feature = "http")]
        store,
        #[cfg(feature = "http")]
        loaded,
        #[cfg(feature = "http")]
        platform: platform::Mps2::new(stack, mac, settings.network.mode),
        #[cfg(feature = "http")]
        http_port: Some(adapter::http::HTTP_PORT),
        #[cfg(all(feature = "http", feature = "tls"))]
        https_port: Some(adapter::http::HTTPS_PORT),
        #[cfg(feature = "tls")]
        tls,
    });
    runtime::run(|spawner| {
        let spawned = program::spawn(spawner, program, runner, RamInputs::default(), NoRobot)
            .and_then(|()| spawn_board(spawner, program));
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

/// What this board runs besides the program's tasks: the locate blinker,
/// and with `update` the confirmation and the bootloader's watchdog.
fn spawn_board(spawner: Spawner, program: Program) -> Result<(), embassy_executor::SpawnError> {
    let _ = (spawner, program);
    spawner.spawn(stack_task()?);
    // Without an updater the confirmation only settles the trial flag, so
    // that the watchdog is petted (a reset every 30 s would not help).
    #[cfg(feature = "update")]
    {
        if !update::install() {
            defmt::error!("update: no updater: this image cannot confirm itself");
        }
        spawner.spawn(confirm_task(program.stack, program.device, &program.settings.network)?);
        spawner.spawn(watchdog_task()?);
    }
    #[cfg(feature = "http")]
    {
        spawner.spawn(locate_task()?);
        defmt::info!("HTTP API on port {}", adapter::http::HTTP_PORT);
    }
    Ok(())
}

/// Logs the stack's high-water mark each time it rises (looked at once a second).
#[embassy_executor::task]
async fn stack_task() -> ! {
    cortex_m_support::stack::watch(|used, main, watched| {
        defmt::info!("stack: high-water {=usize} B (main's frame {=usize} B; {=usize} B watched)", used, main, watched)
    })
    .await
}

fn fail(what: &str, error: impl defmt::Format) -> ! {
    defmt::error!("{=str} failed: {}", what, error);
    runtime::exit(runtime::EXIT_FAULT)
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
async fn confirm_task(
    stack: embassy_net::Stack<'static>,
    device: &'static adapter::device::Device<'static>,
    network: &'static adapter::settings::NetworkSettings,
) {
    update::confirm_when_serving(stack, device, network).await
}

/// Pets the bootloader's watchdog, unless this image is on trial.
#[cfg(feature = "update")]
#[embassy_executor::task]
async fn watchdog_task() -> ! {
    update::pet_loop().await
}
