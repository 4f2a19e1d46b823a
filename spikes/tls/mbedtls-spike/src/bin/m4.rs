//! Mbed TLS spike on the Cortex-M4 (QEMU mps2-an386): one full handshake
//! with a client certificate between the device's server configuration and
//! a client in the same image, memory to memory, TLS 1.3 then TLS 1.2. Each
//! side allocates from its own arena; the server's peak is printed over
//! semihosting. Count the server's instructions with spikes/tls/qemu/marks.c
//! (mark_server_enter / mark_server_leave around each server call,
//! mark_phase after each handshake).
//!
//!   RUSTFLAGS="-C link-arg=-Tlink.x" cargo build --release --bin mbedtls-m4 \
//!       --target thumbv7em-none-eabihf [--features server-only|baseline]
//!   qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native \
//!       -kernel $CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/mbedtls-m4 \
//!       [-icount shift=0 -plugin marks.so,enter=0x..,leave=0x..,phase=0x..]
//!
//! Needs clang, libclang, cmake and ninja (Mbed TLS is built from source).
#![cfg_attr(target_os = "none", no_std, no_main)]
// The server-only and baseline variants leave parts unused.
#![allow(dead_code, unused_imports, unused_variables)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("mbedtls-m4 is built for thumbv7em-none-eabihf");
}

#[cfg(target_os = "none")]
#[path = "../libc.rs"]
mod libc;

#[cfg(target_os = "none")]
#[path = "../../../common/stack.rs"]
mod stack;

