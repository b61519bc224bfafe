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

Faults handled here, while the service runs (no restart):

* **Recovery in place** — a supervisor thread (``tcs-recovery``, started with :meth:`start`)
  looks at every drive ten times a second; a drive that sent a boot-up (power blip, reset) or
  shows pre-operational / stopped (it lost the TCS heartbeat) and is no longer wanted enabled
  (:meth:`Cia402Drive.needs_reboot`) is booted again in a worker thread (``tcs-reboot``, up
  to four drives at once) — never in the cycle —
  with its TPDOs out of the cycle's barrier meanwhile. A failed attempt is retried with
  back-off (1 s doubling to 30 s) for as long as it fails, also when the node is silent (a
  drive that failed its boot at start-up too). The axis stays off; the operator's ``ERROR_STATE=0`` and
  ``POWER=1`` bring it back.
  One boot of a drive at a time: an explicit :meth:`boot` and the supervisor's re-boot of the
  same drive never run at once (a per-drive lock; the supervisor skips a drive being booted).
* **Bus faults** — bus-off and error passive (error frames, :class:`~tcs.drivers.canbus.BusHealth`)
  are a fault of every drive on the bus (:meth:`Cia402Drive.set_bus_fault`: its axis makes a
  controlled stop and shows the error); "restarted" / "error active" clear it.
* **Bus reconnect** — when :class:`CanBus` reopened a broken link (the socketcand peer died
  and came back, an interface went down and up) every drive is booted again as above.
* **Idle SYNC** — with ``[can] idle_sync_period`` the SYNC slows while every drive rests
  (:mod:`tcs.drivers.idle_sync`, ``self.idle``); a re-boot above counts as activity.
* **Clean stop** — :meth:`release` (after the axes are off) switches off every disabled
  drive's heartbeat consumer (0x1016:1 = 0) and puts it pre-operational, so stopping the
  service leaves no 0x8130 faults; a crash leaves the consumers armed and the drives react.

``step_all`` is a ready-made callback that steps every booted drive; the axis layer registers
its own callback instead, reading status, setting setpoints, and calling ``step()`` of its
drives.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tcs.config.can import CanSection, DriveSection
from tcs.drivers.boot import NMT_PRE_OPERATIONAL, send_nmt
from tcs.drivers.canbus import CanBus
from tcs.drivers.cia402_drive import Cia402Drive
from tcs.drivers.cycle import Cycle, CycleSource
from tcs.drivers.idle_sync import IdleSync
from tcs.drivers.worker import SdoWorker
from tcs.drivers.eds_check import check_config, log_report
from tcs.errors import ConfigError, ConfigErrors, TcsError
from tcs.resources import hwconfig_file

log = logging.getLogger(__name__)

SIM_EDS = hwconfig_file("eds/tcs-sim-drive.eds")  # package data (tcs.resources)


