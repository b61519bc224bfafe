"""The CAN side of a telescope as the hardware file describes it: bus, drives, cycle.

:class:`CanDrives` is what the service (and tools, tests, benchmarks) create::

    system = CanDrives.from_config(config)     # nothing opened yet
    system.open()                              # bus + notifier + TCS heartbeat + SDO worker
    failures = system.boot()                   # blocking; {name: error} of the drives that failed
    system.cycle.add_callback(control_loop)    # control_loop(cycle) steps the drives
    system.start()                             # SYNC + the cycle thread
    ...
    system.close()                             # stop cycle, forget nodes, close the bus

Booting is blocking (run it in a thread from asyncio: ``await asyncio.to_thread(system.boot)``);
the drives boot in parallel, one thread each, so a node that never answers costs its own
``boot_timeout`` and nothing else. A drive that failed stays in ``drives`` as offline with
its boot error as ``status().fault``; ``boot([name])`` retries it (not while the cycle is
stepping that drive in a mode switch — boot is a set-up action).

``step_all`` is a ready-made callback that steps every booted drive; the axis layer registers
its own callback instead, reading status, setting setpoints, and calling ``step()`` of its
drives.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tcs.config.can import CanSection, DriveSection
from tcs.drivers.canbus import CanBus
from tcs.drivers.cia402_drive import Cia402Drive
from tcs.drivers.cycle import Cycle, CycleSource
from tcs.drivers.worker import SdoWorker
from tcs.drivers.eds_check import check_config, log_report
from tcs.errors import ConfigError, ConfigErrors, TcsError
from tcs.resources import hwconfig_file

log = logging.getLogger(__name__)

SIM_EDS = hwconfig_file("eds/tcs-sim-drive.eds")  # package data (tcs.resources)


class CanDrives:
    """Bus, CiA-402 drives and SYNC cycle of one ``[can]`` section and its ``[drives]``.

    Parameters
    ----------
    can:
        The ``[can]`` table.
    drives:
        ``{name: DriveSection}``.
    resolve:
        Turns a path written in the hardware file into a real path (``HwConfig.resolve``).
    file:
        The hardware file's name, for error messages.
    clock:
        Monotonic clock for the drives and the cycle.
    """

    def __init__(self, can: CanSection, drives: dict[str, DriveSection], *,
                 resolve: Callable[[str], Path] = Path, file: str = "<hardware file>",
                 clock: Callable[[], float] = time.monotonic):
        self.can = can
        self.bus = CanBus(can)
        self.worker = SdoWorker()
        self.cycle = CycleSource(self.bus, can.sync_period, tpdo_deadline=can.tpdo_deadline,
                                 clock=clock, realtime_priority=can.realtime_priority)
        self.drives: dict[str, Cia402Drive] = {}
        # Each drive's configuration against its EDS: refused here, at start, not mid-boot.
        problems, self.eds_reports = check_config(can, drives, None, resolve, file)
        if problems:
            raise ConfigErrors(problems)
        log_report(self.eds_reports)
        for name, section in drives.items():
            eds = resolve(section.eds) if section.eds else SIM_EDS
            if not Path(eds).is_file():
                raise ConfigError(file, f"drives.{name}.eds", f"EDS file {eds} not found")
            self.drives[name] = Cia402Drive(self.bus, name, section, can, eds=eds,
                                            worker=self.worker, clock=clock)

    @classmethod
    def from_config(cls, config, **kwargs) -> CanDrives:
        """From a whole :class:`~tcs.config.HwConfig` (which must have a ``[can]`` section)."""
        if config.can is None:
            raise ConfigError(str(config.source), "can", "no [can] section")
        return cls(config.can, dict(config.drives), resolve=config.resolve,
                   file=str(config.source), **kwargs)

    # ----------------------------------------------------------------- life cycle
    def open(self, heartbeat: bool = True) -> CanDrives:
        """Open the bus (notifier, TCS heartbeat unless ``heartbeat=False``) and start the SDO
        worker (blocking)."""
        self.bus.open(heartbeat)
        self.worker.start()
        return self

    def boot(self, names: Iterable[str] | None = None) -> dict[str, TcsError]:
        """Boot the named drives (default all) in parallel; return ``{name: error}`` of failures.

        Drives that booted are added to the cycle's TPDO barrier; the others are left out
        (and removed from it, when a retry fails).
        """
        chosen = [self.drives[n] for n in (names if names is not None else self.drives)]
        failures: dict[str, TcsError] = {}
        if not chosen:
            return failures

        def one(drive: Cia402Drive) -> TcsError | None:
            try:
                drive.boot()
            except TcsError as exc:
                return exc
            return None

        with ThreadPoolExecutor(max_workers=len(chosen), thread_name_prefix="tcs-boot") as pool:
            results = list(pool.map(one, chosen))
        for drive, error in zip(chosen, results):
            if error is None:
                self.cycle.expect_tpdos(drive.sync_tpdo_ids)
                log.info("%s booted", drive.device)
            else:
                self.cycle.forget_tpdos(drive.sync_tpdo_ids)
                failures[drive.name] = error
                log.error("%s", error)
        return failures

    def start(self) -> None:
        """Start SYNC and the cycle thread."""
        self.cycle.start()

    def stop(self) -> None:
        """Stop SYNC and the cycle thread (enabled drives will fault on missing setpoints)."""
        self.cycle.stop()

    def close(self) -> None:
        """Stop everything this object started (idempotent)."""
        self.cycle.stop()
        self.worker.stop()
        for drive in self.drives.values():
            drive.close()
        self.bus.close()

    def __enter__(self) -> CanDrives:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    # ----------------------------------------------------------------- cycle helpers
    def step_all(self, cycle: Cycle | None = None) -> None:
        """A cycle callback that steps every drive (booted ones send their RPDO)."""
        for drive in self.drives.values():
            drive.step()
