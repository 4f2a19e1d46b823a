//! What every program built on the adapter has the same, assembled in one
//! place ([`program!`](crate::program!)): the top of the crate's layers,
//! which may use every module below it. The boards and hal-sim keep only
//! what their platform has.

/// Sockets a program's stack holds with this build's features: the Modbus
/// listeners (and with `tls` those of port 802), DHCP's, the HTTP listeners
/// (`http`; with `tls` HTTPS's too), mDNS's (`mdns`) and the robot link's client (`robot-link`).
pub const STACK_SOCKETS: usize =
    crate::server::SOCKET_POOL + crate::server::SECURE_POOL + 1 + HTTP_SOCKETS + MDNS_SOCKETS + LINK_SOCKETS;
#[cfg(all(feature = "http", not(feature = "tls")))]
const HTTP_SOCKETS: usize = crate::http::MAX_HTTP_CONNECTIONS;
#[cfg(all(feature = "http", feature = "tls"))]
const HTTP_SOCKETS: usize = crate::http::MAX_HTTP_CONNECTIONS + crate::http::HTTPS_SOCKETS;
#[cfg(not(feature = "http"))]
const HTTP_SOCKETS: usize = 0;
/// The TLS arena a program gives `identity::start`, as measured on the
/// host (the tls crate's tests/regions.rs): the two configurations'
/// certificates and keys (port 802's and HTTPS's: 7 KiB; 8 here), one
/// handshake at its peak (33 KiB with a client certificate: Mbed TLS's 16
/// KiB and 4 KiB record buffers and the key exchange; 34 here), and each
/// other session (up to 29 KiB after a TLS 1.3 handshake with a client
/// certificate; 30 here). `server::secure::MAX_TLS_SESSIONS` sessions.
#[cfg(feature = "tls")]
pub const TLS_ARENA_LEN: usize = (8 + 34 + 30 * (crate::server::secure::MAX_TLS_SESSIONS - 1)) * 1024;

#[cfg(feature = "mdns")]
const MDNS_SOCKETS: usize = 1;
#[cfg(not(feature = "mdns"))]
const MDNS_SOCKETS: usize = 0;
/// The robot link's client connection (`robot-link`).
#[cfg(feature = "robot-link")]
const LINK_SOCKETS: usize = 1;
#[cfg(not(feature = "robot-link"))]
const LINK_SOCKETS: usize = 0;

/// What [`program!`](crate::program!)'s code names from the adapter's
/// dependencies, so that a program needs none of them itself (bar
/// `embassy-executor`, whose task macro names its own crate).
#[doc(hidden)]
pub mod __private {
    pub use embassy_net;
    pub use static_cell::StaticCell;
}

