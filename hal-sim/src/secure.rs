//! Modbus/TCP Security on hal-sim: the TLS arena and entropy (the OS's),
//! the device's identity from the store (docs/tls.md), and the client CA
//! from `--client-ca` while none is installed.

use std::path::Path;

use adapter::program::TLS_ARENA_LEN;
use adapter::settings::Settings;
use adapter::storage::Store;
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

/// Starts TLS on hal-sim (the OS's entropy, an arena of its own):
/// [`adapter::identity::start`].
pub fn configure<F: NorFlash>(
    store: &mut Store<F>,
    settings: &Settings,
    mac: [u8; 6],
    address: Option<[u8; 4]>,
    factory_ca: Option<&[u8]>,
) -> adapter::identity::Servers {
    let arena: &'static mut [u8] = Box::leak(vec![0u8; TLS_ARENA_LEN].into_boxed_slice());
    let started = adapter::identity::start(store, settings, mac, address, [arena], os_entropy, factory_ca);
    embassy_futures::block_on(started)
}