#[cfg(target_os = "none")]
mod m4 {
    use core::ffi::c_void;
    use core::sync::atomic::Ordering;
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};
    use mbedtls_spike::*;

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        hprintln!("PANIC: {}", info);
        debug::exit(debug::EXIT_FAILURE);
        loop {}
    }

    /// Spike-only randomness (QEMU's mps2 has no RNG): NOT for a device.
    fn fake_random(buf: &mut [u8]) {
        static mut STATE: u64 = 0x9e37_79b9_7f4a_7c15;
        for b in buf {
            // SAFETY: single core, no interrupts use it.
            unsafe {
                STATE ^= STATE << 13;
                STATE ^= STATE >> 7;
                STATE ^= STATE << 17;
                *b = STATE as u8;
            }
        }
    }

    #[unsafe(no_mangle)]
    #[inline(never)]
    pub extern "C" fn mark_server_enter() {
        cortex_m::asm::nop();
    }
    #[unsafe(no_mangle)]
    #[inline(never)]
    pub extern "C" fn mark_server_leave() {
        cortex_m::asm::nop();
        cortex_m::asm::nop();
    }
    #[unsafe(no_mangle)]
    #[inline(never)]
    pub extern "C" fn mark_phase() {
        cortex_m::asm::nop();
        cortex_m::asm::nop();
        cortex_m::asm::nop();
    }

    fn server<R>(f: impl FnOnce() -> R) -> R {
        crate::stack::measured(|| {
            mark_server_enter();
            let r = f();
            mark_server_leave();
            r
        })
    }

    /// A one-way byte pipe between the two sides.
    pub struct Pipe {
        buf: [u8; 20 * 1024],
        len: usize,
    }

    /// One side's ends: it sends into `tx` and receives from `rx`.
    pub struct Duplex {
        tx: *mut Pipe,
        rx: *mut Pipe,
    }

    unsafe extern "C" fn pipe_send(p: *mut c_void, data: *const u8, len: usize) -> i32 {
        let pipe = unsafe { &mut *(*p.cast::<Duplex>()).tx };
        let n = len.min(pipe.buf.len() - pipe.len);
        if n == 0 {
            return sys::MBEDTLS_ERR_SSL_WANT_WRITE;
        }
        pipe.buf[pipe.len..pipe.len + n].copy_from_slice(unsafe { core::slice::from_raw_parts(data, n) });
        pipe.len += n;
        n as i32
    }

    unsafe extern "C" fn pipe_recv(p: *mut c_void, data: *mut u8, len: usize) -> i32 {
        let pipe = unsafe { &mut *(*p.cast::<Duplex>()).rx };
        let n = len.min(pipe.len);
        if n == 0 {
            return sys::MBEDTLS_ERR_SSL_WANT_READ;
        }
        unsafe { core::slice::from_raw_parts_mut(data, n) }.copy_from_slice(&pipe.buf[..n]);
        pipe.buf.copy_within(n..pipe.len, 0);
        pipe.len -= n;
        n as i32
    }

    #[cfg(feature = "baseline")]
    #[entry]
    fn main() -> ! {
        // core::fmt for a number, as the other images print some.
        hprintln!("baseline {}", cortex_m::peripheral::DWT::cycle_count());
        debug::exit(debug::EXIT_SUCCESS);
        loop {}
    }

    #[cfg(not(feature = "baseline"))]
    #[entry]
    fn main() -> ! {
        static CLIENT_ARENA: arena::Arena<ARENA_SIZE> = arena::Arena::new();
        unsafe {
            RANDOM = fake_random;
            init().unwrap();
            OTHER_ARENA.store((&raw const CLIENT_ARENA).cast_mut(), Ordering::Relaxed);
        }
        let up = cortex_m::singleton!(: Pipe = Pipe { buf: [0; 20 * 1024], len: 0 }).unwrap();
        let down = cortex_m::singleton!(: Pipe = Pipe { buf: [0; 20 * 1024], len: 0 }).unwrap();
        let (up, down) = (up as *mut Pipe, down as *mut Pipe);
        let sio = cortex_m::singleton!(: Duplex = Duplex { tx: down, rx: up }).unwrap() as *mut Duplex;
        let cio = cortex_m::singleton!(: Duplex = Duplex { tx: up, rx: down }).unwrap() as *mut Duplex;
        let sconf = cortex_m::singleton!(: Config = Config::zeroed()).unwrap();
        let sconn = cortex_m::singleton!(: Conn = Conn::zeroed()).unwrap();
        if let Err(e) = server(|| unsafe { sconf.setup(true, SERVER_CERT, SERVER_KEY, CA_CERT, true) }) {
            hprintln!("server config: -0x{:04x}", -e);
        }
        hprintln!("server config: arena {} B", ARENA.used.load(Ordering::Relaxed));
        mark_phase();

        #[cfg(feature = "server-only")]
        {
            let r = server(|| unsafe {
                sconn.setup(sconf, sio.cast(), pipe_send, pipe_recv, None)?;
                sconn.handshake()
            });
            hprintln!("server alone: {}", if r.is_ok() { "ok" } else { "error" });
        }

        #[cfg(not(feature = "server-only"))]
        {
            let cconf = cortex_m::singleton!(: Config = Config::zeroed()).unwrap();
            let cconn = cortex_m::singleton!(: Conn = Conn::zeroed()).unwrap();
            let cert = include_bytes!("../../../certs/operator.der");
            let key = include_bytes!("../../../certs/operator.key.der");
            // Then the server's arena limited to 20000 B and 30000 B (what an
            // allocation failure does on the device).
            for (tls13, limit) in [(true, 0), (false, 0), (true, 20000), (true, 30000)] {
                if limit != 0 {
                    hprintln!("TLS 1.3 with the server's arena limited to {} B:", limit);
                }
                unsafe { USE_OTHER = true };
                let r = unsafe {
                    cconf.setup(false, cert, key, SERVER_CERT, tls13).and_then(|()| {
                        cconn.setup(cconf, cio.cast(), pipe_send, pipe_recv, Some(c"adapter.local"))
                    })
                };
                unsafe { USE_OTHER = false };
                if let Err(e) = r {
                    hprintln!("client setup: -0x{:04x}", -e);
                }
                let before = ARENA.used.load(Ordering::Relaxed);
                ARENA.reset_peak(limit);
                let r = server(|| unsafe {
                    sconn.setup(sconf, sio.cast(), pipe_send, pipe_recv, None)
                });
                if let Err(e) = r {
                    hprintln!("server setup: -0x{:04x}", -e);
                }
                let (mut s_done, mut c_done) = (false, false);
                for _round in 0..40 {
                    if !c_done {
                        unsafe { USE_OTHER = true };
                        let r = unsafe { cconn.handshake() };
                        unsafe { USE_OTHER = false };
                        match r {
                            Ok(d) => c_done = d,
                            Err(e) => {
                                hprintln!("client error -0x{:04x}", -e);
                                break;
                            }
                        }
                    }
                    if !s_done {
                        match server(|| unsafe { sconn.handshake() }) {
                            Ok(d) => s_done = d,
                            Err(e) => {
                                hprintln!("server error -0x{:04x}", -e);
                                break;
                            }
                        }
                    }
                    if s_done && c_done {
                        break;
                    }
                }
                hprintln!(
                    "{}: server established {} client {} role {:?}; server arena peak {} B above {} B; {} allocations",
                    if tls13 { "TLS 1.3" } else { "TLS 1.2" },
                    s_done,
                    c_done,
                    sconn.role.get(),
                    ARENA.peak.load(Ordering::Relaxed) - before,
                    before,
                    ARENA.allocs.load(Ordering::Relaxed)
                );
                hprintln!("server stack high-water so far: {} B", unsafe { crate::stack::DEEPEST });
                mark_phase();
                server(|| unsafe { sconn.free() });
                unsafe {
                    USE_OTHER = true;
                    cconn.free();
                    sys::mbedtls_ssl_config_free(&mut cconf.conf);
                    sys::mbedtls_x509_crt_free(&mut cconf.own);
                    sys::mbedtls_x509_crt_free(&mut cconf.ca);
                    sys::mbedtls_pk_free(&mut cconf.pk);
                    USE_OTHER = false;
                }
                unsafe {
                    (*up).len = 0;
                    (*down).len = 0;
                }
            }
        }
        hprintln!("server stack high-water: {} B", unsafe { crate::stack::DEEPEST });
        debug::exit(debug::EXIT_SUCCESS);
        loop {}
    }
}
