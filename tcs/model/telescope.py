"""The telescope model: every domain object of one hardware file, built and owned in one place.

:class:`Telescope` is what the OpenTCI declaration binds to. It creates the event hub, the
persistent state store, LOCAL and CONFIG, the axes on their CiA-402 drives (with the control
loop) and, where the file has a ``[simulation]`` section, the simulated drives on the same
``virtual`` bus in this process. Hardware is started and stopped with :meth:`start` /
:meth:`stop` on the server's event loop; attributes that are ``None`` (or empty lists) are
modules the hardware file does not configure, and so do not exist in the tree.

Start order: on a bus other processes share (socketcan, socketcand) the bus is opened first,
silently, and the start is refused (:class:`~tcs.drivers.bus_check.AnotherMaster`, nothing sent
on the bus, nothing started) when another master is heard on it → the PLC and GPS side
(:class:`~tcs.model.peripherals.Peripherals`: their simulators on a virtual bus, drivers, then
DOME[], COVER, SENSOR[], SWITCH[], GPS) → drive simulators (they are "the hardware") → bus
(its TCS heartbeat) → boot every drive in parallel (a drive that fails
to boot leaves its axis in ERROR_STATE, the others work) → axes → control loop and SYNC. Stop
order is the reverse; axes are stopped and their drives disabled first, then released (their
consumer of the TCS heartbeat switched off, NMT pre-operational: a clean stop leaves no drive
faults; a crash does, on purpose).
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import ThreadPoolExecutor

from tcs.config import HwConfig
from tcs.errors import TcsError
from tcs.model.cabinet import Cabinet
from tcs.model.events import EventHub
from tcs.model.log_buffer import LogBuffer
from tcs.model.health import ERROR, WARNING
from tcs.model.local import LocalTime
from tcs.model.mount_config import MountConfig
from tcs.model.peripherals import Peripherals
from tcs.model.state_store import StateDirectoryLock, StateStore

log = logging.getLogger(__name__)


class Telescope:
    """All domain objects of one telescope."""

    def __init__(self, config: HwConfig):
        self.config = config
        self.events = EventHub()
        self.state_dir = config.state_dir()
        self._state_lock = StateDirectoryLock(self.state_dir)  # one service per state directory
        self.store = StateStore(self.state_dir)
        self.local = LocalTime(config, self.store, self.events)
        self.mount_config = MountConfig(config, self.store, self.events)
        self.log_buffer = LogBuffer(config.cabinet.log_lines)
        self.cabinet = Cabinet(config, self.store, self.events, log_buffer=self.log_buffer)
        # whole-telescope verbs and summary states (the OpenTSI tree binds to them)
        from tcs.model.operations import Operations
        self.operations = Operations(self)
        self.cabinet.attach(modules=[self.local, self.mount_config, self.operations])
        self.status_sink = self.cabinet.status_sink
        # DOME[], COVER, SENSOR[], SWITCH[] and GPS on PLCs and NMEA (tcs.model.peripherals)
        self.peripherals = Peripherals(config, events=self.events, local=self.local,
                                       mount_config=self.mount_config, cabinet=self.cabinet)
        self.dome = None  # the DOME[] elements once started (None: no dome)
        self.axes: list = []
        self.can = None
        self.sims = None
        self.control_loop = None
        self.pointing = None  # POINTING (tcs.pointing.pointing_module), made after the axes
        self._blocking: ThreadPoolExecutor | None = None  # boot, bus open/close: off the loop
        self._bus_lock = None  # this machine's lock of a shared bus (tcs.drivers.bus_check)

    # -- lookup for the declaration ---------------------------------------------------------
    def axis(self, module: str):
        """The plain axis module ``module`` (AZ, ZD, HA, DEC, FOCUS, MIRROR) or None."""
        for a in self.axes:
            if a.section.module == module and a.section.index is None:
                return a
        return None

    def axis_array(self, module: str) -> list:
        """Elements of an axis module array, index = position (ports without an axis: absent).

        OpenTCI arrays have consecutive indices; a DEROTATOR at port 2 and one at port 3 give
        ``DEROTATOR[2]`` and ``DEROTATOR[3]`` with elements 0 and 1 absent, so the array holds
        ``None`` there and the tree skips nothing: those elements answer UNKNOWN members."""
        found = {a.section.index: a for a in self.axes
                 if a.section.module == module and a.section.index is not None}
        if not found:
            return []
        return [found.get(i) for i in range(max(found) + 1)]

    def modules_health(self):
        """Every domain object with an ERROR_STATE (for CABINET.ERROR_STATE)."""
        return [m for m in (self.local, self.mount_config, self.operations, *self.axes) if m is not None]

    @property
    def main_power(self) -> bool:
        return True if self.cabinet is None else bool(getattr(self.cabinet, "main_power", True))

    async def run_blocking(self, fn, *args):
        """Run a blocking set-up call (boot, open, close) in the telescope's own worker thread."""
        if self._blocking is None:
            self._blocking = ThreadPoolExecutor(max_workers=2, thread_name_prefix="tcs-blocking")
        return await asyncio.get_running_loop().run_in_executor(self._blocking, fn, *args)

    # -- life cycle ------------------------------------------------------------------------------
    def release_state_dir(self) -> None:
        """Let another service use the state directory (after :meth:`stop`, or a failed start)."""
        self._state_lock.release()

    async def start(self) -> None:
        """Bring up the simulators (if any), the bus, the drives, the axes and the loop."""
        self.events.bind_loop()
        await self.cabinet.start()
        try:
            await self._claim_bus()
            await self.peripherals.start()  # PLC/GPS simulators (virtual bus), drivers, modules
        except BaseException:
            await self.stop()
            raise
        self.dome = self.peripherals.dome or None
        if self.config.can is not None and self.config.drives:
            try:
                await self._start_can()
            except BaseException:
                await self.stop()
                raise

    async def _claim_bus(self) -> None:
        """On a shared bus, listen for another master before this process sends anything.

        Raises
        ------
        AnotherMaster
            Somebody else sends SYNC or the TCS node's heartbeat; the bus is closed again.
        """
        config = self.config
        if config.can is None or not config.drives:
            return
        if config.can.control_process:  # the control process listens before it sends
            from tcs.axes.control_process import ControlProcess
            process = ControlProcess(config, self.local, self.events)
            await self.run_blocking(process.claim, asyncio.get_running_loop())
            self.can = process
            return
        if config.can.interface == "virtual":
            return  # an in-process bus: nobody else can be on it
        from tcs.drivers.bus_check import claim
        from tcs.drivers.can_system import CanDrives

        can = CanDrives.from_config(config)
        self._bus_lock = await self.run_blocking(claim, can)  # (refused: nothing sent)
        self.can = can

    async def _start_can(self) -> None:
        from tcs.axes.axis import Axis, homing_search
        from tcs.axes.control_loop import ControlLoop
        from tcs.drivers.can_system import CanDrives

        config = self.config
        if config.can.control_process:
            await self._start_control_process()
            return
        if config.simulation is not None and config.simulation.drives and config.can.interface == "virtual":
            # simulated drives on an in-process bus live here; on any other bus they are
            # somebody else's (tcs-sim, a gateway), and only the bus settings differ
            from tcs.sim.drive_network import start_simulated_drives
            self.sims = start_simulated_drives(config)
        if self.can is None:
            self.can = CanDrives.from_config(config)
            await self.run_blocking(self.can.open)
        else:  # claimed by _claim_bus: the bus was quiet
            self.can.bus.start_heartbeat()
        failures: dict[str, TcsError] = await self.run_blocking(self.can.boot)
        loop = asyncio.get_running_loop()
        for name, section in config.axes.items():
            axis = Axis(name, section, self.can.drives[section.drive], self.events, self.local.ut1,
                        config.can.sync_period, status_sink=self.status_sink,
                        main_power=lambda: self.main_power)
            axis.bind_loop(loop)
            axis.homing_search = homing_search(config.drives.get(section.drive))
            if section.drive in failures:
                axis.raise_condition("drive offline", ERROR, failures[section.drive].message)
            report = self.can.eds_reports.get(section.drive)
            for name, text in (report.conditions if report is not None else ()):
                axis.raise_condition(name, WARNING, text)  # e.g. no heartbeat consumer: loud
            self.axes.append(axis)
        self.cabinet.attach(axes=self.axes)
        self.operations.park_positions()  # SetPark's saved positions onto the axes (PARKPOS)
        self.control_loop = ControlLoop(self.axes, self.can.cycle, self.local.ut1)
        self.cabinet.loop_stats = self.control_loop.stats
        from tcs.pointing.pointing_module import make_pointing
        self.pointing = make_pointing(self)
        if self.pointing is not None:
            self.cabinet.attach(modules=[self.pointing])
        self.can.start()

    async def _start_control_process(self) -> None:
        """``[can] control_process``: bus, drives, simulated drives and the loop in a child
        process (:mod:`tcs.axes.control_core`); the axes here are its asyncio side."""
        from tcs.axes.axis import homing_search
        from tcs.axes.control_process import RemoteAxis, RemoteLoop, rebuild_error

        config = self.config
        loop = asyncio.get_running_loop()
        process = self.can  # started and claimed the bus in _claim_bus (stop: close ends it)
        info = await self.run_blocking(process.boot)
        log.info("control loop and CAN drivers%s run in the control process (pid %d, %s)",
                 " (and the simulated drives)" if config.can.interface == "virtual" and config.simulation
                 else "", process.proc.pid, f"real-time priority {config.can.realtime_priority}"
                 if info.get("realtime") else "normal scheduling")
        for index, (name, section) in enumerate(config.axes.items()):
            axis = RemoteAxis(process, index, name, section, None, self.events, self.local.ut1,
                              config.can.sync_period, status_sink=self.status_sink,
                              main_power=lambda: self.main_power)
            axis.bind_loop(loop)
            axis.homing_search = homing_search(config.drives.get(section.drive))
            failure = info.get("failures", {}).get(section.drive)
            if failure is not None:
                axis.raise_condition("drive offline", ERROR, rebuild_error(failure).message)
            for condition, text in info.get("conditions", {}).get(section.drive, ()):
                axis.raise_condition(condition, WARNING, text)
            self.axes.append(axis)
        process.attach(self.axes)
        self.cabinet.attach(axes=self.axes)
        self.operations.park_positions()  # SetPark's saved positions onto the axes (PARKPOS)
        self.control_loop = RemoteLoop(process, config.can.sync_period)
        self.cabinet.loop_stats = self.control_loop.stats
        from tcs.pointing.pointing_module import make_pointing
        self.pointing = make_pointing(self)
        if self.pointing is not None:
            self.cabinet.attach(modules=[self.pointing])

    async def stop(self) -> None:
        """Stop motion, disable the drives, stop the loop and the bus, stop the simulators."""
        await self.operations.close()
        if self.pointing is not None:
            await self.pointing.close()  # tracking ends before the axes are stopped
        if self.can is not None:
            for axis in self.axes:
                axis.stop()
            deadline = time.monotonic() + 5.0
            running = lambda: self.control_loop is not None and getattr(self.control_loop, "alive", True)  # noqa: E731
            while running() and time.monotonic() < deadline and any(
                    axis.motion_state & 1 for axis in self.axes):
                await asyncio.sleep(0.02)
            for axis in self.axes:
                axis.shutdown()
            while running() and time.monotonic() < deadline and any(
                    axis.power_state != 0.0 for axis in self.axes):
                await asyncio.sleep(0.02)
            # clean stop: the disabled drives stop watching our heartbeat (no 0x8130 faults
            # left behind); an enabled one keeps watching and reacts when it stops
            await self.run_blocking(self.can.release)
            await self.run_blocking(self.can.close)
            self.can = None
        if self._bus_lock is not None:
            self._bus_lock.close()
            self._bus_lock = None
        if self.sims is not None:
            await self.run_blocking(self.sims.stop)
            self.sims = None
        await self.peripherals.stop()
        await self.cabinet.close()
        self.release_state_dir()
        if self._blocking is not None:
            self._blocking.shutdown(wait=True)
            self._blocking = None