/// Assembles the program, the same for every board and hal-sim: the
/// network stack, the device, the Modbus server, the settings service and
/// the HTTP API in static memory, and the tasks that run them. Embassy's
/// tasks cannot be generic, so this writes them for the program's own
/// types, where it is invoked (once, at the root of a binary crate):
///
/// ```ignore
/// adapter::program! {
///     driver: Lan9118<Mmio>,          // the embassy-net driver
///     inputs: RamInputs,              // the InputPins the refresh samples
///     robot: NoRobot,                 // the board's own robot source
///     flash: platform::SettingsFlash, // the settings store's NorFlash
///     platform: platform::Mps2,       // the settings service's board seam
/// }
/// ```
///
/// It defines, there:
///
/// - `ModbusServer`, `Control` and `Api`: the server over the device, the
///   settings service and the HTTP API, for these types;
/// - `ROBOT_LINK` (`robot-link`): the robot link, the robot's source while
///   `robot.link` is set;
/// - `Board`, what the program takes from the board, and `Program`, what
///   its tasks share;
/// - `program::network` (the stack, with the settings in force),
///   `program::build` (everything else) and `program::spawn` (every shared
///   task), and the tasks themselves.
///
/// The binary's own features `http`, `mdns` and `robot-link` must be the
/// adapter's (each board's `http = ["adapter/http", ...]`): the code here
/// is compiled in the binary, and its `cfg`s read the binary's features.
/// What a board has alone (its LEDs, its watchdog, its update partitions)
/// it spawns itself, after `program::spawn`.
#[macro_export]
macro_rules! program {
    (
        driver: $driver:ty,
        inputs: $inputs:ty,
        robot: $robot:ty,
        flash: $flash:ty,
        platform: $platform:ty $(,)?
    ) => {
        /// The Modbus server over the device.
        pub type ModbusServer = $crate::server::Server<'static, $crate::device::Device<'static>>;
        /// The settings service over this board.
        #[cfg(feature = "http")]
        pub type Control = $crate::control::Controller<'static, $flash, $platform>;
        /// The HTTP API over the settings service.
        #[cfg(feature = "http")]
        pub type Api = $crate::http::Http<'static, $flash, $platform>;

        /// The robot link: the source of the robot's points while `robot.link` is set.
        #[cfg(feature = "robot-link")]
        pub static ROBOT_LINK: $crate::robot_link::Link = $crate::robot_link::Link::new();

        /// What the board gives the program once its stack is up ([`program::network`]).
        pub struct Board {
            pub stack: $crate::program::__private::embassy_net::Stack<'static>,
            /// The settings in force ([`program::network`] keeps them).
            pub settings: &'static $crate::settings::Settings,
            pub mac: [u8; 6],
            /// The board, as Read Device Identification, `/api/status` and mDNS name it.
            pub model: &'static str,
            pub outputs: &'static dyn $crate::io::OutputPins,
            /// The settings store, as its load found it.
            #[cfg(feature = "http")]
            pub store: $crate::storage::Store<$flash>,
            #[cfg(feature = "http")]
            pub loaded: $crate::storage::Loaded,
            #[cfg(feature = "http")]
            pub platform: $platform,
            /// The HTTP API's port; `None`: no API (its service still runs).
            #[cfg(feature = "http")]
            pub http_port: ::core::option::Option<u16>,
            /// The HTTPS port; `None`: no HTTPS.
            #[cfg(all(feature = "http", feature = "tls"))]
            pub https_port: ::core::option::Option<u16>,
            /// The TLS configurations (`identity::start`): port 802's and HTTPS's.
            #[cfg(feature = "tls")]
            pub tls: $crate::identity::Servers,
        }

        /// What the program's tasks share, all of it for the life of the program.
        #[derive(Clone, Copy)]
        pub struct Program {
            pub stack: $crate::program::__private::embassy_net::Stack<'static>,
            /// The settings in force at start.
            pub settings: &'static $crate::settings::Settings,
            pub model: &'static str,
            pub device: &'static $crate::device::Device<'static>,
            pub server: &'static ModbusServer,
            /// The device name in force (the settings service may change it).
            pub names: &'static dyn $crate::net::DeviceName,
            #[cfg(feature = "http")]
            pub control: &'static Control,
            #[cfg(feature = "http")]
            pub api: ::core::option::Option<&'static Api>,
            #[cfg(feature = "tls")]
            pub tls: $crate::identity::Servers,
        }

        pub mod program {
            // The types the invocation names, as its module sees them.
            #[allow(unused_imports)]
            use super::*;
            use $crate::device::Device;
            use $crate::program::__private::StaticCell;
            use $crate::program::__private::embassy_net::{Runner, Stack, StackResources};
            use $crate::program::STACK_SOCKETS;
            use $crate::settings::Settings;

            use super::{Board, ModbusServer, Program};

            /// The network stack over `driver`, with `settings` (from now on
            /// the settings in force; DHCP's hostname is their name, or the
            /// default one of `mac`) and the stack's random `seed`.
            pub fn network(
                driver: $driver,
                settings: Settings,
                mac: [u8; 6],
                seed: u64,
            ) -> (Stack<'static>, Runner<'static, $driver>, &'static Settings) {
                static IN_FORCE: StaticCell<Settings> = StaticCell::new();
                static RESOURCES: StaticCell<StackResources<STACK_SOCKETS>> = StaticCell::new();
                let settings: &'static Settings = IN_FORCE.init(settings);
                let name = settings.device.name.or_default(mac);
                let config = $crate::net::initial_config(&settings.network, &name);
                let (stack, runner) = $crate::program::__private::embassy_net::new(
                    driver,
                    config,
                    RESOURCES.init(StackResources::new()),
                    seed,
                );
                (stack, runner, settings)
            }

            /// The device (its outputs driven as the settings start them),
            /// the Modbus server, the settings service with the robot link,
            /// and the HTTP API over it.
            pub fn build(board: Board) -> Program {
                let settings = board.settings;
                #[cfg(feature = "robot-link")]
                super::ROBOT_LINK.configure(&settings.robot);
                static DEVICE: StaticCell<Device<'static>> = StaticCell::new();
                let device: &'static Device<'static> =
                    DEVICE.init(Device::new(settings.watchdog(), board.model, board.outputs));
                device.drive_outputs();
                static SERVER: StaticCell<ModbusServer> = StaticCell::new();
                let server: &'static ModbusServer =
                    SERVER.init($crate::server::Server::new(settings.server_config(board.mac), device));
                #[cfg(feature = "http")]
                let (control, api) = {
                    let control = $crate::control::Controller::new(server, board.platform, board.store, &board.loaded);
                    #[cfg(feature = "robot-link")]
                    let control = control.with_robot_link(&super::ROBOT_LINK);
                    static CONTROL: StaticCell<super::Control> = StaticCell::new();
                    let control: &'static super::Control = CONTROL.init(control);
                    static API: StaticCell<super::Api> = StaticCell::new();
                    let api = board.http_port.map(|port| {
                        let http = $crate::http::Http::new(control, port);
                        #[cfg(feature = "tls")]
                        let http = http.with_secure_port(board.https_port.filter(|_| board.tls.https.is_some()));
                        &*API.init(http)
                    });
                    (control, api)
                };
                // The name in force: the settings service's (a change takes
                // effect at once), or without it the start's, fixed.
                #[cfg(feature = "http")]
                let names: &'static dyn $crate::net::DeviceName = control;
                #[cfg(not(feature = "http"))]
                let names: &'static dyn $crate::net::DeviceName = {
                    static NAME: StaticCell<$crate::name::Name> = StaticCell::new();
                    NAME.init(settings.device.name.or_default(board.mac))
                };
                Program {
                    stack: board.stack,
                    settings,
                    model: board.model,
                    device,
                    server,
                    names,
                    #[cfg(feature = "http")]
                    control,
                    #[cfg(feature = "http")]
                    api,
                    #[cfg(feature = "tls")]
                    tls: board.tls,
                }
            }

            /// Spawns every task the programs share: the stack's runner, the
            /// network policy, the 100 ms refresh over `inputs` and `robot`
            /// (the robot link wins while it is set), the Modbus listeners,
            /// and with their features the robot link, the HTTP listeners
            /// and the mDNS responder.
            pub fn spawn(
                spawner: ::embassy_executor::Spawner,
                program: Program,
                runner: Runner<'static, $driver>,
                inputs: $inputs,
                robot: $robot,
            ) -> ::core::result::Result<(), ::embassy_executor::SpawnError> {
                let Program { stack, settings, device, server, names, .. } = program;
                spawner.spawn(tasks::net(runner)?);
                spawner.spawn(tasks::link(stack, settings, server, names)?);
                // mDNS's socket before the listeners' (as the boards had it):
                // smoltcp walks the sockets in order on every poll, and the
                // MCU bench measured a request 68 instructions dearer with
                // it last.
                #[cfg(feature = "mdns")]
                {
                    let services = $crate::mdns::Services {
                        model: program.model,
                        version: $crate::VERSION_TEXT,
                        modbus_port: server.config().port,
                        #[cfg(feature = "http")]
                        http_port: program.api.map(|api| api.port()),
                        #[cfg(not(feature = "http"))]
                        http_port: None,
                    };
                    spawner.spawn(tasks::mdns(stack, names, services)?);
                }
                spawner.spawn(tasks::refresh(device, inputs, robot)?);
                #[cfg(feature = "robot-link")]
                spawner.spawn(tasks::robot_link(stack, device)?);
                #[cfg(feature = "tls")]
                let plain = settings.tls.plain_modbus;
                #[cfg(not(feature = "tls"))]
                let plain = true;
                if plain {
                    for slot in 0..$crate::server::SOCKET_POOL {
                        spawner.spawn(tasks::modbus(stack, server, slot)?);
                    }
                }
                #[cfg(feature = "tls")]
                if let Some(tls) = program.tls.modbus.filter(|_| settings.tls.modbus) {
                    for slot in $crate::server::SOCKET_POOL..$crate::server::SLOT_COUNT {
                        spawner.spawn(tasks::modbus_secure(stack, server, tls, slot)?);
                    }
                }
                #[cfg(feature = "http")]
                if let Some(api) = program.api {
                    for _ in 0..$crate::http::MAX_HTTP_CONNECTIONS {
                        spawner.spawn(tasks::http(stack, api)?);
                    }
                    #[cfg(feature = "tls")]
                    if let (Some(tls), Some(port)) = (program.tls.https, api.secure_port()) {
                        for _ in 0..$crate::http::HTTPS_SOCKETS {
                            spawner.spawn(tasks::https(stack, api, tls, port)?);
                        }
                    }
                }
                Ok(())
            }

            /// The tasks: each a few lines around the adapter's `async fn`.
            mod tasks {
                #[allow(unused_imports)]
                use super::super::*;
                use $crate::device::Device;
                use $crate::net::DeviceName;
                use $crate::program::__private::embassy_net::{Runner, Stack};
                use $crate::settings::Settings;

                use super::super::ModbusServer;

                #[::embassy_executor::task]
                pub async fn net(mut runner: Runner<'static, $driver>) -> ! {
                    runner.run().await
                }

                /// Follows the link with the network policy (DHCP's hostname: the name in force).
                #[::embassy_executor::task]
                pub async fn link(
                    stack: Stack<'static>,
                    settings: &'static Settings,
                    server: &'static ModbusServer,
                    names: &'static dyn DeviceName,
                ) -> ! {
                    $crate::net::run(stack, &settings.network, server, names).await
                }

                #[::embassy_executor::task]
                pub async fn refresh(device: &'static Device<'static>, mut inputs: $inputs, robot: $robot) -> ! {
                    #[cfg(feature = "robot-link")]
                    let mut robot = $crate::robot_link::Gated::new(&super::super::ROBOT_LINK, robot);
                    #[cfg(not(feature = "robot-link"))]
                    let mut robot = robot;
                    $crate::device::refresh_loop(device, &mut inputs, &mut robot).await
                }

                /// Polls the robot controller while `robot.link` is set.
                #[cfg(feature = "robot-link")]
                #[::embassy_executor::task]
                pub async fn robot_link(stack: Stack<'static>, device: &'static Device<'static>) -> ! {
                    $crate::robot_link::run(stack, device, &super::super::ROBOT_LINK).await
                }

                /// One Modbus listener per socket; its buffers live in the task's static storage.
                #[::embassy_executor::task(pool_size = $crate::server::SOCKET_POOL)]
                pub async fn modbus(
                    stack: Stack<'static>,
                    server: &'static ModbusServer,
                    slot: $crate::server::SlotId,
                ) -> ! {
                    $crate::server::listen(stack, server, slot).await
                }

                /// One Modbus/TCP Security listener per socket on port 802.
                #[cfg(feature = "tls")]
                #[::embassy_executor::task(pool_size = $crate::server::SECURE_POOL)]
                pub async fn modbus_secure(
                    stack: Stack<'static>,
                    server: &'static ModbusServer,
                    tls: &'static $crate::tls::Server,
                    slot: $crate::server::SlotId,
                ) -> ! {
                    $crate::server::secure::listen_secure(stack, server, tls, slot).await
                }

                /// One HTTP listener per connection served at once.
                #[cfg(feature = "http")]
                #[::embassy_executor::task(pool_size = $crate::http::MAX_HTTP_CONNECTIONS)]
                pub async fn http(stack: Stack<'static>, api: &'static super::super::Api) -> ! {
                    $crate::http::listen(stack, api).await
                }

                /// One HTTPS listener per socket.
                #[cfg(all(feature = "http", feature = "tls"))]
                #[::embassy_executor::task(pool_size = $crate::http::HTTPS_SOCKETS)]
                pub async fn https(
                    stack: Stack<'static>,
                    api: &'static super::super::Api,
                    tls: &'static $crate::tls::Server,
                    port: u16,
                ) -> ! {
                    $crate::http::listen_secure(stack, api, tls, port).await
                }

                /// Answers mDNS queries for the name in force and the services.
                #[cfg(feature = "mdns")]
                #[::embassy_executor::task]
                pub async fn mdns(
                    stack: Stack<'static>,
                    names: &'static dyn DeviceName,
                    services: $crate::mdns::Services,
                ) -> ! {
                    $crate::mdns::run(stack, names, services).await
                }
            }
        }
    };
}
