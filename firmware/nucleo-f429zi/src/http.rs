//! NOT WIRED: the HTTP API on this board with a stand-in backend, behind
//! the opt-in `http` feature (off by default, and not in any release
//! image), so the API builds for the board and its flash and RAM can be
//! measured (docs/http-api.md, *What it costs*). The board's real backend
//! (settings saved in flash, the password hash, locate on the LEDs) is the
//! next issue's. Until then this stand-in:
//!
//! - puts a change in force (the Modbus server's configuration, the
//!   watchdog) but saves nothing: a reboot forgets it;
//! - sets no password (501), so changes are open to `allow_write`;
//! - does not blink for locate; reboot and factory reset reset the MCU.

use core::cell::Cell;

use adapter::http::{self, Backend, Http, MAX_HTTP_CONNECTIONS, NetworkStatus, Refusal};
use adapter::settings::{Cidr, Ipv4, Settings};
use defmt::unwrap;
use embassy_executor::Spawner;
use embassy_net::Stack;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::Duration;
use static_cell::StaticCell;

use crate::{ModbusServer, SETTINGS};
use adapter::device::Device;
use adapter::server::Server;

/// The stand-in backend (see the module's documentation: NOT WIRED).
pub struct StubBackend {
    server: &'static ModbusServer,
    stack: Stack<'static>,
    mac: [u8; 6],
    settings: Mutex<CriticalSectionRawMutex, Cell<Settings>>,
}

impl Backend for StubBackend {
    fn server(&self) -> &Server<'_, Device<'_>> {
        self.server
    }

    fn settings(&self) -> Settings {
        self.settings.lock(Cell::get)
    }

    async fn apply(&self, settings: &Settings) -> Result<bool, Refusal> {
        let old = self.settings.lock(|cell| cell.replace(*settings));
        let port = self.server.config().port;
        self.server.set_config(adapter::server::Config { port, ..settings.server_config() });
        self.server.service().set_watchdog(settings.watchdog());
        Ok(old.reboot_required(settings))
    }

    fn password_set(&self) -> bool {
        false
    }

    async fn verify_password(&self, _password: &[u8]) -> bool {
        false
    }

    async fn set_password(&self, _password: &[u8]) -> Result<(), Refusal> {
        Err(Refusal::Unsupported)
    }

    fn reboot(&self) {
        cortex_m::peripheral::SCB::sys_reset();
    }

    async fn factory_reset(&self) {
        cortex_m::peripheral::SCB::sys_reset();
    }

    fn locate(&self, _duration: Duration) {}

    fn model(&self) -> &'static str {
        "nucleo-f429zi"
    }

    fn mac(&self) -> [u8; 6] {
        self.mac
    }

    fn network(&self) -> NetworkStatus {
        let config = self.stack.config_v4();
        NetworkStatus {
            mode: SETTINGS.network.mode,
            address: config
                .as_ref()
                .map(|c| Cidr { address: c.address.address().octets(), prefix_len: c.address.prefix_len() }),
            gateway: config.and_then(|c| c.gateway).map(|gateway| Ipv4(gateway.octets())),
            link: self.stack.is_link_up(),
        }
    }
}

/// The API over the stand-in backend.
pub type Api = Http<'static, StubBackend>;

/// One HTTP listener per connection; its buffers live in the task's static storage.
#[embassy_executor::task(pool_size = MAX_HTTP_CONNECTIONS)]
async fn http_task(stack: Stack<'static>, api: &'static Api) -> ! {
    http::listen(stack, api, http::HTTP_PORT).await
}

/// Starts the HTTP listeners.
pub fn spawn(spawner: Spawner, stack: Stack<'static>, server: &'static ModbusServer, mac: [u8; 6]) {
    static BACKEND: StaticCell<StubBackend> = StaticCell::new();
    static API: StaticCell<Api> = StaticCell::new();
    let backend = BACKEND.init(StubBackend { server, stack, mac, settings: Mutex::new(Cell::new(SETTINGS)) });
    let api = &*API.init(Http::new(backend));
    for _ in 0..MAX_HTTP_CONNECTIONS {
        spawner.spawn(unwrap!(http_task(stack, api)));
    }
    defmt::warn!("HTTP API on port {} with a stand-in backend: NOT WIRED (changes are not saved)", http::HTTP_PORT);
}
