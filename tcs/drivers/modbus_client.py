"""The only module on the client side that imports pymodbus: one Modbus link to one PLC.

:class:`ModbusLink` opens a pymodbus asyncio client (``AsyncModbusTcpClient`` for
``transport = "tcp"``, ``AsyncModbusSerialClient`` with the RTU framer for ``"rtu"``; the
serial port may be a device path or any pyserial URL such as ``socket://host:port``) and turns
every pymodbus outcome into the project's errors:

* cannot connect, connection closed → :class:`~tcs.errors.CommunicationError` number 4 (nocon);
* no answer within ``timeout``, garbled answer → ``CommunicationError`` number 3 (confail);
* a Modbus exception response (the PLC refused the request) → :class:`ModbusExceptionResponse`
  (number 3), which leaves the connection usable.

pymodbus's own reconnect and retries are switched off (``reconnect_delay=0``, ``retries=0``):
the driver (:mod:`tcs.drivers.modbus`) owns reconnecting and its backoff, so the state it
reports is the state of the link. One request is in flight at a time; only the driver's I/O
task calls a link.
"""

from __future__ import annotations

import asyncio
import logging

from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType

from tcs.config.plc import PlcSection
from tcs.errors import CommunicationError, ErrorNumber, HardwareError

# The driver reports link problems itself (state, callbacks, one log line per change);
# pymodbus would log every failed connect and timeout again.
_pymodbus_log = logging.getLogger("pymodbus.logging")
if _pymodbus_log.level == logging.NOTSET:
    _pymodbus_log.setLevel(logging.CRITICAL)

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "device failure", 5: "acknowledge", 6: "device busy",
                   8: "memory parity error", 10: "gateway path unavailable",
                   11: "gateway target did not respond"}


class ModbusExceptionResponse(HardwareError):
    """The PLC answered a request with a Modbus exception (``code``): it refused it."""

    default_number = ErrorNumber.CONFAIL

    def __init__(self, device: str, what: str, code: int):
        self.code = code
        name = EXCEPTION_NAMES.get(code, "unknown exception")
        super().__init__(device, f"PLC refused {what}: Modbus exception {code} ({name})")


class ModbusLink:
    """One connection (TCP) or one serial port (RTU) to one PLC.

    Parameters
    ----------
    name:
        The PLC's name in the hardware file, used in every error message.
    section:
        The ``[plcs.<name>]`` section (transport, address, device id, timeout).
    """

    def __init__(self, name: str, section: PlcSection):
        self.name = name
        self.section = section
        self._client: AsyncModbusTcpClient | AsyncModbusSerialClient | None = None

    @property
    def where(self) -> str:
        s = self.section
        return f"{s.host}:{s.port}" if s.transport == "tcp" else s.serial_port

    @property
    def connected(self) -> bool:
        return self._client is not None and self._client.connected

    def _new_client(self):
        s = self.section
        if s.transport == "tcp":
            return AsyncModbusTcpClient(s.host, port=s.port, timeout=s.timeout, retries=0,
                                        reconnect_delay=0, name=self.name)
        return AsyncModbusSerialClient(s.serial_port, framer=FramerType.RTU, baudrate=s.baudrate,
                                       bytesize=s.bytesize, parity=s.parity, stopbits=s.stopbits,
                                       timeout=s.timeout, retries=0, reconnect_delay=0,
                                       name=self.name)

    async def connect(self) -> None:
        """Open the connection; raise ``CommunicationError`` (nocon) when it cannot be opened."""
        self.close()
        client = self._new_client()
        try:
            ok = await client.connect()
        except Exception as exc:  # pyserial and asyncio raise a zoo of OSError subclasses
            client.close()
            raise CommunicationError(self.name, f"cannot open {self.where}: {exc}",
                                     ErrorNumber.NOCON) from None
        if not ok:
            client.close()
            raise CommunicationError(self.name, f"cannot connect to {self.where}", ErrorNumber.NOCON)
        self._client = client

    def close(self) -> None:
        """Close the connection (idempotent)."""
        client, self._client = self._client, None
        if client is not None:
            client.close()

    async def read(self, kind: str, address: int, count: int) -> list:
        """Read ``count`` coils/discrete inputs (list of bool) or registers (list of int)."""
        c = self._require()
        fn = {"coil": c.read_coils, "discrete": c.read_discrete_inputs,
              "holding": c.read_holding_registers, "input": c.read_input_registers}[kind]
        what = f"reading {count} {kind} at {address}"
        response = await self._call(lambda: fn(address, count=count, device_id=self.section.device_id),
                                    what)
        data = response.bits if kind in ("coil", "discrete") else response.registers
        if len(data) < count:
            raise CommunicationError(self.name, f"short answer {what}: {len(data)} values",
                                     ErrorNumber.CONFAIL)
        return list(data[:count])

    async def write(self, kind: str, address: int, values: list) -> None:
        """Write coils (list of bool) or holding registers (list of int) starting at ``address``.

        One value uses the single-write function (5 or 6), several the multiple-write (15, 16).
        """
        c = self._require()
        dev = self.section.device_id
        what = f"writing {kind} {address}" + (f"..{address + len(values) - 1}" if len(values) > 1 else "")
        if kind == "coil":
            if len(values) == 1:
                call = lambda: c.write_coil(address, bool(values[0]), device_id=dev)  # noqa: E731
            else:
                call = lambda: c.write_coils(address, [bool(v) for v in values], device_id=dev)  # noqa: E731
        elif kind == "holding":
            if len(values) == 1:
                call = lambda: c.write_register(address, int(values[0]), device_id=dev)  # noqa: E731
            else:
                call = lambda: c.write_registers(address, [int(v) for v in values], device_id=dev)  # noqa: E731
        else:  # pragma: no cover - the configuration refuses writable discrete/input points
            raise ValueError(f"{kind} cannot be written")
        await self._call(call, what)

    def _require(self):
        if self._client is None or not self._client.connected:
            raise CommunicationError(self.name, f"not connected to {self.where}", ErrorNumber.NOCON)
        return self._client

    async def _call(self, request, what: str):
        try:
            # pymodbus applies `timeout` itself; the outer guard only catches a hung transport.
            response = await asyncio.wait_for(request(), self.section.timeout * 2 + 1.0)
        except ConnectionException:
            raise CommunicationError(self.name, f"connection to {self.where} lost ({what})",
                                     ErrorNumber.NOCON) from None
        except (ModbusIOException, asyncio.TimeoutError):
            raise CommunicationError(self.name, f"no answer from {self.where} within "
                                     f"{self.section.timeout:g} s ({what})", ErrorNumber.CONFAIL) from None
        except (ModbusException, OSError, ValueError) as exc:
            raise CommunicationError(self.name, f"{what} failed: {exc}", ErrorNumber.CONFAIL) from None
        if response.isError():
            raise ModbusExceptionResponse(self.name, what, int(getattr(response, "exception_code", 0)))
        return response
