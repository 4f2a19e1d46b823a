//! A minimal rustls crypto provider written for the spike: what the device
//! configures and nothing else. P-256 ECDHE, ECDSA P-256 with SHA-256
//! (signing the handshake, verifying the client's chain), SHA-256, HMAC,
//! AES-128-GCM for TLS 1.3 and TLS 1.2; RustCrypto's p256, sha2, hmac and
//! aes-gcm; randomness through getrandom. Built with `--features own-provider`.

use alloc::boxed::Box;
use alloc::sync::Arc;
use alloc::vec::Vec;

use aes_gcm::aead::AeadInPlace;
use aes_gcm::{Aes128Gcm, KeyInit};
use hmac::Mac;
use p256::elliptic_curve::sec1::ToEncodedPoint;
use p256::pkcs8::DecodePrivateKey;
use rand_core::OsRng;
use rustls::crypto::cipher::{
    AeadKey, InboundOpaqueMessage, InboundPlainMessage, Iv, KeyBlockShape, MessageDecrypter,
    MessageEncrypter, Nonce, OutboundOpaqueMessage, OutboundPlainMessage, PrefixedPayload,
    Tls12AeadAlgorithm, Tls13AeadAlgorithm, UnsupportedOperationError, make_tls12_aad,
    make_tls13_aad,
};
use rustls::crypto::{self, CipherSuiteCommon, CryptoProvider, GetRandomFailed, KeyExchangeAlgorithm};
use rustls::pki_types::{
    AlgorithmIdentifier, InvalidSignature, PrivateKeyDer, SignatureVerificationAlgorithm, alg_id,
};
use rustls::{
    CipherSuite, ConnectionTrafficSecrets, ContentType, Error, NamedGroup, ProtocolVersion,
    SignatureAlgorithm, SignatureScheme, SupportedCipherSuite, Tls12CipherSuite, Tls13CipherSuite,
};
use sha2::{Digest, Sha256};

type HmacSha256 = hmac::Hmac<Sha256>;

#[derive(Debug)]
struct Hash;
impl crypto::hash::Hash for Hash {
    fn start(&self) -> Box<dyn crypto::hash::Context> {
        Box::new(HashContext(Sha256::new()))
    }
    fn hash(&self, data: &[u8]) -> crypto::hash::Output {
        crypto::hash::Output::new(&Sha256::digest(data))
    }
    fn algorithm(&self) -> crypto::hash::HashAlgorithm {
        crypto::hash::HashAlgorithm::SHA256
    }
    fn output_len(&self) -> usize {
        32
    }
}

struct HashContext(Sha256);
impl crypto::hash::Context for HashContext {
    fn fork_finish(&self) -> crypto::hash::Output {
        crypto::hash::Output::new(&self.0.clone().finalize())
    }
    fn fork(&self) -> Box<dyn crypto::hash::Context> {
        Box::new(HashContext(self.0.clone()))
    }
    fn finish(self: Box<Self>) -> crypto::hash::Output {
        crypto::hash::Output::new(&self.0.finalize())
    }
    fn update(&mut self, data: &[u8]) {
        self.0.update(data)
    }
}

struct Hmac;
impl crypto::hmac::Hmac for Hmac {
    fn with_key(&self, key: &[u8]) -> Box<dyn crypto::hmac::Key> {
        // HMAC takes a key of any length: the error arm is never taken.
        let mac = <HmacSha256 as Mac>::new_from_slice(key)
            .unwrap_or_else(|_| <HmacSha256 as KeyInit>::new(&Default::default()));
        Box::new(HmacKey(mac))
    }
    fn hash_output_len(&self) -> usize {
        32
    }
}

struct HmacKey(HmacSha256);
impl crypto::hmac::Key for HmacKey {
    fn sign_concat(&self, first: &[u8], middle: &[&[u8]], last: &[u8]) -> crypto::hmac::Tag {
        let mut mac = self.0.clone();
        mac.update(first);
        for m in middle {
            mac.update(m);
        }
        mac.update(last);
        crypto::hmac::Tag::new(&mac.finalize().into_bytes())
    }
    fn tag_len(&self) -> usize {
        32
    }
}

static HASH: Hash = Hash;
static HMAC: Hmac = Hmac;

#[derive(Debug)]
struct P256;
impl crypto::SupportedKxGroup for P256 {
    fn start(&self) -> Result<Box<dyn crypto::ActiveKeyExchange>, Error> {
        let secret = p256::ecdh::EphemeralSecret::random(&mut OsRng);
        let public = secret.public_key().to_encoded_point(false).as_bytes().to_vec();
        Ok(Box::new(P256Exchange { secret, public }))
    }
    fn name(&self) -> NamedGroup {
        NamedGroup::secp256r1
    }
}

