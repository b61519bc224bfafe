"""The cyclic control loop: one step per SYNC period for every axis, in its own thread.

:class:`ControlLoop` is a callback of the drivers' :class:`~tcs.drivers.cycle.CycleSource`
(the ``tcs-cycle`` thread): each SYNC period it computes the UT1 time at which this cycle's
setpoints will be *reached*, then runs :meth:`tcs.axes.axis.Axis.cycle` of every axis —
which reads its drive's status, computes and hands over the setpoint and steps the drive. The
asyncio world never runs here: axes take commands through their own lock-protected queues.

When a setpoint is reached (docs/cia402.md, "The CSP cycle"): the RPDO sent in cycle k is
latched by the drives at SYNC k+1, and a CSP drive then interpolates linearly from its
previous demand to it over the interpolation period 0x60C2 (= the SYNC period), so the
demand equals the setpoint at SYNC k+1 + one period. Computing the setpoint for the next SYNC
instead would make every trajectory lag by one period (36″ at 1°/s). The delay is
``reach_delay`` (default: one SYNC period).

A fault of one axis of the mount (AZ/ZD, HA/DEC) gives the others up too when they move:
they are stopped and powered off (:meth:`tcs.axes.axis.Axis.give_up`; the driver brings
each drive to a controlled stop before it disables it).

Health is reported, not assumed: the loop counts its own exceptions (an axis whose step raises
is logged, counted and stopped; the other axes go on) and the cycle source counts late and
missed cycles; :meth:`healthy` is what the systemd watchdog is fed from. Each step's own time
and the SYNC's lateness also go into fixed-bucket histograms (:data:`HISTOGRAM_BOUNDS`,
cumulative counts in :meth:`stats`, for ``/metrics``: a few integer additions per cycle).
"""

from __future__ import annotations

import bisect
import logging
import time
from typing import Callable, Sequence

from tcs.drivers.cycle import Cycle, CycleSource
from tcs.errors import ErrorNumber, TcsError
from tcs.state_epoch import bump as bump_epoch

log = logging.getLogger(__name__)

MOUNT_MODULES = frozenset({"AZ", "ZD", "HA", "DEC"})

#: Upper bounds (s) of the loop-time and lateness histogram buckets (one more: +Inf).
HISTOGRAM_BOUNDS = (0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1)


class Histogram:
    """Counts per bucket of ``bounds`` (default :data:`HISTOGRAM_BOUNDS`; one more bucket past
    the last bound) and the sum; written by one thread only (the loop's: the control loop;
    the event loop's: a front end's command latencies)."""

    __slots__ = ("bounds", "counts", "sum")

    def __init__(self, bounds: tuple[float, ...] = HISTOGRAM_BOUNDS) -> None:
        self.bounds = bounds
        self.counts = [0] * (len(bounds) + 1)
        self.sum = 0.0

    def observe(self, value: float) -> None:
        self.counts[bisect.bisect_left(self.bounds, value)] += 1
        self.sum += value

    def export(self) -> tuple[list[int], float]:
        return list(self.counts), self.sum


