//! hal-sim under test: started in its own network namespace, driven by a
//! client on a thread that entered that namespace.
//!
//! ```no_run
//! use system_tests::hal_sim::HalSim;
//! let sim = HalSim::start(&["--robot", "idle"]);
//! sim.run(|| async {
//!     let mut ctx = sim.connect().await;
//!     // ... tokio-modbus requests ...
//! });
//! ```

use std::io::{BufRead, BufReader, Write};
use std::net::{Ipv4Addr, SocketAddr};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use test_support::framer;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio_modbus::client::Context;

use crate::netns::{DEVICE_IP, Namespace, TAP};

/// How long hal-sim may take to print its "listening" line.
pub const START_TIMEOUT: Duration = Duration::from_secs(10);
/// The Modbus port hal-sim listens on in the tests (each test has its own namespace).
pub const PORT: u16 = 502;

/// The hal-sim binary: `HAL_SIM_BIN`, or `target/debug/hal-sim` of this workspace.
pub fn binary() -> PathBuf {
    if let Some(path) = std::env::var_os("HAL_SIM_BIN") {
        let path = PathBuf::from(path);
        assert!(path.is_file(), "HAL_SIM_BIN={} is not a file", path.display());
        return path;
    }
    let target = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) => PathBuf::from(dir),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("target"),
    };
    let path = target.join("debug").join("hal-sim");
    assert!(
        path.is_file(),
        "hal-sim is not built ({} is missing): run `cargo build -p hal-sim` first, or set HAL_SIM_BIN",
        path.display()
    );
    path
}

/// A running hal-sim in a namespace of its own; killed (and the namespace
/// deleted) on drop.
#[derive(Debug)]
pub struct HalSim {
    child: Child,
    control: PathBuf,
    log: PathBuf,
    ns: Namespace,
}

