"""``DOME[0].TRAJECTORY``: a rotating dome following a time-stamped path (spec §5.1.1).

How it works
------------
The points go into the same :class:`~tcs.axes.trajectory.TrajectoryQueue` as a drive axis's
(``BUFFER[]`` staging, ``ADDPOINTS``, ``FREEPOINTS``, C2 interpolation, cyclic unwrapping). A
PLC dome cannot be fed setpoints every 10 ms, so the runner is deliberately simple: on every
poll of the dome's PLC (``poll_interval``, 10 Hz in the simulated dome) it samples the path
``lead`` seconds ahead, adds ``OFFSET`` and, when that aim point moved by more than a
hundredth of ``track_tolerance`` and no write is on its way, writes it to the PLC as a plain
move target (the PLC is polled at its full rate meanwhile, never at its ``idle_poll_interval``).
The PLC's own positioning chases it. That is good enough for a dome, whose slit
is several degrees wider than the telescope's beam.

``RUN=1`` (long) completes when the path's last point is in the past (the last aim point is
the path's end; the dome may still be arriving) with ``EVENT INFO DOME[0]:32``, or when it is
aborted: ``RUN=0``, ``STOP`` and a ``TARGETPOS`` complete it too; a lost PLC or a fault fail
it with their number. ``MOTION_STATE`` bit 3 while running means the dome is within
``track_tolerance`` of the path (events 29 TRAJ_GOOD / 30 TRAJ_LOOSE on changes). Ending,
for whatever reason, frees the buffers. Everything runs on the event loop, driven by
:class:`~tcs.model.plc_axis_module.PlcAxisModule`'s poll handler.
"""

from __future__ import annotations

import asyncio
import math
from typing import Callable

from tcs.axes.axis import BufferSlot, add_staged_points
from tcs.axes.trajectory import TrajectoryQueue
from tcs.errors import ErrorNumber
from tcs.model.events import INFO


class PlcTrajectory:
    """The TRAJECTORY sub-module of a PLC axis (bound as ``axis.trajectory``).

    Parameters
    ----------
    axis:
        The :class:`~tcs.model.plc_axis_module.PlcAxisModule` it moves.
    capacity:
        ``BUFFER[]`` size and queue capacity.
    lead:
        Seconds the runner aims ahead on the path.
    tolerance:
        On the path within this (axis units).
    ut1:
        The time base of the points (``LocalTime.ut1``).
    """

    def __init__(self, axis, capacity: int, lead: float, tolerance: float, ut1: Callable[[], float]):
        self.axis = axis
        self.ut1 = ut1
        self.lead = lead
        self.tolerance = tolerance
        self.buffer = [BufferSlot() for _ in range(capacity)]
        self.queue = TrajectoryQueue(capacity, axis.section.cyclic or None)
        self.addpoints = 0
        self.running = False
        self.on_path = False
        self._aim: float | None = None
        self._write: asyncio.Task | None = None
        self._offset_dirty = False
        self._offset_write: asyncio.Task | None = None

    # -- the variables -----------------------------------------------------------------------
    @property
    def freepoints(self) -> int:
        return self.queue.free_points_at(self.ut1())

    def set_addpoints(self, count: int) -> None:
        """Move BUFFER[0..count-1] into the queue (returns at once)."""
        self.addpoints = add_staged_points(self.axis, self.buffer, self.queue, int(count), self.ut1())

    @property
    def run(self) -> int:
        return 1 if self.running else 0

    def set_run(self, value: int):
        return self.axis.set_run(int(value))

    @property
    def starttime(self) -> float:
        start = self.queue.start_time
        return start if start is not None else 0.0

    @property
    def runtime(self) -> float:
        return self.queue.remaining(self.ut1()) if self.running else 0.0

    # -- the runner ----------------------------------------------------------------------------
    def path_now(self) -> float:
        """The path's position now (user frame, unwrapped)."""
        if len(self.queue) == 0:
            return self.axis.current_position
        return self.queue.sample(self.ut1())[0]

    def start(self) -> None:
        self.running = True
        self.on_path = False
        self._aim = None
        self._offset_dirty = False
        self.axis.group.driver.hold_full_rate(self)  # (sampled at every poll: not the idle rate)

    def halt(self) -> None:
        """End following (the caller completes RUN) and free the buffers."""
        self.running = False
        self.on_path = False
        self.queue.clear()
        self.axis.group.driver.hold_full_rate(self, False)

    def offset_changed(self) -> None:
        """OFFSET was written while following: its SET completes once an aim point with it
        was written and the dome is on the path."""
        self._offset_dirty = True
        self._offset_write = None

    def step(self, state, snapshot) -> None:
        """One poll of the PLC while running."""
        axis = self.axis
        now = self.ut1()
        end = self.queue.end_time
        if end is None:
            self.halt()
            axis._resolve("run")
            return
        if now >= end:
            final = self.queue.sample(end)[0] + axis.offset
            self.halt()
            axis.write_track(final)
            axis.emit(INFO, ErrorNumber.TRAJ_STOP, "trajectory ended", axis.cause_of("run"))
            axis._resolve("run")
            return
        self.queue.drop_before(now)
        here = self.queue.sample(now)[0]
        deviation = state.position - axis.offset - here
        if axis.section.cyclic:
            deviation = math.remainder(deviation, axis.section.cyclic)
        on = abs(deviation) <= self.tolerance
        if on != self.on_path:
            self.on_path = on
            axis.emit(INFO, ErrorNumber.TRAJ_GOOD if on else ErrorNumber.TRAJ_LOOSE,
                      "on the path" if on else f"{deviation:+.2f} off the path", axis.cause_of("run"))
        if on and not self._offset_dirty and self._offset_write is not None and self._offset_write.done():
            self._offset_write = None
            axis._resolve("offset")
        aim = self.queue.sample(min(now + self.lead, end))[0] + axis.offset
        busy = self._write is not None and not self._write.done()
        moved = self._aim is None or abs(aim - self._aim) > max(self.tolerance / 100.0, 1e-6)
        if not busy and (moved or self._offset_dirty):
            self._aim = aim
            self._write = axis.write_track(aim)
            if self._offset_dirty:
                self._offset_dirty = False
                self._offset_write = self._write
