#!/usr/bin/env python3
"""pymodbus's Modbus/TCP Security client (ModbusTlsClient) against a device:
HOST PORT CERT KEY SERVER_CERT. With CERT and KEY ("-" for none) as its
client certificate, and the device's certificate SERVER_CERT as the one
it trusts (the device's name or address checked against it), it reads
coils 16-19 and writes coil 16 on, then off. Prints one JSON object:

  {"connected": bool, "read": [bools] | {"exception": code} | null,
   "write": "ok" | {"exception": code} | null, "error": text | null}
"""
import json
import ssl
import sys

from pymodbus.client import ModbusTlsClient
from pymodbus.exceptions import ModbusException

host, port, cert, key, server_cert = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5]


class DeviceContext(ssl.SSLContext):
    """pymodbus wraps its socket without a server_hostname; this names the
    device (its address), so that its certificate is checked against it."""

    def wrap_socket(self, sock, *args, **kwargs):
        kwargs.setdefault("server_hostname", host)
        return super().wrap_socket(sock, *args, **kwargs)


context = DeviceContext(ssl.PROTOCOL_TLS_CLIENT)
context.minimum_version = ssl.TLSVersion.TLSv1_2
context.load_verify_locations(server_cert)
context.check_hostname = True
if cert != "-":
    context.load_cert_chain(cert, key)
result = {"connected": False, "read": None, "write": None, "error": None}
client = ModbusTlsClient(host, port=port, sslctx=context, timeout=3, retries=0)
try:
    result["connected"] = bool(client.connect())
    if result["connected"]:
        rr = client.read_coils(16, count=4, device_id=1)
        result["read"] = {"exception": rr.exception_code} if rr.isError() else list(rr.bits[:4])
        wr = client.write_coil(16, True, device_id=1)
        result["write"] = {"exception": wr.exception_code} if wr.isError() else "ok"
        if not wr.isError():
            client.write_coil(16, False, device_id=1)
except (ModbusException, OSError, ssl.SSLError) as error:
    result["error"] = f"{type(error).__name__}: {error}"
finally:
    client.close()
print(json.dumps(result))
