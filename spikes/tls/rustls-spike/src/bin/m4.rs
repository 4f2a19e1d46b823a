//! rustls spike on the Cortex-M4 (QEMU mps2-an386): one full handshake with
//! a client certificate between the device's server configuration and a
//! client in the same image, memory to memory, for TLS 1.3 then TLS 1.2.
//! Each side allocates from its own arena; the server's arena peak is
//! printed over semihosting. The server's instructions are those between
//! mark_server_enter and mark_server_leave (count them with the TCG plugin
//! in spikes/tls/qemu/marks.c, whose header says how; mark_phase ends each
//! handshake's count).
//!
//!   RUSTFLAGS="-C link-arg=-Tlink.x" cargo build --release --bin rustls-m4 \
//!       --target thumbv7em-none-eabihf [--features server-only|baseline]
//!   qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native \
//!       -kernel $CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/rustls-m4 \
//!       [-icount shift=0 -plugin marks.so,enter=0x..,leave=0x..,phase=0x..]
//!
//! `server-only` links the server without the client (it is fed nothing):
//! the image for the flash figure; `baseline` the same skeleton with no TLS.
#![cfg_attr(target_os = "none", no_std, no_main)]
// The server-only and baseline variants leave parts unused.
#![allow(dead_code, unused_imports, unused_variables)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("rustls-m4 is built for thumbv7em-none-eabihf");
}

#[cfg(target_os = "none")]
#[path = "../../../common/stack.rs"]
mod stack;

