//! Cost per request: parse + execute + emit of one whole Modbus TCP ADU, by
//! this project's handler or by rmodbus 0.13, `ITERATIONS` times.
//!
//! Run under `valgrind --tool=cachegrind` by `scripts/bench-cost`, which
//! takes the difference between two iteration counts so start-up cancels
//! out, and reports instructions per request and the ratio.
//!
//! Usage: cost ours|rmodbus fc03x10|fc03x125|fc10x120|fc10x123 ITERATIONS

use std::hint::black_box;
use std::process::ExitCode;

use adapter::map::Image;
use adapter::server::handler::{self, Context, Outcome, Policy};
use adapter::server::{Identity, Stats};
use adapter::settings::Name;
use modbus::mbap::{HEADER_LEN, MAX_ADU_LEN};
use rmodbus::server::ModbusFrame;
use rmodbus::server::storage::ModbusStorageSmall;
use rmodbus::{ModbusFrameBuf, ModbusProto};

/// A request ADU (transaction 1, unit 1) and the length of the normal reply
/// ADU it must get, derived from the request's quantity.
fn request(case: &str) -> Option<(Vec<u8>, usize)> {
    let (pdu, reply_pdu_len) = match case {
        "fc03x10" | "fc03x125" => {
            let quantity: u16 = if case == "fc03x10" { 10 } else { 125 };
            let mut pdu = vec![0x03, 0x00, 0x80];
            pdu.extend(quantity.to_be_bytes());
            // Reply: function code, byte count, then the registers.
            (pdu, 2 + 2 * usize::from(quantity))
        }
        "fc10x120" | "fc10x123" => {
            let quantity: u16 = if case == "fc10x120" { 120 } else { 123 };
            let mut pdu = vec![0x10, 0x00, 0x80];
            pdu.extend(quantity.to_be_bytes());
            pdu.push((2 * quantity) as u8);
            pdu.extend((0..quantity).flat_map(|v| (v * 7).to_be_bytes()));
            // Reply: function code, start address, quantity.
            (pdu, 5)
        }
        _ => return None,
    };
    let mut adu = vec![0x00, 0x01, 0x00, 0x00];
    adu.extend(((pdu.len() + 1) as u16).to_be_bytes());
    adu.push(1);
    adu.extend(pdu);
    Some((adu, HEADER_LEN + reply_pdu_len))
}

fn ours(adu: &[u8], iterations: u64) -> usize {
    let mut image = Image::new();
    let policy = Policy::default();
    let stats = Stats::new();
    let context =
        Context { identity: Identity { model: "bench", name: &Name::UNSET, previous_firmware: None }, stats: &stats };
    let mut reply = [0u8; MAX_ADU_LEN];
    let mut total = 0;
    for _ in 0..iterations {
        if let Outcome::Reply { len, .. } = handler::respond(black_box(adu), &mut reply, &mut image, &policy, &context)
        {
            total += black_box(&reply)[..len].len();
        }
    }
    total
}

fn rmodbus(adu: &[u8], iterations: u64) -> usize {
    let mut storage = ModbusStorageSmall::default();
    // rmodbus reads a request from a 256-byte frame buffer, as its TCP server example does.
    let mut buf: ModbusFrameBuf = [0; 256];
    let Some(dst) = buf.get_mut(..adu.len()) else { return 0 };
    dst.copy_from_slice(adu);
    let mut response: Vec<u8> = Vec::with_capacity(256);
    let mut total = 0;
    for _ in 0..iterations {
        response.clear();
        let mut frame = ModbusFrame::new(1, black_box(&buf), ModbusProto::TcpUdp, &mut response);
        if frame.parse().is_err() {
            return 0;
        }
        if frame.processing_required {
            let result = if frame.readonly { frame.process_read(&storage) } else { frame.process_write(&mut storage) };
            if result.is_err() {
                return 0;
            }
        }
        if frame.response_required && frame.finalize_response().is_err() {
            return 0;
        }
        total += black_box(&response).len();
    }
    total
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let (Some(which), Some(case), Some(iterations)) = (args.get(1), args.get(2), args.get(3)) else {
        eprintln!("usage: cost ours|rmodbus fc03x10|fc03x125|fc10x120|fc10x123 ITERATIONS");
        return ExitCode::from(2);
    };
    let (Some((adu, expected_reply)), Ok(iterations)) = (request(case), iterations.parse::<u64>()) else {
        eprintln!("cost: unknown case {case:?} or bad iteration count {iterations:?}");
        return ExitCode::from(2);
    };
    let bytes = match which.as_str() {
        "ours" => ours(&adu, iterations),
        "rmodbus" if adu.len() <= 256 => rmodbus(&adu, iterations),
        "rmodbus" => {
            eprintln!("cost: rmodbus cannot hold a {}-byte request in its 256-byte buffer", adu.len());
            return ExitCode::from(3);
        }
        _ => {
            eprintln!("cost: unknown implementation {which:?}");
            return ExitCode::from(2);
        }
    };
    // Every request must have been answered with a normal reply.
    if bytes != expected_reply * iterations as usize {
        eprintln!("cost: {which} gave {bytes} reply bytes for {iterations} requests, expected {expected_reply} each");
        return ExitCode::FAILURE;
    }
    ExitCode::SUCCESS
}
