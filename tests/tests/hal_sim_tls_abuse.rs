//! Abuse of port 802 on hal-sim while plain Modbus is polled on 502
//! (system_tests::tls_abuse): half-open and stalled handshakes, handshakes
//! sent a byte at a time, 100 handshakes a second, garbage. Every request
//! on 502 is answered on the one connection within 2 s, hal-sim does not
//! restart, the TLS counters move, and an operator still gets a session on
//! 802 afterwards.
//!
//! Needs root (a namespace), python3 with pymodbus, and openssl; fails
//! loudly without them.

use std::time::Instant;

use system_tests::hal_sim::HalSim;
use system_tests::tls::{device_certificate, fixture, pymodbus, require_tools};
use system_tests::tls_abuse::{self, LIMIT, abuse_802, assert_counters_moved, assert_not_restarted};
use system_tests::update::test_dir;

#[test]
fn abuse_on_802_never_delays_502_beyond_2_s_nor_restarts_hal_sim() {
    require_tools();
    let mut sim = HalSim::start(&["--robot", "idle", "--client-ca", &fixture("client-ca.pem")]);
    let pid = sim.pid();
    let before = tls_abuse::status(sim.ns());
    let looked = Instant::now();

    let summary = abuse_802(sim.ns(), sim.addr(), 2);
    summary.print();
    summary.watch.assert_within(LIMIT);
    summary.assert_device_coped();

    // hal-sim ran on: the same process, not restarted (a reboot is an exec
    // of the same process, which sets the uptime back), no panic.
    assert!(sim.is_running(), "hal-sim died; its log:\n{}", sim.log());
    assert_eq!(sim.pid(), pid);
    let after = tls_abuse::status(sim.ns());
    assert_not_restarted(&before, &after, looked.elapsed());
    assert!(!sim.log().contains("panicked"), "{}", sim.log());

    // An operator still gets a session on 802, and the counters moved.
    let dir = test_dir("hal-sim-tls-abuse");
    let server_cert = device_certificate(sim.ns(), &dir, 802);
    let operator = pymodbus(sim.ns(), Some(("operator.pem", "operator.key")), &server_cert);
    assert_eq!(operator["write"], "ok", "an operator after the abuse: {operator}");
    let after = tls_abuse::status(sim.ns());
    assert_counters_moved(&before, &after);
    std::fs::remove_dir_all(&dir).unwrap();
}
