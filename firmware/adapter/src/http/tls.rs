//! The TLS part of the API (feature `tls`, docs/tls.md):
//!
//! - `GET /api/tls`: the device's certificate and the client CA as saved
//!   (subject, issuer, validity, SHA-256 fingerprint, names); never a key;
//! - `PUT /api/tls/client-ca` `{"certificate": "-----BEGIN CERTIFICATE-----..."}`:
//!   the CA that Modbus/TCP Security clients' certificates must chain to,
//!   checked whole (one PEM certificate, a CA, with a P-256 key, that Mbed
//!   TLS reads) before it is saved;
//! - `DELETE /api/tls/client-ca`: no CA, so port 802 serves no one;
//! - `PUT /api/tls/certificate` `{"certificate": PEM, "key": PEM}`: the
//!   device's own certificate and P-256 key, signed by the plant's CA, for
//!   HTTPS and port 802: checked whole (one PEM certificate with a P-256
//!   key, the key SEC1 or PKCS#8, the pair matching) and saved in one
//!   record; the key never leaves the device again;
//! - `DELETE /api/tls/certificate`: the device's own self-signed
//!   certificate again.
//!
//! Changes apply at the next start, as the Modbus port does: the TLS
//! configurations are made once, at start.

use embedded_storage_async::nor_flash::NorFlash;
use sha2::{Digest, Sha256};

use super::api::Reply;
use super::json::{Malformed, Out, Reader, Value};
use super::response::Status;
use crate::control::{Controller, Platform};
use crate::identity::{MAX_CERTIFICATE_LEN, MAX_INSTALLED_LEN};
use crate::storage::key;
use tls::identity::KEY_LEN;

/// The longest PEM text taken for a certificate.
const MAX_PEM_LEN: usize = MAX_CERTIFICATE_LEN * 4 / 3 + 160;

