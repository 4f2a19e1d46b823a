//! The Mbed TLS side of the TLS engine spike (docs/tls.md): Mbed TLS 3.6
//! through mbedtls-rs-sys's raw bindings, configured as the device would
//! be (P-256 key, TLS 1.2 + 1.3, TLS_AES_128_GCM_SHA256 and
//! TLS_ECDHE_ECDSA_WITH_AES_128_GCM_SHA256, P-256 key exchange, client
//! certificates required and verified against the plant's CA, the role read
//! in the verify callback), its calloc/free on a fixed arena where an
//! allocation past the arena returns NULL. The bins: mbedtls-host (against
//! openssl s_client) and mbedtls-m4 (QEMU mps2-an386).
#![no_std]
#![allow(clippy::missing_safety_doc)]

#[path = "../../common/arena.rs"]
pub mod arena;
#[path = "../../common/role.rs"]
pub mod role;

use core::alloc::Layout;
use core::ffi::{c_int, c_uchar, c_void};
use core::sync::atomic::{AtomicPtr, Ordering};
pub use mbedtls_rs_sys as sys;
use sys::*;

pub const SERVER_CERT: &[u8] = include_bytes!("../../certs/server.der");
pub const SERVER_KEY: &[u8] = include_bytes!("../../certs/server.key.der");
pub const CA_CERT: &[u8] = include_bytes!("../../certs/ca.der");

/// The TLS arena: every allocation Mbed TLS makes, and nothing else.
pub const ARENA_SIZE: usize = 96 * 1024;
pub static ARENA: arena::Arena<ARENA_SIZE> = arena::Arena::new();
/// Where the client of the M4 image allocates (None: the same arena).
pub static OTHER_ARENA: AtomicPtr<arena::Arena<ARENA_SIZE>> = AtomicPtr::new(core::ptr::null_mut());
pub static mut USE_OTHER: bool = false;

const HEADER: usize = 8;

fn current() -> &'static arena::Arena<ARENA_SIZE> {
    // SAFETY: single-threaded use in the spike.
    let other = OTHER_ARENA.load(Ordering::Relaxed);
    if unsafe { USE_OTHER } && !other.is_null() { unsafe { &*other } } else { &ARENA }
}

pub unsafe extern "C" fn arena_calloc(n: usize, size: usize) -> *mut c_void {
    let Some(bytes) = n.checked_mul(size).and_then(|b| b.checked_add(HEADER)) else {
        return core::ptr::null_mut();
    };
    let Ok(layout) = Layout::from_size_align(bytes, 8) else { return core::ptr::null_mut() };
    let p = unsafe { current().alloc(layout) };
    if p.is_null() {
        return p.cast();
    }
    unsafe {
        core::ptr::write_bytes(p, 0, bytes);
        p.cast::<usize>().write(bytes);
        p.add(HEADER).cast()
    }
}

pub unsafe extern "C" fn arena_free(ptr: *mut c_void) {
    if ptr.is_null() {
        return;
    }
    unsafe {
        let p = ptr.cast::<u8>().sub(HEADER);
        let bytes = p.cast::<usize>().read();
        let layout = Layout::from_size_align_unchecked(bytes, 8);
        let other = OTHER_ARENA.load(Ordering::Relaxed);
        if !other.is_null() && (*other).contains(p) {
            (*other).dealloc(p, layout)
        } else {
            ARENA.dealloc(p, layout)
        }
    }
}

/// Randomness: set by the program (host: the OS; M4: a spike-only PRNG).
pub static mut RANDOM: fn(&mut [u8]) = |_| {};

