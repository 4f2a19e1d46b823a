//! hal-sim: the adapter's firmware logic on a Linux TAP, with simulated pins
//! and robot. The same sessions, map and tasks as the boards; only the board
//! differs (docs/hal-sim.md).

mod cli;
mod control;
mod platform;
mod runtime;
mod secure;
mod sim;
mod state;
mod tap;

use std::ffi::OsString;
use std::hash::{BuildHasher, Hasher, RandomState};
use std::io::Write as _;
use std::os::unix::net::UnixListener;
use std::process::ExitCode;

use adapter::settings::Settings;
use adapter::storage::Store;
use embassy_executor::Spawner;
use embassy_net::{Runner, Stack};
use sim_robot::SimRobot;

use crate::cli::{Action, Options};
use crate::platform::SimPlatform;
use crate::runtime::Executor;
use crate::sim::{Board as SimBoard, OutputLatch, PinReader, RobotReader};
use crate::state::Flash;
use crate::tap::TunTapDevice;

adapter::program! {
    driver: TunTapDevice,
    inputs: PinReader<'static>,
    robot: RobotReader<'static>,
    flash: Flash,
    platform: SimPlatform,
}

/// Exit status for a command line hal-sim cannot run with.
const EXIT_USAGE: u8 = 2;
/// Exit status when the TAP or the control socket cannot be opened.
const EXIT_UNAVAILABLE: u8 = 1;
/// The simulated device's MAC unless `--mac` gives another: locally administered, unicast.
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
    device.set_hardware_address(options.mac);

    let control = match options.control.as_deref().map(control::bind).transpose() {
        Ok(control) => control,
        Err(e) => {
            let path = options.control.as_deref().unwrap_or(std::path::Path::new("")).display();
            eprintln!("hal-sim: cannot open the control socket {path}: {e}");
            return ExitCode::from(EXIT_UNAVAILABLE);
        }
    };

    let client_ca = match options.client_ca.as_deref().map(secure::read_client_ca).transpose() {
        Ok(client_ca) => client_ca,
        Err(e) => {
            eprintln!("hal-sim: --client-ca {e}");
            return ExitCode::from(EXIT_UNAVAILABLE);
        }
    };

    run(options, device, control, flash, args, client_ca)
}

/// Loads the saved settings, builds the stack, the board and the API over
/// them, and runs the runtime's loop forever.
fn run(
    options: Options,
    device: TunTapDevice,
    control: Option<UnixListener>,
    flash: Flash,
    args: Vec<OsString>,
    client_ca: Option<Vec<u8>>,
) -> ! {
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
    let settings = running_settings(&loaded.settings, &options);
    // The TLS identity, made and saved at once if it is new (before the
    // executor runs, so without the flash's time).
    let address = settings.network.address.map(|cidr| cidr.address);
    let tls = secure::configure(&mut store, &settings, options.mac, address, client_ca.as_deref());
    // Saves from now on run in the executor and take the flash's time.
    store.flash().start_timing();
    let (stack, runner, settings) =
        program::network(device, settings, options.mac, RandomState::new().build_hasher().finish());
    let outputs: &'static OutputLatch = Box::leak(Box::new(OutputLatch::new()));
    let program = program::build(Board {
        stack,
        settings,
        mac: options.mac,
        model: MODEL,
        outputs,
        store,
        loaded,
        platform: SimPlatform::new(stack, settings.network.mode, options.mac),
        http_port: options.http_port,
        https_port: options.https_port,
        tls,
    });
    let board: &'static SimBoard =
        Box::leak(Box::new(SimBoard::new(program.device, outputs, SimRobot::new(options.robot))));
    let options: &'static Options = Box::leak(Box::new(options));

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
        if let Err(e) = start(spawner, program, board, runner, control, args, options) {
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

/// Spawns the program's tasks over the simulated board, then hal-sim's own:
/// the control socket, the reboot, the line that says it is ready.
fn start(
    spawner: Spawner,
    program: Program,
    board: &'static SimBoard,
    runner: Runner<'static, TunTapDevice>,
    control: Option<UnixListener>,
    args: Vec<OsString>,
    options: &'static Options,
) -> Result<(), embassy_executor::SpawnError> {
    let (pins, robot) = board.sources();
    program::spawn(spawner, program, runner, pins, robot)?;
    if let Some(listener) = control {
        spawner.spawn(control::accept_task(spawner, listener, board, program.control)?);
    }
    spawner.spawn(platform::reboot_task(args)?);
    let tls = Open {
        modbus: program.tls.modbus.is_some() && program.settings.tls.modbus,
        https: program.tls.https.is_some(),
    };
    spawner.spawn(ready_task(program.stack, program.server, program.settings, tls, options)?);
    Ok(())
}

/// Which TLS services started.
#[derive(Clone, Copy)]
struct Open {
    modbus: bool,
    https: bool,
}

/// Prints the one line that says hal-sim is ready, once the address is up.
#[embassy_executor::task]
async fn ready_task(
    stack: Stack<'static>,
    server: &'static ModbusServer,
    settings: &'static Settings,
    tls: Open,
    options: &'static Options,
) {
    stack.wait_config_up().await;
    let config = server.config();
    log::info!(
        "max {} connections, idle timeout {:?}, unit id {:?}, write policy {:?}, robot {:?}, robot link {}",
        config.max_connections,
        config.idle_timeout.map(|t| t.as_secs()),
        config.policy.unit_id,
        config.policy.write_policy,
        options.robot,
        ROBOT_LINK.health().target.map_or_else(|| "none".to_owned(), |link| link.to_string()),
    );
    if let Some(path) = &options.control {
        log::info!("control socket at {}", path.display());
    }
    match options.http_port {
        Some(port) => log::info!("http api on port {port}"),
        None => log::info!("http api off (--http-port 0)"),
    }
    match (tls.https, options.https_port) {
        (true, Some(port)) => log::info!("https on port {port}"),
        (false, Some(_)) => log::warn!("https off: TLS did not start"),
        (_, None) => log::info!("https off (--https-port 0)"),
    }
    let address = stack.config_v4().map(|v4| v4.address.address());
    let address = address.map_or_else(|| "?".to_owned(), |address| address.to_string());
    if settings.tls.plain_modbus {
        println!("hal-sim: modbus tcp listening on {address}:{} (tap {})", config.port, options.tap);
    }
    if tls.modbus {
        println!(
            "hal-sim: modbus/tcp security listening on {address}:{} (tap {})",
            adapter::server::secure::SECURE_PORT,
            options.tap
        );
    }
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