#[cfg(target_os = "none")]
mod m4 {
    use core::alloc::{GlobalAlloc, Layout};
    use core::sync::atomic::{AtomicBool, Ordering};
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};
    use rustls_spike::arena::Arena;

    pub const SERVER_ARENA: usize = 96 * 1024;
    pub static SERVER: Arena<SERVER_ARENA> = Arena::new();
    static CLIENT: Arena<{ 96 * 1024 }> = Arena::new();
    /// Which side is running: its allocations go to its arena.
    static SERVER_SIDE: AtomicBool = AtomicBool::new(true);

    struct Dispatch;
    unsafe impl GlobalAlloc for Dispatch {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            if SERVER_SIDE.load(Ordering::Relaxed) {
                unsafe { SERVER.alloc(layout) }
            } else {
                unsafe { CLIENT.alloc(layout) }
            }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            if SERVER.contains(ptr) {
                unsafe { SERVER.dealloc(ptr, layout) }
            } else {
                unsafe { CLIENT.dealloc(ptr, layout) }
            }
        }
    }
    #[global_allocator]
    static GLOBAL: Dispatch = Dispatch;

    /// Spike-only randomness (QEMU's mps2 has no RNG): NOT for a device.
    fn fake_random(buf: &mut [u8]) -> Result<(), getrandom::Error> {
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
        Ok(())
    }
    getrandom::register_custom_getrandom!(fake_random);

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

    /// After each handshake: the plugin prints the server's count so far.
    #[unsafe(no_mangle)]
    #[inline(never)]
    pub extern "C" fn mark_phase() {
        cortex_m::asm::nop();
        cortex_m::asm::nop();
        cortex_m::asm::nop();
    }

    fn server<R>(f: impl FnOnce() -> R) -> R {
        SERVER_SIDE.store(true, Ordering::Relaxed);
        crate::stack::measured(|| {
            mark_server_enter();
            let r = f();
            mark_server_leave();
            r
        })
    }
    #[cfg(not(feature = "server-only"))]
    fn client<R>(f: impl FnOnce() -> R) -> R {
        SERVER_SIDE.store(false, Ordering::Relaxed);
        let r = f();
        SERVER_SIDE.store(true, Ordering::Relaxed);
        r
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        hprintln!("PANIC: {}", info);
        debug::exit(debug::EXIT_FAILURE);
        loop {}
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
        use rustls::server::UnbufferedServerConnection;
        use rustls_spike::*;
        const IN: usize = 16 * 1024 + 325;
        const OUT: usize = 4096;
        let sb: &'static mut Buffers<IN, OUT> =
            cortex_m::singleton!(: Buffers<IN, OUT> = Buffers::new()).unwrap();
        let provider = server(provider);
        let config = server(|| server_config(provider.clone())).unwrap();
        hprintln!("server config: arena {} B", SERVER.used.load(Ordering::Relaxed));
        mark_phase();

        #[cfg(feature = "server-only")]
        {
            let mut conn = server(|| UnbufferedServerConnection::new(config.clone())).unwrap();
            let r = server(|| step_server(&mut conn, sb, &mut |_| {}));
            hprintln!("server alone: {}", if r.is_ok() { "ok" } else { "error" });
        }

        #[cfg(not(feature = "server-only"))]
        {
            use rustls::client::UnbufferedClientConnection;
            let cb: &'static mut Buffers<IN, OUT> =
                cortex_m::singleton!(: Buffers<IN, OUT> = Buffers::new()).unwrap();
            let cert = include_bytes!("../../../certs/operator.der");
            let key = include_bytes!("../../../certs/operator.key.der");
            // The third: the server's arena limited to 4000 B (what an
            // allocation failure does on the device).
            for (tls13, limit) in [(true, 0), (false, 0), (true, 4000)] {
                if limit != 0 {
                    hprintln!("TLS 1.3 with the server's arena limited to {} B:", limit);
                }
                let cconf = client(|| client_config(provider.clone(), tls13, cert, key)).unwrap();
                let name = rustls::pki_types::ServerName::try_from("adapter.local").unwrap();
                let mut cc = client(|| UnbufferedClientConnection::new(cconf, name)).unwrap();
                let before = SERVER.used.load(Ordering::Relaxed);
                SERVER.reset_peak(limit);
                let mut sc = server(|| UnbufferedServerConnection::new(config.clone())).unwrap();
                let (mut s_done, mut c_done) = (false, false);
                for _round in 0..20 {
                    if !c_done {
                        match client(|| step_client(&mut cc, cb)) {
                            Ok(Step::Established) => c_done = true,
                            Ok(_) => {}
                            Err(e) => { hprintln!("client error {:?}", e); break; }
                        }
                    }
                    // client -> server
                    let n = cb.out_len.min(IN - sb.in_len);
                    sb.inb[sb.in_len..sb.in_len + n].copy_from_slice(&cb.out[..n]);
                    sb.in_len += n;
                    cb.out.copy_within(n..cb.out_len, 0);
                    cb.out_len -= n;
                    if !s_done {
                        match server(|| step_server(&mut sc, sb, &mut |_| {})) {
                            Ok(Step::Established) => s_done = true,
                            Ok(_) => {}
                            Err(e) => { hprintln!("server error {:?}", e); break; }
                        }
                    }
                    // server -> client
                    let n = sb.out_len.min(IN - cb.in_len);
                    cb.inb[cb.in_len..cb.in_len + n].copy_from_slice(&sb.out[..n]);
                    cb.in_len += n;
                    sb.out.copy_within(n..sb.out_len, 0);
                    sb.out_len -= n;
                    if s_done && c_done && sb.out_len == 0 && cb.out_len == 0 {
                        break;
                    }
                }
                let role = sc
                    .peer_certificates()
                    .and_then(|c| c.first())
                    .map(|c| role::role(c).ok().flatten().map(|r| r.len()));
                hprintln!(
                    "{}: server established {} client {} role len {:?}; server arena peak {} B above {} B; {} allocations",
                    if tls13 { "TLS 1.3" } else { "TLS 1.2" },
                    s_done,
                    c_done,
                    role,
                    SERVER.peak.load(Ordering::Relaxed) - before,
                    before,
                    SERVER.allocs.load(Ordering::Relaxed)
                );
                hprintln!("server stack high-water so far: {} B", unsafe { crate::stack::DEEPEST });
                mark_phase();
                server(|| drop(sc));
                client(|| drop(cc));
                sb.in_len = 0;
                sb.out_len = 0;
                cb.in_len = 0;
                cb.out_len = 0;
            }
        }
        hprintln!("server stack high-water: {} B", unsafe { crate::stack::DEEPEST });
        debug::exit(debug::EXIT_SUCCESS);
        loop {}
    }
}
