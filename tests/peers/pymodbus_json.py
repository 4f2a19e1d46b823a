#!/usr/bin/env python3
"""pymodbus as the independent check of mbio's reads and writes: runs the
requests given as JSON on argv[3] against HOST PORT and prints the answers
as JSON, one per request.

  ["read_holding", ADDRESS, COUNT] -> [values...]
  ["read_coils", ADDRESS, COUNT]   -> [bools...]
  ["write_register", ADDRESS, VALUE] -> "ok"
  ["write_coil", ADDRESS, BOOL]    -> "ok"
"""
import json
import sys

from pymodbus.client import ModbusTcpClient

host, port, requests = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
client = ModbusTcpClient(host, port=port, timeout=3)
if not client.connect():
    sys.exit(f"no connection to {host}:{port}")
answers = []
for kind, address, arg in requests:
    if kind == "read_holding":
        rr = client.read_holding_registers(address, count=arg, device_id=1)
        answers.append(None if rr.isError() else list(rr.registers))
    elif kind == "read_coils":
        rr = client.read_coils(address, count=arg, device_id=1)
        answers.append(None if rr.isError() else list(rr.bits[:arg]))
    elif kind == "write_register":
        rr = client.write_register(address, arg, device_id=1)
        answers.append(None if rr.isError() else "ok")
    elif kind == "write_coil":
        rr = client.write_coil(address, bool(arg), device_id=1)
        answers.append(None if rr.isError() else "ok")
    else:
        sys.exit(f"unknown request {kind}")
client.close()
print(json.dumps(answers))
