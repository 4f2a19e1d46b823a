//! hal-sim: the adapter's firmware logic on a Linux TAP, with simulated pins
//! and robot. The same sessions, map and tasks as the boards; only the board
//! differs (docs/hal-sim.md).

mod cli;
mod control;
mod runtime;
mod sim;
mod tap;

use std::hash::{BuildHasher, Hasher, RandomState};
use std::io::Write as _;
use std::os::unix::net::UnixListener;
use std::process::ExitCode;

use adapter::device::{self, Device};
use adapter::server::{self, SOCKET_POOL, Server, SlotId};
use embassy_executor::Spawner;
use embassy_net::{Runner, Stack, StackResources};
use sim_robot::SimRobot;

use crate::cli::{Action, Options};
use crate::runtime::Executor;
use crate::sim::{Board, OutputLatch};
use crate::tap::TunTapDevice;

/// The Modbus server over the simulated device.
type ModbusServer = Server<'static, Device<'static>>;

/// Exit status for a command line hal-sim cannot run with.
const EXIT_USAGE: u8 = 2;
/// Exit status when the TAP or the control socket cannot be opened.
const EXIT_UNAVAILABLE: u8 = 1;
/// The simulated device's MAC: locally administered, unicast.
pub(crate) const MAC: [u8; 6] = [0x02, 0x4d, 0x42, 0x53, 0x49, 0x4d];

fn main() -> ExitCode {
    init_logging();
    let options = match cli::parse(std::env::args().skip(1)) {
        Ok(Action::Run(options)) => *options,
        Ok(Action::Help) => {
            println!("{}", cli::usage());
            return ExitCode::SUCCESS;
        }
        Ok(Action::Version) => {
            let adapter::io::Version { major, minor, patch } = adapter::VERSION;
            println!("hal-sim {} (firmware {major}.{minor}.{patch})", env!("CARGO_PKG_VERSION"));
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("hal-sim: error: {e}\n\n{}", cli::usage());
            return ExitCode::from(EXIT_USAGE);
        }
    };

    let mut device = match TunTapDevice::new(&options.tap) {
        Ok(device) => device,
        Err(e) => {
            eprintln!("{}", tap_error(&options.tap, &e));
            return ExitCode::from(EXIT_UNAVAILABLE);
        }
    };
    device.set_hardware_address(MAC);

    let control = match options.control.as_deref().map(control::bind).transpose() {
        Ok(control) => control,
        Err(e) => {
            let path = options.control.as_deref().unwrap_or(std::path::Path::new("")).display();
            eprintln!("hal-sim: cannot open the control socket {path}: {e}");
            return ExitCode::from(EXIT_UNAVAILABLE);
        }
    };

    run(options, device, control)
}

/// Builds the stack and the board, and runs the runtime's loop forever.
fn run(options: Options, device: TunTapDevice, control: Option<UnixListener>) -> ! {
    let net_config = adapter::net::initial_config(&options.settings.network);
    // The Modbus listeners, and DHCP's socket when the mode is dhcp.
    let resources = Box::leak(Box::new(StackResources::<{ SOCKET_POOL + 1 }>::new()));
    let (stack, runner) = embassy_net::new(device, net_config, resources, RandomState::new().build_hasher().finish());

    let outputs: &'static OutputLatch = Box::leak(Box::new(OutputLatch::new()));
    let device: &'static Device<'static> =
        Box::leak(Box::new(Device::new(options.settings.watchdog(), adapter::VERSION, outputs)));
    device.drive_outputs();
    let server: &'static ModbusServer = Box::leak(Box::new(Server::new(options.settings.server_config(), device)));
    let board: &'static Board = Box::leak(Box::new(Board::new(device, outputs, SimRobot::new(options.robot))));
    let options: &'static Options = Box::leak(Box::new(options));

    let executor: &'static mut Executor = match Executor::new() {
        Ok(executor) => Box::leak(Box::new(executor)),
        Err(e) => {
            eprintln!("hal-sim: cannot make its executor: {e}");
            std::process::exit(i32::from(EXIT_UNAVAILABLE));
        }
    };
    executor.run(|spawner| {
        if let Err(e) = start(spawner, stack, runner, board, server, options, control) {
            eprintln!("hal-sim: cannot start its tasks: {e:?}");
            std::process::exit(i32::from(EXIT_UNAVAILABLE));
        }
    })
}

