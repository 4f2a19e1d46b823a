#!/usr/bin/env python3
"""The mDNS system tests' independent client: python-zeroconf on the test
namespace's TAP (host side 198.18.0.1), IPv4 only. Prints one JSON line.

    zeroconf-client.py resolve NAME.local. [TIMEOUT_S]
        {"addresses": ["198.18.0.2"]}           (empty when nothing answered)
    zeroconf-client.py browse _modbus._tcp.local. [TIMEOUT_S]
        {"instances": [{"name": ..., "port": ..., "server": ..., "addresses": [...], "txt": {...}}]}
"""

import json
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


def browse(zc, type_, timeout):
    listener = Collect()
    browser = ServiceBrowser(zc, type_, listener)
    deadline = time.monotonic() + timeout
    while not listener.names and time.monotonic() < deadline:
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


def main():
    if len(sys.argv) < 3 or sys.argv[1] not in ("resolve", "browse"):
        print(__doc__, file=sys.stderr)
        return 2
    command, what = sys.argv[1], sys.argv[2]
    timeout = float(sys.argv[3]) if len(sys.argv) > 3 else 5.0
    zc = Zeroconf(interfaces=[HOST_SIDE], ip_version=IPVersion.V4Only)
    try:
        result = resolve(zc, what, timeout) if command == "resolve" else browse(zc, what, timeout)
    finally:
        zc.close()
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