def stop_decelerations(drives: dict[str, DriveSection], axes) -> dict[str, DriveSection]:
    """The drives with 0x6085 (``quick_stop_deceleration``) at most their axis's configured
    stop deceleration (``[axes.x] stop_deceleration``, default 2 × max_acceleration): a drive
    that stops by itself — the master lost, a quick stop or a fault reaction — decelerates no
    harder than the TCS's own STOP."""
    import dataclasses
    out = dict(drives)
    for axis in (axes or {}).values():
        section = out.get(axis.drive)
        if section is None:
            continue
        stop = axis.stop_deceleration or 2 * axis.max_acceleration
        quick = section.quick_stop_deceleration or section.max_acceleration
        if stop < quick:
            out[axis.drive] = dataclasses.replace(section, quick_stop_deceleration=stop)
    return out


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
        self._clock = clock
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
        self.cycle.add_callback(self._note_cycle)  # (first: before any status is read)
        self.bus.add_error_callback(self._on_bus_error)
        self.bus.add_reconnect_callback(self._on_reconnect)
        self._supervisor: threading.Thread | None = None
        self._supervising = threading.Event()
        self._supervisor_stop = threading.Event()  # wakes the supervisor to end it
        self._retry: dict[str, tuple[float, float]] = {}  # name -> (next attempt, back-off)
        self._recovering: set[str] = set()
        self._boot_locks = {name: threading.Lock() for name in self.drives}  # one boot at a time
        self._pool: ThreadPoolExecutor | None = None
        self.recoveries = 0
        #: the slower SYNC of a resting telescope (``[can] idle_sync_period``; inactive at 0)
        self.idle = IdleSync(self.drives, self.cycle, self.worker, can, self._boot_locks, clock=clock)
        self._idle_added = False

    @classmethod
    def from_config(cls, config, **kwargs) -> CanDrives:
        """From a whole :class:`~tcs.config.HwConfig` (which must have a ``[can]`` section)."""
        if config.can is None:
            raise ConfigError(str(config.source), "can", "no [can] section")
        return cls(config.can, stop_decelerations(config.drives, getattr(config, "axes", None)),
                   resolve=config.resolve, file=str(config.source), **kwargs)

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
                with self._boot_locks[drive.name]:  # (waits for a re-boot under way)
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
        """Start SYNC and the cycle thread, and the recovery supervisor (and the idle SYNC,
        stepped after every callback added so far: after the drives' step)."""
        if self.idle.enabled and not self._idle_added:
            self._idle_added = True
            self.cycle.add_callback(self.idle.step)
        self.cycle.start()
        if self._supervisor is None:
            self._supervising.set()
            self._supervisor_stop.clear()
            self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="tcs-reboot")
            self._supervisor = threading.Thread(target=self._supervise, name="tcs-recovery",
                                                daemon=True)
            self._supervisor.start()

    def stop(self) -> None:
        """Stop SYNC and the cycle thread (enabled drives will fault on missing setpoints)."""
        self._stop_supervisor()
        self.cycle.stop()

    def _stop_supervisor(self) -> None:
        self._supervising.clear()
        self._supervisor_stop.set()
        thread, self._supervisor = self._supervisor, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=10.0)
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True)  # (a boot under way ends within its boot_timeout)

    # ----------------------------------------------------------------- recovery, bus faults
    def _supervise(self) -> None:
        while self._supervising.is_set():
            for name, drive in self.drives.items():
                if not self._supervising.is_set():
                    return
                try:
                    if name not in self._recovering and drive.needs_reboot() and \
                            time.monotonic() >= self._retry.get(name, (0.0, 0.5))[0]:
                        self._recovering.add(name)  # one boot thread per drive, several at once
                        self._pool.submit(self._recover, name, drive)
                except Exception:  # the supervisor must outlive any one drive's trouble
                    log.exception("%s: recovery failed", drive.device)
            if self._supervisor_stop.wait(0.1):
                return

    def _recover(self, name: str, drive: Cia402Drive) -> None:
        try:
            self._reboot(name, drive)
        except Exception:
            log.exception("%s: recovery failed", drive.device)
        finally:
            self._recovering.discard(name)

    def _reboot(self, name: str, drive: Cia402Drive) -> None:
        lock = self._boot_locks[name]
        if not lock.acquire(blocking=False):
            return  # booted right now by boot(): two boots at once detach each other's node
        try:
            if drive.needs_reboot():  # (not when a boot() just finished)
                self._reboot_locked(name, drive)
        finally:
            lock.release()

    def _reboot_locked(self, name: str, drive: Cia402Drive) -> None:
        backoff = self._retry.get(name, (0.0, 0.5))[1]
        log.warning("%s must be booted again (it rebooted, lost the TCS heartbeat, or the bus "
                    "was reopened): booting it", drive.device)
        self.cycle.forget_tpdos(drive.sync_tpdo_ids)
        try:
            drive.boot()
        except TcsError as exc:
            backoff = min(2 * backoff, 30.0)
            self._retry[name] = (time.monotonic() + backoff, backoff)
            log.error("%s (retry in %g s)", exc, backoff)
            return
        self._retry.pop(name, None)
        self.cycle.expect_tpdos(drive.sync_tpdo_ids)
        self.recoveries += 1
        log.warning("%s booted again; its axis stays off until ERROR_STATE=0 and POWER=1",
                    drive.device)

    def _note_cycle(self, cycle: Cycle) -> None:
        """Each cycle, first: the drives notice a stall of this process (heartbeat window)."""
        now = self._clock()
        step = self.cycle.period * self.cycle.divider
        for drive in self.drives.values():
            drive.note_cycle(now, step, cycle)

    def _on_bus_error(self, error: TcsError) -> None:
        """Bus health changed (notifier thread): bus-off / error passive fault every drive."""
        state = self.bus.health().state
        fault = error if state in ("bus-off", "passive") else None
        if state not in ("bus-off", "passive", "ok"):
            return  # warnings, single error frames: counted, not acted on
        for drive in self.drives.values():
            drive.set_bus_fault(fault)

    def _on_reconnect(self) -> None:
        """The bus was reopened: every drive is booted again (as after a power blip)."""
        for drive in self.drives.values():
            drive.request_reboot()
        self._retry.clear()

    def release(self) -> None:
        """Clean stop (blocking; after the axes are off): every booted drive that is not
        enabled gets its TCS-heartbeat consumer switched off (0x1016:1 = 0) and NMT
        pre-operational, so the service's end leaves no heartbeat faults. An enabled drive
        is left watching: it reacts when the heartbeat stops."""
        from tcs.drivers.drive import DriveState

        self._stop_supervisor()

        def release(drive: Cia402Drive) -> None:
            status = drive.status()
            if not status.booted or status.state in (DriveState.OPERATION_ENABLED,
                                                      DriveState.QUICK_STOP_ACTIVE,
                                                      DriveState.OFFLINE):
                return
            try:
                drive.release()
                send_nmt(self.bus.network, NMT_PRE_OPERATIONAL, drive.node_id)
            except Exception as exc:
                log.warning("%s: could not switch its heartbeat consumer off: %s", drive.device, exc)

        drives = list(self.drives.values())
        if drives:  # one SDO exchange per drive, all drives at once (as the boot)
            with ThreadPoolExecutor(max_workers=len(drives), thread_name_prefix="tcs-release") as pool:
                list(pool.map(release, drives))

    def close(self) -> None:
        """Stop everything this object started (idempotent)."""
        self._stop_supervisor()
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
