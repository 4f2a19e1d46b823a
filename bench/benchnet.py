"""What scripts/bench-net and scripts/bench-soak share: the builds, the
network namespaces, the servers under test and the load generator.

Every address is in 198.18.0.0/15 (RFC 2544's test bench range) and lives in
network namespaces made here and deleted on exit: no traffic leaves them.

    namespace "client" (mbbench-PID)         namespace "peers" (mbbench-PID-p)
      loadgen (pinned to the client CPU)       libmodbus_server, pymodbus_server
      tap0 198.18.0.1/24 --- hal-sim 198.18.0.2  (pinned to the server CPU)
      veth0 198.18.1.1/24 -------------------- veth1 198.18.1.2/24
      tap1 198.18.3.1/24 --- a second hal-sim 198.18.3.2 (bench-net: with --busy-poll)

The peers sit in a namespace of their own so their traffic really crosses
the veth pair: two ends in one namespace would be short-cut through `lo`.
hal-sim runs in the client namespace on the TAP (its TCP/IP stack is its own).
"""

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TAP_HOST = "198.18.0.1/24"
HAL_SIM_IP = "198.18.0.2"
# A second TAP and hal-sim (`Bench.add_tap`), for another hal-sim in the same run.
TAP1_HOST = "198.18.3.1/24"
HAL_SIM1_IP = "198.18.3.2"
VETH_CLIENT = "198.18.1.1/24"
PEER_IP = "198.18.1.2"
MODBUS_PORT = 502
LIBMODBUS_PORT = 1502
PYMODBUS_PORT = 1503
START_TIMEOUT = 20.0


def say(message):
    print(message, file=sys.stderr, flush=True)


def run(command, **kwargs):
    """Runs a command; raises with its output when it fails."""
    result = subprocess.run(command, capture_output=True, text=True, **kwargs)
    if result.returncode != 0:
        raise RuntimeError(f"`{shlex.join(command)}` failed ({result.returncode}): {result.stderr.strip()}")
    return result.stdout


def target_dir():
    out = run(["cargo", "metadata", "--format-version", "1", "--no-deps"], cwd=ROOT)
    return Path(json.loads(out)["target_directory"])


def cpus():
    """(server CPU, client CPU): BENCH_SERVER_CPU / BENCH_CLIENT_CPU, else the first two this process may use."""
    allowed = sorted(os.sched_getaffinity(0))
    server = int(os.environ.get("BENCH_SERVER_CPU", allowed[0]))
    client = int(os.environ.get("BENCH_CLIENT_CPU", allowed[1] if len(allowed) > 1 else allowed[0]))
    return server, client


def require_root():
    if os.geteuid() != 0:
        say("needs root: it makes network namespaces, a TAP and a veth pair (sudo it)")
        sys.exit(2)


def build_hal_sim():
    """The release hal-sim (or $HAL_SIM_BIN, not rebuilt)."""
    if os.environ.get("HAL_SIM_BIN"):
        path = Path(os.environ["HAL_SIM_BIN"])
        if not path.is_file():
            raise RuntimeError(f"HAL_SIM_BIN={path} is not a file")
        return path
    say("$ cargo build --release -p hal-sim")
    subprocess.run(["cargo", "build", "-q", "--release", "-p", "hal-sim"], cwd=ROOT, check=True)
    return target_dir() / "release" / "hal-sim"


def build_loadgen():
    say("$ cargo build --profile bench -p bench --bin loadgen")
    subprocess.run(["cargo", "build", "-q", "--profile", "bench", "-p", "bench", "--bin", "loadgen"], cwd=ROOT,
                   check=True)
    return target_dir() / "release" / "loadgen"


def build_libmodbus_server():
    """gcc -O2 against Debian's libmodbus-dev (installed when missing and root)."""
    if subprocess.run(["pkg-config", "--exists", "libmodbus"], capture_output=True).returncode != 0:
        if os.geteuid() != 0:
            raise RuntimeError("libmodbus-dev is missing: apt-get install libmodbus-dev")
        say("$ apt-get install -y libmodbus-dev")
        subprocess.run(["apt-get", "install", "-y", "-qq", "libmodbus-dev"], check=True, stdout=subprocess.DEVNULL)
    out_dir = target_dir() / "bench-peers"
    out_dir.mkdir(parents=True, exist_ok=True)
    binary = out_dir / "libmodbus_server"
    source = ROOT / "bench" / "peers" / "libmodbus_server.c"
    flags = run(["pkg-config", "--cflags", "--libs", "libmodbus"]).split()
    run(["gcc", "-O2", "-Wall", "-Wextra", "-o", str(binary), str(source), *flags])
    version = run(["pkg-config", "--modversion", "libmodbus"]).strip()
    return binary, version


