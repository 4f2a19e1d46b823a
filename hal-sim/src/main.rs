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

use adapter::server::{self, SOCKET_POOL, Shared, SlotId};
use embassy_executor::Spawner;
use embassy_net::{Ipv4Cidr, Runner, Stack, StackResources, StaticConfigV4};
use sim_robot::SimRobot;

use crate::cli::{Action, Options};
use crate::runtime::Executor;
use crate::sim::{Board, OutputLatch};
use crate::tap::TunTapDevice;

/// Exit status for a command line hal-sim cannot run with.
const EXIT_USAGE: u8 = 2;
/// Exit status when the TAP or the control socket cannot be opened.
const EXIT_UNAVAILABLE: u8 = 1;
/// The simulated device's MAC: locally administered, unicast.
const MAC: [u8; 6] = [0x02, 0x4d, 0x42, 0x53, 0x49, 0x4d];

fn main() -> ExitCode {
    init_logging();
    let options = match cli::parse(std::env::args().skip(1)) {
        Ok(Action::Run(options)) => *options,
        Ok(Action::Help) => {
            println!("{}", cli::USAGE);
            return ExitCode::SUCCESS;
        }
        Ok(Action::Version) => {
            let adapter::io::Version { major, minor, patch } = adapter::VERSION;
            println!("hal-sim {} (firmware {major}.{minor}.{patch})", env!("CARGO_PKG_VERSION"));
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("hal-sim: error: {e}\n\n{}", cli::USAGE);
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
    let net_config = embassy_net::Config::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(options.address, options.prefix_len),
        gateway: options.gateway,
        dns_servers: Default::default(),
    });
    let resources = Box::leak(Box::new(StackResources::<SOCKET_POOL>::new()));
    let (stack, runner) = embassy_net::new(device, net_config, resources, RandomState::new().build_hasher().finish());

    let outputs: &'static OutputLatch = Box::leak(Box::new(OutputLatch::new()));
    let shared: &'static Shared<'static> = Box::leak(Box::new(Shared::new(options.config, adapter::VERSION, outputs)));
    shared.drive_outputs();
    let board: &'static Board = Box::leak(Box::new(Board::new(shared, outputs, SimRobot::new(options.robot))));
    let options: &'static Options = Box::leak(Box::new(options));

    let executor: &'static mut Executor = match Executor::new() {
        Ok(executor) => Box::leak(Box::new(executor)),
        Err(e) => {
            eprintln!("hal-sim: cannot make its executor: {e}");
            std::process::exit(i32::from(EXIT_UNAVAILABLE));
        }
    };
    executor.run(|spawner| {
        if let Err(e) = start(spawner, stack, runner, board, options, control) {
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
    options: &'static Options,
    control: Option<UnixListener>,
) -> Result<(), embassy_executor::SpawnError> {
    spawner.spawn(net_task(runner)?);
    spawner.spawn(refresh_task(board)?);
    for slot in 0..SOCKET_POOL {
        spawner.spawn(modbus_task(stack, board.shared, slot)?);
    }
    if let Some(listener) = control {
        spawner.spawn(control::accept_task(spawner, listener, board)?);
    }
    spawner.spawn(ready_task(stack, options)?);
    Ok(())
}

#[embassy_executor::task]
async fn net_task(mut runner: Runner<'static, TunTapDevice>) -> ! {
    runner.run().await
}

/// One Modbus listener per socket.
#[embassy_executor::task(pool_size = SOCKET_POOL)]
async fn modbus_task(stack: Stack<'static>, shared: &'static Shared<'static>, slot: SlotId) -> ! {
    server::listen(stack, shared, slot).await
}

#[embassy_executor::task]
async fn refresh_task(board: &'static Board) -> ! {
    let (mut pins, mut robot) = board.sources();
    server::refresh_loop(board.shared, &mut pins, &mut robot).await
}

/// Prints the one line that says hal-sim is ready, once the address is up.
#[embassy_executor::task]
async fn ready_task(stack: Stack<'static>, options: &'static Options) {
    stack.wait_config_up().await;
    let config = options.config;
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
    println!("hal-sim: modbus tcp listening on {}:{} (tap {})", options.address, config.port, options.tap);
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
