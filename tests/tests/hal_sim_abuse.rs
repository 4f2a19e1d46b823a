//! hal-sim under abuse: a thousand connections opened and dropped, eight
//! clients sitting on half-sent frames, pipelined bursts larger than the
//! socket buffers, random byte streams, and clients that reset mid-request.
//!
//! After each, a fresh tokio-modbus client is answered, the map holds
//! exactly the writes hal-sim acknowledged (a [`Ledger`] replays them on the
//! library's own map; registers 128-255 and the outputs are read back), and
//! all sessions are free again: nine clients get eight sessions and the
//! idlest is closed, as with a fresh server. Each test runs its own hal-sim
//! in its own namespace; the random ones print their seed.

use std::time::Duration;

use system_tests::abuse::{Ledger, Rng, read_frames_until_close};
use system_tests::hal_sim::{HalSim, controller_version, end_within, read_frame};
use test_support::framer::{self, adu};
use tokio::io::AsyncWriteExt;
use tokio_modbus::prelude::*;

const REPLY_WAIT: Duration = Duration::from_secs(2);
/// Longer than the 100 ms refresh, so every source has re-asserted its points.
const AFTER_REFRESH: Duration = Duration::from_millis(350);
/// hal-sim as the other system tests run it, with its default policy.
const ARGS: [&str; 2] = ["--robot", "idle"];

/// An FC 06 frame: register `address` := `value` (unit 1).
fn write_register(transaction: u16, address: u16, value: u16) -> Vec<u8> {
    let [a, b] = address.to_be_bytes();
    let [c, d] = value.to_be_bytes();
    adu(transaction, 0, 1, &[0x06, a, b, c, d])
}

/// An FC 10 frame: registers `start..` := `values` (unit 1).
fn write_registers(transaction: u16, start: u16, values: &[u16]) -> Vec<u8> {
    let mut pdu = vec![0x10];
    pdu.extend(start.to_be_bytes());
    pdu.extend((values.len() as u16).to_be_bytes());
    pdu.push(2 * values.len() as u8);
    pdu.extend(values.iter().flat_map(|v| v.to_be_bytes()));
    adu(transaction, 0, 1, &pdu)
}

/// An FC 03 frame: read `quantity` registers from `start` (unit 1).
fn read_registers(transaction: u16, start: u16, quantity: u16) -> Vec<u8> {
    let [a, b] = start.to_be_bytes();
    let [c, d] = quantity.to_be_bytes();
    adu(transaction, 0, 1, &[0x03, a, b, c, d])
}

