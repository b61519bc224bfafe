"""The idle SYNC: a slower cycle while every drive rests with its power stage off.

A telescope spends most of its life parked with the drives disabled, and at 10 ms the cycle
costs the same whether anything moves or not: a SYNC, an RPDO per drive and its TPDOs every
period, each through the CAN stack, the drivers and (simulated) drives. With ``[can]
idle_sync_period`` set (a multiple of ``sync_period``, e.g. 0.05 s), :class:`IdleSync` slows
the SYNC to it while nothing can move, and brings the full rate back before anything can.

States (``state``), stepped once per cycle in the cycle thread after the axes' step:

* ``full`` — SYNC every ``sync_period``. When every drive has been :meth:`resting
  <tcs.drivers.cia402_drive.Cia402Drive.resting>` (booted drives in a state without power
  stage, not wanted enabled, no request or SDO job under way) for :data:`IDLE_AFTER` s with
  no drive booted meanwhile, the drives are told first: a job on the bus's SDO worker writes
  each drive's RPDO deadlines for the slower period, then its 0x1006
  (:func:`tcs.drivers.boot.cycle_period_writes`) → ``relaxing``.
* ``relaxing`` — the job runs; the SYNC is still fast, so every drive keeps getting its RPDOs
  long before the wider deadlines. Done: the SYNC slows (:meth:`CycleSource.set_divider
  <tcs.drivers.cycle.CycleSource.set_divider>`) → ``idle``. A drive that refused a write (some
  devices change PDO parameters only in pre-operational), or one that is being booted, ends
  the attempt: the drives written so far get their full-rate values back (``tightening``), and
  the next attempt waits :data:`RETRY_AFTER` s (a refusal is logged once, as a warning).
* ``idle`` — SYNC every ``idle_sync_period``. Any drive not resting (an enable requested, a
  reset, a fault reset, a drive booted again, data gone stale) → the SYNC speeds up at once →
  ``tightening``.
* ``tightening`` — a job writes each drive's 0x1006 for the full rate, then its deadlines
  back (exactly the boot's values, only the objects that were changed). A drive is released
  to switch its power stage on (its ``may_enable`` gate) once its own writes are done; a
  drive whose writes failed is tried again every second and stays held (its enable times
  out with the driver's usual error) — its deadlines are still the wide ones. All done →
  ``full``.

Safety: a drive never gets its power stage while the SYNC is slow or its deadlines are wide —
:meth:`Cia402Drive.step <tcs.drivers.cia402_drive.Cia402Drive.step>` holds an enable
(controlword for "disabled") while ``may_enable()`` is false, and the idle state is entered
only when every drive rests. The TCS heartbeat, the drives' heartbeats and EMCYs do not depend
on the SYNC; a fault shows in the next TPDO (at most ``idle_sync_period`` later). The
readbacks of a resting telescope come at the idle rate (``CABINET.CORE.CYCLE.CYCLES`` counts
the SYNCs sent).

Who touches it: :class:`tcs.drivers.can_system.CanDrives` creates one and adds :meth:`step`
to the cycle when it starts; each drive's ``may_enable`` (a gate set here) is called from its
step (cycle thread); jobs run in the SDO worker thread. ``state``, ``entered`` and ``left``
may be read from any thread.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from tcs.config.can import CanSection
from tcs.drivers.cia402_drive import Cia402Drive
from tcs.drivers.cycle import Cycle, CycleSource
from tcs.drivers.worker import Job, SdoWorker

log = logging.getLogger(__name__)

#: Seconds every drive must have rested before the SYNC slows (a power cycle of the operator,
#: a fault reset, a re-boot settle first).
IDLE_AFTER = 2.0
#: Seconds before another attempt after one that failed (a refusing drive, a boot under way).
RETRY_AFTER = 60.0
#: Seconds between attempts to restore a drive whose full-rate writes failed.
TIGHTEN_RETRY = 1.0


class IdleSync:
    """Slows the SYNC of ``cycle`` to ``can.idle_sync_period`` while every drive rests.

    Parameters
    ----------
    drives:
        The bus's drives by name.
    cycle, worker, can:
        The bus's cycle source, SDO worker and ``[can]`` table.
    locks:
        The per-drive boot locks (:class:`~tcs.drivers.can_system.CanDrives`): a job never
        writes to a drive that is being booted.
    clock:
        Monotonic clock.
    """

    def __init__(self, drives: dict[str, Cia402Drive], cycle: CycleSource, worker: SdoWorker,
                 can: CanSection, locks: dict[str, threading.Lock],
                 clock: Callable[[], float] = time.monotonic):
        self.drives = drives
        self.cycle = cycle
        self.worker = worker
        self.full_period = can.sync_period
        self.idle_period = can.idle_sync_period or can.sync_period
        self.divider = max(1, round(self.idle_period / self.full_period))
        self._locks = locks
        self._clock = clock
        self.state = "full"
        self._job: Job | None = None
        self._tight: set[str] = set()     # drives back at the full rate while tightening
        self._loose: dict[str, list] = {}  # drive -> objects told the slow rate
        self._quiet_since: float | None = None
        self._generation: tuple[int, ...] | None = None
        self._not_before = 0.0
        self._retry_at = 0.0
        self._warned = False
        self._restore_warned = False
        self.entered = 0                  # times the SYNC slowed
        self.left = 0                     # times it came back
        for name, drive in drives.items():
            drive.may_enable = self._gate(name)

    @property
    def enabled(self) -> bool:
        return self.divider > 1

    def _gate(self, name: str) -> Callable[[], bool]:
        def may_enable() -> bool:
            state = self.state
            return state == "full" or (state == "tightening" and name in self._tight)
        return may_enable

    # ---------------------------------------------------------------- cycle thread
    def step(self, cycle: Cycle | None = None) -> None:
        """Once per cycle, after the drives' step (cycle thread)."""
        if not self.enabled:
            return
        now = self._clock()
        generation = tuple(d.boot_count for d in self.drives.values())
        booted, self._generation = generation != self._generation, generation
        resting = not booted and all(d.resting() for d in self.drives.values())
        state = self.state
        if state == "full":
            if not resting or now < self._not_before:
                self._quiet_since = None
            elif self._quiet_since is None:
                self._quiet_since = now
            elif now - self._quiet_since >= IDLE_AFTER:
                self._loose = {}
                self._job = self.worker.submit(self._relax, "idle SYNC: slower")
                self.state = "relaxing"
        elif state == "relaxing":
            job = self._job
            if not job.done:
                return
            self._job = None
            if job.error is not None:
                self._failed(job.error, now)
                self._tighten()
            elif not resting:
                self._tighten()  # (wanted while the drives were being told)
            else:
                self.cycle.set_divider(self.divider)
                self.state = "idle"
                self.entered += 1
                log.info("idle SYNC: every drive rests; SYNC every %g s now (%g s when anything "
                         "is to move)", self.idle_period, self.full_period)
        elif state == "idle":
            if not resting:
                self.cycle.set_divider(1)
                self.left += 1
                log.info("idle SYNC: SYNC every %g s again", self.full_period)
                self._tighten()
        elif state == "tightening":
            job = self._job
            if job is not None and not job.done:
                return
            if job is not None:
                self._job = None
                if job.error is not None:
                    (log.debug if self._restore_warned else log.error)(
                        "idle SYNC: could not give every drive its full-rate SYNC period and RPDO "
                        "deadlines back (%s); held off its power stage, trying again every %g s",
                        job.error, TIGHTEN_RETRY)
                    self._restore_warned = True
                    self._retry_at = now + TIGHTEN_RETRY
            if set(self._loose) - self._tight:
                if now >= self._retry_at:
                    self._job = self.worker.submit(self._restore, "idle SYNC: full rate")
                return
            if self._restore_warned:
                log.warning("idle SYNC: every drive has its full-rate values back")
                self._restore_warned = False
            self.state = "full"
            self._quiet_since = None

    def _tighten(self) -> None:
        self.cycle.set_divider(1)
        self._tight = set()
        self._retry_at = 0.0
        self.state = "tightening"
        self._job = self.worker.submit(self._restore, "idle SYNC: full rate")

    def _failed(self, error: BaseException, now: float) -> None:
        self._not_before = now + RETRY_AFTER
        if isinstance(error, _Busy):
            log.debug("idle SYNC: %s; trying again later", error)
        elif not self._warned:
            self._warned = True
            log.warning("idle SYNC not used: %s; the SYNC stays at %g s (tried again every %g s)",
                        error, self.full_period, RETRY_AFTER)
        else:
            log.debug("idle SYNC not used: %s", error)

    # ---------------------------------------------------------------- SDO worker thread
    def _relax(self) -> None:
        for name, drive in self.drives.items():
            lock = self._locks[name]
            if not lock.acquire(blocking=False):
                raise _Busy(f"{drive.device} is being booted")
            try:
                done = self._loose[name] = []  # (filled as it goes: a refusal half-way is undone)
                drive.write_cycle_period(self.idle_period, done)
            finally:
                lock.release()

    def _restore(self) -> None:
        errors = []
        for name in sorted(set(self._loose) - self._tight):
            drive = self.drives[name]
            lock = self._locks[name]
            if not lock.acquire(blocking=False):
                self._tight.add(name)  # being booted: the boot writes the full-rate values
                continue
            try:
                drive.write_cycle_period(self.full_period, only=set(self._loose[name]))
                self._tight.add(name)
            except Exception as exc:
                errors.append(str(exc))
            finally:
                lock.release()
        if errors:
            raise _RestoreFailed("; ".join(errors))


class _Busy(RuntimeError):
    """A drive is being booted: no writes to it now."""


class _RestoreFailed(RuntimeError):
    """Some drives did not take their full-rate values back."""
