//! The TLS part of the API (feature `tls`, docs/tls.md):
//!
//! - `GET /api/tls`: the device's certificate and the client CA as saved
//!   (subject, issuer, validity, SHA-256 fingerprint, names); never a key;
//! - `PUT /api/tls/client-ca` `{"certificate": "-----BEGIN CERTIFICATE-----..."}`:
//!   the CA that Modbus/TCP Security clients' certificates must chain to,
//!   checked whole (one PEM certificate, a CA, with a P-256 key, that Mbed
//!   TLS reads) before it is saved;
//! - `DELETE /api/tls/client-ca`: no CA, so port 802 serves no one.
//!
//! Changes apply at the next start, as the Modbus port does: the TLS
//! configurations are made once, at start.

use embedded_storage_async::nor_flash::NorFlash;
use sha2::{Digest, Sha256};

use super::api::Reply;
use super::json::{Malformed, Out, Reader, Value};
use super::response::Status;
use crate::control::{Controller, Platform};
use crate::identity::MAX_CERTIFICATE_LEN;
use crate::storage::key;

/// The longest PEM text taken for a certificate.
const MAX_PEM_LEN: usize = MAX_CERTIFICATE_LEN * 4 / 3 + 160;

/// `GET /api/tls`.
pub(super) async fn document<F: NorFlash, P: Platform>(control: &Controller<'_, F, P>, out: &mut Out<'_>) -> Reply {
    out.text("{\"device\":");
    let device = control
        .with_record(key::TLS_CERTIFICATE, |record| match record {
            Some([1, origin, der @ ..]) => {
                summary(out, der, Some(if *origin == 1 { "installed" } else { "self-signed" }));
            }
            _ => out.text("null"),
        })
        .await;
    out.text(",\"client_ca\":");
    let client_ca = control
        .with_record(key::TLS_CLIENT_CA, |record| match record {
            Some([1, der @ ..]) => summary(out, der, None),
            _ => out.text("null"),
        })
        .await;
    out.text(",\"modbus_security_port\":");
    out.number(crate::server::secure::SECURE_PORT);
    out.text(",\"applies\":\"at the next start\"}");
    if device.is_err() || client_ca.is_err() {
        out.clear();
        out.text("{\"errors\":{\"request\":\"the settings flash cannot be read\"}}");
        return Reply::new(Status::INTERNAL_SERVER_ERROR);
    }
    Reply::new(Status::OK)
}

/// A certificate as the document shows it.
fn summary(out: &mut Out<'_>, der: &[u8], origin: Option<&str>) {
    let Ok(parsed) = certificate::Certificate::parse(der) else {
        out.text("{\"error\":\"not a certificate this device reads\"}");
        return;
    };
    out.text("{\"subject\":");
    name(out, certificate::common_name(parsed.subject));
    out.text(",\"issuer\":");
    name(out, certificate::common_name(parsed.issuer));
    out.text(",\"not_before\":");
    out.string_with(|w| write!(w, "{}", parsed.not_before));
    out.text(",\"not_after\":");
    out.string_with(|w| write!(w, "{}", parsed.not_after));
    out.text(",\"sha256\":");
    let digest = Sha256::digest(der);
    out.string_of(
        digest.iter().flat_map(|byte| [crate::text::hex_digit(byte >> 4), crate::text::hex_digit(byte & 0xf)]),
    );
    out.text(",\"dns\":[");
    for (i, dns) in parsed.dns_names().enumerate() {
        if i > 0 {
            out.text(",");
        }
        out.string(dns);
    }
    out.text("],\"ip\":[");
    for (i, address) in parsed.ipv4_addresses().enumerate() {
        if i > 0 {
            out.text(",");
        }
        out.string_with(|w| crate::text::write_ipv4(w, address));
    }
    out.text("]");
    if let Some(origin) = origin {
        out.text(",\"origin\":");
        out.string(origin);
    }
    out.text("}");
}

fn name(out: &mut Out<'_>, name: Option<&str>) {
    match name {
        Some(name) => out.string(name),
        None => out.text("null"),
    }
}

/// Why a client CA is refused, for the `certificate` key.
fn check_client_ca(der: &[u8]) -> Result<(), &'static str> {
    let parsed = certificate::Certificate::parse(der).map_err(|_| "not an X.509 certificate")?;
    if !parsed.is_ca() {
        return Err("not a CA certificate (basic constraints CA:TRUE)");
    }
    if !parsed.has_p256_key() {
        return Err("the device verifies ECDSA P-256 only: the CA's key must be P-256");
    }
    tls::identity::check_certificate(der).map_err(|_| "not a certificate the TLS engine reads")
}

/// `PUT /api/tls/client-ca`.
pub(super) async fn put_client_ca<F: NorFlash, P: Platform>(
    control: &Controller<'_, F, P>,
    body: &[u8],
    out: &mut Out<'_>,
) -> Result<Reply, Malformed> {
    let mut pem = [0u8; MAX_PEM_LEN];
    let mut der = [0u8; MAX_CERTIFICATE_LEN];
    let mut json = Reader::new(body);
    json.begin_object()?;
    let mut text = None;
    let mut problem = None;
    while let Some(field) = json.next_key()? {
        let value = json.value()?;
        match value {
            Value::String(value) if field.is("certificate") && text.is_none() => {
                text = value.decode(&mut pem).map(str::len);
                if text.is_none() {
                    problem = Some("longer than a certificate this device keeps");
                }
            }
            _ if field.is("certificate") => problem = Some("one PEM certificate, as a string, once"),
            _ => problem = problem.or(Some("the only field is certificate")),
        }
    }
    json.end()?;
    let checked = match (problem, text) {
        (Some(problem), _) => Err(problem),
        (None, None) => Err("required"),
        (None, Some(len)) => match pem_rfc7468::decode(pem.get(..len).unwrap_or_default(), &mut der) {
            Ok(("CERTIFICATE", der)) => check_client_ca(der).map(|()| der.len()),
            Ok(_) => Err("a PEM CERTIFICATE is expected"),
            Err(_) => Err("not one PEM certificate"),
        },
    };
    let len = match checked {
        Ok(len) => len,
        Err(reason) => {
            out.text("{\"errors\":{\"certificate\":");
            out.string(reason);
            out.text("}}");
            return Ok(Reply::new(Status::BAD_REQUEST));
        }
    };
    if control.save_client_ca(der.get(..len)).await.is_err() {
        out.text("{\"errors\":{\"request\":\"the client CA was not saved; nothing changed\"}}");
        return Ok(Reply::new(Status::INTERNAL_SERVER_ERROR));
    }
    info!("tls: a client CA installed; it applies at the next start");
    Ok(document(control, out).await)
}

/// `DELETE /api/tls/client-ca`.
pub(super) async fn delete_client_ca<F: NorFlash, P: Platform>(
    control: &Controller<'_, F, P>,
    out: &mut Out<'_>,
) -> Reply {
    if control.save_client_ca(None).await.is_err() {
        out.text("{\"errors\":{\"request\":\"the client CA was not removed; nothing changed\"}}");
        return Reply::new(Status::INTERNAL_SERVER_ERROR);
    }
    info!("tls: the client CA removed; port 802 serves no one from the next start");
    document(control, out).await
}