/// `GET /api/tls`.
pub(super) async fn document<F: NorFlash, P: Platform>(control: &Controller<'_, F, P>, out: &mut Out<'_>) -> Reply {
    out.text("{\"device\":");
    let device = control
        .with_record(key::TLS_CERTIFICATE, |record| match record {
            // An installed certificate's record holds its key first: skipped.
            Some([1, 1, rest @ ..]) => summary(out, rest.get(KEY_LEN..).unwrap_or_default(), Some("installed")),
            Some([1, _, der @ ..]) => summary(out, der, Some("self-signed")),
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

/// `PUT /api/tls/certificate`.
pub(super) async fn put_certificate<F: NorFlash, P: Platform>(
    control: &Controller<'_, F, P>,
    body: &[u8],
    out: &mut Out<'_>,
) -> Result<Reply, Malformed> {
    // Only the DER and the scalar live across the save's `.await` (in every
    // HTTP task's future): the PEM texts are read in `read_installed`.
    let mut der = [0u8; MAX_INSTALLED_LEN];
    let (scalar, len) = match read_installed(body, &mut der)? {
        Ok(checked) => checked,
        Err((field, reason)) => return Ok(super::api::refusal(out, Status::BAD_REQUEST, field, reason)),
    };
    if control.save_installed(Some((&scalar, der.get(..len).unwrap_or_default()))).await.is_err() {
        out.text("{\"errors\":{\"request\":\"the certificate was not saved; nothing changed\"}}");
        return Ok(Reply::new(Status::INTERNAL_SERVER_ERROR));
    }
    info!("tls: a certificate installed for the device; it applies at the next start");
    Ok(document(control, out).await)
}

/// A refused field and why.
type FieldError = (&'static str, &'static str);

/// `PUT /api/tls/certificate`'s body, read and checked whole: the
/// certificate's DER in `der`, and the key's scalar.
fn read_installed(
    body: &[u8],
    der: &mut [u8; MAX_INSTALLED_LEN],
) -> Result<Result<([u8; KEY_LEN], usize), FieldError>, Malformed> {
    let mut pem = [0u8; MAX_PEM_LEN];
    let mut key_pem = [0u8; MAX_KEY_PEM_LEN];
    let mut json = Reader::new(body);
    json.begin_object()?;
    let (mut certificate, mut key) = (None, None);
    let mut problem = None;
    while let Some(field) = json.next_key()? {
        match json.value()? {
            Value::String(value) if field.is("certificate") && certificate.is_none() => {
                certificate =
                    Some(value.decode(&mut pem).map(str::len).ok_or("longer than a certificate this device keeps"));
            }
            Value::String(value) if field.is("key") && key.is_none() => {
                key = Some(value.decode(&mut key_pem).map(str::len).ok_or("longer than a P-256 key"));
            }
            _ => problem = problem.or(Some(("request", "the fields are certificate and key, each a PEM string, once"))),
        }
    }
    json.end()?;
    Ok(match (problem, certificate, key) {
        (Some(problem), _, _) => Err(problem),
        (None, None, _) => Err(("certificate", "required")),
        (None, _, None) => Err(("key", "required")),
        (None, Some(Err(why)), _) => Err(("certificate", why)),
        (None, _, Some(Err(why))) => Err(("key", why)),
        (None, Some(Ok(cert_len)), Some(Ok(key_len))) => {
            check_installed(pem.get(..cert_len).unwrap_or_default(), key_pem.get(..key_len).unwrap_or_default(), der)
        }
    })
}

/// `DELETE /api/tls/certificate`.
pub(super) async fn delete_certificate<F: NorFlash, P: Platform>(
    control: &Controller<'_, F, P>,
    out: &mut Out<'_>,
) -> Reply {
    if control.save_installed(None).await.is_err() {
        out.text("{\"errors\":{\"request\":\"the certificate was not removed; nothing changed\"}}");
        return Reply::new(Status::INTERNAL_SERVER_ERROR);
    }
    info!("tls: the installed certificate removed; the device's own from the next start");
    document(control, out).await
}

/// The longest PEM text taken for a key (PKCS#8 of a P-256 key with its
/// public key is about 250 bytes).
const MAX_KEY_PEM_LEN: usize = 320;

/// A certificate and key for the device, checked whole: the certificate's
/// DER in `der` and the key's scalar, or the field and why not.
fn check_installed(
    certificate: &[u8],
    key: &[u8],
    der: &mut [u8; MAX_INSTALLED_LEN],
) -> Result<([u8; KEY_LEN], usize), FieldError> {
    let der = match pem_rfc7468::decode(certificate, der) {
        Ok(("CERTIFICATE", der)) => der,
        Ok(_) => return Err(("certificate", "a PEM CERTIFICATE is expected")),
        Err(_) => return Err(("certificate", "not one PEM certificate, or longer than this device keeps")),
    };
    let parsed = certificate::Certificate::parse(der).map_err(|_| ("certificate", "not an X.509 certificate"))?;
    if !parsed.has_p256_key() {
        return Err(("certificate", "the device's key is ECDSA P-256: the certificate's must be too"));
    }
    let mut key_der = [0u8; MAX_KEY_PEM_LEN];
    let scalar = match pem_rfc7468::decode(key, &mut key_der) {
        Ok(("EC PRIVATE KEY", sec1)) => sec1_scalar(sec1),
        Ok(("PRIVATE KEY", pkcs8)) => pkcs8_scalar(pkcs8),
        Ok(_) => None,
        Err(_) => return Err(("key", "not one PEM key")),
    }
    .ok_or(("key", "not a P-256 private key (SEC1 EC PRIVATE KEY or PKCS#8 PRIVATE KEY)"))?;
    let key = tls::identity::key_der(&scalar);
    match tls::Server::new(&tls::Credentials { certificate: der, key: &key, client_ca: None }) {
        Ok(_) => Ok((scalar, der.len())),
        Err(tls::Error::KeyMismatch) => Err(("key", "not the certificate's key")),
        Err(tls::Error::OutOfMemory) => Err(("request", "the TLS engine is busy: try again")),
        Err(_) => Err(("certificate", "not a certificate the TLS engine reads")),
    }
}

/// P-256's name (OID 1.2.840.10045.3.1.7), and an EC key's (1.2.840.10045.2.1).
const PRIME256V1: &[u8] = &[0x2a, 0x86, 0x48, 0xce, 0x3d, 0x03, 0x01, 0x07];
const EC_PUBLIC_KEY: &[u8] = &[0x2a, 0x86, 0x48, 0xce, 0x3d, 0x02, 0x01];

/// The scalar of a SEC1 `ECPrivateKey` (RFC 5915) on P-256: version 1, the
/// key, and the curve, if named, P-256.
fn sec1_scalar(der: &[u8]) -> Option<[u8; KEY_LEN]> {
    use certificate::der::{Reader, tag};
    let mut outer = Reader::new(der);
    let mut key = Reader::new(outer.expect(tag::SEQUENCE).ok()?.value);
    outer.finish().ok()?;
    if key.expect(tag::INTEGER).ok()?.value != [1] {
        return None;
    }
    let scalar = <[u8; KEY_LEN]>::try_from(key.expect(tag::OCTET_STRING).ok()?.value).ok()?;
    if let Some(curve) = key.optional(tag::explicit(0)).ok()? {
        let mut curve = Reader::new(curve.value);
        if curve.expect(tag::OID).ok()?.value != PRIME256V1 {
            return None;
        }
    }
    Some(scalar)
}

/// The scalar of a PKCS#8 `PrivateKeyInfo` (RFC 5208) holding a P-256 key.
fn pkcs8_scalar(der: &[u8]) -> Option<[u8; KEY_LEN]> {
    use certificate::der::{Reader, tag};
    let mut outer = Reader::new(der);
    let mut info = Reader::new(outer.expect(tag::SEQUENCE).ok()?.value);
    outer.finish().ok()?;
    if info.expect(tag::INTEGER).ok()?.value != [0] {
        return None;
    }
    let mut algorithm = Reader::new(info.expect(tag::SEQUENCE).ok()?.value);
    let named =
        algorithm.expect(tag::OID).ok()?.value == EC_PUBLIC_KEY && algorithm.expect(tag::OID).ok()?.value == PRIME256V1;
    if !named {
        return None;
    }
    sec1_scalar(info.expect(tag::OCTET_STRING).ok()?.value)
}
