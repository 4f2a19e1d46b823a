//! The NUCLEO-F429ZI image: Modbus TCP on port 502 over the board's Ethernet.
//!
//! Build and flash: `cargo nucleo` (see `docs/nucleo-f429zi.md`).
#![no_std]
#![no_main]

mod board;
mod leds;
mod net;
mod pins;
mod safety;
mod settings;

use adapter::server::{self, SOCKET_POOL, Shared, SlotId};
use defmt::unwrap;
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_net::Stack;
use panic_probe as _;
use static_cell::StaticCell;

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

    static SHARED: StaticCell<Shared<'static>> = StaticCell::new();
    let shared = &*SHARED.init(Shared::new(adapter::settings::CONFIG, adapter::VERSION, board.outputs));
    shared.drive_outputs();

    let (stack, runner) = embassy_net::new(board.ethernet, net::config(), net::resources(), board.seed);

    // Every task pool is sized for exactly these spawns; a failure is a build
    // mistake, and its panic ends in the fault handler (outputs off, reset).
    unwrap!(board::spawn(spawner, board.tasks, runner, stack, shared));
    for slot in 0..SOCKET_POOL {
        spawner.spawn(unwrap!(modbus_task(stack, shared, slot)));
    }
    spawner.spawn(unwrap!(refresh_task(shared, board.inputs)));
    defmt::info!("serving Modbus TCP on port {}, {} sessions", shared.config().port, shared.config().max_connections);
}

/// The 100 ms refresh of the inputs, the analog readings and the robot data.
#[embassy_executor::task]
async fn refresh_task(shared: &'static Shared<'static>, mut inputs: pins::Inputs) -> ! {
    let mut robot = robot();
    server::refresh_loop(shared, &mut inputs, &mut robot).await
}

/// One Modbus listener per socket; its buffers live in the task's static storage.
#[embassy_executor::task(pool_size = SOCKET_POOL)]
async fn modbus_task(stack: Stack<'static>, shared: &'static Shared<'static>, slot: SlotId) -> ! {
    server::listen(stack, shared, slot).await
}
