//! The device's TLS identity (docs/tls.md), kept in the settings store
//! beside the settings, power-fail safe as they are:
//!
//! - its P-256 private key, made at the first start from the board's
//!   entropy, made anew after a factory reset (which erases the store);
//! - its certificate: self-signed, naming the device (its name,
//!   `NAME.local`, its address), and made again with the same key when the
//!   name or the address changes; or one a plant installed;
//! - the CA that Modbus/TCP Security clients' certificates chain to, once
//!   a plant installed it (until then port 802 serves no one).
//!
//! Records (the store's keys `TLS_*`): a version byte (1; 0 marks a record
//! removed), then for the key its 32-byte scalar, for the certificate its
//! origin byte (0 self-signed, 1 installed), for an installed one its key's
//! scalar (one record: a certificate and its key are saved together, or
//! not at all), and its DER; for the CA its DER.

use embedded_storage_async::nor_flash::NorFlash;
use heapless::Vec;
use static_cell::StaticCell;
use tls::identity::{self as made, KEY_LEN, Names};

use crate::settings::Settings;
use crate::storage::{MAX_OTHER_RECORD_LEN, Store, StoreError, key};

/// The longest certificate the device keeps (its own, or the client CA), in DER.
pub const MAX_CERTIFICATE_LEN: usize = MAX_OTHER_RECORD_LEN - 2;

/// The longest certificate a plant installs for the device, in DER: its
/// record holds its key beside it.
pub const MAX_INSTALLED_LEN: usize = MAX_CERTIFICATE_LEN - KEY_LEN;

/// A certificate in DER, as kept.
pub type Der = Vec<u8, MAX_CERTIFICATE_LEN>;

const VERSION: u8 = 1;
const REMOVED: u8 = 0;

/// Where the device's certificate came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Origin {
    /// Made by the device, naming itself.
    SelfSigned,
    /// Installed by the plant through the API.
    Installed,
}

impl Origin {
    const fn byte(self) -> u8 {
        match self {
            Self::SelfSigned => 0,
            Self::Installed => 1,
        }
    }
}

/// The identity the TLS configurations are made from.
#[derive(Clone, Debug)]
pub struct Identity {
    /// The private key's scalar. Never leaves the device.
    pub key: [u8; KEY_LEN],
    pub certificate: Der,
    pub origin: Origin,
    pub client_ca: Option<Der>,
}

/// Why the identity could not be made (the store's failures are not among
/// them: an identity that cannot be saved is still used, and made again
/// at the next start).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    Tls(tls::Error),
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Tls(e) => write!(f, "{e}"),
        }
    }
}

/// The TLS configurations a program serves with (`Board::tls`).
#[derive(Clone, Copy, Debug, Default)]
pub struct Servers {
    /// Port 802's: the device's credentials and the client CA; `None`:
    /// 802 stays closed.
    pub modbus: Option<&'static tls::Server>,
    /// HTTPS's: the device's credentials; `None`: no HTTPS.
    pub https: Option<&'static tls::Server>,
}

/// Starts TLS for a program: the arena (its regions) and the entropy
/// source, the identity from `store` (made and saved when new), and the
/// configurations of HTTPS and of port 802. Port 802's is `None`, with
/// the reason logged, when `tls.modbus` is off or no client CA is
/// installed (nor a `factory_ca` given, as hal-sim's `--client-ca`); both
/// are when TLS cannot start. Once, before the program is built; `address`
/// is the static address the device starts with, if any (its certificate
/// names it).
pub async fn start<F: NorFlash>(
    store: &mut Store<F>,
    settings: &Settings,
    mac: [u8; 6],
    address: Option<[u8; 4]>,
    arena: impl IntoIterator<Item = &'static mut [u8]>,
    entropy: tls::Entropy,
    factory_ca: Option<&[u8]>,
) -> Servers {
    if let Err(e) = tls::init(arena, entropy) {
        warn!("tls: cannot start: {}", e);
        return Servers::default();
    }
    let name = settings.device.name.or_default(mac);
    let names = Names { name: name.as_str(), address };
    let identity = match load(store, &names).await {
        Ok(identity) => identity,
        Err(e) => {
            warn!("tls: no identity: {}", e);
            return Servers::default();
        }
    };
    let key = made::key_der(&identity.key);
    let configure = |client_ca, what| {
        let credentials = tls::Credentials { certificate: &identity.certificate, key: &key, client_ca };
        tls::Server::new(&credentials).inspect_err(|e| warn!("{}: cannot make its configuration: {}", what, e)).ok()
    };
    static HTTPS: StaticCell<tls::Server> = StaticCell::new();
    let https = configure(None, "https").map(|server| &*HTTPS.init(server));
    let client_ca = identity.client_ca.as_deref().or(factory_ca);
    let modbus = match client_ca {
        _ if !settings.tls.modbus => {
            info!("modbus/tcp security off (tls.modbus)");
            None
        }
        None => {
            info!("modbus/tcp security: no client CA installed: port 802 stays closed");
            None
        }
        Some(client_ca) => {
            static MODBUS: StaticCell<tls::Server> = StaticCell::new();
            configure(Some(client_ca), "modbus/tcp security").map(|server| &*MODBUS.init(server))
        }
    };
    Servers { modbus, https }
}

