"""What scripts/bench-mcu and scripts/bench-tls share: the mps2-an386 image
as it ships, QEMU with slirp and our TCG plugin (bench/qemu/request_windows.c,
which counts the guest's instructions per window, from a frame's interrupt
to the core's idle), the plugin's window lines, and the raw-socket Modbus
client (its requests, each reply checked).

Every port is forwarded on 127.0.0.1 only (slirp's hostfwd, `restrict=on`:
the guest reaches nothing outside). Needs no root.
"""

import os
import re
import shutil
import socket
import struct
import subprocess
import tempfile
import time
from pathlib import Path

import benchnet
from benchnet import say

ROOT = benchnet.ROOT
TARGET = "thumbv7em-none-eabihf"
PLUGIN_SOURCE = ROOT / "bench" / "qemu" / "request_windows.c"
# QEMU's mps2 machine RAM (the PSRAM the firmware keeps its settings in): the state file.
STATE_LEN = 16 * 1024 * 1024
MODBUS_PORT = 502
UNIT = 1
READY_TIMEOUT = 30.0
# A boot is served steadily this long after its first answer (see wait_ready).
READY_SETTLE = 1.0
REPLY_TIMEOUT = 2.0
QEMU_TIMEOUT = 600


class Setup(Exception):
    """The bench cannot run: exit 2 with the reason."""


class BenchError(Exception):
    """A request went wrong, or the windows do not match the requests: exit 1."""


# --- setup -------------------------------------------------------------------


# The tools the benches run, and the Debian package of each.
TOOLS = {"qemu-system-arm": "qemu-system-arm", "gcc": "gcc", "llvm-nm": "llvm", "llvm-size": "llvm",
         "llvm-symbolizer": "llvm"}


def require_tools():
    path = os.environ.get("PATH", "").split(":")
    missing = [tool for tool in TOOLS if not any(os.access(Path(d) / tool, os.X_OK) for d in path)]
    if missing:
        packages = " ".join(sorted({TOOLS[tool] for tool in missing}))
        raise Setup(f"{', '.join(missing)} missing: run scripts/setup as root, or apt-get install {packages}")


def build_image(name):
    """The mps2-an386 release image as it ships; `name` prefixes the messages."""
    say(f"{name}: building the mps2-an386 image (release, as it ships)")
    result = subprocess.run(["cargo", "build", "-q", "-p", "mps2-an386", "--release", "--target", TARGET], cwd=ROOT)
    if result.returncode != 0:
        raise Setup("the mps2-an386 build failed")
    return benchnet.target_dir() / TARGET / "release" / "mps2-an386"


def build_plugin():
    out_dir = benchnet.target_dir() / "bench-mcu"
    out_dir.mkdir(parents=True, exist_ok=True)
    plugin = out_dir / "request_windows.so"
    if not plugin.exists() or plugin.stat().st_mtime < PLUGIN_SOURCE.stat().st_mtime:
        command = ["gcc", "-O2", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC", "-o", str(plugin),
                   str(PLUGIN_SOURCE)]
        result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0:
            raise Setup(f"building the QEMU plugin failed:\n{result.stderr}")
    return plugin


def vector_handlers(elf):
    """The addresses of the LAN9118's interrupt handler and of SysTick's (cortex-m-rt's symbols)."""
    out = subprocess.run(["llvm-nm", "--defined-only", str(elf)], capture_output=True, text=True).stdout
    symbols = {parts[2]: int(parts[0], 16) for parts in (line.split() for line in out.splitlines()) if len(parts) == 3}
    try:
        return symbols["DefaultHandler"], symbols["SysTick"]
    except KeyError as e:
        raise Setup(f"{elf} has no symbol {e}: not the mps2-an386 image?") from None


def image_size(elf):
    out = subprocess.run(["llvm-size", str(elf)], capture_output=True, text=True).stdout.split("\n")
    fields = out[1].split() if len(out) > 1 else []
    return f"text {fields[0]} B" if fields else "size unknown"


def qemu_version():
    out = subprocess.run(["qemu-system-arm", "--version"], capture_output=True, text=True).stdout.split()
    return out[3] if len(out) > 3 else "?"


