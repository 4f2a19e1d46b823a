#!/usr/bin/env python3
"""Abuse of a Modbus/TCP Security port with python's ssl (OpenSSL), for the
TLS abuse tests (tests/src/tls_abuse.rs). The first argument is the mode:

  hello HOST
      prints a real ClientHello (TLS 1.2-1.3, as this client sends it to
      HOST) as hex, and connects nowhere.
  flood HOST PORT RATE SECONDS CERT_DIR
      starts RATE handshakes a second for SECONDS, each on a thread of its
      own: in turn with CERT_DIR's operator.pem, its stranger.pem (another
      CA) and no certificate; the server's certificate is not checked.
  slow HOST PORT CERT KEY DELAY_MS LIMIT_S
      one real handshake with CERT and KEY whose bytes are sent one at a
      time, DELAY_MS apart, until it ends or LIMIT_S pass.
  hello-junk HOST PORT COUNT
      COUNT connections that each send a real ClientHello, then 4 KiB of
      random bytes, and read until the server closes (at most 15 s).

Each mode but `hello` prints one JSON object: what happened, by outcome.
"""
import json
import os
import socket
import ssl
import sys
import threading
import time


def context(cert=None, key=None):
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    if cert:
        ctx.load_cert_chain(cert, key)
    return ctx


def client_hello(host):
    """The first flight of a handshake, made in memory."""
    incoming, outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
    tls = context().wrap_bio(incoming, outgoing, server_hostname=host)
    try:
        tls.do_handshake()
    except ssl.SSLWantReadError:
        pass
    return outgoing.read()


def outcome_of(error):
    if isinstance(error, ConnectionRefusedError):
        return "refused"
    if isinstance(error, (ConnectionResetError, BrokenPipeError)):
        return "reset"
    if isinstance(error, (socket.timeout, TimeoutError)):
        return "timeout"
    if isinstance(error, ssl.SSLError):
        return "tls_error"
    return "other:" + type(error).__name__


def flood(host, port, rate, seconds, cert_dir):
    kinds = [
        ("operator", context(os.path.join(cert_dir, "operator.pem"), os.path.join(cert_dir, "operator.key"))),
        ("stranger", context(os.path.join(cert_dir, "stranger.pem"), os.path.join(cert_dir, "stranger.key"))),
        ("none", context()),
    ]
    counts = {}
    lock = threading.Lock()

    def attempt(kind, ctx):
        started = time.monotonic()
        try:
            with socket.create_connection((host, port), timeout=3) as raw:
                with ctx.wrap_socket(raw, server_hostname=host) as tls:
                    # TLS 1.3: the server judges the client's certificate
                    # after the client's side is done; a read shows it.
                    tls.settimeout(1)
                    try:
                        data = tls.recv(1)
                        outcome = "handshake_closed" if not data else "handshake_data"
                    except (socket.timeout, TimeoutError):
                        outcome = "handshake_open"
                    except (ssl.SSLError, OSError):
                        outcome = "handshake_closed"
        except Exception as error:  # noqa: BLE001: every outcome is counted
            outcome = outcome_of(error)
        with lock:
            key = f"{kind}:{outcome}"
            counts[key] = counts.get(key, 0) + 1
            counts["slowest_s"] = max(counts.get("slowest_s", 0), round(time.monotonic() - started, 3))

    threads = []
    start = time.monotonic()
    total = int(rate * seconds)
    for i in range(total):
        due = start + i / rate
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        kind, ctx = kinds[i % len(kinds)]
        thread = threading.Thread(target=attempt, args=(kind, ctx), daemon=True)
        thread.start()
        threads.append(thread)
    started_in = time.monotonic() - start
    for thread in threads:
        thread.join(10)
    counts["attempts"] = total
    counts["started_in_s"] = round(started_in, 3)
    counts["unfinished"] = sum(thread.is_alive() for thread in threads)
    return counts


def slow(host, port, cert, key, delay_ms, limit_s):
    incoming, outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
    tls = context(cert, key).wrap_bio(incoming, outgoing, server_hostname=host)
    raw = socket.create_connection((host, port), timeout=5)
    raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    raw.setblocking(False)
    started = time.monotonic()
    sent = 0
    result = {"result": None}
    pending = b""
    while time.monotonic() - started < limit_s:
        try:
            tls.do_handshake()
            result["result"] = "handshake_done"
        except ssl.SSLWantReadError:
            pass
        except ssl.SSLError as error:
            result["result"] = f"tls_error: {error.reason}"
        pending += outgoing.read()
        if result["result"] and not pending:
            break
        try:
            data = raw.recv(4096)
            if not data:
                result["result"] = result["result"] or "closed"
                break
            incoming.write(data)
        except BlockingIOError:
            pass
        except OSError as error:
            result["result"] = result["result"] or outcome_of(error)
            break
        if pending:
            try:
                raw.send(pending[:1])
                pending = pending[1:]
                sent += 1
            except OSError as error:
                result["result"] = outcome_of(error)
                break
        time.sleep(delay_ms / 1000)
    if result["result"] == "handshake_done":
        # TLS 1.3: the server may still refuse the certificate; a read shows it.
        raw.setblocking(True)
        raw.settimeout(2)
        try:
            data = raw.recv(4096)
            incoming.write(data)
            if data:
                try:
                    tls.read(1)
                except ssl.SSLWantReadError:
                    pass
            result["after"] = "closed" if not data else "open"
        except (socket.timeout, TimeoutError):
            result["after"] = "open"
        except (ssl.SSLError, OSError) as error:
            result["after"] = f"refused: {error}"
    raw.close()
    result["result"] = result["result"] or "limit"
    result["bytes_sent"] = sent
    result["seconds"] = round(time.monotonic() - started, 3)
    result["version"] = tls.version()
    return result


def hello_junk(host, port, count):
    hello = client_hello(host)
    counts = {}
    for _ in range(count):
        started = time.monotonic()
        try:
            with socket.create_connection((host, port), timeout=15) as raw:
                raw.sendall(hello)
                time.sleep(0.05)
                try:
                    raw.sendall(os.urandom(4096))
                except OSError:
                    pass
                got = 0
                while True:
                    data = raw.recv(4096)
                    if not data:
                        outcome = "closed"
                        break
                    got += len(data)
                counts["bytes_from_server"] = counts.get("bytes_from_server", 0) + got
        except Exception as error:  # noqa: BLE001: every outcome is counted
            outcome = outcome_of(error)
        counts[outcome] = counts.get(outcome, 0) + 1
        counts["slowest_s"] = max(counts.get("slowest_s", 0), round(time.monotonic() - started, 3))
    return counts


def main():
    mode, args = sys.argv[1], sys.argv[2:]
    if mode == "hello":
        print(client_hello(args[0]).hex())
        return
    if mode == "flood":
        result = flood(args[0], int(args[1]), float(args[2]), float(args[3]), args[4])
    elif mode == "slow":
        result = slow(args[0], int(args[1]), args[2], args[3], float(args[4]), float(args[5]))
    elif mode == "hello-junk":
        result = hello_junk(args[0], int(args[1]), int(args[2]))
    else:
        sys.exit(f"unknown mode {mode}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
