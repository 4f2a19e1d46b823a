//! The adapter on QEMU's `mps2-an386` board (docs/qemu.md): the LAN9118 on
//! embassy-net, the Modbus listeners, the 100 ms refresh with no robot, and
//! digital outputs 1 and 2 on the FPGA user LEDs.
//!
//! Address: DHCP (slirp gives 10.0.2.15); with no answer within
//! [`DHCP_TIMEOUT`], the static [`FALLBACK_ADDRESS`] (the TAP test bench).
#![no_std]
#![no_main]

use defmt_semihosting as _;
use embassy_executor::Spawner;
use embassy_net::{Config, ConfigV4, Ipv4Address, Ipv4Cidr, Runner, Stack, StackResources, StaticConfigV4};
use embassy_time::{Duration, with_timeout};
mod board;
mod runtime;
mod systick;

use adapter::fmt::Ip;
use adapter::io::NoRobot;
use adapter::server::{self, SOCKET_POOL, Shared, SlotId};
use board::{Leds, Mmio, RamInputs};
use lan9118::Lan9118;
use static_cell::StaticCell;

/// Sockets the stack holds: the Modbus listeners, and DHCP's.
const SOCKETS: usize = SOCKET_POOL + 1;
/// How long to wait for a DHCP server before using [`FALLBACK_ADDRESS`].
const DHCP_TIMEOUT: Duration = Duration::from_secs(3);
/// The static address without DHCP: the test bench range (RFC 2544).
const FALLBACK_ADDRESS: Ipv4Cidr = Ipv4Cidr::new(Ipv4Address::new(198, 18, 0, 2), 24);

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
    let config = Config::dhcpv4(Default::default());
    let (stack, runner) = embassy_net::new(ethernet, config, RESOURCES.init(StackResources::new()), seed);

    static SHARED: StaticCell<Shared<'static>> = StaticCell::new();
    let shared: &'static Shared<'static> = SHARED.init(Shared::new(adapter::settings::CONFIG, adapter::VERSION, &LEDS));
    shared.drive_outputs();

    runtime::run(|spawner| {
        if let Err(e) = spawn_all(spawner, stack, runner, shared) {
            fail("spawn", e)
        }
    })
}

fn spawn_all(
    spawner: Spawner,
    stack: Stack<'static>,
    runner: Runner<'static, Lan9118<Mmio>>,
    shared: &'static Shared<'static>,
) -> Result<(), embassy_executor::SpawnError> {
    spawner.spawn(net_task(runner)?);
    spawner.spawn(address_task(stack)?);
    spawner.spawn(refresh_task(shared)?);
    for slot in 0..SOCKET_POOL {
        spawner.spawn(modbus_task(stack, shared, slot)?);
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

#[embassy_executor::task]
async fn refresh_task(shared: &'static Shared<'static>) -> ! {
    server::refresh_loop(shared, &mut RamInputs::default(), &mut NoRobot).await
}

/// DHCP, or the fallback address; then logs where the server listens.
#[embassy_executor::task]
async fn address_task(stack: Stack<'static>) {
    if with_timeout(DHCP_TIMEOUT, stack.wait_config_up()).await.is_err() {
        let address = FALLBACK_ADDRESS.address().octets();
        defmt::info!("no DHCP answer: using {}/{}", Ip(address), FALLBACK_ADDRESS.prefix_len());
        stack.set_config_v4(ConfigV4::Static(StaticConfigV4 {
            address: FALLBACK_ADDRESS,
            gateway: None,
            dns_servers: Default::default(),
        }));
    }
    stack.wait_config_up().await;
    if let Some(config) = stack.config_v4() {
        defmt::info!("Modbus TCP server at {}:{=u16}", Ip(config.address.address().octets()), server::MODBUS_PORT);
    }
}

/// One Modbus listener per socket; its buffers live in the task's static storage.
#[embassy_executor::task(pool_size = SOCKET_POOL)]
async fn modbus_task(stack: Stack<'static>, shared: &'static Shared<'static>, slot: SlotId) -> ! {
    server::listen(stack, shared, slot).await
}
