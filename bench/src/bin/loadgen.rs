//! A closed-loop Modbus TCP load generator: N connections, one request in
//! flight on each, every reply checked byte by byte against its request.
//!
//! Raw frames over tokio (one thread: pin it with `taskset`), so the client
//! costs little next to the server under test. Reports requests per second
//! and the p50, p99 and p99.9 latency of the requests completed after the
//! warm-up, as one line of `key=value` pairs on stdout:
//!
//! ```text
//! loadgen --target 198.18.0.2:502 --connections 8 --duration 10 --fc 3 --count 10
//! target=198.18.0.2:502 connections=8 request=fc03x10@0 seconds=10.000 requests=... errors=0 rps=... p50_us=... p99_us=... p999_us=... max_us=... conn_min=... conn_max=...
//! ```
//!
//! `--mix` cycles through reads and writes of all six function codes instead
//! (what the soak runs). `--progress` prints the rate of each second on
//! stderr. Any error (connect, timeout, exception, malformed or mismatched
//! reply, closed connection) is counted, printed on stderr, and makes the
//! exit status 1; the connection is then opened again. Exit status 2: the
//! command line or the first connections failed.

use std::cell::RefCell;
use std::net::SocketAddr;
use std::process::ExitCode;
use std::rc::Rc;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const USAGE: &str = "\
usage: loadgen --target IP:PORT [--connections 1] [--duration 10] [--warmup 1]
               [--fc 3] [--address A] [--count N] [--mix] [--unit 1]
               [--timeout-ms 1000] [--progress]

  --target IP:PORT   the server
  --connections N    connections, one request in flight on each (default 1)
  --duration SECS    measured time after the warm-up (default 10; fractions allowed)
  --warmup SECS      time run first and not measured (default 1)
  --fc CODE          1, 3, 5, 6, 15 or 16 (default 3: read holding registers)
  --address A        first address (default: 0 for reads, 128 for register writes,
                     16 for coil writes: valid on this project's map)
  --count N          registers or coils per request (default 10; 1 for fc 5 and 6)
  --mix              cycle through fc 3, 1, 16, 6, 15, 5 on valid addresses instead
  --unit ID          the unit id sent (default 1)
  --timeout-ms MS    a reply later than this is an error (default 1000)
  --progress         print each second's request rate and errors on stderr";

/// Largest Modbus TCP ADU (MBAP 7 + PDU 253).
const MAX_ADU_LEN: usize = 260;
/// MBAP header: transaction id, protocol id, length, unit id.
const MBAP_LEN: usize = 7;
/// Errors printed per connection; the rest are only counted.
const MAX_REPORTED_ERRORS: usize = 5;
/// A latency sample: nanoseconds, saturated at `u32::MAX` (4.3 s).
type Sample = u32;

/// One kind of request.
#[derive(Clone, Copy, Debug)]
struct Request {
    fc: u8,
    address: u16,
    count: u16,
}

impl Request {
    fn new(fc: u8, address: Option<u16>, count: Option<u16>) -> Result<Self, String> {
        let (default_address, max_count) = match fc {
            1 => (0, 2000),
            3 => (0, 125),
            5 => (16, 1),
            6 => (128, 1),
            15 => (16, 1968),
            16 => (128, 123),
            _ => return Err(format!("--fc {fc}: one of 1, 3, 5, 6, 15, 16")),
        };
        let count = count.unwrap_or(if max_count == 1 { 1 } else { 10 });
        if count == 0 || count > max_count {
            return Err(format!("--count {count}: 1..={max_count} for fc {fc}"));
        }
        Ok(Self { fc, address: address.unwrap_or(default_address), count })
    }

    /// The requests of `--mix`: valid on this project's map and on the peers' (266 coils, 436 registers).
    fn mix() -> Vec<Self> {
        [(3, 256, 10), (1, 0, 44), (16, 128, 20), (3, 270, 125), (6, 129, 1), (15, 16, 16), (5, 17, 1), (3, 128, 20)]
            .into_iter()
            .map(|(fc, address, count)| Self { fc, address, count })
            .collect()
    }

    fn label(&self) -> String {
        format!("fc{:02}x{}@{}", self.fc, self.count, self.address)
    }

    /// Writes the request ADU into `buf` and returns its length. `seq` varies the written values.
    fn emit(&self, buf: &mut [u8; MAX_ADU_LEN], transaction: u16, unit: u8, seq: u16) -> usize {
        let pdu = &mut buf[MBAP_LEN..];
        pdu[0] = self.fc;
        pdu[1..3].copy_from_slice(&self.address.to_be_bytes());
        let count = usize::from(self.count);
        let pdu_len = match self.fc {
            1 | 3 => {
                pdu[3..5].copy_from_slice(&self.count.to_be_bytes());
                5
            }
            5 => {
                pdu[3..5].copy_from_slice(if seq.is_multiple_of(2) { &[0xff, 0x00] } else { &[0x00, 0x00] });
                5
            }
            6 => {
                pdu[3..5].copy_from_slice(&seq.to_be_bytes());
                5
            }
            15 => {
                let bytes = count.div_ceil(8);
                pdu[3..5].copy_from_slice(&self.count.to_be_bytes());
                pdu[5] = bytes as u8;
                let values = &mut pdu[6..6 + bytes];
                values.fill(0);
                for i in 0..count {
                    if (usize::from(seq) + i) % 3 == 0 {
                        values[i / 8] |= 1 << (i % 8);
                    }
                }
                6 + bytes
            }
            16 => {
                pdu[3..5].copy_from_slice(&self.count.to_be_bytes());
                pdu[5] = (2 * count) as u8;
                for (i, value) in pdu[6..6 + 2 * count].chunks_exact_mut(2).enumerate() {
                    value.copy_from_slice(&seq.wrapping_add(i as u16).to_be_bytes());
                }
                6 + 2 * count
            }
            _ => unreachable!("checked in Request::new"),
        };
        buf[0..2].copy_from_slice(&transaction.to_be_bytes());
        buf[2..4].copy_from_slice(&[0, 0]);
        buf[4..6].copy_from_slice(&((pdu_len + 1) as u16).to_be_bytes());
        buf[6] = unit;
        MBAP_LEN + pdu_len
    }

    /// The reply's PDU length when the request succeeds.
    fn reply_pdu_len(&self) -> usize {
        match self.fc {
            1 => 2 + usize::from(self.count).div_ceil(8),
            3 => 2 + 2 * usize::from(self.count),
            _ => 5,
        }
    }

    /// Checks a reply ADU against the request ADU it answers.
    fn check(&self, request: &[u8], reply: &[u8]) -> Result<(), String> {
        let pdu = &reply[MBAP_LEN..];
        if pdu.first() == Some(&(self.fc | 0x80)) {
            return Err(format!("{}: exception {:02x}", self.label(), pdu.get(1).copied().unwrap_or(0)));
        }
        if pdu.len() != self.reply_pdu_len() || pdu[0] != self.fc {
            return Err(format!("{}: unexpected reply pdu {:02x?}", self.label(), &pdu[..pdu.len().min(8)]));
        }
        let ok = match self.fc {
            1 | 3 => usize::from(pdu[1]) == pdu.len() - 2,
            5 | 6 => pdu == &request[MBAP_LEN..],
            _ => pdu == &request[MBAP_LEN..MBAP_LEN + 5],
        };
        if ok { Ok(()) } else { Err(format!("{}: reply does not match the request: {:02x?}", self.label(), pdu)) }
    }
}

#[derive(Debug)]
struct Options {
    target: SocketAddr,
    connections: usize,
    duration: Duration,
    warmup: Duration,
    requests: Vec<Request>,
    unit: u8,
    timeout: Duration,
    progress: bool,
}

fn parse(args: impl IntoIterator<Item = String>) -> Result<Option<Options>, String> {
    let mut target = None;
    let mut connections = 1usize;
    let mut duration = 10.0f64;
    let mut warmup = 1.0f64;
    let (mut fc, mut address, mut count) = (3u8, None, None);
    let mut mix = false;
    let mut unit = 1u8;
    let mut timeout_ms = 1000u64;
    let mut progress = false;
    let mut args = args.into_iter();
    while let Some(flag) = args.next() {
        match flag.as_str() {
            "-h" | "--help" => return Ok(None),
            "--mix" => {
                mix = true;
                continue;
            }
            "--progress" => {
                progress = true;
                continue;
            }
            _ => {}
        }
        let value = args.next().ok_or_else(|| format!("{flag} needs a value"))?;
        let bad = |_| format!("{flag} {value}: not a valid value");
        match flag.as_str() {
            "--target" => target = Some(value.parse().map_err(|_| format!("--target {value}: IP:PORT"))?),
            "--connections" => connections = value.parse().map_err(bad)?,
            "--duration" => duration = value.parse().map_err(|_| format!("--duration {value}: seconds"))?,
            "--warmup" => warmup = value.parse().map_err(|_| format!("--warmup {value}: seconds"))?,
            "--fc" => fc = value.parse().map_err(bad)?,
            "--address" => address = Some(value.parse().map_err(bad)?),
            "--count" => count = Some(value.parse().map_err(bad)?),
            "--unit" => unit = value.parse().map_err(bad)?,
            "--timeout-ms" => timeout_ms = value.parse().map_err(bad)?,
            _ => return Err(format!("unknown option {flag}")),
        }
    }
    if connections == 0 || connections > 1000 {
        return Err("--connections: 1..=1000".into());
    }
    if !(duration > 0.0 && duration < 1e6 && (0.0..1e6).contains(&warmup)) {
        return Err("--duration must be > 0 and --warmup >= 0".into());
    }
    let requests = if mix { Request::mix() } else { vec![Request::new(fc, address, count)?] };
    Ok(Some(Options {
        target: target.ok_or("--target is required")?,
        connections,
        duration: Duration::from_secs_f64(duration),
        warmup: Duration::from_secs_f64(warmup),
        requests,
        unit,
        timeout: Duration::from_millis(timeout_ms),
        progress,
    }))
}

/// What every connection adds to: completed requests per second of the run, and errors.
#[derive(Debug, Default)]
struct Tally {
    per_second: Vec<u64>,
    errors_per_second: Vec<u64>,
    errors: u64,
}

impl Tally {
    fn count(&mut self, second: usize, error: bool) {
        let slots = if error { &mut self.errors_per_second } else { &mut self.per_second };
        if slots.len() <= second {
            slots.resize(second + 1, 0);
        }
        slots[second] += 1;
        self.errors += u64::from(error);
    }
}

/// One connection's result: latency samples of measured requests.
struct Connection {
    samples: Vec<Sample>,
}

async fn connect(target: SocketAddr) -> std::io::Result<TcpStream> {
    let stream = TcpStream::connect(target).await?;
    stream.set_nodelay(true)?;
    Ok(stream)
}

/// One request and its reply on `stream`.
async fn exchange(stream: &mut TcpStream, request: &[u8], reply: &mut [u8; MAX_ADU_LEN]) -> Result<usize, String> {
    stream.write_all(request).await.map_err(|e| format!("write: {e}"))?;
    stream.read_exact(&mut reply[..MBAP_LEN]).await.map_err(|e| format!("read: {e}"))?;
    let length = usize::from(u16::from_be_bytes([reply[4], reply[5]]));
    if !(2..=254).contains(&length) {
        return Err(format!("reply with MBAP length {length}"));
    }
    let total = MBAP_LEN - 1 + length;
    stream.read_exact(&mut reply[MBAP_LEN..total]).await.map_err(|e| format!("read: {e}"))?;
    if reply[0..2] != request[0..2] || reply[2..4] != [0, 0] || reply[6] != request[6] {
        return Err(format!("reply header {:02x?} does not match the request's {:02x?}", &reply[..7], &request[..7]));
    }
    Ok(total)
}

/// Runs one connection in a closed loop until `end`.
async fn run_connection(
    index: usize,
    mut stream: TcpStream,
    options: Rc<Options>,
    start: Instant,
    measure_from: Instant,
    end: Instant,
    tally: Rc<RefCell<Tally>>,
) -> Connection {
    let mut samples = Vec::with_capacity(1 << 16);
    let mut request = [0u8; MAX_ADU_LEN];
    let mut reply = [0u8; MAX_ADU_LEN];
    let mut seq: u16 = (index as u16).wrapping_mul(7919);
    let mut transaction: u16 = 0;
    let mut kind = index % options.requests.len();
    let mut reported = 0;
    let mut report = |message: String| {
        reported += 1;
        if reported <= MAX_REPORTED_ERRORS {
            eprintln!("loadgen: connection {index}: {message}");
        } else if reported == MAX_REPORTED_ERRORS + 1 {
            eprintln!("loadgen: connection {index}: further errors are counted, not printed");
        }
    };
    loop {
        let sent = Instant::now();
        if sent >= end {
            break;
        }
        let request_kind = options.requests[kind];
        kind = (kind + 1) % options.requests.len();
        transaction = transaction.wrapping_add(1);
        seq = seq.wrapping_add(1);
        let len = request_kind.emit(&mut request, transaction, options.unit, seq);
        let result =
            match tokio::time::timeout(options.timeout, exchange(&mut stream, &request[..len], &mut reply)).await {
                Ok(Ok(n)) => request_kind.check(&request[..len], &reply[..n]).map_err(|e| (e, false)),
                Ok(Err(e)) => Err((e, true)),
                Err(_) => Err((format!("no reply within {:?}", options.timeout), true)),
            };
        let done = Instant::now();
        let second = done.saturating_duration_since(start).as_secs() as usize;
        tally.borrow_mut().count(second, result.is_err());
        match result {
            Ok(()) if sent >= measure_from && done <= end => {
                samples.push((done - sent).as_nanos().min(u128::from(Sample::MAX)) as Sample);
            }
            Ok(()) => {}
            Err((message, lost)) => {
                report(message);
                if lost {
                    // The stream is out of step: open it again.
                    loop {
                        if Instant::now() >= end {
                            return Connection { samples };
                        }
                        match connect(options.target).await {
                            Ok(s) => {
                                stream = s;
                                break;
                            }
                            Err(e) => {
                                report(format!("reconnect: {e}"));
                                tally.borrow_mut().count(second, true);
                                tokio::time::sleep(Duration::from_millis(100)).await;
                            }
                        }
                    }
                }
            }
        }
    }
    Connection { samples }
}

fn percentile(sorted: &[Sample], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = ((p * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    f64::from(sorted[rank - 1]) / 1000.0
}

async fn run(options: Options) -> ExitCode {
    let options = Rc::new(options);
    let mut streams = Vec::with_capacity(options.connections);
    for i in 0..options.connections {
        match tokio::time::timeout(Duration::from_secs(5), connect(options.target)).await {
            Ok(Ok(stream)) => streams.push(stream),
            Ok(Err(e)) => {
                eprintln!("loadgen: connection {i} to {}: {e}", options.target);
                return ExitCode::from(2);
            }
            Err(_) => {
                eprintln!("loadgen: connection {i} to {}: no answer within 5 s", options.target);
                return ExitCode::from(2);
            }
        }
    }

    let start = Instant::now();
    let measure_from = start + options.warmup;
    let end = measure_from + options.duration;
    let tally = Rc::new(RefCell::new(Tally::default()));
    let local = tokio::task::LocalSet::new();
    let handles: Vec<_> = streams
        .into_iter()
        .enumerate()
        .map(|(i, stream)| {
            local.spawn_local(run_connection(i, stream, options.clone(), start, measure_from, end, tally.clone()))
        })
        .collect();
    if options.progress {
        let tally = tally.clone();
        local.spawn_local(async move {
            let mut second = 0;
            loop {
                tokio::time::sleep_until((start + Duration::from_secs(second as u64 + 1)).into()).await;
                let t = tally.borrow();
                let n = t.per_second.get(second).copied().unwrap_or(0);
                let e = t.errors_per_second.get(second).copied().unwrap_or(0);
                eprintln!("loadgen: t={:>4} s rps={n} errors={e}", second + 1);
                second += 1;
            }
        });
    }
    let connections = local
        .run_until(async {
            let mut results = Vec::with_capacity(handles.len());
            for handle in handles {
                results.push(handle.await.expect("a connection task"));
            }
            results
        })
        .await;

    let per_connection: Vec<usize> = connections.iter().map(|c| c.samples.len()).collect();
    let mut samples: Vec<Sample> = connections.into_iter().flat_map(|c| c.samples).collect();
    samples.sort_unstable();
    let seconds = options.duration.as_secs_f64();
    let errors = tally.borrow().errors;
    let request = options.requests.iter().map(Request::label).collect::<Vec<_>>().join(",");
    println!(
        "target={} connections={} request={} seconds={:.3} requests={} errors={} rps={:.0} p50_us={:.1} p99_us={:.1} \
         p999_us={:.1} max_us={:.1} conn_min={} conn_max={}",
        options.target,
        options.connections,
        if options.requests.len() > 1 { "mix" } else { &request },
        seconds,
        samples.len(),
        errors,
        samples.len() as f64 / seconds,
        percentile(&samples, 0.50),
        percentile(&samples, 0.99),
        percentile(&samples, 0.999),
        percentile(&samples, 1.0),
        per_connection.iter().min().copied().unwrap_or(0),
        per_connection.iter().max().copied().unwrap_or(0),
    );
    if errors > 0 || samples.is_empty() { ExitCode::FAILURE } else { ExitCode::SUCCESS }
}

fn main() -> ExitCode {
    let options = match parse(std::env::args().skip(1)) {
        Ok(Some(options)) => options,
        Ok(None) => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("loadgen: {e}\n\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("a tokio runtime");
    runtime.block_on(run(options))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn emit(request: Request, transaction: u16, seq: u16) -> Vec<u8> {
        let mut buf = [0xa5; MAX_ADU_LEN];
        let len = request.emit(&mut buf, transaction, 1, seq);
        buf[..len].to_vec()
    }

    #[test]
    fn read_holding_registers_request_is_the_spec_bytes() {
        let request = Request::new(3, None, None).unwrap();
        assert_eq!(
            emit(request, 0x0102, 0),
            [
                0x01, 0x02, // transaction id
                0x00, 0x00, // protocol id
                0x00, 0x06, // length: unit + 5 PDU bytes
                0x01, // unit id
                0x03, 0x00, 0x00, 0x00, 0x0a, // fc 03, address 0, quantity 10
            ]
        );
    }

    #[test]
    fn write_requests_carry_their_byte_counts_and_values() {
        let fc16 = emit(Request::new(16, None, Some(3)).unwrap(), 1, 7);
        assert_eq!(&fc16[4..], [0x00, 0x0d, 0x01, 0x10, 0x00, 0x80, 0x00, 0x03, 0x06, 0, 7, 0, 8, 0, 9]);
        let fc15 = emit(Request::new(15, None, Some(10)).unwrap(), 1, 0);
        // Coils 16..=25, every third one on starting with the first: bits 0, 3, 6, 9.
        assert_eq!(&fc15[4..], [0x00, 0x09, 0x01, 0x0f, 0x00, 0x10, 0x00, 0x0a, 0x02, 0b0100_1001, 0b0000_0010]);
        let fc05 = emit(Request::new(5, None, None).unwrap(), 1, 2);
        assert_eq!(&fc05[7..], [0x05, 0x00, 0x10, 0xff, 0x00]);
    }

    #[test]
    fn replies_are_checked_against_their_request() {
        let read = Request::new(3, None, Some(2)).unwrap();
        let request = emit(read, 1, 0);
        let good = [0, 1, 0, 0, 0, 7, 1, 0x03, 0x04, 0, 1, 0, 2];
        assert_eq!(read.check(&request, &good), Ok(()));
        let exception = [0, 1, 0, 0, 0, 3, 1, 0x83, 0x02];
        assert!(read.check(&request, &exception).unwrap_err().contains("exception 02"));
        let short = [0, 1, 0, 0, 0, 5, 1, 0x03, 0x02, 0, 1];
        assert!(read.check(&request, &short).is_err());

        let write = Request::new(16, None, Some(2)).unwrap();
        let request = emit(write, 1, 0);
        let echo = [0, 1, 0, 0, 0, 6, 1, 0x10, 0x00, 0x80, 0x00, 0x02];
        assert_eq!(write.check(&request, &echo), Ok(()));
        let wrong_quantity = [0, 1, 0, 0, 0, 6, 1, 0x10, 0x00, 0x80, 0x00, 0x03];
        assert!(write.check(&request, &wrong_quantity).is_err());
    }

    #[test]
    fn the_mix_fits_the_map_and_the_limits() {
        for request in Request::mix() {
            let limit = if matches!(request.fc, 1 | 5 | 15) { 266 } else { 436 };
            assert!(u32::from(request.address) + u32::from(request.count) <= limit, "{request:?}");
            assert!(Request::new(request.fc, Some(request.address), Some(request.count)).is_ok(), "{request:?}");
        }
    }

    #[test]
    fn counts_outside_the_function_limits_are_refused() {
        assert!(Request::new(3, None, Some(0)).is_err());
        assert!(Request::new(3, None, Some(126)).is_err());
        assert!(Request::new(16, None, Some(124)).is_err());
        assert!(Request::new(7, None, None).is_err());
        assert!(Request::new(3, None, Some(125)).is_ok());
    }

    #[test]
    fn percentiles_take_the_nearest_rank() {
        let samples: Vec<Sample> = (1..=1000).map(|i| i * 1000).collect();
        assert_eq!(percentile(&samples, 0.5), 500.0);
        assert_eq!(percentile(&samples, 0.99), 990.0);
        assert_eq!(percentile(&samples, 0.999), 999.0);
        assert_eq!(percentile(&samples, 1.0), 1000.0);
        assert_eq!(percentile(&[], 0.5), 0.0);
    }
}