unsafe extern "C" fn f_rng(_: *mut c_void, out: *mut c_uchar, len: usize) -> c_int {
    unsafe { RANDOM(core::slice::from_raw_parts_mut(out, len)) };
    0
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn mbedtls_psa_external_get_random(
    _: *mut c_void,
    out: *mut u8,
    size: usize,
    len: *mut usize,
) -> i32 {
    unsafe {
        RANDOM(core::slice::from_raw_parts_mut(out, size));
        *len = size;
    }
    0
}

/// Once, before anything else: the allocator and PSA (TLS 1.3 needs it).
pub unsafe fn init() -> Result<(), c_int> {
    unsafe {
        mbedtls_platform_set_calloc_free(Some(arena_calloc), Some(arena_free));
        check(psa_crypto_init())
    }
}

fn check(r: c_int) -> Result<(), c_int> {
    if r == 0 { Ok(()) } else { Err(r) }
}

static SUITES: [c_int; 3] = [0x1301, 0xc02b, 0]; // TLS_AES_128_GCM_SHA256, ECDHE-ECDSA-AES128-GCM-SHA256
static GROUPS: [u16; 2] = [23, 0]; // secp256r1
static SIG_ALGS: [u16; 2] = [0x0403, 0]; // ecdsa_secp256r1_sha256

/// A configuration with its certificates and key; must not move once set up.
pub struct Config {
    pub conf: mbedtls_ssl_config,
    pub own: mbedtls_x509_crt,
    pub ca: mbedtls_x509_crt,
    pub pk: mbedtls_pk_context,
}

impl Config {
    pub fn zeroed() -> Self {
        // SAFETY: plain C structs; each is initialised by its _init below.
        unsafe { core::mem::zeroed() }
    }

    /// endpoint: MBEDTLS_SSL_IS_SERVER or _CLIENT; max_tls13: false caps at 1.2.
    pub unsafe fn setup(
        &mut self,
        server: bool,
        own_cert: &[u8],
        own_key: &[u8],
        ca: &[u8],
        max_tls13: bool,
    ) -> Result<(), c_int> {
        unsafe {
            mbedtls_ssl_config_init(&mut self.conf);
            mbedtls_x509_crt_init(&mut self.own);
            mbedtls_x509_crt_init(&mut self.ca);
            mbedtls_pk_init(&mut self.pk);
            check(mbedtls_x509_crt_parse_der(&mut self.own, own_cert.as_ptr(), own_cert.len()))?;
            check(mbedtls_x509_crt_parse_der(&mut self.ca, ca.as_ptr(), ca.len()))?;
            check(mbedtls_pk_parse_key(
                &mut self.pk,
                own_key.as_ptr(),
                own_key.len(),
                core::ptr::null(),
                0,
                Some(f_rng),
                core::ptr::null_mut(),
            ))?;
            let endpoint = if server { MBEDTLS_SSL_IS_SERVER } else { MBEDTLS_SSL_IS_CLIENT };
            check(mbedtls_ssl_config_defaults(
                &mut self.conf,
                endpoint as c_int,
                MBEDTLS_SSL_TRANSPORT_STREAM as c_int,
                MBEDTLS_SSL_PRESET_DEFAULT as c_int,
            ))?;
            mbedtls_ssl_conf_rng(&mut self.conf, Some(f_rng), core::ptr::null_mut());
            mbedtls_ssl_conf_authmode(&mut self.conf, MBEDTLS_SSL_VERIFY_REQUIRED as c_int);
            mbedtls_ssl_conf_ca_chain(&mut self.conf, &mut self.ca, core::ptr::null_mut());
            check(mbedtls_ssl_conf_own_cert(&mut self.conf, &mut self.own, &mut self.pk))?;
            mbedtls_ssl_conf_ciphersuites(&mut self.conf, SUITES.as_ptr());
            mbedtls_ssl_conf_groups(&mut self.conf, GROUPS.as_ptr());
            mbedtls_ssl_conf_sig_algs(&mut self.conf, SIG_ALGS.as_ptr());
            self.conf.private_min_tls_version = mbedtls_ssl_protocol_version_MBEDTLS_SSL_VERSION_TLS1_2;
            self.conf.private_max_tls_version = if max_tls13 {
                mbedtls_ssl_protocol_version_MBEDTLS_SSL_VERSION_TLS1_3
            } else {
                mbedtls_ssl_protocol_version_MBEDTLS_SSL_VERSION_TLS1_2
            };
        }
        Ok(())
    }
}

/// The client's role, copied out of its certificate by the verify callback.
#[derive(Debug, Default)]
pub struct RoleSlot {
    pub seen: bool,
    pub malformed: bool,
    pub len: usize,
    pub role: [u8; 32],
}

impl RoleSlot {
    pub fn get(&self) -> Option<&str> {
        self.role.get(..self.len).and_then(|r| core::str::from_utf8(r).ok()).filter(|_| self.seen && self.len > 0)
    }
}

unsafe extern "C" fn verify_role(p: *mut c_void, crt: *mut mbedtls_x509_crt, depth: c_int, _flags: *mut u32) -> c_int {
    if depth == 0 && !p.is_null() && !crt.is_null() {
        unsafe {
            let slot = &mut *p.cast::<RoleSlot>();
            let der = core::slice::from_raw_parts((*crt).raw.p, (*crt).raw.len);
            slot.seen = true;
            match role::role(der) {
                Ok(Some(r)) if r.len() <= slot.role.len() => {
                    slot.role[..r.len()].copy_from_slice(r.as_bytes());
                    slot.len = r.len();
                }
                Ok(None) => slot.len = 0,
                _ => slot.malformed = true,
            }
        }
    }
    0
}

pub type Bio = unsafe extern "C" fn(*mut c_void, *const c_uchar, usize) -> c_int;
pub type BioRecv = unsafe extern "C" fn(*mut c_void, *mut c_uchar, usize) -> c_int;

/// One connection: the context and the role slot; must not move once set up.
pub struct Conn {
    pub ssl: mbedtls_ssl_context,
    pub role: RoleSlot,
}

impl Conn {
    pub fn zeroed() -> Self {
        // SAFETY: initialised by mbedtls_ssl_init.
        unsafe { core::mem::zeroed() }
    }

    pub unsafe fn setup(
        &mut self,
        config: &Config,
        bio: *mut c_void,
        send: Bio,
        recv: BioRecv,
        hostname: Option<&core::ffi::CStr>,
    ) -> Result<(), c_int> {
        unsafe {
            mbedtls_ssl_init(&mut self.ssl);
            self.role = RoleSlot::default();
            check(mbedtls_ssl_setup(&mut self.ssl, &config.conf))?;
            if let Some(h) = hostname {
                check(mbedtls_ssl_set_hostname(&mut self.ssl, h.as_ptr()))?;
            }
            mbedtls_ssl_set_verify(&mut self.ssl, Some(verify_role), (&raw mut self.role).cast());
            mbedtls_ssl_set_bio(&mut self.ssl, bio, Some(send), Some(recv), None);
        }
        Ok(())
    }

    /// One handshake step: Ok(true) done, Ok(false) wants I/O, Err(code).
    pub unsafe fn handshake(&mut self) -> Result<bool, c_int> {
        let r = unsafe { mbedtls_ssl_handshake(&mut self.ssl) };
        match r {
            0 => Ok(true),
            r if r == MBEDTLS_ERR_SSL_WANT_READ || r == MBEDTLS_ERR_SSL_WANT_WRITE => Ok(false),
            r => Err(r),
        }
    }

    pub unsafe fn free(&mut self) {
        unsafe { mbedtls_ssl_free(&mut self.ssl) }
    }
}

