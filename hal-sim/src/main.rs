//! hal-sim: the adapter's firmware logic on a Linux TAP, with simulated pins
//! and robot. The same sessions, map and tasks as the boards; only the board
//! differs (docs/hal-sim.md).

mod cli;
mod control;
mod platform;
mod runtime;
mod sim;
mod state;
mod tap;

use std::ffi::OsString;
use std::hash::{BuildHasher, Hasher, RandomState};
use std::io::Write as _;
use std::os::unix::net::UnixListener;
use std::process::ExitCode;

use adapter::device::{self, Device};
use adapter::http::{self, Http, MAX_HTTP_CONNECTIONS};
use adapter::link::{self as robot_link, Gated, Link};
use adapter::mdns;
use adapter::net::DeviceName;
use adapter::server::{self, SOCKET_POOL, Server, SlotId};
use adapter::settings::Settings;
use adapter::storage::Store;
use embassy_executor::Spawner;
use embassy_net::{Runner, Stack, StackResources};
use sim_robot::SimRobot;

use crate::cli::{Action, Options};
use crate::platform::{SimController, SimPlatform};
use crate::runtime::Executor;
use crate::sim::{Board, OutputLatch};
use crate::state::Flash;
use crate::tap::TunTapDevice;

/// The Modbus server over the simulated device.
type ModbusServer = Server<'static, Device<'static>>;
/// The HTTP API over hal-sim's backend.
type Api = Http<'static, crate::state::Flash, SimPlatform>;

/// Sockets in the stack: the Modbus listeners, DHCP's, the HTTP listeners, mDNS's and the robot link's.
const NET_SOCKETS: usize = adapter::program::STACK_SOCKETS;

/// The robot link (`--robot-link`, `robot.link`): the source of the robot's
/// points while it is set; the simulated robot's otherwise.
pub(crate) static ROBOT_LINK: Link = Link::new();

/// Exit status for a command line hal-sim cannot run with.
const EXIT_USAGE: u8 = 2;
/// Exit status when the TAP or the control socket cannot be opened.
const EXIT_UNAVAILABLE: u8 = 1;
/// The simulated device's MAC: locally administered, unicast.
pub(crate) const MAC: [u8; 6] = [0x02, 0x4d, 0x42, 0x53, 0x49, 0x4d];
/// The board, as Read Device Identification (ModelName), `/api/status` and mDNS's TXT name it.
pub(crate) const MODEL: &str = "hal-sim";