# --- QEMU ----------------------------------------------------------------------


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Qemu:
    """The image in QEMU with an erased state file, slirp forwarding each of
    `guest_ports` from a free port of 127.0.0.1 (`port(guest)`), and the
    plugin writing its windows to `out` (with `live`, as they happen).
    `with` it: on leaving, QEMU is told to quit and its files are removed."""

    def __init__(self, elf, plugin, handlers, guest_ports, live=False):
        irq, tick = handlers
        self.dir = Path(tempfile.mkdtemp(prefix="bench-mcu."))
        self.state, self.ctl, self.out = self.dir / "psram.state", self.dir / "phase", self.dir / "windows"
        self.monitor = self.dir / "monitor.sock"
        self.state.write_bytes(b"\xff" * STATE_LEN)
        self.ctl.write_text("0\n")
        self.ports = {guest: free_port() for guest in guest_ports}
        forwards = ",".join(f"hostfwd=tcp:127.0.0.1:{host}-:{guest}" for guest, host in self.ports.items())
        plugin_arg = f"{plugin},irq={irq:#x},tick={tick:#x},ctl={self.ctl},out={self.out}" + (",live=1" if live else "")
        command = [
            "timeout", "-k", "5", str(QEMU_TIMEOUT), "qemu-system-arm",
            "-M", "mps2-an386,memory-backend=psram", "-cpu", "cortex-m4", "-display", "none", "-serial", "none",
            "-object", f"memory-backend-file,id=psram,size={STATE_LEN},mem-path={self.state},share=on",
            "-semihosting-config", "enable=on,target=native",
            "-monitor", f"unix:{self.monitor},server=on,wait=off",
            "-nic", f"user,model=lan9118,restrict=on,{forwards}",
            "-plugin", plugin_arg, "-kernel", str(elf),
        ]
        # The firmware's log goes to a file: a pipe whose reader died would stall it.
        with open(self.dir / "firmware.log", "wb") as log, open(self.dir / "qemu.stderr", "wb") as err:
            self.process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=log, stderr=err)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.quit()
        shutil.rmtree(self.dir, ignore_errors=True)

    def port(self, guest):
        return self.ports[guest]

    def set_phase(self, phase):
        # In place (the plugin keeps the file open and reads it at each window).
        with open(self.ctl, "r+") as f:
            f.write(f"{phase:<4}\n")

    def running(self):
        return self.process.poll() is None

    def stderr(self):
        return (self.dir / "qemu.stderr").read_text(errors="replace")

    def quit(self):
        if self.process.poll() is None:
            try:
                with socket.socket(socket.AF_UNIX) as m:
                    m.settimeout(5)
                    m.connect(str(self.monitor))
                    m.recv(4096)
                    m.sendall(b"quit\n")
                    # The socket stays open until QEMU is gone: QEMU reads the command a character at a
                    # time, and what is left unread when the client hangs up is dropped.
                    self.process.wait(timeout=20)
            except (OSError, subprocess.TimeoutExpired):
                self.process.terminate()
                self.process.wait()
        return self.process.returncode

    def keep(self, directory):
        """Copies the firmware log and the plugin output to directory, numbered."""
        directory.mkdir(parents=True, exist_ok=True)
        number = len(list(directory.glob("windows.*"))) + 1
        for name in ("windows", "firmware.log"):
            if (self.dir / name).exists():
                (directory / f"{name}.{number}").write_bytes((self.dir / name).read_bytes())


# --- the plugin's output ---------------------------------------------------------


class Window:
    """One `W` line of the plugin: a window, from a frame's interrupt to the core's idle."""

    FIELDS = ("phase", "instructions", "irqs", "ticks", "rx_frames", "tx_frames",
              "irq_last", "rx_status", "rx_data", "tx_first", "tx_last", "outside", "outside_ticks")

    def __init__(self, values):
        for name, value in zip(self.FIELDS, values):
            setattr(self, name, value)

    def is_request(self):
        # request_windows.c's is_request: one frame in, one frame out.
        return self.rx_frames == 1 and self.tx_frames == 1

    def frame_to_reply(self):
        return self.tx_last + 1


def window(fields):
    """The Window of a `W` line's fields (after the `W`)."""
    return Window([int(v) for v in fields])


