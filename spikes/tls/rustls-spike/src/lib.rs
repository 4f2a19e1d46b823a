//! The rustls side of the TLS engine spike (docs/tls.md): the device's
//! engine configuration (P-256 key, TLS 1.2 + 1.3, one AES-128-GCM suite
//! of each, P-256 key exchange, client certificates required and verified
//! against the plant's CA) over rustls 0.23's unbuffered API, and a step
//! driver over caller-owned record buffers. The bins: rustls-host (against
//! openssl s_client) and rustls-m4 (QEMU mps2-an386).
#![no_std]

extern crate alloc;

#[path = "../../common/arena.rs"]
pub mod arena;
#[path = "../../common/role.rs"]
pub mod role;
#[cfg(feature = "own-provider")]
pub mod own;

use alloc::sync::Arc;
use alloc::vec;
use rustls::client::UnbufferedClientConnection;
use rustls::crypto::CryptoProvider;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer, UnixTime};
use rustls::server::{UnbufferedServerConnection, WebPkiClientVerifier};
use rustls::time_provider::TimeProvider;
use rustls::unbuffered::{ConnectionState, EncodeError, UnbufferedStatus};
use rustls::{ClientConfig, RootCertStore, ServerConfig};

pub const SERVER_CERT: &[u8] = include_bytes!("../../certs/server.der");
pub const SERVER_KEY: &[u8] = include_bytes!("../../certs/server.key.der");
pub const CA_CERT: &[u8] = include_bytes!("../../certs/ca.der");

/// The device has no clock: certificate validity is checked against a fixed
/// time (here 2027-01-01), as the firmware would without SNTP.
#[derive(Debug)]
pub struct FixedTime;
impl TimeProvider for FixedTime {
    fn current_time(&self) -> Option<UnixTime> {
        Some(UnixTime::since_unix_epoch(core::time::Duration::from_secs(1_798_761_600)))
    }
}

/// One suite family: TLS_AES_128_GCM_SHA256 and
/// TLS_ECDHE_ECDSA_WITH_AES_128_GCM_SHA256, P-256 only.
#[cfg(feature = "own-provider")]
pub fn provider() -> Arc<CryptoProvider> {
    Arc::new(own::provider())
}

#[cfg(not(feature = "own-provider"))]
pub fn provider() -> Arc<CryptoProvider> {
    let all = rustls_rustcrypto::provider();
    let kx = all
        .kx_groups
        .iter()
        .copied()
        .filter(|g| g.name() == rustls::NamedGroup::secp256r1)
        .collect();
    Arc::new(CryptoProvider {
        cipher_suites: vec![
            rustls_rustcrypto::TLS13_AES_128_GCM_SHA256,
            rustls_rustcrypto::TLS_ECDHE_ECDSA_WITH_AES_128_GCM_SHA256,
        ],
        kx_groups: kx,
        ..all
    })
}

pub fn server_config(provider: Arc<CryptoProvider>) -> Result<Arc<ServerConfig>, rustls::Error> {
    let mut roots = RootCertStore::empty();
    roots.add(CertificateDer::from(CA_CERT))?;
    let verifier = WebPkiClientVerifier::builder_with_provider(Arc::new(roots), provider.clone())
        .build()
        .map_err(|e| rustls::Error::General(alloc::format!("{e:?}")))?;
    let mut config = ServerConfig::builder_with_details(provider, Arc::new(FixedTime))
        .with_protocol_versions(&[&rustls::version::TLS13, &rustls::version::TLS12])?
        .with_client_cert_verifier(verifier)
        .with_single_cert(
            vec![CertificateDer::from(SERVER_CERT)],
            PrivateKeyDer::Pkcs8(PrivatePkcs8KeyDer::from(SERVER_KEY)),
        )?;
    config.send_tls13_tickets = 0;
    Ok(Arc::new(config))
}

pub fn client_config(
    provider: Arc<CryptoProvider>,
    tls13: bool,
    cert: &'static [u8],
    key: &'static [u8],
) -> Result<Arc<ClientConfig>, rustls::Error> {
    let mut roots = RootCertStore::empty();
    roots.add(CertificateDer::from(SERVER_CERT))?;
    let version = if tls13 { &rustls::version::TLS13 } else { &rustls::version::TLS12 };
    let config = ClientConfig::builder_with_details(provider, Arc::new(FixedTime))
        .with_protocol_versions(&[version])?
        .with_root_certificates(roots)
        .with_client_auth_cert(
            vec![CertificateDer::from(cert)],
            PrivateKeyDer::Pkcs8(PrivatePkcs8KeyDer::from(key)),
        )?;
    Ok(Arc::new(config))
}

/// Why a step stopped.
#[derive(Debug, PartialEq, Eq)]
pub enum Step {
    /// Needs more bytes in the incoming buffer.
    WantRead,
    /// The outgoing buffer holds bytes to send.
    Wrote,
    /// Handshake done: application data may flow.
    Established,
    Closed,
}

#[derive(Debug, PartialEq)]
pub enum StepError {
    Tls(rustls::Error),
    /// A message does not fit the outgoing buffer.
    OutFull,
    /// A message does not fit the incoming buffer: an oversized peer
    /// message (e.g. a client certificate chain) fails the handshake here.
    InFull,
    Unexpected,
}