impl HalSim {
    /// Starts hal-sim on a new namespace's TAP at 198.18.0.2 with a control
    /// socket, plus `args`, and waits for its "listening" line.
    pub fn start(args: &[&str]) -> Self {
        let ns = Namespace::new().expect("a network namespace with a TAP");
        let dir = std::env::temp_dir();
        let control = dir.join(format!("{}.control.sock", ns.name()));
        let log = dir.join(format!("{}.hal-sim.log", ns.name()));
        let stderr = std::fs::File::create(&log).expect("a log file in the temp dir");
        let mut child = ns
            .command(binary())
            .args(["--tap", TAP, "--ip", &format!("{DEVICE_IP}/24"), "--control"])
            .arg(&control)
            .args(args)
            .env("RUST_LOG", std::env::var("RUST_LOG").unwrap_or_else(|_| "debug".into()))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .expect("hal-sim starts");
        let stdout = child.stdout.take().expect("hal-sim's stdout");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let mut sim = Self { child, control, log, ns };
        let deadline = Instant::now() + START_TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match rx.recv_timeout(left) {
                Ok(line) if line.starts_with("hal-sim: modbus tcp listening on ") => {
                    let expected = format!("hal-sim: modbus tcp listening on {DEVICE_IP}:");
                    assert!(line.starts_with(&expected) && line.ends_with(&format!("(tap {TAP})")), "{line}");
                    break;
                }
                Ok(_) => {}
                Err(_) => {
                    let status = sim.child.try_wait().ok().flatten();
                    panic!("hal-sim did not say it was listening (exit: {status:?}); its log:\n{}", sim.log());
                }
            }
        }
        sim
    }

    /// The namespace hal-sim runs in.
    pub fn ns(&self) -> &Namespace {
        &self.ns
    }

    /// hal-sim's Modbus address.
    pub fn addr(&self) -> SocketAddr {
        let ip: Ipv4Addr = DEVICE_IP.parse().expect("DEVICE_IP is an IPv4 address");
        SocketAddr::from((ip, PORT))
    }

    /// The control socket's path.
    pub fn control_path(&self) -> &Path {
        &self.control
    }

    /// hal-sim's log so far (stderr).
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Sends one control command and returns the reply line (without newline).
    pub fn control(&self, command: &str) -> String {
        let mut stream = UnixStream::connect(&self.control).expect("the control socket accepts");
        stream.set_read_timeout(Some(Duration::from_secs(5))).expect("a read timeout");
        stream.write_all(format!("{command}\n").as_bytes()).expect("the command is sent");
        let mut reply = String::new();
        BufReader::new(&mut stream).read_line(&mut reply).expect("a reply line");
        assert!(reply.ends_with('\n'), "a whole reply line to {command:?}: {reply:?}");
        reply.trim_end().to_owned()
    }

    /// Sends a control command that must succeed; returns what follows `ok`.
    pub fn control_ok(&self, command: &str) -> String {
        let reply = self.control(command);
        match reply.strip_prefix("ok") {
            Some(rest) => rest.trim().to_owned(),
            None => panic!("{command:?} answered {reply:?}"),
        }
    }

    /// Runs `test` on a new thread inside the namespace, on a current-thread
    /// tokio runtime, and returns its result (a panic inside fails the test,
    /// and so does running longer than [`crate::TEST_TIMEOUT`]).
    pub fn run<T, F, Fut>(&self, test: F) -> T
    where
        T: Send,
        F: FnOnce() -> Fut + Send,
        Fut: Future<Output = T>,
    {
        crate::run_client(Some(&self.ns), test)
    }

    /// A tokio-modbus client connected to hal-sim (unit id 0xFF). Call it
    /// inside [`HalSim::run`].
    pub async fn connect(&self) -> Context {
        tokio_modbus::client::tcp::connect(self.addr()).await.expect("tokio-modbus connects to hal-sim")
    }

    /// A tokio-modbus client connected to hal-sim (unit id 0xFF) that can
    /// also tell how hal-sim ends the connection. Call it inside [`HalSim::run`].
    pub async fn connect_watched(&self) -> WatchedClient {
        let stream = tokio::net::TcpStream::connect(self.addr()).await.expect("a TCP connection to hal-sim");
        // Out of tokio (it stays non-blocking) to duplicate the descriptor; both go back in.
        let stream = stream.into_std().expect("the stream out of tokio");
        let watch = stream.try_clone().expect("a second descriptor of the socket");
        let ctx = tokio_modbus::client::tcp::attach(tokio::net::TcpStream::from_std(stream).expect("back in tokio"));
        let socket = tokio::net::TcpStream::from_std(watch).expect("the second descriptor in tokio");
        WatchedClient { ctx, socket }
    }

    /// A raw TCP stream to hal-sim, without Nagle, for hand-made frames.
    pub async fn raw(&self) -> tokio::net::TcpStream {
        let stream = tokio::net::TcpStream::connect(self.addr()).await.expect("a TCP connection to hal-sim");
        stream.set_nodelay(true).expect("TCP_NODELAY");
        stream
    }

    /// Whether hal-sim is still running.
    pub fn is_running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }
}

impl Drop for HalSim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.control);
        if std::thread::panicking() {
            eprintln!("--- hal-sim log ({}) ---\n{}", self.log.display(), self.log());
        } else {
            let _ = std::fs::remove_file(&self.log);
        }
    }
}

/// Reads one whole reply frame within `wait`, as long as its length field
/// says (which must be one a reply may carry: test-support's reference
/// framer); `None` if nothing complete arrived, or the connection closed (to
/// tell which, see [`end_within`]).
pub async fn read_frame<R: AsyncRead + Unpin>(stream: &mut R, wait: Duration) -> Option<Vec<u8>> {
    let read = async {
        let mut frame = vec![0u8; framer::LENGTH_END];
        stream.read_exact(&mut frame).await.ok()?;
        let length = framer::length_field(&frame)?;
        assert!(framer::REPLY_LENGTH_RANGE.contains(&length), "a reply with length field {length}: {frame:02x?}");
        frame.resize(framer::LENGTH_END + usize::from(length), 0);
        stream.read_exact(&mut frame[framer::LENGTH_END..]).await.ok()?;
        Some(frame)
    };
    tokio::time::timeout(wait, read).await.ok().flatten()
}