class ControlLoop:
    """Steps ``axes`` once per cycle of ``source``; ``ut1()`` is the telescope's time base;
    ``reach_delay`` is how long after the next SYNC a drive reaches the setpoint (s)."""

    def __init__(self, axes: Sequence, source: CycleSource, ut1: Callable[[], float],
                 clock: Callable[[], float] = time.monotonic, reach_delay: float | None = None):
        self.axes = list(axes)
        self.source = source
        self.reach_delay = source.period if reach_delay is None else float(reach_delay)
        self.ut1 = ut1
        self.clock = clock
        self.errors = 0
        self.cycles = 0
        self.resumes = 0  # cycles after a gap (Cycle.resumed): the axes re-anchored
        self.last_cycle = 0.0
        self.max_step = 0.0
        self.setpoint_ut1 = self.measured_ut1 = 0.0
        self.loop_time = Histogram()   # each step's own time
        self.lateness = Histogram()    # each SYNC's lateness (the cycle source's newest)
        self.mount = [a for a in self.axes if getattr(getattr(a, "section", None), "module", None)
                      in MOUNT_MODULES and getattr(a.section, "index", None) is None]
        self._mount_faulted: set = set()
        source.add_callback(self.step)

    #: a monotonic/UT1 reading pair is taken again when a preemption between the reads
    #: made them further apart than this (s)
    PAIR_SPREAD = 50e-6

    def _clocks(self) -> tuple[float, float, float]:
        """(monotonic now, the monotonic time ``ut1`` was read at, ``ut1``). The UT1 clock and
        the cycle's monotonic clock are read one after the other: a thread preempted between
        the two reads on a busy host maps cycle times to UT1 wrongly by the preemption, and a
        trajectory sampled there is off its path by velocity × preemption (4″ at 3°/s for
        0.4 ms were seen). So the UT1 read is bracketed by two monotonic reads and taken
        again (twice at most; the tightest pair is kept) when they are far apart."""
        now = before = self.clock()
        best = None
        for _ in range(3):
            ut1 = self.ut1()
            after = self.clock()
            spread = after - before
            if best is None or spread < best[0]:
                best = (spread, (before + after) / 2, ut1)
            if spread <= self.PAIR_SPREAD:
                break
            before = after
        return now, best[1], best[2]

    def step(self, cycle: Cycle) -> None:
        now, at, ut1 = self._clocks()
        t = ut1 + (cycle.next_sync - at) + self.reach_delay
        measured = ut1 + (cycle.sync_time - at)  # the drives sampled their position at SYNC
        #: for observers (tests, diagnostics): this cycle's setpoint and measurement times
        self.setpoint_ut1, self.measured_ut1 = t, measured
        # (after a gap the axes re-anchor on their drives' readback; the interval to the next
        # SYNC bounds the next setpoint step: tcs.axes.axis, "Stall recovery" in docs/motion.md)
        resumed, times = cycle.resumed, (cycle.sync_time, cycle.next_sync)
        periods = 1
        if cycle.previous_sync is not None:
            periods = max(1, round((cycle.sync_time - cycle.previous_sync) / self.source.period))
        if resumed:
            self.resumes += 1
        for axis in self.axes:
            axis.cycle_resumed, axis.cycle_times = resumed, times
            axis.cycle_fresh, axis.cycle_periods = cycle.tpdos_complete, periods
            try:
                axis.cycle(t, now, measured)
            except Exception:
                self.errors += 1
                log.exception("control loop: %s failed this cycle; stopping it", axis.module_name)
                try:
                    axis.drive.quick_stop()
                    axis.drive.step()
                except Exception:
                    pass
        if self.mount:
            self._couple_mount()
        bump_epoch()  # the axes' readings changed (tcs.state_epoch; threaded mode's readbacks)
        self.cycles += 1
        end = self.clock()
        self.last_cycle = end
        self.max_step = max(self.max_step, end - now)
        self.loop_time.observe(end - now)
        late = self.source.lateness
        if late:
            self.lateness.observe(max(0.0, late[-1]))

    def _couple_mount(self) -> None:
        faulted = {a for a in self.mount if getattr(a, "fault", None) is not None}
        for axis in faulted - self._mount_faulted:
            for other in self.mount:
                if other not in faulted and other.power_state == 1.0 and other.motion_state & 1:
                    other.give_up(TcsError(f"{other.module_name}: stopped and powered off: "
                                           f"{axis.module_name} faulted ({axis.fault.message})",
                                           ErrorNumber.LIBFAIL))
        self._mount_faulted = faulted

    def stats(self) -> dict:
        """Counters for CABINET.CORE and the benchmarks."""
        s = self.source.stats()
        return {"cycles": s.cycles, "late": s.late, "missed": s.missed,
                "tpdo_timeouts": s.tpdo_timeouts, "errors": self.errors,
                "resumes": self.resumes, "dropped": s.dropped,
                "max_step_ms": self.max_step * 1e3, "max_lateness": self.source.max_lateness,
                "realtime": int(self.source.realtime), "period": self.source.period,
                "sync_divider": self.source.divider,
                "loop_time_hist": self.loop_time.export(), "lateness_hist": self.lateness.export()}

    def samples(self, clear: bool = False):
        """(lateness list, loop time list, cycle counters as a dict) of the cycle source, for
        the benchmarks; ``clear`` empties the bounded histories (same as in the control
        process: :meth:`tcs.axes.control_process.RemoteLoop.samples`)."""
        source = self.source
        lateness, loop = list(source.lateness), list(source.callback_time)
        if clear:
            source.lateness.clear()
            source.callback_time.clear()
        return lateness, loop, dict(source.stats().__dict__)

    def healthy(self, max_age_periods: float = 10.0, within: float | None = None) -> bool:
        """True when the loop ran within the last ``max_age_periods`` SYNC periods (or the
        last ``within`` seconds: the systemd watchdog asks whether it ran at all since its
        previous ping — a late loop on a busy host is alive, only a dead one is not)."""
        age = max_age_periods * self.source.period * self.source.divider if within is None else within
        return self.cycles > 0 and self.clock() - self.last_cycle < age