# --- where the instructions go ---------------------------------------------------


def symbolize(elf, addresses):
    """address -> [(function, file)], innermost frame first (llvm-symbolizer, inlined frames)."""
    addresses = sorted(addresses)
    command = ["llvm-symbolizer", f"--obj={elf}", "--functions=linkage", "--demangle", "--inlining"]
    out = subprocess.run(command, input="".join(f"{a:#x}\n" for a in addresses), capture_output=True, text=True,
                         check=True).stdout
    frames = {}
    for address, block in zip(addresses, out.split("\n\n")):
        lines = block.strip("\n").split("\n")
        frames[address] = [(clean_name(lines[i]), lines[i + 1]) for i in range(0, len(lines) - 1, 2)]
    return frames


MANGLE = [("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$C$", ","), ("$RF$", "&"), ("$u7b$", "{"),
          ("$u7d$", "}"), ("$BP$", "*"), ("$u27$", "'"), ("$u5b$", "["), ("$u5d$", "]"), ("$u3b$", ";")]


def clean_name(name):
    name = re.sub(r"::h[0-9a-f]{16}$", "", name)
    if name.startswith("_$"):
        name = name[1:]
    for code, text in MANGLE:
        name = name.replace(code, text)
    return name.replace("..", "::")



# --- the Modbus client -------------------------------------------------------------


class Case:
    def __init__(self, name, pdu, reply_len):
        self.name, self.pdu, self.reply_len = name, pdu, reply_len


def read_registers(start, count):
    return struct.pack(">BHH", 3, start, count)


def write_registers(start, values):
    return struct.pack(">BHHB", 16, start, len(values), 2 * len(values)) + struct.pack(f">{len(values)}H", *values)


def connect(port):
    conn = socket.create_connection(("127.0.0.1", port), timeout=REPLY_TIMEOUT)
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return conn


def wait_ready(qemu, port):
    """Until a request on `port` is answered READY_SETTLE after the first answer.

    slirp accepts before the firmware listens, and resets then: so try
    again. And the firmware's network policy, at its first look at the link
    (up to 100 ms after boot), starts DHCP over the lease the stack already
    has, which resets the connections made meanwhile: so wait that out.
    """
    deadline = time.monotonic() + READY_TIMEOUT
    version = Case("version", read_registers(256, 3), 7 + 2 + 6)
    first = None
    while time.monotonic() < deadline:
        if not qemu.running():
            raise BenchError(f"QEMU stopped at start-up ({qemu.process.returncode})")
        try:
            with connect(port) as conn:
                request(conn, version, 0)
            now = time.monotonic()
            first = first or now
            if now - first >= READY_SETTLE:
                return
        except (OSError, BenchError):
            pass
        time.sleep(0.2)
    raise BenchError(f"the firmware did not answer within {READY_TIMEOUT:.0f} s")


def request(conn, case, transaction):
    try:
        exchange(conn, case, transaction)
    except OSError as e:
        raise BenchError(f"{case.name}, request {transaction}: {e}") from None


def exchange(conn, case, transaction):
    tid = transaction & 0xFFFF
    conn.sendall(struct.pack(">HHHB", tid, 0, len(case.pdu) + 1, UNIT) + case.pdu)
    reply = b""
    while len(reply) < case.reply_len:
        chunk = conn.recv(case.reply_len - len(reply))
        if not chunk:
            raise BenchError(f"{case.name}: the connection closed after {len(reply)} bytes")
        reply += chunk
    check_reply(case, tid, reply)


def check_reply(case, tid, reply):
    r_tid, protocol, length, unit, function = struct.unpack(">HHHBB", reply[:8])
    expected_function = case.pdu[0]
    if (r_tid, protocol, length, unit, function) != (tid, 0, case.reply_len - 6, UNIT, expected_function):
        raise BenchError(f"{case.name}: bad reply {reply.hex()}")
    if function == 3 and reply[8] != case.reply_len - 9:
        raise BenchError(f"{case.name}: bad byte count in {reply.hex()}")
    if function == 16 and reply[8:12] != case.pdu[1:5]:
        raise BenchError(f"{case.name}: the reply does not echo the request: {reply.hex()}")
