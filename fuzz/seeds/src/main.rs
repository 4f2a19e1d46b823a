//! Writes the seed corpora of the fuzz targets from the codec fixtures
//! (`test_support::fixtures::PYMODBUS`, bytes captured from pymodbus), and
//! the store's from records and real saves (`firmware_fuzz::storage::seeds`):
//!
//! ```text
//! cargo run -p fuzz-seeds -- DIR    # writes DIR/session, DIR/handler, DIR/codec, DIR/store
//! ```
//!
//! Each seed runs through its target's checks before it is written, so a
//! seed that fails them is reported here and not handed to the fuzzer.

use std::path::{Path, PathBuf};

use firmware_fuzz::input::{PARTIAL_WRITES, STALL_READS, STRICT, UNIT_FILTER};
use firmware_fuzz::{HandlerInput, SessionInput};
use test_support::fixtures::PYMODBUS;

fn main() {
    let dir = std::env::args_os().nth(1).map(PathBuf::from).unwrap_or_else(|| {
        eprintln!("usage: fuzz-seeds DIR");
        std::process::exit(2);
    });
    let written = [
        write(&dir.join("session"), &session_seeds(), firmware_fuzz::session),
        write(&dir.join("handler"), &handler_seeds(), firmware_fuzz::handler),
        write(&dir.join("codec"), &codec_seeds(), firmware_fuzz::codec),
        write(&dir.join("store"), &firmware_fuzz::storage::seeds(), firmware_fuzz::store),
    ];
    println!(
        "fuzz-seeds: {} session, {} handler, {} codec, {} store seeds in {}",
        written[0],
        written[1],
        written[2],
        written[3],
        dir.display()
    );
}

/// Runs each seed through `check`, then writes it as `DIR/seed-NN`.
fn write(dir: &Path, seeds: &[Vec<u8>], check: fn(&[u8])) -> usize {
    std::fs::create_dir_all(dir).unwrap_or_else(|e| panic!("creating {}: {e}", dir.display()));
    for (i, seed) in seeds.iter().enumerate() {
        check(seed);
        let path = dir.join(format!("seed-{i:03}"));
        std::fs::write(&path, seed).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
    }
    seeds.len()
}

fn requests() -> impl Iterator<Item = &'static [u8]> {
    PYMODBUS.iter().map(|f| f.request)
}

/// `frame` with another unit id, protocol id or length field.
fn with(frame: &[u8], at: usize, bytes: &[u8]) -> Vec<u8> {
    let mut out = frame.to_vec();
    out[at..at + bytes.len()].copy_from_slice(bytes);
    out
}

fn session_seeds() -> Vec<Vec<u8>> {
    let all: Vec<u8> = requests().flatten().copied().collect();
    let seed =
        |flags: u8, unit_id: u8, cuts: &[u8], stream: &[u8]| SessionInput { flags, unit_id, cuts, stream }.to_bytes();
    let mut seeds: Vec<Vec<u8>> = requests().map(|r| seed(0, 0, &[], r)).collect();
    seeds.extend([
        // Every fixture pipelined, in one read, in single bytes, in odd cuts.
        seed(0, 0, &[], &all),
        seed(0, 0, &[1], &all),
        seed(0, 0, &[5, 0, 13, 2], &all),
        seed(STALL_READS | PARTIAL_WRITES, 0, &[3, 7], &all),
        // The unit id filter (the fixtures use unit 1) and the strict policy.
        seed(UNIT_FILTER, 1, &[], &all),
        seed(UNIT_FILTER, 2, &[], &all),
        seed(STRICT, 0, &[], &all),
    ]);
    // Not Modbus (protocol id 1) between two requests; a bad length; a frame cut short.
    let first = PYMODBUS[0].request;
    let other_protocol = [with(first, 2, &[0, 1]), first.to_vec()].concat();
    seeds.push(seed(0, 0, &[], &other_protocol));
    seeds.push(seed(0, 0, &[], &[first, &with(first, 4, &[0, 255])].concat()));
    seeds.push(seed(0, 0, &[], &[first, &first[..9]].concat()));
    seeds
}

fn handler_seeds() -> Vec<Vec<u8>> {
    let mut seeds: Vec<Vec<u8>> = requests().map(|r| HandlerInput::encode(0, 0, &[r])).collect();
    let all: Vec<&[u8]> = requests().collect();
    seeds.push(HandlerInput::encode(0, 0, &all));
    seeds.push(HandlerInput::encode(UNIT_FILTER | STRICT, 1, &all));
    // Replies are no requests: each gets an exception or is discarded.
    let replies: Vec<&[u8]> = PYMODBUS.iter().map(|f| f.reply).collect();
    seeds.push(HandlerInput::encode(0, 0, &replies));
    seeds
}

fn codec_seeds() -> Vec<Vec<u8>> {
    let mut seeds = Vec::new();
    for fixture in &PYMODBUS {
        seeds.push(fixture.request[7..].to_vec());
        seeds.push(fixture.reply[7..].to_vec());
        seeds.push(fixture.request.to_vec());
    }
    seeds
}