/// How a connection's server ended it, or did not, as one read by the client
/// saw it.
#[derive(Debug, PartialEq, Eq)]
pub enum End {
    /// End of stream: the server closed the connection (FIN).
    Closed,
    /// The server reset the connection (RST): `ECONNRESET`, or `EPIPE` when
    /// the reset answered a write to a connection the server had closed.
    Reset,
    /// Bytes came instead of an end (the first read's worth).
    Bytes(Vec<u8>),
    /// Nothing came within the wait: the connection hangs, open.
    Hang,
    /// Another read error.
    Error(std::io::ErrorKind),
}

impl End {
    /// Whether the server closed or reset the connection.
    pub fn is_closed(&self) -> bool {
        matches!(self, End::Closed | End::Reset)
    }
}

/// How the server ends `stream` within `wait`: what one read returns. An
/// end already read is read again (a closed socket keeps reading as closed),
/// so this also tells why an earlier read loop stopped.
pub async fn end_within<R: tokio::io::AsyncRead + Unpin>(stream: &mut R, wait: Duration) -> End {
    use std::io::ErrorKind;
    use tokio::io::AsyncReadExt;
    let mut buf = [0u8; 64];
    match tokio::time::timeout(wait, stream.read(&mut buf)).await {
        Err(_) => End::Hang,
        Ok(Ok(0)) => End::Closed,
        Ok(Ok(n)) => End::Bytes(buf[..n].to_vec()),
        Ok(Err(e)) if matches!(e.kind(), ErrorKind::ConnectionReset | ErrorKind::BrokenPipe) => End::Reset,
        Ok(Err(e)) => End::Error(e.kind()),
    }
}

/// A tokio-modbus client that can also tell how the server ended its
/// connection, which tokio-modbus cannot: it reports an end of stream as
/// whatever the thread's last OS error was, and a server that stops
/// answering as a request that never completes. So this keeps a second
/// descriptor of the same socket, and reads the end there. It derefs to the
/// tokio-modbus [`Context`].
pub struct WatchedClient {
    ctx: Context,
    socket: tokio::net::TcpStream,
}

impl WatchedClient {
    /// How the server ends the connection within `wait` (see [`end_within`]).
    /// Call it with no request pending: a reply would be read as [`End::Bytes`].
    pub async fn end_within(&mut self, wait: Duration) -> End {
        end_within(&mut self.socket, wait).await
    }
}

impl std::ops::Deref for WatchedClient {
    type Target = Context;

    fn deref(&self) -> &Context {
        &self.ctx
    }
}

impl std::ops::DerefMut for WatchedClient {
    fn deref_mut(&mut self) -> &mut Context {
        &mut self.ctx
    }
}

/// The firmware version the hal-sim binary was built from, as it reports it
/// in registers 256-258 (from `hal-sim --version`: `hal-sim X (firmware A.B.C)`).
pub fn firmware_version() -> [u16; 3] {
    let output = std::process::Command::new(binary()).arg("--version").output().expect("hal-sim --version runs");
    let text = String::from_utf8_lossy(&output.stdout);
    let version = text
        .split("(firmware ")
        .nth(1)
        .and_then(|rest| rest.split(')').next())
        .unwrap_or_else(|| panic!("hal-sim --version names the firmware version: {text:?}"));
    let parts: Vec<u16> = version.split('.').map(|p| p.parse().expect("a numeric version")).collect();
    assert_eq!(parts.len(), 3, "{text:?}");
    assert_ne!(parts, [0, 0, 0], "a version is set");
    [parts[0], parts[1], parts[2]]
}