struct P256Exchange {
    secret: p256::ecdh::EphemeralSecret,
    public: Vec<u8>,
}
impl crypto::ActiveKeyExchange for P256Exchange {
    fn complete(self: Box<Self>, peer: &[u8]) -> Result<crypto::SharedSecret, Error> {
        let peer = p256::PublicKey::from_sec1_bytes(peer)
            .map_err(|_| Error::from(rustls::PeerMisbehaved::InvalidKeyShare))?;
        let shared = self.secret.diffie_hellman(&peer);
        Ok(crypto::SharedSecret::from(&shared.raw_secret_bytes()[..]))
    }
    fn pub_key(&self) -> &[u8] {
        &self.public
    }
    fn group(&self) -> NamedGroup {
        NamedGroup::secp256r1
    }
}

#[derive(Debug)]
struct EcdsaKey(Arc<p256::ecdsa::SigningKey>);
impl rustls::sign::SigningKey for EcdsaKey {
    fn choose_scheme(&self, offered: &[SignatureScheme]) -> Option<Box<dyn rustls::sign::Signer>> {
        if offered.contains(&SignatureScheme::ECDSA_NISTP256_SHA256) {
            Some(Box::new(EcdsaSigner(self.0.clone())))
        } else {
            None
        }
    }
    fn algorithm(&self) -> SignatureAlgorithm {
        SignatureAlgorithm::ECDSA
    }
}

#[derive(Debug)]
struct EcdsaSigner(Arc<p256::ecdsa::SigningKey>);
impl rustls::sign::Signer for EcdsaSigner {
    fn sign(&self, message: &[u8]) -> Result<Vec<u8>, Error> {
        use p256::ecdsa::signature::RandomizedSigner;
        let sig: p256::ecdsa::Signature = self
            .0
            .try_sign_with_rng(&mut OsRng, message)
            .map_err(|_| Error::General("ECDSA signing failed".into()))?;
        Ok(sig.to_der().as_bytes().to_vec())
    }
    fn scheme(&self) -> SignatureScheme {
        SignatureScheme::ECDSA_NISTP256_SHA256
    }
}

#[derive(Debug)]
struct EcdsaP256Sha256;
impl SignatureVerificationAlgorithm for EcdsaP256Sha256 {
    fn verify_signature(&self, public_key: &[u8], message: &[u8], signature: &[u8]) -> Result<(), InvalidSignature> {
        use p256::ecdsa::signature::Verifier;
        let key = p256::ecdsa::VerifyingKey::from_sec1_bytes(public_key).map_err(|_| InvalidSignature)?;
        let sig = p256::ecdsa::Signature::from_der(signature).map_err(|_| InvalidSignature)?;
        key.verify(message, &sig).map_err(|_| InvalidSignature)
    }
    fn public_key_alg_id(&self) -> AlgorithmIdentifier {
        alg_id::ECDSA_P256
    }
    fn signature_alg_id(&self) -> AlgorithmIdentifier {
        alg_id::ECDSA_SHA256
    }
}

const VERIFY: &[&dyn SignatureVerificationAlgorithm] = &[&EcdsaP256Sha256];
static MAPPING: &[(SignatureScheme, &[&dyn SignatureVerificationAlgorithm])] =
    &[(SignatureScheme::ECDSA_NISTP256_SHA256, VERIFY)];

struct Aes128GcmTls13;
impl Tls13AeadAlgorithm for Aes128GcmTls13 {
    fn encrypter(&self, key: AeadKey, iv: Iv) -> Box<dyn MessageEncrypter> {
        Box::new(Tls13Gcm(Aes128Gcm::new_from_slice(key.as_ref()).ok(), iv))
    }
    fn decrypter(&self, key: AeadKey, iv: Iv) -> Box<dyn MessageDecrypter> {
        Box::new(Tls13Gcm(Aes128Gcm::new_from_slice(key.as_ref()).ok(), iv))
    }
    fn key_len(&self) -> usize {
        16
    }
    fn extract_keys(&self, key: AeadKey, iv: Iv) -> Result<ConnectionTrafficSecrets, UnsupportedOperationError> {
        Ok(ConnectionTrafficSecrets::Aes128Gcm { key, iv })
    }
}

const TAG: usize = 16;