def pymodbus_version():
    """pymodbus's version, or None when it is missing (pip install 'pymodbus==3.16.*')."""
    result = subprocess.run([sys.executable, "-c", "import pymodbus; print(pymodbus.__version__)"],
                            capture_output=True, text=True)
    return result.stdout.strip() if result.returncode == 0 else None


class Bench:
    """The namespaces and every process started in them; `close()` (or `with`) removes it all."""

    def __init__(self, peers=True):
        require_root()
        self.client_ns = f"mbbench-{os.getpid()}"
        self.peer_ns = f"{self.client_ns}-p" if peers else None
        self.processes = []
        self.logs = Path(tempfile.mkdtemp(prefix="mbbench-"))
        self.namespaces = []
        try:
            self._make()
        except BaseException:
            self.close()
            raise

    def _make(self):
        ns = self.client_ns
        run(["ip", "netns", "add", ns])
        self.namespaces.append(ns)
        self.ip(ns, "link", "set", "lo", "up")
        self.ip(ns, "tuntap", "add", "dev", "tap0", "mode", "tap")
        self.ip(ns, "addr", "add", TAP_HOST, "dev", "tap0")
        self.ip(ns, "link", "set", "tap0", "up")
        if self.peer_ns:
            peer = self.peer_ns
            run(["ip", "netns", "add", peer])
            self.namespaces.append(peer)
            self.ip(peer, "link", "set", "lo", "up")
            self.ip(ns, "link", "add", "veth0", "type", "veth", "peer", "name", "veth1", "netns", peer)
            self.ip(ns, "addr", "add", VETH_CLIENT, "dev", "veth0")
            self.ip(peer, "addr", "add", f"{PEER_IP}/24", "dev", "veth1")
            self.ip(ns, "link", "set", "veth0", "up")
            self.ip(peer, "link", "set", "veth1", "up")

    def add_tap(self, name, host):
        """Another TAP in the client namespace, `host` (address/prefix) its end."""
        self.ip(self.client_ns, "tuntap", "add", "dev", name, "mode", "tap")
        self.ip(self.client_ns, "addr", "add", host, "dev", name)
        self.ip(self.client_ns, "link", "set", name, "up")

    @staticmethod
    def ip(ns, *args):
        run(["ip", "-n", ns, *args])

    def start(self, name, ns, cpu, command, ready, env=None):
        """Starts `command` in `ns` pinned to `cpu`; waits for `ready` in its stdout. Returns the Popen."""
        out = open(self.logs / f"{name}.out", "w")
        err = open(self.logs / f"{name}.err", "w")
        full = ["ip", "netns", "exec", ns, "taskset", "-c", str(cpu), *map(str, command)]
        process = subprocess.Popen(full, stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                   env={**os.environ, **(env or {})})
        process.name = name
        self.processes.append(process)
        deadline = time.monotonic() + START_TIMEOUT
        while time.monotonic() < deadline:
            if ready in (self.logs / f"{name}.out").read_text():
                return process
            if process.poll() is not None:
                break
            time.sleep(0.05)
        raise RuntimeError(f"{name} did not start: {self.log_tail(name)}")

    def stop(self, process):
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()

    def log_tail(self, name, lines=5):
        text = ""
        for suffix in ("out", "err"):
            path = self.logs / f"{name}.{suffix}"
            if path.exists():
                text += "".join(path.read_text().splitlines(keepends=True)[-lines:])
        return text.strip() or "(no output)"

    def start_hal_sim(self, binary, cpu, args=(), tap="tap0", ip=HAL_SIM_IP, name="hal-sim"):
        return self.start(name, self.client_ns, cpu, [binary, "--tap", tap, "--ip", f"{ip}/24", *args],
                          "listening on", env={"RUST_LOG": os.environ.get("RUST_LOG", "info")})

    def loadgen(self, binary, cpu, target, args):
        """Runs the load generator in the client namespace: (its key=value line as a dict, exit status)."""
        command = ["ip", "netns", "exec", self.client_ns, "taskset", "-c", str(cpu), str(binary),
                   "--target", target, *map(str, args)]
        result = subprocess.run(command, capture_output=True, text=True)
        fields = {}
        for line in result.stdout.splitlines():
            if line.startswith("target="):
                fields = dict(item.split("=", 1) for item in line.split())
        if result.stderr.strip():
            say(result.stderr.strip())
        return fields, result.returncode

    def close(self):
        for process in reversed(self.processes):
            self.stop(process)
        self.processes.clear()
        for ns in reversed(self.namespaces):
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
        self.namespaces.clear()
        shutil.rmtree(self.logs, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.close()
