#!/usr/bin/env python3
"""A pymodbus 3.16 Modbus TCP server: the Python peer of scripts/bench-net.

It holds the same spaces as the product's map, 266 coils (0-265) and 436
holding registers (0-435), plain memory, so the requests the load generator
sends succeed on it too. pymodbus's own asyncio server, as its examples run
it, with no logging.

    python3 pymodbus_server.py IP PORT     prints "listening on IP:PORT" once ready
"""
import asyncio
import logging
import sys

from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

COILS = 266
HOLDING_REGISTERS = 436


async def main(host, port):
    coils = [SimData(address=0, count=COILS, values=False, datatype=DataType.BITS)]
    registers = [SimData(address=0, count=HOLDING_REGISTERS, values=0, datatype=DataType.REGISTERS)]
    discrete_inputs = [SimData(address=0, count=1, values=False, datatype=DataType.BITS)]
    input_registers = [SimData(address=0, count=1, values=0, datatype=DataType.REGISTERS)]
    device = SimDevice(1, simdata=(coils, discrete_inputs, registers, input_registers), use_bit_addressing=True)
    server = ModbusTcpServer(device, address=(host, port))
    await server.serve_forever(background=True)
    print(f"listening on {host}:{port}", flush=True)
    await server.serving


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(f"usage: {sys.argv[0]} IP PORT", file=sys.stderr)
        sys.exit(2)
    logging.disable(logging.CRITICAL)
    asyncio.run(main(sys.argv[1], int(sys.argv[2])))