struct Tls13Gcm(Option<Aes128Gcm>, Iv);
impl MessageEncrypter for Tls13Gcm {
    fn encrypt(&mut self, msg: OutboundPlainMessage<'_>, seq: u64) -> Result<OutboundOpaqueMessage, Error> {
        let cipher = self.0.as_ref().ok_or(Error::EncryptError)?;
        let total = self.encrypted_payload_len(msg.payload.len());
        let mut payload = PrefixedPayload::with_capacity(total);
        payload.extend_from_chunks(&msg.payload);
        payload.extend_from_slice(&[u8::from(msg.typ)]);
        let nonce = Nonce::new(&self.1, seq);
        let tag = cipher
            .encrypt_in_place_detached(&nonce.0.into(), &make_tls13_aad(total), payload.as_mut())
            .map_err(|_| Error::EncryptError)?;
        payload.extend_from_slice(&tag);
        Ok(OutboundOpaqueMessage::new(ContentType::ApplicationData, ProtocolVersion::TLSv1_2, payload))
    }
    fn encrypted_payload_len(&self, payload_len: usize) -> usize {
        payload_len + 1 + TAG
    }
}

impl MessageDecrypter for Tls13Gcm {
    fn decrypt<'a>(&mut self, mut msg: InboundOpaqueMessage<'a>, seq: u64) -> Result<InboundPlainMessage<'a>, Error> {
        let cipher = self.0.as_ref().ok_or(Error::DecryptError)?;
        let payload = &mut msg.payload;
        let len = payload.len();
        let Some(body) = len.checked_sub(TAG) else { return Err(Error::DecryptError) };
        let aad = make_tls13_aad(len);
        let nonce = Nonce::new(&self.1, seq);
        let (text, tag) = payload.split_at_mut(body);
        let tag = aes_gcm::Tag::clone_from_slice(tag);
        cipher
            .decrypt_in_place_detached(&nonce.0.into(), &aad, text, &tag)
            .map_err(|_| Error::DecryptError)?;
        payload.truncate(body);
        msg.into_tls13_unpadded_message()
    }
}

struct Aes128GcmTls12;
impl Tls12AeadAlgorithm for Aes128GcmTls12 {
    fn encrypter(&self, key: AeadKey, iv: &[u8], extra: &[u8]) -> Box<dyn MessageEncrypter> {
        let mut nonce = [0u8; 12];
        if let (Some(a), Some(b)) = (nonce.get_mut(..4), iv.get(..4)) {
            a.copy_from_slice(b);
        }
        if let (Some(a), Some(b)) = (nonce.get_mut(4..), extra.get(..8)) {
            a.copy_from_slice(b);
        }
        Box::new(Tls12Gcm(Aes128Gcm::new_from_slice(key.as_ref()).ok(), Iv::new(nonce)))
    }
    fn decrypter(&self, key: AeadKey, iv: &[u8]) -> Box<dyn MessageDecrypter> {
        let mut nonce = [0u8; 12];
        if let (Some(a), Some(b)) = (nonce.get_mut(..4), iv.get(..4)) {
            a.copy_from_slice(b);
        }
        Box::new(Tls12Gcm(Aes128Gcm::new_from_slice(key.as_ref()).ok(), Iv::new(nonce)))
    }
    fn key_block_shape(&self) -> KeyBlockShape {
        KeyBlockShape { enc_key_len: 16, fixed_iv_len: 4, explicit_nonce_len: 8 }
    }
    fn extract_keys(&self, key: AeadKey, iv: &[u8], explicit: &[u8]) -> Result<ConnectionTrafficSecrets, UnsupportedOperationError> {
        let mut nonce = [0u8; 12];
        match (nonce.get_mut(..4), iv.get(..4), explicit.get(..8)) {
            (Some(a), Some(b), Some(c)) => {
                a.copy_from_slice(b);
                nonce[4..].copy_from_slice(c);
            }
            _ => return Err(UnsupportedOperationError),
        }
        Ok(ConnectionTrafficSecrets::Aes128Gcm { key, iv: Iv::new(nonce) })
    }
}

const EXPLICIT: usize = 8;

