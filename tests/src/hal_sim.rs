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
//!
//! The HTTP API is reached with curl run inside the namespace
//! ([`HalSim::http`]), as a user would; settings kept across runs need a
//! state file ([`HalSim::start_with`], [`HalSim::restart`]).

use std::io::{BufRead, BufReader, Write};
use std::net::{Ipv4Addr, SocketAddr};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::{Mutex, mpsc};
use std::time::{Duration, Instant};

use test_support::framer;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio_modbus::client::Context;

use crate::OWNER_PASSWORD;
use crate::netns::{DEVICE_IP, Namespace, TAP};

/// How long hal-sim may take to print its "listening" line.
pub const START_TIMEOUT: Duration = Duration::from_secs(10);
/// The Modbus port hal-sim listens on in the tests (each test has its own namespace).
pub const PORT: u16 = 502;

/// The hal-sim binary: `HAL_SIM_BIN`, or `target/debug/hal-sim` of this workspace.
pub fn binary() -> PathBuf {
    crate::host_binary("HAL_SIM_BIN", "hal-sim")
}

/// A running hal-sim in a namespace of its own; killed (and the namespace
/// deleted) on drop.
#[derive(Debug)]
pub struct HalSim {
    child: Child,
    /// hal-sim's stdout, line by line (in a mutex: a `HalSim` is shared
    /// with the client's thread).
    lines: Mutex<mpsc::Receiver<String>>,
    control: PathBuf,
    log: PathBuf,
    /// The arguments after the TAP, the address and the control socket.
    args: Vec<String>,
    http_port: u16,
    ns: Namespace,
}

impl HalSim {
    /// Starts hal-sim on a new namespace's TAP at 198.18.0.2 with a control
    /// socket, plus `args`, and waits for its "listening" line. Its settings
    /// store is in memory, its HTTP API on port 80 (unless `args` say
    /// otherwise: `--state FILE`, `--http-port N`).
    pub fn start(args: &[&str]) -> Self {
        Self::start_with(None, HTTP_PORT, args)
    }

    /// Starts hal-sim as [`HalSim::start`] does, with its settings store in
    /// `state` (a file kept across runs; `None`: in memory) and its HTTP API
    /// on `http_port` (0: none).
    pub fn start_with(state: Option<&Path>, http_port: u16, args: &[&str]) -> Self {
        Self::start_in(Namespace::new().expect("a network namespace with a TAP"), state, http_port, args)
    }

    /// Starts hal-sim as [`HalSim::start_with`] does, in `ns`, a namespace
    /// the test made (with a DHCP server on its TAP, say) and hands over.
    pub fn start_in(ns: Namespace, state: Option<&Path>, http_port: u16, args: &[&str]) -> Self {
        let dir = std::env::temp_dir();
        let control = dir.join(format!("{}.control.sock", ns.name()));
        let log = dir.join(format!("{}.hal-sim.log", ns.name()));
        let mut own = Vec::new();
        if let Some(state) = state {
            own.extend(["--state".to_owned(), state.to_str().expect("a UTF-8 state path").to_owned()]);
        }
        own.extend(["--http-port".to_owned(), http_port.to_string()]);
        let args: Vec<String> = own.into_iter().chain(args.iter().map(|a| a.to_string())).collect();
        let (child, lines) = spawn(&ns, &control, &log, &args, false);
        let mut sim = Self { child, lines: Mutex::new(lines), control, log, args, http_port, ns };
        sim.wait_ready();
        sim
    }

    /// Kills hal-sim at once (SIGKILL: a power cut) and waits for it to be gone.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Kills hal-sim (if it runs) and starts it again in the same namespace
    /// with the same arguments (the same state file), as a power cycle does;
    /// waits for its "listening" line.
    pub fn restart(&mut self) {
        self.kill();
        let (child, lines) = spawn(&self.ns, &self.control, &self.log, &self.args, true);
        self.child = child;
        self.lines = Mutex::new(lines);
        self.wait_ready();
    }

