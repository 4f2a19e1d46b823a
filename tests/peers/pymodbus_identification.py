#!/usr/bin/env python3
"""Read Device Identification (2B/0E) and Diagnostics (08) of hal-sim, as
pymodbus' client asks for them.

Run inside the network namespace where hal-sim listens (the Rust test
tests/tests/hal_sim_identification.rs does this):
    python3 pymodbus_identification.py HOST PORT FIRMWARE_VERSION DEVICE_NAME
Prints one line per check and closes with "N passed, N failed"; exits 1 on
any failure. Needs `pip install pymodbus` (3.x).
"""
import sys

from pymodbus.client import ModbusTcpClient

host, port, version, name = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
passed = failed = 0

# What hal-sim answers (docs/data-map.md, Read Device Identification).
OBJECTS = {
    0: b"mbio",
    1: b"mbio-tcp-io",
    2: version.encode(),
    3: b"",
    4: b"Modbus TCP I/O adapter",
    5: b"hal-sim",
    6: name.encode(),
}


def check(label, condition, detail=""):
    global passed, failed
    if condition:
        passed += 1
        print(f"ok   {label}")
    else:
        failed += 1
        print(f"FAIL {label} {detail}")


def exception(rr, code):
    return rr.isError() and getattr(rr, "exception_code", None) == code


client = ModbusTcpClient(host, port=port, timeout=3)
check("connect", client.connect())

# Read Device Identification.
rr = client.read_device_information(read_code=1, object_id=0, device_id=1)
check("basic: objects 0-2", not rr.isError() and rr.information == {i: OBJECTS[i] for i in range(3)}, rr)
check("conformity level 0x82", not rr.isError() and rr.conformity == 0x82, rr)
check("nothing more follows", not rr.isError() and rr.more_follows == 0 and rr.next_object_id == 0, rr)

rr = client.read_device_information(read_code=2, object_id=0, device_id=1)
check("regular: all seven objects in one reply", not rr.isError() and rr.information == OBJECTS, rr)
check("regular: seven counted", not rr.isError() and rr.number_of_objects == 7, rr)

rr = client.read_device_information(read_code=2, object_id=4, device_id=1)
check("regular from object 4", not rr.isError() and rr.information == {i: OBJECTS[i] for i in (4, 5, 6)}, rr)

rr = client.read_device_information(read_code=1, object_id=5, device_id=1)
check("basic from a regular object starts at 0", not rr.isError() and sorted(rr.information) == [0, 1, 2], rr)

for object_id in range(7):
    rr = client.read_device_information(read_code=4, object_id=object_id, device_id=1)
    check(f"object {object_id} alone", not rr.isError() and rr.information == {object_id: OBJECTS[object_id]}, rr)

rr = client.read_device_information(read_code=4, object_id=7, device_id=1)
check("object 7: exception 02", exception(rr, 2), rr)
rr = client.read_device_information(read_code=4, object_id=0x80, device_id=1)
check("object 0x80: exception 02", exception(rr, 2), rr)
rr = client.read_device_information(read_code=3, object_id=0, device_id=1)
check("read code 03 (extended): exception 03", exception(rr, 3), rr)

# Diagnostics.
rr = client.diag_query_data(b"\x12\x34\x56\x78", device_id=1)
check("return query data echoes", not rr.isError() and rr.message == b"\x12\x34\x56\x78", rr)

rr = client.diag_clear_counters(device_id=1)
check("clear counters", not rr.isError(), rr)
rr = client.diag_read_bus_message_count(device_id=1)
check("bus messages after a clear: the clear", not rr.isError() and rr.message == 1, rr)
rr = client.diag_read_device_message_count(device_id=1)
check("server messages: the clear and the read before", not rr.isError() and rr.message == 2, rr)
client.read_holding_registers(436, count=1, device_id=1)
rr = client.diag_read_bus_exception_error_count(device_id=1)
check("exceptions: the read past the end", not rr.isError() and rr.message == 1, rr)
for label, call in [
    ("communication errors", client.diag_read_bus_comm_error_count),
    ("no response", client.diag_read_device_no_response_count),
    ("overrun", client.diag_read_bus_char_overrun_count),
]:
    rr = call(device_id=1)
    check(f"{label}: 0", not rr.isError() and rr.message == 0, rr)

for label, call in [
    ("restart communications (01)", lambda: client.diag_restart_communication(False, device_id=1)),
    ("diagnostic register (02)", lambda: client.diag_read_diagnostic_register(device_id=1)),
    ("NAK count (10)", lambda: client.diag_read_device_nak_count(device_id=1)),
    ("busy count (11)", lambda: client.diag_read_device_busy_count(device_id=1)),
    ("clear overrun (14)", lambda: client.diag_clear_overrun_counter(device_id=1)),
]:
    rr = call()
    check(f"{label}: exception 01", exception(rr, 1), rr)

rr = client.read_holding_registers(128, count=1, device_id=1)
check("the connection survives it all", not rr.isError() and rr.registers == [0], rr)

client.close()
print(f"{passed} passed, {failed} failed")
sys.exit(1 if failed else 0)