/// Reads the identity from `store`, making (and saving) what is missing:
/// the key, and a self-signed certificate naming `names` when there is none
/// or the saved one names the device otherwise. `tls::init` must have run.
pub async fn load<F: NorFlash>(store: &mut Store<F>, names: &Names<'_>) -> Result<Identity, Error> {
    let mut buf = [0u8; MAX_OTHER_RECORD_LEN];
    let saved_key = match store.fetch_record(key::TLS_KEY, &mut buf).await {
        Ok(Some([VERSION, scalar @ ..])) => <[u8; KEY_LEN]>::try_from(scalar).ok(),
        Ok(_) => None,
        Err(e) => {
            warn!("tls: the key cannot be read ({}): a new one", e);
            None
        }
    };
    let key = match saved_key {
        Some(key) => key,
        None => {
            let key = made::generate_key().map_err(Error::Tls)?;
            let mut record = [0u8; 1 + KEY_LEN];
            if let Some((version, scalar)) = record.split_first_mut() {
                *version = VERSION;
                scalar.copy_from_slice(&key);
            }
            note(store.save_record(key::TLS_KEY, &record).await, "key");
            info!("tls: a new device key");
            key
        }
    };

    let saved = match store.fetch_record(key::TLS_CERTIFICATE, &mut buf).await {
        Ok(Some([VERSION, 1, rest @ ..])) => rest
            .split_first_chunk::<KEY_LEN>()
            .and_then(|(scalar, der)| Der::from_slice(der).ok().map(|der| (Origin::Installed, der, Some(*scalar)))),
        Ok(Some([VERSION, _, der @ ..])) => Der::from_slice(der).ok().map(|der| (Origin::SelfSigned, der, None)),
        _ => None,
    };
    let (key, origin, certificate) = match saved {
        Some((Origin::Installed, der, Some(scalar))) => (scalar, Origin::Installed, der),
        Some((Origin::SelfSigned, der, _)) if names_device(&der, names) => (key, Origin::SelfSigned, der),
        _ => {
            let der = self_signed(&key, names).map_err(Error::Tls)?;
            note(save_certificate(store, Origin::SelfSigned, &der).await, "certificate");
            info!("tls: a self-signed certificate for {}", names.name);
            (key, Origin::SelfSigned, der)
        }
    };

    let client_ca = match store.fetch_record(key::TLS_CLIENT_CA, &mut buf).await {
        Ok(Some([VERSION, der @ ..])) => Der::from_slice(der).ok(),
        _ => None,
    };
    Ok(Identity { key, certificate, origin, client_ca })
}

/// Whether a self-signed certificate names the device as `names` do now.
fn names_device(der: &[u8], names: &Names<'_>) -> bool {
    let Ok(parsed) = certificate::Certificate::parse(der) else { return false };
    let named = certificate::common_name(parsed.subject) == Some(names.name);
    let mut addresses = parsed.ipv4_addresses();
    let address = match names.address {
        Some(address) => addresses.next() == Some(address) && addresses.next().is_none(),
        None => addresses.next().is_none(),
    };
    named && address
}

/// A self-signed certificate for `key` naming `names`, serial 1.
fn self_signed(key: &[u8; KEY_LEN], names: &Names<'_>) -> Result<Der, tls::Error> {
    let mut buf = [0u8; made::MAX_SELF_SIGNED_LEN];
    let der = made::self_signed(key, names, &[1], &mut buf)?;
    Der::from_slice(der).map_err(|_| tls::Error::Internal)
}

/// Saves the device's certificate with its origin.
pub async fn save_certificate<F: NorFlash>(store: &mut Store<F>, origin: Origin, der: &[u8]) -> Result<(), StoreError> {
    let mut record = [0u8; MAX_OTHER_RECORD_LEN];
    let len = 2 + der.len();
    let out = record.get_mut(..len).ok_or(StoreError::Record(crate::storage::RecordError::TooLong))?;
    if let Some(([version, origin_byte], rest)) = out.split_first_chunk_mut::<2>() {
        *version = VERSION;
        *origin_byte = origin.byte();
        rest.copy_from_slice(der);
    }
    store.save_record(key::TLS_CERTIFICATE, out).await
}

/// Saves a certificate a plant installed with its key's scalar, in one
/// record; `None`: the device's own self-signed one again, made at the
/// next start with the device's key.
pub async fn save_installed<F: NorFlash>(
    store: &mut Store<F>,
    installed: Option<(&[u8; KEY_LEN], &[u8])>,
) -> Result<(), StoreError> {
    let Some((scalar, der)) = installed else { return store.save_record(key::TLS_CERTIFICATE, &[REMOVED]).await };
    let mut record = [0u8; MAX_OTHER_RECORD_LEN];
    let len = 2 + KEY_LEN + der.len();
    let out = record.get_mut(..len).ok_or(StoreError::Record(crate::storage::RecordError::TooLong))?;
    if let Some(([version, origin], rest)) = out.split_first_chunk_mut::<2>() {
        *version = VERSION;
        *origin = Origin::Installed.byte();
        if let Some((key, cert)) = rest.split_first_chunk_mut::<KEY_LEN>() {
            key.copy_from_slice(scalar);
            cert.copy_from_slice(der);
        }
    }
    store.save_record(key::TLS_CERTIFICATE, out).await
}

/// Saves the client CA, or marks it removed (`None`).
pub async fn save_client_ca<F: NorFlash>(store: &mut Store<F>, der: Option<&[u8]>) -> Result<(), StoreError> {
    let Some(der) = der else { return store.save_record(key::TLS_CLIENT_CA, &[REMOVED]).await };
    let mut record = [0u8; MAX_OTHER_RECORD_LEN];
    let out = record.get_mut(..1 + der.len()).ok_or(StoreError::Record(crate::storage::RecordError::TooLong))?;
    if let Some((version, rest)) = out.split_first_mut() {
        *version = VERSION;
        rest.copy_from_slice(der);
    }
    store.save_record(key::TLS_CLIENT_CA, out).await
}

fn note(result: Result<(), StoreError>, what: &str) {
    if let Err(e) = result {
        warn!("tls: the {} cannot be saved ({}): made again at the next start", what, e);
    }
}
