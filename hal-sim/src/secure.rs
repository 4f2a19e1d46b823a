//! Modbus/TCP Security on hal-sim: the TLS arena and entropy (the OS's),
//! the device's key and self-signed certificate, and the client CA from
//! `--client-ca` (docs/tls.md).

use std::path::Path;

use adapter::server::secure::ARENA_LEN;
use adapter::settings::Settings;
use adapter::tls::{self, Credentials, identity};

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

/// Starts TLS and makes port 802's configuration: `None` (and why, logged)
/// when no client CA is given or the credentials cannot be made.
pub fn configure(
    settings: &Settings,
    mac: [u8; 6],
    address: Option<[u8; 4]>,
    client_ca: Option<&[u8]>,
) -> Option<&'static tls::Server> {
    if !settings.tls.modbus {
        log::info!("modbus/tcp security off (tls.modbus)");
        return None;
    }
    let Some(client_ca) = client_ca else {
        log::info!("modbus/tcp security: no client CA (--client-ca): port 802 stays closed");
        return None;
    };
    let arena: &'static mut [u8] = Box::leak(vec![0u8; ARENA_LEN].into_boxed_slice());
    if let Err(e) = tls::init(arena, os_entropy) {
        log::error!("tls: cannot start: {e}");
        return None;
    }
    let name = settings.device.name.or_default(mac);
    let made = identity::generate_key().and_then(|key| {
        let mut buf = [0u8; identity::MAX_SELF_SIGNED_LEN];
        let names = identity::Names { name: name.as_str(), address };
        let certificate = identity::self_signed(&key, &names, &[1], &mut buf)?.to_vec();
        let key = identity::key_der(&key);
        tls::Server::new(&Credentials { certificate: &certificate, key: &key, client_ca: Some(client_ca) })
    });
    match made {
        Ok(server) => Some(Box::leak(Box::new(server))),
        Err(e) => {
            log::error!("modbus/tcp security: cannot make its configuration: {e}");
            None
        }
    }
}
