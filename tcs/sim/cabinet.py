"""The whole simulated cabinet of a hardware file, as hardware in another process would be.

:class:`SimCabinet` starts, from one hardware file:

* the ``[simulation]`` drives on a private ``virtual`` CAN bus, offered to other processes by a
  :class:`~tcs.sim.socketcand_server.SocketcandServer` on the ``[can]`` host and port (the
  file's bus is ``socketcand``: that is how a separate ``tcs-server`` reaches it) — or, when the
  file's bus is ``socketcan``, straight on that kernel interface (e.g. a ``vcan0`` shared with a
  ``tcs-server`` as the master: real frames through the kernel, SYNC from its broadcast manager);
* every ``[plcs.<name>]`` with a ``sim`` table as a Modbus TCP server on its host and port;
* the ``[gps]`` receiver, when it has a ``sim`` table and a ``socket://host:port`` URL, as an
  NMEA stream on that TCP port.

This is what ``tcs-sim`` runs. It never imports the TCS's drivers: only the protocols.
"""

from __future__ import annotations

import asyncio
import logging
import uuid

from tcs.config import HwConfig
from tcs.errors import ConfigError, ConfigErrors

log = logging.getLogger(__name__)


class SimCabinet:
    """Simulated drives (socketcand), PLCs (Modbus TCP) and GPS (NMEA over TCP) of ``config``."""

    def __init__(self, config: HwConfig, port: int | None = None):
        self.config = config
        self.can_port = port
        self.drives = None
        self.socketcand = None
        self.plcs: dict = {}
        self.gps = None
        self.peripherals = None  # the PLC and GPS simulators (tcs.sim.peripherals)
        problems = []
        if config.simulation and config.simulation.drives:
            if config.can is None or config.can.interface not in ("socketcand", "socketcan"):
                problems.append(ConfigError(str(config.source), "can.interface",
                                            "tcs-sim offers the drives over socketcand or on a kernel "
                                            "interface: set interface = \"socketcand\" (see "
                                            "hwconfig/sim-remote.toml) or \"socketcan\""))
        if problems:
            raise ConfigErrors(problems)

    async def start(self) -> None:
        config = self.config
        try:
            if config.simulation and config.simulation.drives:
                await self._start_drives()
            from tcs.sim.peripherals import start_peripherals

            self.peripherals = await start_peripherals(config, free_ports=False, gps_pty=False)
            self.plcs, self.gps = self.peripherals.plcs, self.peripherals.gps
        except BaseException:
            await self.stop()
            raise

    async def _start_drives(self) -> None:
        from tcs.sim.drive_network import SimDriveNetwork, params_from_config
        from tcs.sim.socketcand_server import SocketcandServer

        can = self.config.can
        params = params_from_config(self.config)
        if can.interface == "socketcan":
            self.drives = await asyncio.to_thread(SimDriveNetwork, can.bus_kwargs(), params)
            log.info("simulated drives %s on socketcan %s", sorted(params), can.channel)
            return
        channel = f"tcs-sim-{uuid.uuid4().hex[:8]}"
        self.socketcand = SocketcandServer(channel, can.host, can.port if self.can_port is None else self.can_port)
        self.can_port = await self.socketcand.start()
        self.drives = await asyncio.to_thread(SimDriveNetwork, {"interface": "virtual", "channel": channel}, params)
        log.info("simulated drives %s on socketcand %s:%d", sorted(params), can.host, self.can_port)

    async def stop(self) -> None:
        if self.peripherals is not None:
            await self.peripherals.stop()
            self.peripherals = None
            self.plcs, self.gps = {}, None
        if self.drives is not None:
            await asyncio.to_thread(self.drives.stop)
            self.drives = None
        if self.socketcand is not None:
            await self.socketcand.stop()
            self.socketcand = None
