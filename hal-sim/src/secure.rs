//! Modbus/TCP Security on hal-sim: the TLS arena and entropy (the OS's),
//! the device's identity from the store (docs/tls.md), and the client CA
//! from `--client-ca` while none is installed.

use std::path::Path;

use adapter::server::secure::ARENA_LEN;
use adapter::settings::Settings;
use adapter::storage::Store;
use adapter::tls::{self, Credentials, identity};
use embedded_storage_async::nor_flash::NorFlash;

/// The host's entropy for the TLS generator.
fn os_entropy(buf: &mut [u8]) -> bool {
    getrandom::fill(buf).is_ok()
}

/// The client CA in DER, from a PEM (`CERTIFICATE`) or DER file.
pub fn read_client_ca(path: &Path) -> Result<Vec<u8>, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    if !bytes.starts_with(b"-----BEGIN") {
        return Ok(bytes);
    }
    let mut der = vec![0u8; bytes.len()];
    let (label, decoded) =
        pem_rfc7468::decode(&bytes, &mut der).map_err(|e| format!("{}: not one PEM block: {e}", path.display()))?;
    if label != "CERTIFICATE" {
        return Err(format!("{}: a PEM {label}, not a CERTIFICATE", path.display()));
    }
    Ok(decoded.to_vec())
}

/// Starts TLS, loads (or makes) the device's identity from `store`, and
/// makes port 802's configuration: `None` (and why, logged) when there is
/// no client CA (none installed, and no `--client-ca`) or it cannot be made.
pub fn configure<F: NorFlash>(
    store: &mut Store<F>,
    settings: &Settings,
    mac: [u8; 6],
    address: Option<[u8; 4]>,
    factory_ca: Option<&[u8]>,
) -> Option<&'static tls::Server> {
    if !settings.tls.modbus {
        log::info!("modbus/tcp security off (tls.modbus)");
        return None;
    }
    let arena: &'static mut [u8] = Box::leak(vec![0u8; ARENA_LEN].into_boxed_slice());
    if let Err(e) = tls::init(arena, os_entropy) {
        log::error!("tls: cannot start: {e}");
        return None;
    }
    let name = settings.device.name.or_default(mac);
    let names = identity::Names { name: name.as_str(), address };
    let loaded = match embassy_futures::block_on(adapter::identity::load(store, &names)) {
        Ok(loaded) => loaded,
        Err(e) => {
            log::error!("tls: no identity: {e}");
            return None;
        }
    };
    let Some(client_ca) = loaded.client_ca.as_deref().or(factory_ca) else {
        log::info!("modbus/tcp security: no client CA installed (nor --client-ca): port 802 stays closed");
        return None;
    };
    let key = identity::key_der(&loaded.key);
    let credentials = Credentials { certificate: &loaded.certificate, key: &key, client_ca: Some(client_ca) };
    match tls::Server::new(&credentials) {
        Ok(server) => Some(Box::leak(Box::new(server))),
        Err(e) => {
            log::error!("modbus/tcp security: cannot make its configuration: {e}");
            None
        }
    }
}
