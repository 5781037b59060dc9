"""A Modbus TCP server this project did not write (Debian's python3-pymodbus
3.0), for tests/test_modbus_pymodbus.cpp: it checks the wire format of
markerd's Modbus drive against an independent implementation.

The datastore is pymodbus's own; the script only watches it. Every write a
client makes is appended to --log as one JSON line
{"table": "hr"|"co", "address": A, "values": [...]}, flushed at once, so the
test reads what arrived on the wire, in order. A write of 1 to --start-coil
"moves" the drive: the two registers of the target position (holding
registers at --target) are copied to the actual position (input registers at
--position), word for word, so a client sees its move end where it asked.
Discrete inputs 0 (ready) and 2 (in position) are on. Once serving, the bound
port is written to --port-file.

Run with Debian's /usr/bin/python3 (pymodbus is installed for it).
"""

import argparse
import asyncio
import json
import os

from pymodbus.datastore import (
    ModbusSequentialDataBlock,
    ModbusServerContext,
    ModbusSlaveContext,
)
from pymodbus.server import StartAsyncTcpServer


class WatchedContext(ModbusSlaveContext):
    def __init__(self, log, target, position, start_coil, **kwargs):
        super().__init__(**kwargs)
        self.log = log
        self.target = target
        self.position = position
        self.start_coil = start_coil

    def setValues(self, fc_as_hex, address, values):  # noqa: N802 (pymodbus's name)
        super().setValues(fc_as_hex, address, values)
        table = self.decode(fc_as_hex)
        values = [int(v) for v in values]
        self.log.write(json.dumps({"table": {"h": "hr", "c": "co"}.get(table, table),
                                   "address": address, "values": values}) + "\n")
        self.log.flush()
        if table == "c" and address <= self.start_coil < address + len(values) \
                and values[self.start_coil - address] == 1:
            words = self.getValues(3, self.target, 2)
            self.store["i"].setValues(self.position, words)


async def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--port-file", required=True)
    parser.add_argument("--log", required=True)
    parser.add_argument("--target", type=int, required=True)
    parser.add_argument("--position", type=int, required=True)
    parser.add_argument("--start-coil", type=int, required=True)
    args = parser.parse_args()

    log = open(args.log, "a", encoding="utf-8")
    discrete = [0] * 16
    discrete[0] = 1  # ready
    discrete[2] = 1  # in position
    slave = WatchedContext(
        log, args.target, args.position, args.start_coil, zero_mode=True,
        di=ModbusSequentialDataBlock(0, discrete),
        co=ModbusSequentialDataBlock(0, [0] * 64),
        hr=ModbusSequentialDataBlock(0, [0] * 256),
        ir=ModbusSequentialDataBlock(0, [0] * 256))
    context = ModbusServerContext(slaves={1: slave}, single=False)
    server = await StartAsyncTcpServer(context, address=("127.0.0.1", 0), defer_start=True)
    task = asyncio.create_task(server.serve_forever())
    await server.serving
    port = server.server.sockets[0].getsockname()[1]
    with open(args.port_file + ".tmp", "w", encoding="utf-8") as f:
        f.write(f"{port}\n")
    # Renamed into place, so the test never reads a half-written file.
    os.rename(args.port_file + ".tmp", args.port_file)
    await task


if __name__ == "__main__":
    asyncio.run(main())