/// After the abuse: hal-sim runs, a fresh client is answered and the map
/// holds exactly the acknowledged writes, and every session is free: eight
/// clients are served at once, and a ninth closes only the idlest of them.
fn finish(sim: &mut HalSim, ledger: &Ledger) {
    assert!(sim.is_running(), "hal-sim died; its log:\n{}", sim.log());
    sim.run(|| async {
        let mut fresh = sim.connect().await;
        ledger.verify(&mut fresh).await;
        // A `seed` write to the controller version's registers lasts until the next refresh.
        tokio::time::sleep(AFTER_REFRESH).await;
        assert_eq!(fresh.read_holding_registers(256, 3).await.unwrap().unwrap(), controller_version());
        drop(fresh);
        // hal-sim closes the fresh client's session before the nine come.
        tokio::time::sleep(Duration::from_millis(200)).await;

        let mut clients = Vec::new();
        for i in 0..8u16 {
            let mut ctx = sim.connect_watched().await;
            ctx.read_holding_registers(128 + i, 1).await.unwrap().unwrap();
            clients.push(ctx);
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let mut ninth = sim.connect().await;
        ninth.read_holding_registers(128, 1).await.unwrap().unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let end = clients[0].end_within(REPLY_WAIT).await;
        assert!(end.is_closed(), "the idlest of nine is closed: {end:?}");
        for (i, ctx) in clients.iter_mut().enumerate().skip(1) {
            ctx.read_holding_registers(128, 1).await.unwrap().unwrap_or_else(|e| panic!("client {i}: {e:?}"));
        }
        ninth.read_holding_registers(128, 1).await.unwrap().unwrap();
    });
    assert!(sim.is_running(), "hal-sim died; its log:\n{}", sim.log());
    assert!(!sim.log().contains("panicked"), "{}", sim.log());
    // Everyone may connect (no allow-list): whatever the clients did, no
    // connection counts as refused.
    let stats = sim.control_ok("get stats");
    assert!(stats.split_whitespace().any(|kv| kv == "refused_connections=0"), "get stats: {stats}");
}

#[test]
fn a_thousand_connect_disconnect_cycles() {
    let mut sim = HalSim::start(&ARGS);
    let ledger = sim.run(|| async {
        let mut ledger = Ledger::new();
        for cycle in 0..1000u16 {
            let mut raw = sim.raw().await;
            let address = 128 + cycle % 128;
            match cycle % 5 {
                // Connect and close at once.
                0 => {}
                // A write, answered, then close.
                1 => {
                    let request = write_register(cycle, address, cycle);
                    raw.write_all(&request).await.unwrap();
                    let reply = read_frame(&mut raw, REPLY_WAIT).await.unwrap_or_else(|| panic!("cycle {cycle}"));
                    ledger.record(&request, &reply);
                }
                // Half a write, then close: it must not happen.
                2 => {
                    let request = write_register(cycle, address, 0xdead);
                    raw.write_all(&request[..8]).await.unwrap();
                }
                // A read, and close before its reply comes.
                3 => raw.write_all(&read_registers(cycle, 128, 125)).await.unwrap(),
                // Reset at once.
                _ => raw.set_zero_linger().unwrap(),
            }
            drop(raw);
        }
        assert_eq!(ledger.acknowledged(), 200);
        ledger
    });
    finish(&mut sim, &ledger);
}

#[test]
fn eight_clients_holding_half_frames_do_not_stop_a_ninth() {
    let mut sim = HalSim::start(&ARGS);
    let ledger = sim.run(|| async {
        let mut ledger = Ledger::new();
        let requests: Vec<Vec<u8>> =
            (0..8u16).map(|i| write_registers(0x100 + i, 200 + 2 * i, &[0xab00 + i, 0xcd00 + i])).collect();
        // Each holder sends half its write and stops (the frame timeout, 2 s,
        // runs from here). Holder 0 connected first: it is the idlest.
        let mut holders = Vec::new();
        for request in &requests {
            let mut raw = sim.raw().await;
            raw.write_all(&request[..request.len() / 2]).await.unwrap();
            holders.push(raw);
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        // The ninth is served while all eight hold their frames.
        let mut ninth = sim.connect().await;
        for k in 0..10u16 {
            ninth.write_single_register(128 + k, 0x900 + k).await.unwrap().unwrap();
            ledger.acknowledge(&write_register(0, 128 + k, 0x900 + k));
        }
        assert_eq!(ninth.read_holding_registers(128, 10).await.unwrap().unwrap(), (0x900..0x90a).collect::<Vec<_>>());
        // Holder 0 made room for it; the seven others finish their frames
        // and are answered.
        tokio::time::sleep(Duration::from_millis(50)).await;
        for (i, (raw, request)) in holders.iter_mut().zip(&requests).enumerate() {
            let _ = raw.write_all(&request[request.len() / 2..]).await;
            if i == 0 {
                let end = end_within(raw, REPLY_WAIT).await;
                assert!(end.is_closed(), "the idlest holder is closed: {end:?}");
            } else {
                let reply = read_frame(raw, REPLY_WAIT).await;
                let reply = reply.unwrap_or_else(|| panic!("holder {i} was closed or not answered"));
                ledger.record(request, &reply);
            }
        }
        assert_eq!(ledger.acknowledged(), 10 + 7);
        ninth.read_holding_registers(200, 16).await.unwrap().unwrap();
        ledger
    });
    assert!(sim.log().contains("closing the idlest"), "{}", sim.log());
    finish(&mut sim, &ledger);
}

#[test]
fn pipelined_bursts_larger_than_the_socket_buffers_are_answered_in_order() {
    // Per client: 400 requests, about 8 KiB in and 22 KiB out, against
    // socket buffers of 512 bytes in and 512 bytes out (SOCKET_RX_LEN, SOCKET_TX_LEN).
    const CLIENTS: u16 = 3;
    const REQUESTS: u16 = 400;
    const SPAN: u16 = 40;
    assert!(usize::from(REQUESTS) * 12 > 4 * adapter::server::SOCKET_RX_LEN);
    let mut sim = HalSim::start(&ARGS);
    let ledger = sim.run(|| async {
        // Each client writes and reads its own 40 registers: alternating an
        // FC 10 of 4 registers and an FC 03 of all 40.
        let burst = |client: u16| -> Vec<Vec<u8>> {
            let base = 128 + client * SPAN;
            (0..REQUESTS)
                .map(|i| match i % 2 {
                    0 => {
                        let start = base + (i / 2 * 4) % SPAN;
                        write_registers(i, start, &[client, i, !i, i ^ 0x5a5a])
                    }
                    _ => read_registers(i, base, SPAN),
                })
                .collect()
        };
        let sim = &sim;
        let client = |requests: Vec<Vec<u8>>| async move {
            let raw = sim.raw().await;
            let (mut reader, mut writer) = raw.into_split();
            let bytes = requests.concat();
            let write = async move {
                writer.write_all(&bytes).await.unwrap();
                writer
            };
            // Read only once the server must have stalled on full buffers.
            let read = async {
                tokio::time::sleep(Duration::from_millis(300)).await;
                let mut replies = Vec::new();
                for i in 0..requests.len() {
                    let reply = read_frame(&mut reader, REPLY_WAIT).await.unwrap_or_else(|| panic!("reply {i}"));
                    replies.push(reply);
                }
                replies
            };
            let (_writer, replies) = tokio::join!(write, read);
            (requests, replies)
        };
        let (a, b, c) = tokio::join!(client(burst(0)), client(burst(1)), client(burst(2)));
        let mut ledger = Ledger::new();
        for (requests, replies) in [a, b, c] {
            for (request, reply) in requests.iter().zip(&replies) {
                ledger.record(request, reply);
            }
        }
        assert_eq!(ledger.acknowledged(), usize::from(CLIENTS * REQUESTS / 2));
        ledger
    });
    finish(&mut sim, &ledger);
}

#[test]
fn random_byte_streams_are_answered_or_closed_and_change_only_acknowledged_points() {
    let seed = std::env::var("ABUSE_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(0x6d62_7573);
    eprintln!("random streams: ABUSE_SEED={seed}");
    let mut sim = HalSim::start(&ARGS);
    let ledger = sim.run(|| async {
        let mut rng = Rng::new(seed);
        let mut ledger = Ledger::new();
        #[derive(Default)]
        struct Counts {
            requests: usize,
            bad_protocol: usize,
            bad_length: usize,
        }
        let mut expected = Counts::default();
        for round in 0..120 {
            // A quarter plain noise (almost always a bad length at once), the
            // rest requests with some junk among them.
            let stream = if round % 4 == 0 {
                let n = 1 + rng.below(600) as usize;
                rng.bytes(n)
            } else {
                let items = 1 + rng.below(40) as usize;
                rng.stream(items)
            };
            let mut cuts = Vec::new();
            let mut rest = stream.as_slice();
            while !rest.is_empty() {
                let (chunk, tail) = rest.split_at((1 + rng.below(300) as usize).min(rest.len()));
                cuts.push(chunk.to_vec());
                rest = tail;
            }
            let raw = sim.raw().await;
            let (mut reader, mut writer) = raw.into_split();
            let write = async move {
                for chunk in cuts {
                    if writer.write_all(&chunk).await.is_err() {
                        break; // closed by the server after a bad length
                    }
                    tokio::task::yield_now().await;
                }
                let _ = writer.shutdown().await;
            };
            let (_, replies) = tokio::join!(write, read_frames_until_close(&mut reader, REPLY_WAIT));
            // The replies stop because hal-sim closed the connection, not
            // because it stopped answering.
            let end = end_within(&mut reader, REPLY_WAIT).await;
            assert!(end.is_closed(), "round {round} (ABUSE_SEED={seed}): the connection is closed: {end:?}");
            let framed = framer::split(&stream);
            let requests = framed.requests();
            assert_eq!(
                replies.len(),
                requests.len(),
                "round {round} (ABUSE_SEED={seed}): one reply per Modbus frame before any bad length"
            );
            for (request, reply) in requests.iter().zip(&replies) {
                ledger.record(request, reply);
            }
            expected.requests += requests.len();
            expected.bad_protocol += framed.skipped();
            expected.bad_length += usize::from(framed.bad_length.is_some());
        }
        eprintln!("random streams: {} writes acknowledged", ledger.acknowledged());
        assert!(ledger.acknowledged() > 40, "the streams exercised writes");
        // hal-sim's counters saw the same.
        let stats = sim.control_ok("get stats");
        for (name, value) in [
            ("requests", expected.requests),
            ("bad_protocol", expected.bad_protocol),
            ("bad_length", expected.bad_length),
        ] {
            assert!(stats.split_whitespace().any(|kv| kv == format!("{name}={value}")), "{name}={value}: {stats}");
        }
        ledger
    });
    finish(&mut sim, &ledger);
}

#[test]
fn clients_that_reset_mid_request_change_nothing_unacknowledged() {
    let mut sim = HalSim::start(&ARGS);
    let ledger = sim.run(|| async {
        let mut rng = Rng::new(0x7265_7365);
        let mut ledger = Ledger::new();
        let mut bystander = sim.connect().await;
        let values = |rng: &mut Rng, n: u64| -> Vec<u16> { (0..1 + rng.below(n)).map(|_| rng.u16()).collect() };

        // Part of a write, then a reset (SO_LINGER 0): it never happens.
        for round in 0..60u16 {
            let v = values(&mut rng, 4);
            let request = write_registers(round, 128 + rng.below(120) as u16, &v);
            let mut raw = sim.raw().await;
            let cut = 1 + rng.below(request.len() as u64 - 1) as usize;
            raw.write_all(&request[..cut]).await.unwrap();
            if round % 2 == 0 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            raw.set_zero_linger().unwrap();
            drop(raw);
        }
        ledger.verify(&mut bystander).await;

        // A whole write, a second one cut short, then a reset before any
        // reply is read: the first lands or not, all or nothing; the second never.
        for round in 0..20u16 {
            let first = write_registers(round, 128 + rng.below(120) as u16, &values(&mut rng, 4));
            let second = write_registers(round, 128 + rng.below(120) as u16, &values(&mut rng, 4));
            let mut raw = sim.raw().await;
            raw.write_all(&[&first[..], &second[..second.len() - 1]].concat()).await.unwrap();
            raw.set_zero_linger().unwrap();
            drop(raw);
            // Let hal-sim take in (or drop) what came before the reset.
            tokio::time::sleep(Duration::from_millis(100)).await;
            ledger.settle(&mut bystander, &first).await;
            ledger.verify(&mut bystander).await;
        }

        eprintln!("resets: {} of 20 whole writes landed before their reset", ledger.acknowledged());

        // A reset while large replies are going out.
        for round in 0..10u16 {
            let burst: Vec<u8> = (0..20).flat_map(|i| read_registers(round * 20 + i, 128, 125)).collect();
            let mut raw = sim.raw().await;
            raw.write_all(&burst).await.unwrap();
            tokio::time::sleep(Duration::from_millis(rng.below(5))).await;
            raw.set_zero_linger().unwrap();
            drop(raw);
        }
        // The bystander was served throughout.
        ledger.verify(&mut bystander).await;
        ledger
    });
    finish(&mut sim, &ledger);
}

#[test]
fn random_stream_helpers_frame_as_the_specification_says() {
    // Not a hal-sim test: the generator the random test relies on frames
    // as the reference framer (test-support, tested there) says.
    let mut rng = Rng::new(1);
    // A PDU too long for one ADU gets a length field out of range: keep the others.
    let requests: Vec<Vec<u8>> = (0..80).map(|_| rng.request()).filter(|r| r.len() <= 260).collect();
    let stream = requests.concat();
    let framed = framer::split(&stream);
    assert_eq!(framed.frames, requests);
    assert_eq!((framed.bad_length, framed.rest), (None, &[][..]));
    let lengths: Vec<usize> = (0..200).map(|_| rng.pdu().len()).collect();
    assert!(lengths.iter().any(|&l| l > 100), "some multiple writes are long");
}
