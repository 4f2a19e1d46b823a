//! `mbio`: the integrators' command line for a fleet of Modbus TCP I/O
//! adapters (docs/mbio.md). Finds them (mDNS), shows and changes their
//! settings, backs them up and restores them, updates their firmware a few
//! at a time, and reads and writes their points by the names of the map the
//! firmware serves (`adapter::map::names`).

#![cfg_attr(
    test,
    allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing, clippy::unreachable)
)]

/// `println!` that ends quietly when stdout is closed (`mbio find | head`).
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

mod device;
mod discover;
mod points;
mod settings;
mod update;
mod watch;

use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{CommandFactory as _, Parser, Subcommand};

/// What went wrong, and the exit code that says so (docs/mbio.md, "Exit codes").
#[derive(Debug)]
pub enum Failure {
    /// 1: the device refused, or an operation failed on it.
    Refused(String),
    /// 3: no such device: a name that does not resolve, an address that does not answer.
    Unreachable(String),
    /// 4: no password, or the device did not take it (401, 403).
    Denied(String),
    /// 5: the user said no (a restore not confirmed).
    Cancelled(String),
    /// 6: the device answered something this tool cannot read.
    BadReply(String),
    /// 2: a usage error clap did not catch (a bad point, a bad value, an unreadable file).
    Usage(String),
}

impl Failure {
    fn code(&self) -> u8 {
        match self {
            Failure::Refused(_) => 1,
            Failure::Usage(_) => 2,
            Failure::Unreachable(_) => 3,
            Failure::Denied(_) => 4,
            Failure::Cancelled(_) => 5,
            Failure::BadReply(_) => 6,
        }
    }

    pub fn message(&self) -> &str {
        match self {
            Failure::Refused(m)
            | Failure::Unreachable(m)
            | Failure::Denied(m)
            | Failure::Cancelled(m)
            | Failure::BadReply(m)
            | Failure::Usage(m) => m,
        }
    }
}

pub type Outcome<T = ()> = Result<T, Failure>;

#[derive(Debug, Parser)]
#[command(
    name = "mbio",
    version,
    about = "Find, configure, back up, update and read a fleet of Modbus TCP I/O adapters"
)]
#[command(after_help = "Exit codes: 0 done; 1 a device refused or an operation failed; 2 usage; \
3 device not found or not answering; 4 password missing or refused; 5 cancelled; 6 a reply mbio cannot read.")]
pub struct Cli {
    /// A file whose first line is the admin password (else $MBIO_PASSWORD, else a prompt).
    #[arg(long, global = true, value_name = "FILE")]
    password_file: Option<PathBuf>,
    /// The devices' HTTP port.
    #[arg(long, global = true, default_value_t = 80)]
    http_port: u16,
    /// The devices' Modbus TCP port.
    #[arg(long, global = true, default_value_t = 502)]
    modbus_port: u16,
    /// Seconds to wait for a name to resolve through mDNS.
    #[arg(long, global = true, default_value_t = 3.0)]
    resolve_wait: f64,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Browse _modbus._tcp and _http._tcp and list the devices found.
    Find {
        /// Seconds to listen for answers.
        #[arg(long, default_value_t = 3.0)]
        wait: f64,
        /// JSON for scripts: one array of devices.
        #[arg(long)]
        json: bool,
    },
    /// A device's state (GET /api/status).
    Status {
        /// NAME (NAME.local through mDNS) or an IPv4 address.
        device: String,
        #[arg(long)]
        json: bool,
    },
    /// A device's settings, or one of them (group.field).
    Get {
        device: String,
        key: Option<String>,
        #[arg(long)]
        json: bool,
    },
    /// Change settings, all or nothing: group.field=value ...
    Set {
        device: String,
        #[arg(required = true, value_name = "GROUP.FIELD=VALUE")]
        changes: Vec<String>,
        #[arg(long)]
        json: bool,
    },
    /// Set the admin password: the first one (a new device takes no other change
    /// until it has one), or a new one with the current one.
    Password {
        device: String,
        /// A file whose first line is the new password, when one is set already
        /// (else $MBIO_NEW_PASSWORD, else a prompt). The first password is the
        /// usual one (--password-file, $MBIO_PASSWORD, a prompt).
        #[arg(long, value_name = "FILE")]
        new_password_file: Option<PathBuf>,
    },
    /// Print a device's settings as a backup (JSON) on stdout: `mbio backup NAME > file.json`.
    Backup { device: String },
    /// Put a backup's settings on a device: shows the difference and asks first.
    Restore {
        device: String,
        file: PathBuf,
        /// Do not ask (for scripts).
        #[arg(long)]
        yes: bool,
        /// Restore the network settings too (left alone by default).
        #[arg(long)]
        network: bool,
    },
    /// Send a signed update file to devices, a few at a time, and check their new version.
    Update {
        file: PathBuf,
        /// Devices (names or addresses).
        #[arg(required_unless_present = "all")]
        devices: Vec<String>,
        /// Every device `mbio find` finds.
        #[arg(long, conflicts_with = "devices")]
        all: bool,
        /// Devices updated at once.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u16).range(1..=64))]
        parallel: u16,
        /// Go on with the other devices after a failure (else the rollout stops at the first).
        #[arg(long)]
        keep_going: bool,
        /// Seconds a device has to come back with its new version after the reboot.
        #[arg(long, default_value_t = 120)]
        timeout: u64,
        /// Seconds `--all` listens for devices.
        #[arg(long, default_value_t = 3.0)]
        wait: f64,
        #[arg(long)]
        json: bool,
    },
    /// Read points by name (`mbio points` lists them): robot.joint_position, di, do.3 ...
    Read {
        device: String,
        #[arg(required = true)]
        points: Vec<String>,
        #[arg(long)]
        json: bool,
    },
    /// Write points by name: do.3=on, ao.1=12.5, gp.1=7 ...
    Write {
        device: String,
        #[arg(required = true, value_name = "POINT=VALUE")]
        values: Vec<String>,
    },
    /// The map's point names, units and access.
    Points {
        #[arg(long)]
        json: bool,
    },
    /// A live view of a device's I/O and robot (Ctrl-C ends it).
    Watch {
        device: String,
        /// Seconds between refreshes.
        #[arg(long, default_value_t = 0.5)]
        interval: f64,
        /// Stop after this many refreshes (0: never).
        #[arg(long, default_value_t = 0)]
        count: u64,
    },
    /// Shell completions on stdout.
    Completions { shell: clap_complete::Shell },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            let _ = writeln!(std::io::stderr(), "mbio: {}", failure.message());
            ExitCode::from(failure.code())
        }
    }
}

