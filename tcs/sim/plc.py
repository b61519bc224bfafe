"""A simulated PLC: a real Modbus server whose registers follow the hardware file's map.

How it works
------------
:class:`SimPlc` reads the same ``[plcs.<name>]`` section as the driver: the register map
(``points``) says where each named value lives and how it is encoded (the shared
:class:`~tcs.config.plc.RegisterPoint` codec), and ``[plcs.<name>.sim]`` says what is behind
the names:

* ``axes.<X>`` — a PLC axis (``tcs/sim/plc_axis.py``; dome presets in ``enclosure.py``,
  mirror covers in ``covers.py``);
* ``sensors.<point>`` — a sensor with a slowly changing value (``weather.py``);
* ``switches.<point>`` — a switch with an optional feedback point (``switches.py``);
* every other point is plain PLC memory (reads what was last written, 0 at start).

The PLC's state lives in the models and in a register image; the Modbus server
(``modbus_server.py``, the one module importing pymodbus) calls :meth:`read` / :meth:`write`
on every request, and those first bring every model to the clock's *now*. Physics is
therefore a function of the injectable ``clock`` — a test that advances a manual clock sees
the dome arrive without waiting.

Watchdog: like a real PLC program, the simulated PLC stops every axis when the map's
``watchdog`` point (``tcs_watchdog``, a counter the TCS increments at every poll) has not
changed for ``[plcs.<name>.sim] watchdog_timeout`` seconds, once it was written at all. That
time is wall-clock time (``wall_clock``), not the physics clock: the watchdog watches the link
to the TCS, which lives in real time, and tests that jump the physics clock forward must not
trip it.

Fault injection: ``set_responding(False)`` (the PLC stops answering), ``drop_connections()``,
``await power_off()`` / ``await power_on()`` (nothing listens, then the PLC is back on the
same port), ``axis(X).inject_stall(...)`` (via :meth:`stall`), ``force(point, value)``
(rain, wind, any reading) and ``release(point)``.

Only tests, benchmarks and the simulator process touch this; the TCS sees a Modbus server.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from urllib.parse import urlparse

from tcs.config.plc import AXIS_STOP, PlcSection, RegisterPoint
from tcs.sim import covers, enclosure
from tcs.sim.modbus_server import ModbusServer
from tcs.sim.plc_axis import GENERIC, AxisParams, SimPlcAxis
from tcs.sim.switches import SimSwitch
from tcs.sim.weather import SimSensor

log = logging.getLogger(__name__)

ILLEGAL_ADDRESS = 2
PRESETS: dict[str, AxisParams] = {"generic": GENERIC, **enclosure.PRESETS, **covers.PRESETS}


class SimPlc:
    """One simulated PLC serving Modbus TCP (or RTU frames over TCP) on 127.0.0.1.

    Parameters
    ----------
    name:
        The PLC's name (for messages).
    section:
        Its ``[plcs.<name>]`` section; ``sim`` may be absent (then all points are memory).
    clock:
        Seconds, monotonic; physics and sensors are functions of it.
    port:
        Listening port; default: the section's ``port`` (tcp) or the port of a
        ``socket://host:port`` serial URL (rtu). 0 picks a free port (see :attr:`port`).
    """

    def __init__(self, name: str, section: PlcSection, *, clock: Callable[[], float] = time.monotonic,
                 host: str = "127.0.0.1", port: int | None = None,
                 wall_clock: Callable[[], float] = time.monotonic):
        self.name = name
        self.section = section
        self.clock = clock
        self.wall_clock = wall_clock
        self.watchdog_trips = 0
        self._wd_value = None
        self._wd_changed: float | None = None  # wall time of the watchdog's last change
        self._wd_task: asyncio.Task | None = None
        self.points: dict[str, RegisterPoint] = dict(section.map)
        framer = "socket"
        default_port = section.port
        if section.transport == "rtu":
            framer = "rtu"
            url = urlparse(section.serial_port)
            default_port = (url.port or 0) if url.scheme == "socket" else 0
        self._image: dict[str, dict[int, int | bool]] = {k: {} for k in ("coil", "discrete", "holding", "input")}
        self._encoded: dict[str, tuple] = {}  # point -> (value, its words): see _store
        self._by_kind: dict[str, list[RegisterPoint]] = {k: [] for k in self._image}
        for p in sorted(self.points.values(), key=lambda p: p.address):
            self._by_kind[p.kind].append(p)
            self._store(p, False if p.type == "bool" else 0)
        self.axes: dict[str, SimPlcAxis] = {}
        self.sensors: dict[str, SimSensor] = {}
        self.switches: dict[str, SimSwitch] = {}
        self._owner: dict[str, object] = {}
        self._forced: dict[str, object] = {}
        self._build_models(clock())
        self._refresh(clock())
        spans = {}
        for kind, pts in self._by_kind.items():
            if pts:
                first = min(p.address for p in pts)
                spans[kind] = (first, max(p.end for p in pts) - first)
        self.server = ModbusServer(self, spans, device_id=section.device_id, host=host,
                                   port=default_port if port is None else port, framer=framer)

    def _build_models(self, now: float) -> None:
        sim = self.section.sim
        if sim is None:
            return
        for name, ax in sim.axes.items():
            model = SimPlcAxis(name, AxisParams.resolve(ax, PRESETS), now)
            self.axes[name] = model
            self._own(model)
        for point, sens in sim.sensors.items():
            model = SimSensor(point, sens, sim.seed, now)
            self.sensors[point] = model
            self._own(model)
        for point, sw in sim.switches.items():
            model = SimSwitch(point, sw, now)
            self.switches[point] = model
            self._own(model)

    def _own(self, model) -> None:
        for point in model.points:
            if point in self.points:
                self._owner[point] = model

    # ------------------------------------------------------------- lifecycle

    async def start(self) -> None:
        """Start serving (again, after :meth:`power_off`, on the same port)."""
        await self.server.start()
        timeout = self.section.sim.watchdog_timeout if self.section.sim is not None else 0.0
        if self._wd_task is None and timeout > 0 and self.section.watchdog in self.points and self.axes:
            self._wd_task = asyncio.get_running_loop().create_task(self._watch(timeout),
                                                                   name=f"sim plc {self.name} watchdog")

    async def stop(self) -> None:
        task, self._wd_task = self._wd_task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        await self.server.stop()

    async def _watch(self, timeout: float) -> None:
        """The PLC program's watchdog: runs from start to stop, power cuts of the server aside."""
        while True:
            await asyncio.sleep(min(0.05, timeout / 4))
            changed = self._wd_changed
            if changed is not None and self.wall_clock() - changed > timeout:
                self._wd_changed = None  # tripped: armed again by the next change
                self.watchdog_trips += 1
                now = self.clock()
                self._refresh(now)
                for name, axis in self.axes.items():
                    axis.write(f"{name}_command", AXIS_STOP, now)
                self._refresh(now)
                log.warning("simulated PLC %s: watchdog %s silent for %.1f s: axes stopped",
                            self.name, self.section.watchdog, timeout)

    async def __aenter__(self) -> SimPlc:
        await self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()

    @property
    def port(self) -> int:
        return self.server.port

    # ------------------------------------------------------------- fault injection

    def set_responding(self, responding: bool) -> None:
        """False: requests are swallowed — no answer, no effect (a hung PLC)."""
        self.server.responding = responding

    def drop_connections(self) -> int:
        """Close every client connection; return how many."""
        return self.server.drop_connections()

    async def power_off(self) -> None:
        """Nothing listens any more (connections refused) until :meth:`power_on`."""
        await self.server.stop()

    async def power_on(self) -> None:
        await self.server.start()

    def stall(self, axis: str, stalled: bool = True) -> None:
        """Make an axis' motor stall now (or repair it)."""
        model = self.axes[axis]
        if stalled:
            model.inject_stall(self.clock())
        else:
            model.clear_stall(self.clock())

    def force(self, point: str, value) -> None:
        """Override a point's value (rain = True, wind = 30 m/s …) until :meth:`release`."""
        p = self.points[point]
        p.encode(value)  # refuse a value the register cannot hold now, not at the next read
        self._forced[point] = value

    def release(self, point: str) -> None:
        self._forced.pop(point, None)

    def read_point(self, point: str):
        """The engineering value of a point now, as a client would read it."""
        self._refresh(self.clock())
        p = self.points[point]
        return p.decode([self._image[p.kind].get(a, 0) for a in range(p.address, p.end)])

    # ------------------------------------------------------------- the register handler

    def _store(self, p: RegisterPoint, value) -> None:
        # encode() is a pure function of the point and the value: the words of the value
        # stored last are reused (the same type too: True and 1 encode alike, 1.0 and 1 may not)
        last = self._encoded.get(p.name)
        if last is not None and last[0] == value and type(last[0]) is type(value):
            raw = last[1]
        else:
            try:
                raw = p.encode(value)
            except ValueError:
                return  # a model value the register cannot hold keeps the last one
            self._encoded[p.name] = (value, raw)
        table = self._image[p.kind]
        for i, word in enumerate(raw):
            table[p.address + i] = word

    def _refresh(self, now: float) -> None:
        done = set()
        for model in self._owner.values():
            if id(model) in done:
                continue
            done.add(id(model))
            for point, value in model.update(now).items():
                p = self.points.get(point)
                if p is not None:
                    self._store(p, value)
        for point, value in self._forced.items():
            self._store(self.points[point], value)

    def read(self, kind: str, address: int, count: int) -> list:
        self._refresh(self.clock())
        table = self._image[kind]
        default = False if kind in ("coil", "discrete") else 0
        return [table.get(a, default) for a in range(address, address + count)]

    def write(self, kind: str, address: int, values: list) -> int | None:
        now = self.clock()
        self._refresh(now)
        end = address + len(values)
        touched = [p for p in self._by_kind[kind] if p.address < end and p.end > address]
        covered = sum(min(p.end, end) - max(p.address, address) for p in touched)
        if covered != len(values):
            return ILLEGAL_ADDRESS  # part of the write hits no point
        for p in touched:
            if p.address < address or p.end > end or not p.writable:
                return ILLEGAL_ADDRESS  # half of a 32-bit value, or a read-only point
        for p in touched:
            raw = values[p.address - address:p.end - address]
            if p.name == self.section.watchdog:
                value = p.decode(raw)
                if value != self._wd_value:
                    self._wd_value = value
                    self._wd_changed = self.wall_clock()
            model = self._owner.get(p.name)
            if model is not None:
                code = model.write(p.name, p.decode(raw), now)
                if code:
                    self._refresh(now)
                    return code
            else:
                for i, word in enumerate(raw):
                    self._image[kind][p.address + i] = word
        self._refresh(now)
        return None
