//! The NUCLEO-F429ZI image: Modbus TCP on port 502 over the board's Ethernet.
//!
//! Build and flash: `cargo nucleo` (see `docs/nucleo-f429zi.md`).
#![no_std]
#![no_main]

use defmt::unwrap;
use defmt_rtt as _;
use embassy_executor::Spawner;
use firmware::board::nucleo_f429zi::{self as board, net, pins};
use firmware::server::{self, Shared};
use panic_probe as _;
use static_cell::StaticCell;

#[cfg(not(feature = "sim-robot"))]
type BoardRobot = firmware::io::NoRobot;
#[cfg(feature = "sim-robot")]
type BoardRobot = firmware::sim_robot::SimRobot;

/// No robot link on this board: NOT READY and zeros, or the simulated robot for demos.
const fn robot() -> BoardRobot {
    #[cfg(not(feature = "sim-robot"))]
    return firmware::io::NoRobot;
    #[cfg(feature = "sim-robot")]
    return firmware::sim_robot::SimRobot::new(firmware::sim_robot::Mode::Demo);
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let board = board::init();

    static SHARED: StaticCell<Shared<'static>> = StaticCell::new();
    let shared = &*SHARED.init(Shared::new(firmware::settings::CONFIG, firmware::VERSION, board.outputs));
    shared.drive_outputs();

    let (stack, runner) = embassy_net::new(board.ethernet, net::config(), net::resources(), board.seed);

    // Every task pool is sized for exactly these spawns; a failure is a build
    // mistake, and its panic ends in the fault handler (outputs off, reset).
    unwrap!(board::spawn(spawner, board.tasks, runner, stack, shared));
    unwrap!(server::spawn_listeners(spawner, stack, shared));
    spawner.spawn(unwrap!(refresh_task(shared, board.inputs)));
    defmt::info!("serving Modbus TCP on port {}, {} sessions", shared.config().port, shared.config().max_connections);
}

/// The 100 ms refresh of the inputs, the analog readings and the robot data.
#[embassy_executor::task]
async fn refresh_task(shared: &'static Shared<'static>, mut inputs: pins::Inputs) -> ! {
    let mut robot = robot();
    server::refresh_loop(shared, &mut inputs, &mut robot).await
}