    /// Waits for hal-sim's next "listening" line: after a start, or after a
    /// reboot (when hal-sim executes itself again, the same process).
    pub fn wait_ready(&mut self) {
        let deadline = Instant::now() + START_TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let lines = self.lines.get_mut().unwrap_or_else(std::sync::PoisonError::into_inner);
            match lines.recv_timeout(left) {
                Ok(line) if line.starts_with("hal-sim: modbus tcp listening on ") => {
                    let expected = format!("hal-sim: modbus tcp listening on {DEVICE_IP}:");
                    assert!(line.starts_with(&expected) && line.ends_with(&format!("(tap {TAP})")), "{line}");
                    return;
                }
                Ok(_) => {}
                Err(_) => {
                    let status = self.child.try_wait().ok().flatten();
                    panic!("hal-sim did not say it was listening (exit: {status:?}); its log:\n{}", self.log());
                }
            }
        }
    }

    /// hal-sim's process id (the same across a reboot, which is an exec).
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// A curl command inside the namespace, to hal-sim's HTTP API at `path`,
    /// quiet, with a 5 s limit; it prints the body, a newline and the status
    /// code (read it with [`Reply::parse`]). Add the method, the body, the
    /// credentials and the source address as curl's arguments.
    pub fn curl(&self, path: &str) -> std::process::Command {
        let mut command = self.ns.command("curl");
        command
            .args(["-sS", "-m", "5", "-w", "\n%{http_code}"])
            .arg(format!("http://{DEVICE_IP}:{}{path}", self.http_port))
            .stdin(Stdio::null());
        command
    }

    /// Runs curl (see [`HalSim::curl`]) with `args` and returns the reply.
    pub fn http(&self, path: &str, args: &[&str]) -> Reply {
        let output = self.curl(path).args(args).output().expect("curl runs");
        Reply::parse(&output.stdout)
            .unwrap_or_else(|| panic!("curl {path} {args:?} failed: {}", String::from_utf8_lossy(&output.stderr)))
    }

    /// `GET path`.
    pub fn get(&self, path: &str) -> Reply {
        self.http(path, &[])
    }

    /// Sets the first admin password, [`OWNER_PASSWORD`], as its owner does
    /// first, unless the test set it already: until one is set a device
    /// takes no other change (docs/http-api.md, "The first password").
    /// Returns it, for the changes that follow.
    pub fn claim(&self) -> &'static str {
        if self.get("/api/status").json()["admin"]["password_set"] != true {
            let reply = self.put("/api/password", &format!(r#"{{"password": "{OWNER_PASSWORD}"}}"#), None);
            assert_eq!(reply.status, 200, "the first password: {}", reply.body);
        }
        OWNER_PASSWORD
    }

    /// `PUT path` with the JSON `body`, and `admin:PASSWORD` credentials when given.
    pub fn put(&self, path: &str, body: &str, password: Option<&str>) -> Reply {
        let credentials = password.map(|p| format!("admin:{p}"));
        let mut args = vec!["-X", "PUT", "-H", "Content-Type: application/json", "--data-binary", body];
        if let Some(credentials) = &credentials {
            args.extend(["-u", credentials]);
        }
        self.http(path, &args)
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

    /// The counters, from the control socket's `get stats`: name to value.
    pub fn stats(&self) -> std::collections::HashMap<String, u32> {
        self.control_ok("get stats")
            .split_whitespace()
            .map(|pair| {
                let (name, value) = pair.split_once('=').expect("name=value");
                (name.to_owned(), value.parse().expect("a count"))
            })
            .collect()
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

/// Starts hal-sim in `ns` with `args` after the TAP, the address and the
/// control socket; its log goes to `log` (appended to when `append`), its
/// stdout to the receiver, line by line.
fn spawn(ns: &Namespace, control: &Path, log: &Path, args: &[String], append: bool) -> (Child, mpsc::Receiver<String>) {
    let stderr = std::fs::OpenOptions::new()
        .create(true)
        .append(append)
        .write(true)
        .truncate(!append)
        .open(log)
        .expect("a log file in the temp dir");
    let mut child = ns
        .command(binary())
        .args(["--tap", TAP, "--ip", &format!("{DEVICE_IP}/24"), "--control"])
        .arg(control)
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
    (child, rx)
}

/// hal-sim's HTTP port unless told otherwise.
pub const HTTP_PORT: u16 = 80;

/// An HTTP response as curl printed it: the status code and the body.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    pub status: u16,
    pub body: String,
}

impl Reply {
    /// Reads curl's output (`-w '\n%{http_code}'`): `None` when curl got no
    /// response (it prints status 000).
    pub fn parse(output: &[u8]) -> Option<Self> {
        let text = String::from_utf8_lossy(output);
        let (body, code) = text.rsplit_once('\n')?;
        let status = code.trim().parse().ok().filter(|&status| status != 0)?;
        Some(Self { status, body: body.to_owned() })
    }

    /// The body as JSON (every response of the API is).
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.body).unwrap_or_else(|e| panic!("not JSON ({e}): {:?}", self.body))
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

/// What hal-sim reports in registers 256-258: its simulated robot
/// controller's version (not the firmware's, which is in 0x2B).
pub fn controller_version() -> [u16; 3] {
    sim_robot::CONTROLLER_VERSION.registers()
}

/// The firmware version the hal-sim binary was built from, as it reports it
/// in Read Device Identification (from `hal-sim --version`: `hal-sim X (firmware A.B.C)`).
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
