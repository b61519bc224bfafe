"""The only module on the simulator side that imports pymodbus: a Modbus server for one device.

:class:`ModbusServer` runs a pymodbus ``ModbusTcpServer`` (socket framing, or RTU framing over
TCP as serial gateways do) with one ``SimDevice`` whose four tables (coils, discrete inputs,
holding and input registers) are separate address spaces. The registers pymodbus keeps are
only a mirror: the device's ``action`` callback, which pymodbus awaits on every access,

* before a read, refreshes the requested registers from ``handler.read(kind, address, count)``;
* before a write, hands the values to ``handler.write(kind, address, values)``, which may
  refuse with a Modbus exception code (2 illegal address, 3 illegal value…).

So the simulated PLC (:mod:`tcs.sim.plc`) computes every answer from its own state at the
moment of the request, and the deprecated datastore context classes are never used.

Fault knobs: ``responding = False`` swallows every request (no answer, nothing applied — a PLC
that hangs); :meth:`drop_connections` closes the clients' connections; :meth:`stop` and
:meth:`start` again on the same port model a PLC that is switched off and back on.
"""

from __future__ import annotations

from typing import Protocol

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

# Function code -> table. 22 (mask write) and 23 (read/write) are not offered.
_TABLE = {1: "coil", 5: "coil", 15: "coil", 2: "discrete", 3: "holding", 6: "holding",
          16: "holding", 4: "input"}
_WRITES = {5, 6, 15, 16}


class RegisterHandler(Protocol):
    """What the server asks the simulated device (addresses are protocol addresses)."""

    def read(self, kind: str, address: int, count: int) -> list:
        """``count`` values from ``address``: bool for coil/discrete, 0..65535 for registers."""

    def write(self, kind: str, address: int, values: list) -> int | None:
        """Apply a write; return None, or a Modbus exception code to refuse it."""


class ModbusServer:
    """A Modbus TCP server for one device on ``host`` (default loopback).

    Parameters
    ----------
    handler:
        The device (see :class:`RegisterHandler`).
    spans:
        ``{kind: (first_address, count)}`` of each table the device answers for; addresses
        outside answer exception 2.
    device_id:
        The Modbus unit id the device answers to (others get exception 4).
    port:
        0 picks a free port; it is kept across :meth:`stop` / :meth:`start`.
    framer:
        ``"socket"`` (Modbus TCP) or ``"rtu"`` (RTU frames over TCP, for RTU clients using a
        ``socket://`` serial URL).
    """

    def __init__(self, handler: RegisterHandler, spans: dict[str, tuple[int, int]], *,
                 device_id: int = 1, host: str = "127.0.0.1", port: int = 0,
                 framer: str = "socket"):
        self.handler = handler
        self.spans = spans
        self.device_id = device_id
        self.host = host
        self.port = port
        self.framer = FramerType.RTU if framer == "rtu" else FramerType.SOCKET
        self.responding = True
        self.requests = 0
        self._server: ModbusTcpServer | None = None

    @property
    def running(self) -> bool:
        return self._server is not None

    def _device(self) -> SimDevice:
        tables = []
        for kind in ("coil", "discrete", "holding", "input"):
            first, count = self.spans.get(kind, (0, 1))
            if kind in ("coil", "discrete"):
                tables.append([SimData(first, values=[False] * max(count, 1), datatype=DataType.BITS)])
            else:
                tables.append([SimData(first, count=max(count, 1), values=0, datatype=DataType.REGISTERS)])
        return SimDevice(self.device_id, simdata=tuple(tables), action=self._action)

    async def start(self) -> None:
        """Listen (again) on ``host:port``; a port of 0 is replaced by the one chosen."""
        if self._server is not None:
            return
        server = ModbusTcpServer(self._device(), address=(self.host, self.port), framer=self.framer,
                                 trace_packet=self._trace_packet)
        await server.serve_forever(background=True)
        if server.transport is None:  # pragma: no cover - pymodbus logs and returns
            raise OSError(f"cannot listen on {self.host}:{self.port}")
        self.port = server.transport.sockets[0].getsockname()[1]
        self._server = server

    async def stop(self) -> None:
        """Stop listening and close every connection."""
        server, self._server = self._server, None
        if server is not None:
            await server.shutdown()

    def drop_connections(self) -> int:
        """Close every client connection (the listener stays); return how many were closed."""
        if self._server is None:
            return 0
        conns = list(self._server.active_connections.values())
        for conn in conns:
            conn.close()
        return len(conns)

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        return data if (self.responding or not sending) else b""

    async def _action(self, func_code, start_address, address, count, registers, set_values):
        self.requests += 1
        if not self.responding:
            return ExcCodes.DEVICE_FAILURE  # the answer is swallowed by _trace_packet
        kind = _TABLE.get(func_code)
        if kind is None:
            return ExcCodes.ILLEGAL_FUNCTION
        bits = kind in ("coil", "discrete")
        if func_code in _WRITES and set_values is not None:
            values = [bool(v) for v in set_values] if bits else [int(v) for v in set_values]
            code = self.handler.write(kind, address, values)
            if code:
                return ExcCodes(code)
        # Refresh the mirror of the whole requested span (for bits: whole 16-bit words).
        if bits:
            word0 = address // 16 - start_address
            first_bit = (address // 16) * 16
            flags = self.handler.read(kind, first_bit, count * 16)
            for w in range(count):
                word = 0
                for b, on in enumerate(flags[w * 16:(w + 1) * 16]):
                    if on:
                        word |= 1 << b
                registers[word0 + w] = word
        else:
            offset = address - start_address
            registers[offset:offset + count] = [int(v) & 0xFFFF for v in self.handler.read(kind, address, count)]
        return None