/// TLS 1.2 GCM: the fixed IV (4 bytes) and, when sealing, the explicit part.
struct Tls12Gcm(Option<Aes128Gcm>, Iv);
impl MessageEncrypter for Tls12Gcm {
    fn encrypt(&mut self, msg: OutboundPlainMessage<'_>, seq: u64) -> Result<OutboundOpaqueMessage, Error> {
        let cipher = self.0.as_ref().ok_or(Error::EncryptError)?;
        let len = msg.payload.len();
        let nonce = Nonce::new(&self.1, seq);
        let aad = make_tls12_aad(seq, msg.typ, msg.version, len);
        let mut payload = PrefixedPayload::with_capacity(self.encrypted_payload_len(len));
        payload.extend_from_slice(&nonce.0[4..]);
        payload.extend_from_chunks(&msg.payload);
        let text = payload.as_mut().get_mut(EXPLICIT..).ok_or(Error::EncryptError)?;
        let tag = cipher
            .encrypt_in_place_detached(&nonce.0.into(), &aad, text)
            .map_err(|_| Error::EncryptError)?;
        payload.extend_from_slice(&tag);
        Ok(OutboundOpaqueMessage::new(msg.typ, msg.version, payload))
    }
    fn encrypted_payload_len(&self, payload_len: usize) -> usize {
        payload_len + EXPLICIT + TAG
    }
}

impl MessageDecrypter for Tls12Gcm {
    fn decrypt<'a>(&mut self, mut msg: InboundOpaqueMessage<'a>, seq: u64) -> Result<InboundPlainMessage<'a>, Error> {
        let cipher = self.0.as_ref().ok_or(Error::DecryptError)?;
        let len = msg.payload.len();
        let Some(body) = len.checked_sub(EXPLICIT + TAG) else { return Err(Error::DecryptError) };
        let aad = make_tls12_aad(seq, msg.typ, msg.version, body);
        let mut nonce = self.1.as_ref().to_vec();
        let payload = &mut msg.payload;
        nonce[4..].copy_from_slice(&payload[..EXPLICIT]);
        let (text, tag) = payload[EXPLICIT..].split_at_mut(body);
        let tag = aes_gcm::Tag::clone_from_slice(tag);
        cipher
            .decrypt_in_place_detached(aes_gcm::Nonce::from_slice(&nonce), &aad, text, &tag)
            .map_err(|_| Error::DecryptError)?;
        Ok(msg.into_plain_message_range(EXPLICIT..EXPLICIT + body))
    }
}

static TLS13_SUITE: Tls13CipherSuite = Tls13CipherSuite {
    common: CipherSuiteCommon {
        suite: CipherSuite::TLS13_AES_128_GCM_SHA256,
        hash_provider: &HASH,
        confidentiality_limit: 1 << 24,
    },
    hkdf_provider: &crypto::tls13::HkdfUsingHmac(&HMAC),
    aead_alg: &Aes128GcmTls13,
    quic: None,
};

static TLS12_SUITE: Tls12CipherSuite = Tls12CipherSuite {
    common: CipherSuiteCommon {
        suite: CipherSuite::TLS_ECDHE_ECDSA_WITH_AES_128_GCM_SHA256,
        hash_provider: &HASH,
        confidentiality_limit: 1 << 24,
    },
    prf_provider: &crypto::tls12::PrfUsingHmac(&HMAC),
    kx: KeyExchangeAlgorithm::ECDHE,
    sign: &[SignatureScheme::ECDSA_NISTP256_SHA256],
    aead_alg: &Aes128GcmTls12,
};

#[derive(Debug)]
struct Provider;
impl crypto::SecureRandom for Provider {
    fn fill(&self, buf: &mut [u8]) -> Result<(), GetRandomFailed> {
        use rand_core::RngCore;
        OsRng.try_fill_bytes(buf).map_err(|_| GetRandomFailed)
    }
}
impl crypto::KeyProvider for Provider {
    fn load_private_key(&self, der: PrivateKeyDer<'static>) -> Result<Arc<dyn rustls::sign::SigningKey>, Error> {
        let PrivateKeyDer::Pkcs8(der) = der else {
            return Err(Error::General("P-256 PKCS#8 keys only".into()));
        };
        let key = p256::ecdsa::SigningKey::from_pkcs8_der(der.secret_pkcs8_der())
            .map_err(|_| Error::General("not a P-256 PKCS#8 key".into()))?;
        Ok(Arc::new(EcdsaKey(Arc::new(key))))
    }
}

pub fn provider() -> CryptoProvider {
    CryptoProvider {
        cipher_suites: alloc::vec![
            SupportedCipherSuite::Tls13(&TLS13_SUITE),
            SupportedCipherSuite::Tls12(&TLS12_SUITE),
        ],
        kx_groups: alloc::vec![&P256],
        signature_verification_algorithms: crypto::WebPkiSupportedAlgorithms {
            all: VERIFY,
            mapping: MAPPING,
        },
        secure_random: &Provider,
        key_provider: &Provider,
    }
}
