#!/usr/bin/env python3
"""The mDNS system tests' independent client: python-zeroconf on the test
namespace's TAP (host side 198.18.0.1), IPv4 only. Prints one JSON line.

    zeroconf-client.py resolve NAME.local. [TIMEOUT_S]
        {"addresses": ["198.18.0.2"]}           (empty when nothing answered)
    zeroconf-client.py browse _modbus._tcp.local. [TIMEOUT_S] [--wait-for INSTANCE]
        {"instances": [{"name": ..., "port": ..., "server": ..., "addresses": [...], "txt": {...}}]}

Options:
    --toward ADDR        query on this machine's interface toward ADDR (a
                         board on the LAN), not on 198.18.0.1
    --wait-for INSTANCE  browse until this instance (NAME._modbus._tcp.local.)
                         is among the found, not only until a first one is
"""

import json
import socket
import sys
import time

from zeroconf import AddressResolverIPv4, IPVersion, ServiceBrowser, ServiceListener, Zeroconf

HOST_SIDE = "198.18.0.1"


def resolve(zc, name, timeout):
    resolver = AddressResolverIPv4(name)
    resolver.request(zc, timeout * 1000)
    return {"addresses": resolver.parsed_addresses()}


class Collect(ServiceListener):
    def __init__(self):
        self.names = []

    def add_service(self, zc, type_, name):
        self.names.append(name)

    def update_service(self, zc, type_, name):
        pass

    def remove_service(self, zc, type_, name):
        pass


def browse(zc, type_, timeout, wanted=None):
    listener = Collect()
    browser = ServiceBrowser(zc, type_, listener)
    deadline = time.monotonic() + timeout
    found = (lambda: wanted in listener.names) if wanted else (lambda: listener.names)
    while not found() and time.monotonic() < deadline:
        time.sleep(0.05)
    browser.cancel()
    instances = []
    for name in listener.names:
        info = zc.get_service_info(type_, name, timeout=int(max(deadline - time.monotonic(), 1) * 1000))
        if info is None:
            instances.append({"name": name})
            continue
        instances.append({
            "name": name,
            "port": info.port,
            "server": info.server,
            "addresses": info.parsed_addresses(),
            "txt": {k.decode(): (v.decode() if v is not None else None) for k, v in info.properties.items()},
        })
    return {"instances": instances}


def interface_toward(address):
    """This machine's address that the route to `address` leaves from."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.connect((address, 5353))
        return probe.getsockname()[0]


def main():
    args, options = [], {}
    argv = sys.argv[1:]
    while argv:
        arg = argv.pop(0)
        if arg in ("--toward", "--wait-for") and argv:
            options[arg] = argv.pop(0)
        else:
            args.append(arg)
    if len(args) not in (2, 3) or args[0] not in ("resolve", "browse"):
        print(__doc__, file=sys.stderr)
        return 2
    command, what = args[0], args[1]
    timeout = float(args[2]) if len(args) > 2 else 5.0
    toward = options.get("--toward")
    interface = interface_toward(toward) if toward else HOST_SIDE
    zc = Zeroconf(interfaces=[interface], ip_version=IPVersion.V4Only)
    try:
        if command == "resolve":
            result = resolve(zc, what, timeout)
        else:
            result = browse(zc, what, timeout, options.get("--wait-for"))
    finally:
        zc.close()
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
