// The few C library functions Mbed TLS calls that a bare-metal Rust image
// lacks (memcpy, memset, memmove and memcmp come from compiler_builtins).
// Written for the spike; a product would take a vetted small libc.
use core::ffi::{c_char, c_int};

#[unsafe(no_mangle)]
pub unsafe extern "C" fn strlen(s: *const c_char) -> usize {
    let mut n = 0;
    while unsafe { *s.add(n) } != 0 {
        n += 1;
    }
    n
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn strncmp(a: *const c_char, b: *const c_char, n: usize) -> c_int {
    for i in 0..n {
        let (x, y) = unsafe { (*a.add(i) as u8, *b.add(i) as u8) };
        if x != y || x == 0 {
            return c_int::from(x) - c_int::from(y);
        }
    }
    0
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn strcmp(a: *const c_char, b: *const c_char) -> c_int {
    unsafe { strncmp(a, b, usize::MAX) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn strchr(s: *const c_char, c: c_int) -> *mut c_char {
    let mut p = s;
    loop {
        let x = unsafe { *p };
        if x as u8 == c as u8 {
            return p.cast_mut();
        }
        if x == 0 {
            return core::ptr::null_mut();
        }
        p = unsafe { p.add(1) };
    }
}

// Mbed TLS's default calloc/free (before mbedtls_platform_set_calloc_free):
// the same arena.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn calloc(n: usize, size: usize) -> *mut core::ffi::c_void {
    unsafe { mbedtls_spike::arena_calloc(n, size) }
}

#[unsafe(no_mangle)]
pub unsafe extern "C" fn free(p: *mut core::ffi::c_void) {
    unsafe { mbedtls_spike::arena_free(p) }
}
