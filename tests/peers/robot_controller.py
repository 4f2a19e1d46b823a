#!/usr/bin/env python3
"""The robot controller of the robot link's system tests (tests/tests/hal_sim_link.rs).

usage: robot_controller.py HOST PORT MODE

MODE `pymodbus`: pymodbus's own TCP server (its simulator device), fed
with moving values. The
other modes are a plain asyncio server that answers Read Holding Registers
as told, to make a bad controller:

  good       correct replies
  exception  exception 04 (server device failure) to every request
  wrong-tid  the reply of another transaction
  short      a reply whose byte count promises more than the frame holds
  garbage    random bytes
  slow       correct replies, 1.5 s late
  flaky      correct replies, and every 4th one bad (exception, wrong-tid,
             short, garbage in turn)

The values: registers 256-258 = 2.11.3 (the version), 259 = 2 (OPERATING),
260 = 1 (servo on), 261-264 = 0, and every register of 270-315 and 400-435
(reserved ones too) = the generation: the wall clock in 10 ms steps, mod
65536. A reply carries one generation (one snapshot), so a reader can tell
how old a value is and whether one read mixes two snapshots.

Prints "ready" once it listens. Every function code other than 03 it is
sent is printed as "write FC" (the link must never write).
"""

import asyncio
import os
import struct
import sys
import time

VERSION = [2, 11, 3]
STATUS = [2, 1, 0, 0, 0, 1]  # 259-264: OPERATING, servo on, ..., power button pressed
SLOW_S = 1.5


def generation():
    return (time.time_ns() // 10_000_000) & 0xFFFF


def registers(start, count):
    """Registers start..start+count of one snapshot (0 outside the robot's points)."""
    g = generation()
    values = []
    for address in range(start, start + count):
        if 256 <= address <= 258:
            values.append(VERSION[address - 256])
        elif 259 <= address <= 264:
            values.append(STATUS[address - 259])
        elif 270 <= address <= 315 or 400 <= address <= 435:
            values.append(g)
        else:
            values.append(0)
    return values


async def run_pymodbus(host, port):
    from pymodbus.server import StartAsyncTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    size = 500

    # pymodbus calls the action on each request with the device's
    # registers (from start_address): the values move there, one snapshot
    # per request, written before pymodbus copies the reply out of them.
    async def feed(function_code, start_address, address, count, current_registers, set_values):
        if function_code != 3:
            print(f"write {function_code}", flush=True)
        current_registers[256 - start_address : 316 - start_address] = registers(256, 60)
        current_registers[400 - start_address : 436 - start_address] = registers(400, 36)
        return None

    device = SimDevice(
        id=0,
        simdata=[SimData(0, count=size, values=0, datatype=DataType.REGISTERS)],
        action=feed,
    )
    asyncio.get_running_loop().call_later(0.2, lambda: print("ready", flush=True))
    await StartAsyncTcpServer(context=device, address=(host, port))


async def run_raw(host, port, mode):
    count = 0

    async def serve(reader, writer):
        nonlocal count
        try:
            while True:
                header = await reader.readexactly(7)
                tid, proto, length, unit = struct.unpack(">HHHB", header)
                pdu = await reader.readexactly(length - 1)
                function = pdu[0]
                if function != 3:
                    print(f"write {function}", flush=True)
                    continue
                start, quantity = struct.unpack(">HH", pdu[1:5])
                count += 1
                kind = mode
                if mode == "flaky":
                    kinds = ["exception", "wrong-tid", "short", "garbage"]
                    kind = kinds[(count // 4) % len(kinds)] if count % 4 == 0 else "good"
                values = registers(start, quantity)
                body = bytes([3, 2 * quantity]) + struct.pack(f">{quantity}H", *values)
                if kind == "exception":
                    body = bytes([0x83, 0x04])
                elif kind == "wrong-tid":
                    tid = (tid + 7) & 0xFFFF
                elif kind == "short":
                    body = body[: 2 + quantity]
                elif kind == "slow":
                    await asyncio.sleep(SLOW_S)
                if kind == "garbage":
                    frame = os.urandom(3 + count % 40)
                else:
                    frame = struct.pack(">HHHB", tid, 0, len(body) + 1, unit) + body
                writer.write(frame)
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()

    server = await asyncio.start_server(serve, host, port)
    print("ready", flush=True)
    async with server:
        await server.serve_forever()


def main():
    host, port, mode = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    if mode == "pymodbus":
        asyncio.run(run_pymodbus(host, port))
    else:
        asyncio.run(run_raw(host, port, mode))


if __name__ == "__main__":
    main()