fn main() -> ExitCode {
    init_logging();
    // Kept as given, for a reboot (which executes hal-sim again with them).
    let args: Vec<OsString> = std::env::args_os().collect();
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

    let flash = match options.state.as_deref().map(state::open).transpose() {
        Ok(Some(flash)) => flash,
        Ok(None) => state::in_memory(),
        Err(e) if e.is_usage() => {
            eprintln!("hal-sim: error: {e}");
            return ExitCode::from(EXIT_USAGE);
        }
        Err(e) => {
            eprintln!("hal-sim: {e}");
            return ExitCode::from(EXIT_UNAVAILABLE);
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

    run(options, device, control, flash, args)
}

/// Loads the saved settings, builds the stack, the board and the API over
/// them, and runs the runtime's loop forever.
fn run(options: Options, device: TunTapDevice, control: Option<UnixListener>, flash: Flash, args: Vec<OsString>) -> ! {
    let mut store = match Store::new(flash, state::RANGE) {
        Ok(store) => store,
        Err(e) => {
            eprintln!("hal-sim: cannot use its settings flash: {e}");
            std::process::exit(i32::from(EXIT_UNAVAILABLE));
        }
    };
    // The command line's settings are the factory settings; saved ones override them.
    let loaded = embassy_futures::block_on(store.load(&options.settings));
    match &options.state {
        Some(path) => log::info!("settings: kept in {} ({:?})", path.display(), loaded.status),
        None => log::info!("settings: kept in memory (no --state): changes last until hal-sim exits"),
    }
    if let Some(error) = loaded.error {
        log::warn!("settings storage: {error}");
    }
    // Saves from now on run in the executor and take the flash's time.
    store.flash().start_timing();
    let settings: &'static Settings = Box::leak(Box::new(running_settings(&loaded.settings, &options)));

    ROBOT_LINK.configure(&settings.robot);
    let name = settings.device.name.or_default(MAC);
    let net_config = adapter::net::initial_config(&settings.network, &name);
    let resources = Box::leak(Box::new(StackResources::<NET_SOCKETS>::new()));
    let (stack, runner) = embassy_net::new(device, net_config, resources, RandomState::new().build_hasher().finish());

    let outputs: &'static OutputLatch = Box::leak(Box::new(OutputLatch::new()));
    let device: &'static Device<'static> = Box::leak(Box::new(Device::new(settings.watchdog(), MODEL, outputs)));
    device.drive_outputs();
    let server: &'static ModbusServer = Box::leak(Box::new(Server::new(settings.server_config(MAC), device)));
    let board: &'static Board = Box::leak(Box::new(Board::new(device, outputs, SimRobot::new(options.robot))));
    // No API (`--http-port 0`): no port for `modbus.port` to avoid (0 is never a Modbus port).
    let platform = SimPlatform::new(stack, settings.network.mode);
    let controller = SimController::new(server, platform, store, &loaded).with_robot_link(&ROBOT_LINK);
    let controller: &'static SimController = Box::leak(Box::new(controller));
    let api: &'static Api = Box::leak(Box::new(Http::new(controller, options.http_port.unwrap_or(0))));
    let options: &'static Options = Box::leak(Box::new(options));
    let sim = Sim { stack, board, server, controller, api, settings, options };

    if options.busy_poll_us > 0 {
        log::info!("busy polling: up to {} µs before each sleep", options.busy_poll_us);
    }
    let executor: &'static mut Executor = match Executor::new(embassy_time::Duration::from_micros(options.busy_poll_us))
    {
        Ok(executor) => Box::leak(Box::new(executor)),
        Err(e) => {
            eprintln!("hal-sim: cannot make its executor: {e}");
            std::process::exit(i32::from(EXIT_UNAVAILABLE));
        }
    };
    executor.run(|spawner| {
        if let Err(e) = start(spawner, sim, runner, control, args) {
            eprintln!("hal-sim: cannot start its tasks: {e:?}");
            std::process::exit(i32::from(EXIT_UNAVAILABLE));
        }
    })
}

/// The settings hal-sim runs with: the loaded ones, except a saved Modbus
/// port that is the HTTP port (saved while the API listened on another):
/// then the command line's, so that the API stays reachable to mend it.
fn running_settings(loaded: &Settings, options: &Options) -> Settings {
    let mut settings = *loaded;
    if options.http_port == Some(settings.modbus.port) {
        log::warn!(
            "settings: the saved Modbus port {} is the HTTP port; Modbus listens on {} instead",
            settings.modbus.port,
            options.settings.modbus.port
        );
        settings.modbus.port = options.settings.modbus.port;
    }
    settings
}

/// What the tasks share, all of it for the life of the process.
#[derive(Clone, Copy)]
struct Sim {
    stack: Stack<'static>,
    board: &'static Board,
    server: &'static ModbusServer,
    controller: &'static SimController,
    api: &'static Api,
    /// The settings in force at start (the loaded ones).
    settings: &'static Settings,
    options: &'static Options,
}

fn start(
    spawner: Spawner,
    sim: Sim,
    runner: Runner<'static, TunTapDevice>,
    control: Option<UnixListener>,
    args: Vec<OsString>,
) -> Result<(), embassy_executor::SpawnError> {
    let Sim { stack, board, server, controller, api, settings, options } = sim;
    spawner.spawn(net_task(runner)?);
    spawner.spawn(link_task(stack, server, settings, controller)?);
    spawner.spawn(refresh_task(board)?);
    spawner.spawn(robot_link_task(stack, board.device)?);
    for slot in 0..SOCKET_POOL {
        spawner.spawn(modbus_task(stack, server, slot)?);
    }
    if options.http_port.is_some() {
        for _ in 0..MAX_HTTP_CONNECTIONS {
            spawner.spawn(http_task(stack, api)?);
        }
    }
    if let Some(listener) = control {
        spawner.spawn(control::accept_task(spawner, listener, board, controller)?);
    }
    spawner.spawn(platform::reboot_task(args)?);
    let services = mdns::Services {
        model: MODEL,
        version: adapter::VERSION_TEXT,
        modbus_port: server.config().port,
        http_port: options.http_port,
    };
    spawner.spawn(mdns_task(stack, controller, services)?);
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

/// One HTTP listener per connection served at once.
#[embassy_executor::task(pool_size = MAX_HTTP_CONNECTIONS)]
async fn http_task(stack: Stack<'static>, api: &'static Api) -> ! {
    http::listen(stack, api).await
}

/// Answers mDNS queries for the name in force and the services (DEVICE.md section 3).
#[embassy_executor::task]
async fn mdns_task(stack: Stack<'static>, names: &'static dyn DeviceName, services: mdns::Services) -> ! {
    mdns::run(stack, names, services).await
}

/// Follows the TAP's link with the boards' network policy; DHCP's hostname
/// is the name in the settings, as the HTTP API changes them.
#[embassy_executor::task]
async fn link_task(
    stack: Stack<'static>,
    server: &'static ModbusServer,
    settings: &'static Settings,
    names: &'static SimController,
) -> ! {
    adapter::net::run(stack, &settings.network, server, names).await
}

/// The refresh: the simulated robot feeds the robot's points only while no link is set.
#[embassy_executor::task]
async fn refresh_task(board: &'static Board) -> ! {
    let (mut pins, robot) = board.sources();
    device::refresh_loop(board.device, &mut pins, &mut Gated::new(&ROBOT_LINK, robot)).await
}

/// Polls the robot controller while `robot.link` is set (DEVICE.md section 4).
#[embassy_executor::task]
async fn robot_link_task(stack: Stack<'static>, device: &'static Device<'static>) -> ! {
    robot_link::run(stack, device, &ROBOT_LINK).await
}

/// Prints the one line that says hal-sim is ready, once the address is up.
#[embassy_executor::task]
async fn ready_task(stack: Stack<'static>, server: &'static ModbusServer, options: &'static Options) {
    stack.wait_config_up().await;
    let config = server.config();
    log::info!(
        "max {} connections, idle timeout {:?}, unit id {:?}, write policy {:?}, robot {:?}, robot link {}",
        config.max_connections,
        config.idle_timeout.map(|t| t.as_secs()),
        config.policy.unit_id,
        config.policy.write_policy,
        options.robot,
        ROBOT_LINK.status().target.map_or_else(|| "none".to_owned(), |link| link.to_string()),
    );
    if let Some(path) = &options.control {
        log::info!("control socket at {}", path.display());
    }
    match options.http_port {
        Some(port) => log::info!("http api on port {port}"),
        None => log::info!("http api off (--http-port 0)"),
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