fn run(cli: &Cli) -> Outcome {
    let ctx = device::Context::new(cli);
    match &cli.command {
        Command::Find { wait, json } => discover::find(&ctx, *wait, *json),
        Command::Status { device, json } => settings::status(&ctx, device, *json),
        Command::Get { device, key, json } => settings::get(&ctx, device, key.as_deref(), *json),
        Command::Set { device, changes, json } => settings::set(&ctx, device, changes, *json),
        Command::Password { device, new_password_file } => {
            settings::password(&ctx, device, new_password_file.as_deref())
        }
        Command::Backup { device } => settings::backup(&ctx, device),
        Command::Restore { device, file, yes, network } => settings::restore(&ctx, device, file, *yes, *network),
        Command::Update { file, devices, all, parallel, keep_going, timeout, wait, json } => {
            let options = update::Options {
                parallel: usize::from(*parallel),
                keep_going: *keep_going,
                timeout: std::time::Duration::from_secs(*timeout),
                json: *json,
            };
            update::rollout(&ctx, file, devices, all.then_some(*wait), &options)
        }
        Command::Read { device, points, json } => points::read(&ctx, device, points, *json),
        Command::Write { device, values } => points::write(&ctx, device, values),
        Command::Points { json } => points::list(*json),
        Command::Watch { device, interval, count } => watch::watch(&ctx, device, *interval, *count),
        Command::Completions { shell } => {
            let mut script = Vec::new();
            clap_complete::generate(*shell, &mut Cli::command(), "mbio", &mut script);
            let _ = std::io::stdout().write_all(&script);
            Ok(())
        }
    }
}

/// Prints `value` as pretty JSON on stdout.
pub fn print_json(value: &serde_json::Value) {
    say!("{}", serde_json::to_string_pretty(value).unwrap_or_default());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn no_password_argument_exists() {
        let command = Cli::command();
        let mut names: Vec<String> = command.get_arguments().filter_map(|a| a.get_long().map(str::to_owned)).collect();
        for sub in command.get_subcommands() {
            names.extend(sub.get_arguments().filter_map(|a| a.get_long().map(str::to_owned)));
        }
        assert!(names.iter().any(|n| n == "password-file"));
        assert!(!names.iter().any(|n| n == "password"), "a password must never be an argument: {names:?}");
    }
}
