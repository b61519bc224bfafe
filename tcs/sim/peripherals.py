"""The simulated PLCs and GPS receiver of a hardware file, started and stopped together.

:func:`start_peripherals` is the one start-up of these simulators, used by both places that
run them:

* ``tcs-sim`` (:class:`~tcs.sim.cabinet.SimCabinet`) serves them on the host and ports the file
  names, for a ``tcs-server`` in another process;
* the telescope model, when the file's bus is the in-process ``virtual`` one, runs them in its
  own process on **free** ports (``free_ports=True``), and points its drivers at
  :meth:`SimPeripherals.plc_section` / :meth:`SimPeripherals.gps_section` — the file's
  sections with the ports actually used, so services started side by side (tests) never
  clash.

Which simulators exist: every ``[plcs.<name>]`` with a ``sim`` table (Modbus TCP; RTU framing
over TCP for ``transport = "rtu"`` with a ``socket://`` URL), and the ``[gps]`` receiver when it
has a ``sim`` table — over TCP for a ``socket://`` URL, else on a pseudo-terminal (in-process
only: another process cannot open our pty). Nothing here imports the TCS's drivers.
"""

from __future__ import annotations

import dataclasses
import logging
from urllib.parse import urlparse

from tcs.config import HwConfig

log = logging.getLogger(__name__)


class SimPeripherals:
    """Running simulators: ``plcs`` by name (:class:`~tcs.sim.plc.SimPlc`) and ``gps``
    (:class:`~tcs.sim.gps.SimGps` or None)."""

    def __init__(self, config: HwConfig):
        self.config = config
        self.plcs: dict = {}
        self.gps = None

    def plc_section(self, name: str):
        """``[plcs.<name>]`` pointed at the simulator actually serving it (the file's own
        section when that PLC is not simulated here)."""
        section = self.config.plcs[name]
        sim = self.plcs.get(name)
        if sim is None:
            return section
        if section.transport == "tcp":
            return dataclasses.replace(section, host="127.0.0.1", port=sim.port)
        return dataclasses.replace(section, serial_port=f"socket://127.0.0.1:{sim.port}")

    def gps_section(self):
        """``[gps]`` pointed at the simulated receiver (the file's own when not simulated)."""
        gps = self.config.gps
        if gps is None or self.gps is None:
            return gps
        return dataclasses.replace(gps, url=self.gps.url)

    async def stop(self) -> None:
        if self.gps is not None:
            await self.gps.stop()
            self.gps = None
        for plc in self.plcs.values():
            await plc.stop()
        self.plcs.clear()


async def start_peripherals(config: HwConfig, *, free_ports: bool, gps_pty: bool = True) -> SimPeripherals:
    """Start every simulated PLC and the simulated GPS of ``config``.

    Parameters
    ----------
    free_ports:
        True: listen on free loopback ports (in-process use); False: on the host and port
        each section names (``tcs-sim``).
    gps_pty:
        Whether a receiver without a ``socket://`` URL is simulated on a pty (only useful in
        the same process).
    """
    from tcs.sim.gps import SimGps
    from tcs.sim.plc import SimPlc

    sims = SimPeripherals(config)
    try:
        for name, section in config.plcs.items():
            if section.sim is None:
                continue
            if free_ports:
                plc = SimPlc(name, section, port=0)
            else:
                plc = SimPlc(name, section, host=section.host)
            await plc.start()
            sims.plcs[name] = plc
            log.info("simulated PLC %s: Modbus %s on 127.0.0.1:%d", name, section.transport, plc.port)
        gps = config.gps
        if gps is not None and gps.sim is not None:
            tcp = gps.url.startswith("socket://")
            if tcp or gps_pty:
                port = 0 if free_ports or not tcp else (urlparse(gps.url).port or 0)
                sims.gps = SimGps.from_config(gps, config.site, port=port)
                await sims.gps.start()
                log.info("simulated GPS: NMEA on %s", sims.gps.url)
    except BaseException:
        await sims.stop()
        raise
    return sims
