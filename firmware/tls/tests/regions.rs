//! The arena in two regions, as the NUCLEO lays it out: its 64 KiB CCM RAM
//! and 12 KiB of SRAM (`adapter::program::TLS_ARENA_LEN`, 72 KiB, and 4 KiB
//! more, since a block never spans two regions). It must hold what the
//! device holds at its fullest: port 802's and HTTPS's configurations, and
//! two sessions (`MAX_TLS_SESSIONS`: two on 802 with client certificates,
//! or one of them and an HTTPS session without), the second at its
//! handshake's peak, in any order. Its own test binary: its own arena.
//!
//! Needs `openssl` on the PATH (scripts/setup installs it).

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic,
    reason = "a failed step is a failed test"
)]

mod common;

use std::process::Child;

use common::{Blocking, fixture, listener, s_client};
use tls::{Credentials, Server, Session};

/// The NUCLEO's regions: its CCM RAM, and the rest in SRAM.
const REGIONS: [usize; 2] = [64 * 1024, 12 * 1024];

/// One client's side of the test: its process, and the device's session.
type Open<'s> = (Child, Session<'s, Blocking>);

fn open<'s>(server: &'s Server, listener: &std::net::TcpListener, port: u16, args: &[&str]) -> Open<'s> {
    let client = s_client(port, args);
    let (socket, _) = listener.accept().unwrap();
    let mut session = Session::new(server, Blocking(socket)).unwrap();
    let shaken = embassy_futures::block_on(session.handshake());
    assert_eq!(shaken, Ok(()), "{args:?}: {:?}", tls::arena::usage());
    (client, session)
}

#[test]
fn the_nucleo_arena_holds_both_configurations_and_two_sessions() {
    let _serial = common::init_regions(&REGIONS);
    let start = tls::arena::usage();
    assert_eq!(start.size, REGIONS.iter().sum::<usize>());
    let (certificate, key, ca) = (fixture("device.der"), fixture("device.key.der"), fixture("client-ca.der"));
    let modbus = Server::new(&Credentials { certificate: &certificate, key: &key, client_ca: Some(&ca) }).unwrap();
    let https = Server::new(&Credentials { certificate: &certificate, key: &key, client_ca: None }).unwrap();
    let configured = tls::arena::usage().used - start.used;
    println!("both configurations: {configured} B");
    assert!(configured <= 8 * 1024, "TLS_ARENA_LEN counts 8 KiB for them: {configured} B");

    let (listener, port) = listener();
    let operator = ["-tls1_3", "-cert", "operator.pem", "-key", "operator.key"];
    let viewer = ["-tls1_2", "-cert", "viewer.pem", "-key", "viewer.key"];
    let browser: [&str; 1] = ["-tls1_3"];
    // Each pair, in each order: every one is served.
    for order in [
        [&operator[..], &viewer[..]],
        [&viewer[..], &operator[..]],
        [&operator[..], &operator[..]],
        [&browser[..], &operator[..]],
        [&operator[..], &browser[..]],
    ] {
        tls::arena::reset_peak();
        let mut open_now = Vec::new();
        for (i, args) in order.into_iter().enumerate() {
            let server = if args.len() == 1 { &https } else { &modbus };
            open_now.push(open(server, &listener, port, args));
            println!("{} session(s) open: {:?}", i + 1, tls::arena::usage());
        }
        let usage = tls::arena::usage();
        assert_eq!(usage.refused, 0, "{usage:?}");
        for (mut client, session) in open_now {
            drop(session);
            drop(client.stdin.take());
            let _ = client.wait();
        }
    }
    assert_eq!(tls::arena::usage().used, start.used + configured, "the sessions gave back all they took");
}
