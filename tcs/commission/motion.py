"""Slow, jerk-limited CSP motion of one drive for jogging and the limit search.

How it works
------------
A :class:`CspMover` is a cycle hook of a :class:`~tcs.commission.session.DriveSession`. Once
per SYNC, in the cycle thread, it reads the drive's status, hands it to an optional
``watch(status) -> bool`` (the limit search's switch detector: True = stop now), and — while
the drive is in Operation enabled in CSP — samples a
:class:`~tcs.axes.motion.MotionPlanner` (ruckig profiles, software limits) and gives the
setpoint to the drive's ``set_setpoint``; the drive's ``step()`` then sends it. When the drive
is not enabled (fault, disabled) the mover goes idle and takes over from the actual position
the next time it is enabled, so it never jumps.

The main thread only calls :meth:`CspMover.move_to` / :meth:`CspMover.stop` (requests under a
lock, applied at the next cycle) and polls :meth:`CspMover.done`. Positions are user units.
"""

from __future__ import annotations

import threading

from tcs.axes.motion import AxisDynamics, MotionPlanner, SoftLimits
from tcs.axes.profile import Setpoint
from tcs.drivers.drive import CYCLIC_MODES, DriveStatus
from tcs.errors import TcsError


def jog_dynamics(target, speed: float) -> AxisDynamics:
    """Planner limits for slow motion: ``speed``, the drive's acceleration (the axis's if
    lower), the axis's jerk (else 4 × acceleration per second)."""
    section = target.section
    acc = section.max_acceleration
    jerk = 4.0 * acc
    if target.axis_section is not None:
        acc = min(acc, target.axis_section.max_acceleration)
        jerk = target.axis_section.max_jerk
    quick = max(section.quick_stop_deceleration or acc, acc)
    return AxisDynamics(max_velocity=speed, max_acceleration=acc, max_jerk=jerk,
                        quick_stop_acceleration=quick, quick_stop_jerk=max(jerk, 4.0 * quick))


class CspMover:
    """Streams planner setpoints to one drive in CSP (a cycle hook).

    Parameters
    ----------
    drive : the :class:`~tcs.drivers.cia402_drive.Cia402Drive`.
    dynamics : speed, acceleration and jerk of the motion.
    limits : the range setpoints must stay in.
    dt : the SYNC period.
    """

    def __init__(self, drive, dynamics: AxisDynamics, limits: SoftLimits, dt: float):
        self.drive = drive
        self.watch = None
        self._planner = MotionPlanner(dynamics, limits, dt)
        self._lock = threading.Lock()
        self._request: tuple | None = None
        self._seq = 0            # requests made (main thread)
        self._applied = 0        # requests applied (cycle thread)
        self._active = False
        self.moving = False
        self.triggered = False   # the watch stopped the motion
        self.error: TcsError | None = None
        self.last: DriveStatus | None = None

    # ------------------------------------------------------------------ main thread
    def move_to(self, position: float) -> int:
        """Request a move to ``position``; returns the request number for :meth:`done`."""
        with self._lock:
            self._seq += 1
            self._request = ("target", float(position), self._seq)
            self.error = None
            return self._seq

    def stop(self) -> int:
        """Request a (quick) stop of the running motion."""
        with self._lock:
            self._seq += 1
            self._request = ("stop", None, self._seq)
            return self._seq

    def done(self, seq: int) -> bool:
        """Request ``seq`` was applied and the motion has ended (or cannot run)."""
        return self._applied >= seq and not self.moving

    # ------------------------------------------------------------------ cycle thread
    def __call__(self, cycle) -> None:
        st = self.drive.status()
        self.last = st
        watch = self.watch
        stop_now = bool(watch(st)) if watch is not None else False
        planner = self._planner
        if not (st.enabled and st.mode in CYCLIC_MODES):
            self._active = False
            self.moving = False
            with self._lock:  # nothing can move: a pending request ends here
                if self._request is not None:
                    self._applied = self._request[2]
                    self._request = None
            return
        if not self._active:
            planner.take_over(Setpoint(st.position))
            self._active = True
        with self._lock:
            request, self._request = self._request, None
        if request is not None:
            kind, value, seq = request
            try:
                if kind == "target":
                    planner.set_target(value)
                else:
                    planner.stop(quick=True)
            except TcsError as exc:
                self.error = exc
            self._applied = seq
        if stop_now and planner.moving:
            planner.stop(quick=True)
            self.triggered = True
        sp = planner.step()
        self.drive.set_setpoint(sp.position, sp.velocity)
        self.moving = planner.moving
