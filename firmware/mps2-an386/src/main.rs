//! The adapter on QEMU's `mps2-an386` board (docs/qemu.md): the LAN9118 on
//! embassy-net, the Modbus listeners, the 100 ms refresh with no robot, and
//! digital outputs 1 and 2 on the FPGA user LEDs.
//!
//! Address: the adapter's network policy with this board's factory
//! settings ([`SETTINGS`]): DHCP (slirp gives 10.0.2.15); with no answer
//! within 5 s, 198.18.0.2/24 (the TAP test bench, RFC 2544's range).
#![no_std]
#![no_main]

use adapter::device::{self, Device};
use adapter::server::{self, SOCKET_POOL, Server, SlotId};
use adapter::settings::{Cidr, NetMode, NetworkSettings, Settings};
use defmt_semihosting as _;
use embassy_executor::Spawner;
use embassy_net::{Runner, Stack, StackResources};
mod board;
mod runtime;
mod systick;

use adapter::io::NoRobot;
use board::{Leds, Mmio, RamInputs};
use lan9118::Lan9118;
use static_cell::StaticCell;

/// Sockets the stack holds: the Modbus listeners, and DHCP's.
const SOCKETS: usize = SOCKET_POOL + 1;

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

    static RESOURCES: StaticCell<StackResources<SOCKETS>> = StaticCell::new();
    // No entropy source on this board: the seed only varies TCP's initial
    // sequence numbers and ports between boards, so the MAC will do.
    let [a, b, c, d, e, f] = mac;
    let seed = u64::from_le_bytes([a, b, c, d, e, f, 0x4d, 0x42]);
    let config = adapter::net::initial_config(&SETTINGS.network);
    let (stack, runner) = embassy_net::new(ethernet, config, RESOURCES.init(StackResources::new()), seed);

    static DEVICE: StaticCell<Device<'static>> = StaticCell::new();
    let device: &'static Device<'static> = DEVICE.init(Device::new(SETTINGS.watchdog(), adapter::VERSION, &LEDS));
    device.drive_outputs();
    static SERVER: StaticCell<ModbusServer> = StaticCell::new();
    let server: &'static ModbusServer = SERVER.init(Server::new(SETTINGS.server_config(), device));

    runtime::run(|spawner| {
        if let Err(e) = spawn_all(spawner, stack, runner, device, server) {
            fail("spawn", e)
        }
    })
}

fn spawn_all(
    spawner: Spawner,
    stack: Stack<'static>,
    runner: Runner<'static, Lan9118<Mmio>>,
    device: &'static Device<'static>,
    server: &'static ModbusServer,
) -> Result<(), embassy_executor::SpawnError> {
    spawner.spawn(net_task(runner)?);
    spawner.spawn(link_task(stack, server)?);
    spawner.spawn(refresh_task(device)?);
    for slot in 0..SOCKET_POOL {
        spawner.spawn(modbus_task(stack, server, slot)?);
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
async fn link_task(stack: Stack<'static>, server: &'static ModbusServer) -> ! {
    adapter::net::run(stack, &SETTINGS.network, server).await
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
