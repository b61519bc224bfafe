"""The PLC and GPS side of the telescope: simulators, drivers and their OpenTCI modules.

:class:`Peripherals` is built by the :class:`~tcs.model.telescope.Telescope` from the hardware
file and owns, in start order:

1. **simulators** — when the file's bus is the in-process ``virtual`` one
   (``[can] interface = "virtual"``, the same rule as the simulated drives), every PLC and the
   GPS that have a ``sim`` table run in this process on free loopback ports
   (:func:`tcs.sim.peripherals.start_peripherals`); otherwise they are somebody else's
   (``tcs-sim``, or real hardware) and only the addresses in the file count;
2. **drivers** — one :class:`~tcs.drivers.modbus.PlcDriver` per ``[plcs.<name>]`` (pointed at
   the simulator's actual port when simulated here) and the
   :class:`~tcs.drivers.gps.GpsReader`; start waits up to about each PLC's ``timeout`` for the
   first complete poll, so the modules start with real values (a PLC that does not answer
   leaves its modules in ERROR_STATE, the rest work, and it is picked up whenever it appears);
3. **modules** — ``DOME[]`` and ``COVER``/``COVER[]`` (:mod:`tcs.model.enclosure`), ``SENSOR[]``
   and ``SWITCH[]`` (:mod:`tcs.model.aux_io`), ``GPS`` (:mod:`tcs.model.gps_module`) and the
   weather interlock (:mod:`tcs.model.interlocks`). They are attached to the CABINET, so they
   take part in CABINET.POWER (those with ``power``), CABINET.STOP, ERROR_STATE and
   STATUS.LIST.

``CONFIG.DOME`` (:class:`~tcs.model.enclosure.DomeInfo`) comes from the file alone and is set on
CONFIG at construction. :meth:`stop` runs in reverse order; moving parts are stopped first
(except a part the weather interlock is closing).
"""

from __future__ import annotations

import asyncio
import logging

from tcs.config import HwConfig
from tcs.drivers.gps import GpsReader
from tcs.drivers.modbus import PlcDriver
from tcs.model.aux_io import Sensor, Switch
from tcs.model.enclosure import DomeInfo, build_covers, build_dome
from tcs.model.gps_module import GpsModule
from tcs.model.interlocks import WeatherInterlock

log = logging.getLogger(__name__)

CONNECT_GRACE = 1.0  # s beyond a PLC's timeout that start waits for its first poll


class Peripherals:
    """PLCs, GPS and their modules for one hardware file.

    Parameters
    ----------
    config:
        The hardware file.
    events:
        The telescope's event hub.
    local:
        LOCAL (time base for the dome's trajectory, site for SYNCPOS).
    mount_config:
        CONFIG (receives ``dome``).
    cabinet:
        CABINET (the modules are attached to it; its main power gates POWER=1).
    """

    def __init__(self, config: HwConfig, *, events, local, mount_config, cabinet):
        self.config = config
        self.events = events
        self.local = local
        self.cabinet = cabinet
        self.dome_info = DomeInfo.from_section(config.dome) if config.dome is not None else None
        # without a dome CONFIG.DOME still answers: no capabilities, diameter 0 (spec §7 lists it)
        mount_config.dome = self.dome_info if self.dome_info is not None else DomeInfo(0, 0.0)
        self.sims = None
        self.drivers: dict[str, PlcDriver] = {}
        self.gps_reader: GpsReader | None = None
        self.dome: list = []
        self.covers: list = []
        self.sensors: list = []
        self.switches: list = []
        self.gps: GpsModule | None = None
        self.interlock: WeatherInterlock | None = None

    # -- what the declaration binds -------------------------------------------------------------
    @property
    def cover(self):
        """The plain ``COVER`` module (one cover configured), else None."""
        return self.covers[0] if len(self.covers) == 1 else None

    @property
    def cover_array(self) -> list:
        """``COVER[]`` elements (several covers configured), else empty."""
        return self.covers if len(self.covers) > 1 else []

    @property
    def axes(self) -> list:
        """Every DOME[] part and cover."""
        return [m for m in self.dome if m is not None] + list(self.covers)

    @property
    def modules(self) -> list:
        """Every domain object with an ERROR_STATE."""
        out = self.axes + self.sensors + self.switches
        return out + ([self.gps] if self.gps is not None else [])

    @property
    def simulated_here(self) -> bool:
        """The rule for in-process simulators: the file's bus is python-can's ``virtual`` one."""
        return self.config.can is not None and self.config.can.interface == "virtual"

    # -- life cycle -----------------------------------------------------------------------------
    async def start(self) -> None:
        config = self.config
        if not config.plcs and config.gps is None:
            return
        if self.simulated_here:
            from tcs.sim.peripherals import start_peripherals

            self.sims = await start_peripherals(config, free_ports=True)
        for name in config.plcs:
            section = self.sims.plc_section(name) if self.sims else config.plcs[name]
            self.drivers[name] = PlcDriver(name, section)
        for driver in self.drivers.values():
            await driver.start()
        gps_section = self.sims.gps_section() if self.sims else config.gps
        if gps_section is not None:
            self.gps_reader = GpsReader(gps_section)
            await self.gps_reader.start()
        await self._wait_connected()
        self._build()
        self.cabinet.attach(modules=self.modules)
        for module in self.modules:
            module.start()
        if self.interlock is not None:
            self.interlock.start()

    async def _wait_connected(self) -> None:
        waits = {name: d.wait_connected(d.section.timeout + CONNECT_GRACE) for name, d in self.drivers.items()}
        results = await asyncio.gather(*waits.values(), return_exceptions=True)
        for name, result in zip(waits, results):
            if isinstance(result, BaseException):
                # info: the driver has warned once already ("PLC x: lost")
                log.info("PLC %s is not reachable at start: %s", name, result)

    def _build(self) -> None:
        config = self.config
        main_power = lambda: self.cabinet.main_power  # noqa: E731
        if config.dome is not None:
            self.dome = build_dome(config.dome, self.drivers, events=self.events, ut1=self.local.ut1,
                                   main_power=main_power)
        self.covers = build_covers(list(config.covers), self.drivers, events=self.events,
                                   main_power=main_power)
        self.sensors = [Sensor(i, s, self.drivers, self.events) for i, s in enumerate(config.sensors)]
        self.switches = [Switch(i, s, self.drivers, self.events) for i, s in enumerate(config.switches)]
        if self.gps_reader is not None:
            self.gps = GpsModule(self.gps_reader, self.local, self.events)
        if config.interlocks is not None:
            guarded = [m for m in self.axes if m.guarded]
            self.interlock = WeatherInterlock(config.interlocks, self.drivers, guarded)

    async def stop(self) -> None:
        """Stop moving parts, then modules, readers, drivers and simulators (reverse order)."""
        if self.interlock is not None:
            self.interlock.stop()
        axes = self.axes
        if axes:
            await asyncio.gather(*(m.shutdown() for m in axes), return_exceptions=True)
        for module in self.sensors + self.switches + ([self.gps] if self.gps else []):
            module.close()
        if self.gps_reader is not None:
            await self.gps_reader.stop()
            self.gps_reader = None
        for driver in self.drivers.values():
            await driver.stop()
        self.drivers.clear()
        if self.sims is not None:
            await self.sims.stop()
            self.sims = None