fn start(
    spawner: Spawner,
    stack: Stack<'static>,
    runner: Runner<'static, TunTapDevice>,
    board: &'static Board,
    server: &'static ModbusServer,
    options: &'static Options,
    control: Option<UnixListener>,
) -> Result<(), embassy_executor::SpawnError> {
    spawner.spawn(net_task(runner)?);
    spawner.spawn(link_task(stack, server, options)?);
    spawner.spawn(refresh_task(board)?);
    for slot in 0..SOCKET_POOL {
        spawner.spawn(modbus_task(stack, server, slot)?);
    }
    if let Some(listener) = control {
        spawner.spawn(control::accept_task(spawner, listener, board)?);
    }
    spawner.spawn(ready_task(stack, server, options)?);
    Ok(())
}

#[embassy_executor::task]
async fn net_task(mut runner: Runner<'static, TunTapDevice>) -> ! {
    runner.run().await
}

/// One Modbus listener per socket.
#[embassy_executor::task(pool_size = SOCKET_POOL)]
async fn modbus_task(stack: Stack<'static>, server: &'static ModbusServer, slot: SlotId) -> ! {
    server::listen(stack, server, slot).await
}

/// Follows the TAP's link with the boards' network policy.
#[embassy_executor::task]
async fn link_task(stack: Stack<'static>, server: &'static ModbusServer, options: &'static Options) -> ! {
    adapter::net::run(stack, &options.settings.network, server).await
}

#[embassy_executor::task]
async fn refresh_task(board: &'static Board) -> ! {
    let (mut pins, mut robot) = board.sources();
    device::refresh_loop(board.device, &mut pins, &mut robot).await
}

/// Prints the one line that says hal-sim is ready, once the address is up.
#[embassy_executor::task]
async fn ready_task(stack: Stack<'static>, server: &'static ModbusServer, options: &'static Options) {
    stack.wait_config_up().await;
    let config = server.config();
    log::info!(
        "max {} connections, idle timeout {:?}, unit id {:?}, write policy {:?}, robot {:?}",
        config.max_connections,
        config.idle_timeout.map(|t| t.as_secs()),
        config.policy.unit_id,
        config.policy.write_policy,
        options.robot,
    );
    if let Some(path) = &options.control {
        log::info!("control socket at {}", path.display());
    }
    let address = stack.config_v4().map(|v4| v4.address.address());
    let address = address.map_or_else(|| "?".to_owned(), |address| address.to_string());
    println!("hal-sim: modbus tcp listening on {address}:{} (tap {})", config.port, options.tap);
    let _ = std::io::stdout().flush();
}

/// What to tell the user when the TAP cannot be opened.
fn tap_error(tap: &str, e: &std::io::Error) -> String {
    let cause = match e.raw_os_error() {
        Some(libc::EBUSY) => format!("TAP {tap} is already in use by another program (another hal-sim?)"),
        Some(libc::ENOENT | libc::ENODEV) => "/dev/net/tun is missing: load the tun module (`modprobe tun`)".to_owned(),
        Some(libc::EACCES) => "opening a TAP needs the CAP_NET_ADMIN privilege (root), or a TAP made beforehand for \
             your user and /dev/net/tun open to you (most distributions make it mode 0666; if `ls -l /dev/net/tun` \
             shows crw-------, `sudo chmod 0666 /dev/net/tun`)"
            .to_owned(),
        _ => {
            "opening a TAP needs the CAP_NET_ADMIN privilege (root), or a TAP made beforehand for your user".to_owned()
        }
    };
    format!(
        "hal-sim: cannot open TAP {tap}: {e}\n\
         {cause}.\n\
         Without root, have it made once for your user (needs CAP_NET_ADMIN once, e.g. with sudo):\n\
         \x20   sudo ip tuntap add dev {tap} mode tap user $USER\n\
         \x20   sudo ip addr add 198.18.0.1/24 dev {tap}\n\
         \x20   sudo ip link set {tap} up\n\
         or run as root: scripts/hal-sim-run"
    )
}

/// `RUST_LOG` sets the levels (default info); lines carry the seconds since start.
fn init_logging() {
    let start = std::time::Instant::now();
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info"))
        .format(move |out, record| {
            let t = start.elapsed();
            writeln!(
                out,
                "[{:>4}.{:03} {:<5} {}] {}",
                t.as_secs(),
                t.subsec_millis(),
                record.level(),
                record.target(),
                record.args()
            )
        })
        .init();
}
