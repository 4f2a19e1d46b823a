#!/usr/bin/env python3
"""Smoke test of hal-sim with a second independent client: pymodbus.

Run inside the network namespace where hal-sim listens (the Rust test
tests/tests/hal_sim_pymodbus.rs does this):
    python3 pymodbus_smoke.py HOST PORT CONTROL_SOCKET
Prints one line per check and closes with "N passed, N failed"; exits 1 on
any failure. Needs `pip install pymodbus` (3.x).
"""
import socket
import sys

from pymodbus.client import ModbusTcpClient

host, port, control_path = sys.argv[1], int(sys.argv[2]), sys.argv[3]
passed = failed = 0


def check(name, condition, detail=""):
    global passed, failed
    if condition:
        passed += 1
        print(f"ok   {name}")
    else:
        failed += 1
        print(f"FAIL {name} {detail}")


def control(line):
    with socket.socket(socket.AF_UNIX) as s:
        s.connect(control_path)
        s.sendall((line + "\n").encode())
        return s.makefile().readline().strip()


client = ModbusTcpClient(host, port=port, timeout=3)
check("connect", client.connect())

rr = client.read_holding_registers(256, count=3, device_id=1)
check("read version registers", not rr.isError() and len(rr.registers) == 3, rr)

rr = client.write_coil(16, True, device_id=1)
check("write single coil", not rr.isError(), rr)
rr = client.read_coils(16, count=8, device_id=1)
check("coil reads back", not rr.isError() and rr.bits[0] and not any(rr.bits[1:8]), rr)
rr = client.read_holding_registers(1, count=1, device_id=1)
check("register view of the coil", not rr.isError() and rr.registers == [1], rr)
check("control socket sees the output", control("get do") == "ok 1")

rr = client.write_registers(128, [0x000A, 0x0102, 0xFFFF], device_id=1)
check("write multiple registers", not rr.isError(), rr)
rr = client.read_holding_registers(128, count=3, device_id=1)
check("registers read back", not rr.isError() and rr.registers == [0x000A, 0x0102, 0xFFFF], rr)

rr = client.write_coils(38, [True, False, True], device_id=1)
check("write multiple coils", not rr.isError(), rr)
check("tool outputs on the control socket", control("get tool-do") == "ok 5")

check("set an input", control("set di 3 1") == "ok")
rr = client.read_coils(0, count=4, device_id=1)
check("input visible as a coil", not rr.isError() and rr.bits[:4] == [False, False, True, False], rr)

rr = client.write_register(2, 1, device_id=1)
check("reserved write is exception 02", rr.isError() and rr.exception_code == 2, rr)
rr = client.read_holding_registers(430, count=10, device_id=1)
check("read past the end is exception 02", rr.isError() and rr.exception_code == 2, rr)
rr = client.write_register(16, 20001, device_id=1)
check("analog output out of range is exception 03", rr.isError() and rr.exception_code == 3, rr)

check("e-stop on the control socket", control("robot estop press").startswith("ok 6"))
rr = client.read_holding_registers(259, count=3, device_id=1)
check("e-stop in registers 259-261", not rr.isError() and rr.registers == [6, 0, 1], rr)
rr = client.read_coils(261, count=1, device_id=1)
check("e-stop coil 261", not rr.isError() and rr.bits[0], rr)

client.close()
print(f"{passed} passed, {failed} failed")
sys.exit(1 if failed else 0)