/// Caller-owned record buffers of one connection.
pub struct Buffers<const IN: usize, const OUT: usize> {
    pub inb: [u8; IN],
    pub in_len: usize,
    pub out: [u8; OUT],
    pub out_len: usize,
}

impl<const IN: usize, const OUT: usize> Buffers<IN, OUT> {
    pub const fn new() -> Self {
        Self { inb: [0; IN], in_len: 0, out: [0; OUT], out_len: 0 }
    }
}

macro_rules! step_fn {
    ($name:ident, $conn:ty) => {
        /// Run the connection until it needs input, has output, or is
        /// established; app data received is handed to `on_app`.
        pub fn $name<const IN: usize, const OUT: usize>(
            conn: &mut $conn,
            b: &mut Buffers<IN, OUT>,
            on_app: &mut dyn FnMut(&[u8]),
        ) -> Result<Step, StepError> {
            loop {
                let UnbufferedStatus { discard, state } =
                    conn.process_tls_records(&mut b.inb[..b.in_len]);
                let result = match state {
                    Err(e) => Some(Err(StepError::Tls(e))),
                    Ok(ConnectionState::EncodeTlsData(mut e)) => {
                        match e.encode(&mut b.out[b.out_len..]) {
                            Ok(n) => {
                                b.out_len += n;
                                None
                            }
                            Err(EncodeError::InsufficientSize(_)) => Some(Err(StepError::OutFull)),
                            Err(_) => Some(Err(StepError::Unexpected)),
                        }
                    }
                    Ok(ConnectionState::TransmitTlsData(t)) => {
                        t.done();
                        Some(Ok(Step::Wrote))
                    }
                    Ok(ConnectionState::BlockedHandshake) => Some(Ok(Step::WantRead)),
                    Ok(ConnectionState::WriteTraffic(_)) => Some(Ok(Step::Established)),
                    Ok(ConnectionState::ReadTraffic(mut r)) => {
                        let mut err = None;
                        while let Some(rec) = r.next_record() {
                            match rec {
                                Ok(rec) => on_app(rec.payload),
                                Err(e) => {
                                    err = Some(Err(StepError::Tls(e)));
                                    break;
                                }
                            }
                        }
                        err
                    }
                    Ok(ConnectionState::PeerClosed) | Ok(ConnectionState::Closed) => {
                        Some(Ok(Step::Closed))
                    }
                    Ok(_) => Some(Err(StepError::Unexpected)),
                };
                if discard > 0 {
                    b.inb.copy_within(discard..b.in_len, 0);
                    b.in_len -= discard;
                }
                if let Some(r) = result {
                    if r == Ok(Step::WantRead) && b.in_len == IN {
                        return Err(StepError::InFull);
                    }
                    return r;
                }
            }
        }
    };
}

step_fn!(step_server, UnbufferedServerConnection);

/// Encrypt `data` as application data into the outgoing buffer (the
/// connection must be established).
pub fn send_server<const IN: usize, const OUT: usize>(
    conn: &mut UnbufferedServerConnection,
    b: &mut Buffers<IN, OUT>,
    data: &[u8],
    close: bool,
) -> Result<(), StepError> {
    let UnbufferedStatus { state, .. } = conn.process_tls_records(&mut []);
    match state {
        Ok(ConnectionState::WriteTraffic(mut w)) => {
            let n = w.encrypt(data, &mut b.out[b.out_len..]).map_err(|_| StepError::OutFull)?;
            b.out_len += n;
            if close {
                let n = w.queue_close_notify(&mut b.out[b.out_len..]).map_err(|_| StepError::OutFull)?;
                b.out_len += n;
            }
            Ok(())
        }
        Ok(_) => Err(StepError::Unexpected),
        Err(e) => Err(StepError::Tls(e)),
    }
}

/// The client's step (the M4 image's in-memory peer).
pub fn step_client<const IN: usize, const OUT: usize>(
    conn: &mut UnbufferedClientConnection,
    b: &mut Buffers<IN, OUT>,
) -> Result<Step, StepError> {
    loop {
        let UnbufferedStatus { discard, state } = conn.process_tls_records(&mut b.inb[..b.in_len]);
        let result = match state {
            Err(e) => Some(Err(StepError::Tls(e))),
            Ok(ConnectionState::EncodeTlsData(mut e)) => match e.encode(&mut b.out[b.out_len..]) {
                Ok(n) => {
                    b.out_len += n;
                    None
                }
                Err(_) => Some(Err(StepError::OutFull)),
            },
            Ok(ConnectionState::TransmitTlsData(t)) => {
                t.done();
                Some(Ok(Step::Wrote))
            }
            Ok(ConnectionState::BlockedHandshake) => Some(Ok(Step::WantRead)),
            Ok(ConnectionState::WriteTraffic(_)) => Some(Ok(Step::Established)),
            Ok(ConnectionState::ReadTraffic(mut r)) => {
                while let Some(rec) = r.next_record() {
                    if rec.is_err() {
                        break;
                    }
                }
                None
            }
            Ok(ConnectionState::PeerClosed) | Ok(ConnectionState::Closed) => Some(Ok(Step::Closed)),
            Ok(_) => Some(Err(StepError::Unexpected)),
        };
        if discard > 0 {
            b.inb.copy_within(discard..b.in_len, 0);
            b.in_len -= discard;
        }
        if let Some(r) = result {
            return r;
        }
    }
}
