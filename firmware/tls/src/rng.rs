//! Random numbers for Mbed TLS: one CTR_DRBG (NIST SP 800-90A, AES-256),
//! seeded and reseeded from the board's entropy source (the STM32's RNG,
//! the host's OS), serving both the TLS layer (`f_rng`) and PSA crypto,
//! which TLS 1.3 uses (`mbedtls_psa_external_get_random`).

use core::cell::RefCell;
use core::ffi::{c_int, c_uchar, c_void};
use core::mem::MaybeUninit;
use core::ptr;

use critical_section::Mutex;
use mbedtls_rs_sys as sys;

/// Fills a buffer with entropy; `false` when the source failed.
pub type Entropy = fn(&mut [u8]) -> bool;

/// The generator and where it is seeded from.
struct Drbg {
    context: sys::mbedtls_ctr_drbg_context,
    seeded: bool,
}

// SAFETY: the context is touched only inside the critical section below;
// its entropy callback is a plain `fn`.
unsafe impl Send for Drbg {}

static DRBG: Mutex<RefCell<Option<Drbg>>> = Mutex::new(RefCell::new(None));
static ENTROPY: Mutex<RefCell<Option<Entropy>>> = Mutex::new(RefCell::new(None));

/// PSA's "insufficient entropy" status (a macro in its header, so unbound).
const PSA_ERROR_INSUFFICIENT_ENTROPY: sys::psa_status_t = -148;

/// Personalization: who draws from this generator (SP 800-90A 8.7.1).
const PERSONALIZATION: &[u8] = b"mbio adapter tls";

unsafe extern "C" fn entropy(_: *mut c_void, output: *mut c_uchar, len: usize) -> c_int {
    let source = critical_section::with(|cs| *ENTROPY.borrow_ref(cs));
    let Some(source) = source else { return -1 };
    // SAFETY: Mbed TLS passes a buffer of `len` bytes.
    let output = unsafe { core::slice::from_raw_parts_mut(output, len) };
    if source(output) { 0 } else { -1 }
}

/// Seeds the generator from `source`. `false` when the source failed.
/// [`crate::init`] calls it; called again, it starts the generator anew
/// from `source` (the fuzz target does, before every input, so that an
/// input meets the same random numbers whatever ran before it).
pub fn init(source: Entropy) -> bool {
    critical_section::with(|cs| {
        *ENTROPY.borrow_ref_mut(cs) = Some(source);
        let mut drbg = DRBG.borrow_ref_mut(cs);
        // In its place for good before Mbed TLS sees it: nothing moves it later.
        // SAFETY: an all-zero context is what `mbedtls_ctr_drbg_init` starts from.
        let drbg = drbg.insert(Drbg { context: unsafe { MaybeUninit::zeroed().assume_init() }, seeded: false });
        let context = ptr::from_mut(&mut drbg.context);
        // SAFETY: init then seed, as the API asks; the entropy callback's
        // context is null (it reads ENTROPY).
        drbg.seeded = unsafe {
            sys::mbedtls_ctr_drbg_init(context);
            sys::mbedtls_ctr_drbg_seed(
                context,
                Some(entropy),
                ptr::null_mut(),
                PERSONALIZATION.as_ptr(),
                PERSONALIZATION.len(),
            ) == 0
        };
        drbg.seeded
    })
}

/// Fills `output` from the generator; `false` if it is not seeded or failed.
pub fn fill(output: &mut [u8]) -> bool {
    critical_section::with(|cs| {
        let mut drbg = DRBG.borrow_ref_mut(cs);
        let Some(drbg) = drbg.as_mut().filter(|drbg| drbg.seeded) else { return false };
        // SAFETY: a seeded context, and a buffer of `output.len()` bytes.
        unsafe {
            sys::mbedtls_ctr_drbg_random(ptr::from_mut(&mut drbg.context).cast(), output.as_mut_ptr(), output.len())
                == 0
        }
    })
}

/// The TLS layer's and the key generator's `f_rng`.
pub(crate) unsafe extern "C" fn random(_: *mut c_void, output: *mut c_uchar, len: usize) -> c_int {
    if len == 0 {
        return 0;
    }
    // SAFETY: Mbed TLS passes a buffer of `len` bytes.
    let output = unsafe { core::slice::from_raw_parts_mut(output, len) };
    // MBEDTLS_ERR_CTR_DRBG_ENTROPY_SOURCE_FAILED when it cannot.
    if fill(output) { 0 } else { sys::MBEDTLS_ERR_CTR_DRBG_ENTROPY_SOURCE_FAILED }
}

/// PSA crypto's random source (the build defines MBEDTLS_PSA_CRYPTO_EXTERNAL_RNG).
///
/// # Safety
///
/// Called by Mbed TLS with a buffer of `output_size` bytes and a place for
/// the length written.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn mbedtls_psa_external_get_random(
    _: *mut sys::mbedtls_psa_external_random_context_t,
    output: *mut u8,
    output_size: usize,
    output_length: *mut usize,
) -> sys::psa_status_t {
    if output_size == 0 {
        // SAFETY: as the caller promises.
        unsafe { *output_length = 0 };
        return 0;
    }
    // SAFETY: as the caller promises.
    let output = unsafe { core::slice::from_raw_parts_mut(output, output_size) };
    if fill(output) {
        // SAFETY: as the caller promises.
        unsafe { *output_length = output_size };
        0
    } else {
        PSA_ERROR_INSUFFICIENT_ENTROPY
    }
}
