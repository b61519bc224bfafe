"""The OpenTCI generic axis (spec §5.1) on a drive: :class:`Axis`.

How it works
------------
An axis lives on two sides of a small command/status interface:

* **asyncio side** (the TPL2 server's setters, the cabinet): ``set_power``, ``set_target``,
  ``set_offset``, ``set_stop``, ``set_reinit``, ``set_speed``, the TRAJECTORY variables.
  Each validates at once (limits, power, referencing — so a refused request changes
  nothing), then puts a command into the axis's queue and, for a long-running SET, returns an
  ``asyncio.Future`` that the control loop resolves. Readbacks (``real_position``,
  ``motion_state`` …) are plain attributes published by the loop each cycle.
* **control-loop side** (:meth:`cycle`, once per SYNC period in the loop thread): applies the
  queued commands, reads the drive's status, computes the cycle's setpoint with the
  :class:`~tcs.axes.motion.MotionPlanner` (TARGETPOS, OFFSET, STOP) or the
  :class:`~tcs.axes.follower.TrajectoryFollower` (TRAJECTORY.RUN), hands it to the drive and
  steps the drive, then resolves futures and emits events.

Futures are resolved with ``loop.call_soon_threadsafe``; events carry the cause of the
command that started them. Safety rules kept here: software limits are checked before a move
starts (RANGE, nothing moves) and again on every setpoint (the planner's limit guard); STOP is
a quick stop of the planner/follower and always accepted; a drive fault stops the axis, fails
its pending SETs and powers it off — nothing re-enables it but an explicit POWER=1 after the
fault was acknowledged (ERROR_STATE=0); an unreferenced axis refuses TARGETPOS, OFFSET and
trajectories (5 invmode) and moves only to reference. However a homing run ends (done, STOP,
ABORT, time-out, a fault, a run that never started, the envelope's border), the planner
continues from where the drive came to rest, never from a setpoint held before the run; the
envelope bounds the homing search of a main axis (:meth:`Axis._homing_bounds`). A TPL2 ABORT
of the command that started a motion (``abort_request``, matched by the command's cause) stops it with the normal deceleration;
``move_toward`` (Alpaca MoveAxis) runs to a drive-frame end at its own speed, never the other
way; every sent setpoint step is cut to the speed and acceleration limits (``_limit_step``).

After a gap (the control loop says ``cycle_resumed``: the setpoints of the cycle before did not
reach the drive on time — this process stalled or was starved) the drive has bridged the gap by
itself, holding or extrapolating its demand (docs/motion.md, "Stall recovery"). The axis then
*re-anchors* (:meth:`_resume`) before its next setpoint: on the drive's demand of this cycle's
readback (position actual + following error 0x60F4), kept between the last target the drive
latched and the stream extrapolated over the gap, moving on at the stream's speed (in CSV the
actual position and velocity); the planner is planned again from there to its goal
(the follower samples its path by time anyway), and the steps from the re-anchored demand on
stay within the axis's limits — never from the setpoint last *sent*, which would pull the
drive back.

Discrete axes (FILTER, MIRROR) move between configured positions with profile-position moves
of the drive; their positions are the integer keys of ``[axes.<name>].positions``.
"""

from __future__ import annotations

import asyncio
import bisect
import collections
import logging
import math
import threading
from typing import Any, Callable

from tcs.axes.follower import TrajectoryFollower
from tcs.axes.limits import SoftLimits, limit_text
from tcs.axes.motion import MotionPlanner
from tcs.axes.profile import AxisDynamics, Setpoint
from tcs.axes.trajectory import TrajectoryBufferFull, TrajectoryQueue
from tcs.config.axes import DISCRETE_MODULES, TRAJECTORY_MODULES, AxisSection
from tcs.drivers.drive import Drive, DriveState, DriveStatus, Mode, Progress
from tcs.errors import CommunicationError, ErrorNumber, RangeRefused, RequestRefused, TcsError
from tcs.model.events import ERROR, INFO, current_cause
from tcs.model.health import ERROR as ERROR_BIT, WARNING, ModuleHealth

log = logging.getLogger(__name__)

#: MOTION_STATE bits (spec §5.1, notes "Axis semantics").
MOVING, TRAJECTORY, BLOCKED, ON_TARGET, LIMITED = 1, 2, 4, 8, 16
#: LIMIT_STATE bits.
HW_MIN, HW_MAX, HW_BLOCKING, SW_MIN, SW_MAX, SW_BLOCKING = 1, 2, 128, 256, 512, 32768

MEASURED_MOVING_CYCLES = 3  # cycles above standstill before a measured motion sets MOVING
POWER_TIMEOUT = 10.0  # s at least for a drive to reach Operation enabled / disabled
POWER_MARGIN = 2.0  # s the axis waits beyond the drive's own power_timeout (its error first)
HOMING_START_TIMEOUT = 5.0  # s for the drive to show the requested homing run in progress (the
# mode switch to HM alone may take the drive section's mode_switch_timeout, 1 s by default, and a
# busy host adds to it: 2 s failed an Alpaca cold start under the suite's load)
ACK_TIMEOUT = 3.0  # s for the drive's fault reset after ERROR_STATE=0

REFERENCE_ORDER = {"ZD": 0, "DEC": 0, "AZ": 1, "HA": 1}

#: Project event (numbers from 1000): trajectory points already in the past were dropped.
POINTS_DROPPED = 1000


def complete_futures(batch) -> None:
    """Resolve ``(future, error or None)`` pairs on the event loop (futures already ended —
    cancelled by a client that went away — are left alone)."""
    for future, error in batch:
        if future.done():
            continue
        if error is None:
            future.set_result(None)
        else:
            future.set_exception(error)


#: homing methods (CiA-402 0x6098) and the directions, in the drive's own sense, their search
#: may sweep from where the axis stands: 1/17/33 down, 2/18/34 up; 19/21 towards the home switch
#: or, started on it, away from it (the TCS does not read the switch): both; 35/37 none
HOMING_DIRECTIONS = {1: (-1,), 17: (-1,), 33: (-1,), 2: (1,), 18: (1,), 34: (1,),
                     19: (1, -1), 21: (-1, 1), 35: (), 37: ()}


def homing_search(drive_section) -> tuple[tuple[int, ...], float, float] | None:
    """How a drive's homing run searches, for the envelope's judgment: (directions in user
    units — a negative ``increments_per_unit`` reverses them —, the fastest search speed,
    the homing acceleration), or None when the run does not move (an absolute encoder)."""
    if drive_section is None or getattr(drive_section, "absolute", False):
        return None
    home = drive_section.homing
    sign = -1 if drive_section.increments_per_unit < 0 else 1
    directions = tuple(d * sign for d in HOMING_DIRECTIONS.get(int(home.method), (1, -1)))
    if not directions:
        return None
    speed = max(abs(home.speed_switch), abs(home.speed_zero))
    return directions, speed, abs(home.acceleration)


class BufferSlot:
    """One element of ``TRAJECTORY.BUFFER[]``: a staged (TIME, TARGETPOS) pair."""

    __slots__ = ("time", "targetpos")

    def __init__(self) -> None:
        self.time: float | None = None
        self.targetpos: float | None = None

    def set_time(self, value: float) -> None:
        self.time = float(value)

    def set_targetpos(self, value: float) -> None:
        self.targetpos = float(value)


def add_staged_points(axis, buffer: list[BufferSlot], queue: TrajectoryQueue, count: int,
                      now: float) -> int:
    """``ADDPOINTS=count``: move ``buffer[0..count-1]`` into ``queue`` (all or nothing), empty
    those slots, announce points already in the past (event 1000); returns ``count``.
    Shared by the drive axes' and the PLC dome's TRAJECTORY."""
    if count <= 0:  # (the tree's !MIN answers RANGE before)
        raise RangeRefused("ADDPOINTS must be 1 or more")
    if count > len(buffer):  # an action that cannot be done, not a value out of range
        raise TrajectoryBufferFull(f"{axis.module_name}.TRAJECTORY: {count} points offered, "
                                   f"BUFFER[] holds {len(buffer)}")
    slots = buffer[:count]
    if any(s.time is None or s.targetpos is None for s in slots):
        raise TcsError(f"{axis.module_name}.TRAJECTORY: BUFFER[0..{count - 1}] "
                       "has points without TIME or TARGETPOS", ErrorNumber.NOPOINTS)
    try:
        result = queue.add_points([s.time for s in slots], [s.targetpos for s in slots], now)
    except RangeRefused as exc:  # times that do not increase: unusable points (11 nopoints)
        raise TcsError(f"{axis.module_name}.TRAJECTORY: {exc.message}", ErrorNumber.NOPOINTS) from None
    for s in slots:
        s.time = s.targetpos = None
    if result.dropped:
        axis.emit(INFO, POINTS_DROPPED, f"{result.dropped} trajectory points already in the past were dropped")
    return count


class AxisTrajectory:
    """Domain object of ``<axis>.TRAJECTORY``."""

    def __init__(self, axis: "Axis", capacity: int):
        self.axis = axis
        self.buffer = [BufferSlot() for _ in range(capacity)]
        self.addpoints = 0

    @property
    def freepoints(self) -> int:
        return self.axis.queue.free_points_at(self.axis.ut1())

    def set_addpoints(self, count: int) -> None:
        """Move BUFFER[0..count-1] into the running queue (returns at once); points added to
        a running trajectory of a main axis are judged by the safety envelope first."""
        axis = self.axis
        if axis.envelope is not None and axis.trajectory_running and 0 < int(count) <= len(self.buffer):
            slots = self.buffer[:int(count)]
            if all(s.time is not None and s.targetpos is not None for s in slots):
                axis.envelope(axis, "points", ([s.time for s in slots], [s.targetpos for s in slots]))
        self.addpoints = add_staged_points(self.axis, self.buffer, self.axis.queue, int(count),
                                           self.axis.ut1())

    @property
    def run(self) -> int:
        # RUN=0 empties the queue before it answers; the axis may still brake on the path
        # (MOTION_STATE bit 1) but the run is over: 0 as soon as RUN=0 answered
        return 1 if self.axis.trajectory_running and len(self.axis.queue) else 0

    def set_run(self, value: int):
        return self.axis.set_run(int(value))

    def abort_request(self, cause, awaitable=None) -> None:
        """ABORT of a ``RUN=1``: the axis stops (see :meth:`Axis.abort_request`)."""
        self.axis.abort_request(cause, awaitable)

    @property
    def starttime(self) -> float:
        start = self.axis.queue.start_time
        return start if start is not None else 0.0

    @property
    def runtime(self) -> float:
        return self.axis.follower.runtime(self.axis.ut1()) if self.axis.follower else 0.0


#: after a gap the readback decides the drive held its last target (rather than extrapolated
#: at the stream's speed) when its demand lies within this share of the way from that target
#: to the extrapolated stream (:meth:`Axis._resume`)
HELD_SHARE = 0.25


class Axis(ModuleHealth):
    """One OpenTCI axis module bound to one drive.

    Parameters
    ----------
    name:
        The ``[axes.<name>]`` key.
    section:
        Its configuration.
    drive:
        The drive (``tcs.drivers.drive.Drive``).
    events:
        The telescope's event hub.
    ut1:
        The time base (``LocalTime.ut1``); trajectory times are UT1.
    dt:
        Control cycle (the SYNC period), s.
    status_sink:
        Where error conditions are recorded (CABINET.STATUS.LIST).
    main_power:
        Callable telling whether the cabinet's main power is on (axis POWER needs it).
    """

    def __init__(self, name: str, section: AxisSection, drive: Drive, events, ut1: Callable[[], float],
                 dt: float, status_sink=None, main_power: Callable[[], bool] = lambda: True):
        module = section.module + (f"[{section.index}]" if section.index is not None else "")
        super().__init__(module, events, hw_type=section.hw_type, status_sink=status_sink)
        self.name = name
        self.section = section
        self.drive = drive
        self.ut1 = ut1
        self.dt = dt
        self.main_power = main_power
        self.discrete = section.module in DISCRETE_MODULES
        self.reference_order = REFERENCE_ORDER.get(section.module, 2)
        self.positions = {int(k): v for k, v in section.positions.items()}
        #: where the telescope's park moves this axis (user units, OFFSET included; None: not
        #: parked): the hardware file's ``park``, or what SetPark saved (kept up to date by
        #: :meth:`tcs.model.operations.Operations.park_positions`); OpenTCI ``PARKPOS``
        self.park_position = section.park
        cycle = section.cyclic or None
        self.limits = SoftLimits(section.min, section.max, cycle)
        stop = section.stop_deceleration or 2 * section.max_acceleration
        self.dynamics = AxisDynamics(section.max_velocity, section.max_acceleration, section.max_jerk,
                                     quick_stop_acceleration=max(stop, section.max_acceleration),
                                     quick_stop_jerk=section.max_jerk * max(stop, section.max_acceleration)
                                     / section.max_acceleration)
        self.planner = MotionPlanner(self.dynamics, self.limits, dt)
        limit_motion = getattr(drive, "limit_motion", None)
        if limit_motion is not None:  # (a CSV drive's own position loop: the axis's limits)
            limit_motion(section.max_velocity, section.max_acceleration,
                         self.dynamics.quick_stop_acceleration)
        # a drive at rest reports a velocity of a few increments/s (encoder noise): below the
        # tolerance per second it counts as standing still (MOTION_STATE bit 0)
        self._standstill = max(section.tolerance, 1e-9)
        self._drift_cycles = 0  # consecutive cycles measured above _standstill
        self.queue = TrajectoryQueue(section.trajectory_buffer, cycle)
        self.follower: TrajectoryFollower | None = None
        self.trajectory: AxisTrajectory | None = None
        if section.module in TRAJECTORY_MODULES and not self.discrete:
            self.follower = TrajectoryFollower(self.queue, self.dynamics, self.limits, dt)
            self.trajectory = AxisTrajectory(self, section.trajectory_buffer)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._commands: collections.deque = collections.deque()
        self._lock = threading.Lock()
        # -- published by the loop (read from any thread) --
        self.power_state = 0.0
        self.referenced = 0.0
        self.real_position = 0.0
        self.current_speed = 0.0
        self.current_acc = 0.0
        self.current_jerk = 0.0
        self.motion_state = 0
        self.limit_state = 0
        self.target_position = 0.0
        self.offset = 0.0
        #: this cycle's telemetry sample, one tuple written at once (read from any thread):
        #: (SYNC UT1 of the measurement, measured position, UT1 the setpoint is reached at,
        #: setpoint position or None when none was sent), positions in the drive's frame
        self.sample: tuple | None = None
        self.last_status: DriveStatus | None = None
        self.stale: TcsError | None = None  # set while the drive gives no fresh data (FAILED 4)
        self.measured_ut1 = 0.0  # UT1 at which REALPOS was measured (the cycle's SYNC); 0: never
        # -- loop-thread state --
        self._powered = False
        self._want_power: bool | None = None
        self._power_since = 0.0
        self._homing = False
        self._homing_started = False  # the drive showed this run in progress (not the last end)
        self._homing_since = 0.0
        self._settle = False  # a discrete axis homed off its port moves onto it (_watch_settle)
        self._settle_since = 0.0
        self._settle_started = False
        self._reference_cause = None  # the REINIT that started homing (events 19/20 name it)
        self._sp = Setpoint(0.0)
        #: set by the control loop before each cycle: the setpoints of the cycle before did not
        #: reach the drive on time (Cycle.resumed)
        self.cycle_resumed = False
        self.cycle_fresh = True   # every synchronous TPDO of this cycle came (the readback is new)
        self.cycle_periods = 1    # SYNC periods since the previous cycle (more after a gap)
        self._fresh_before = True  # and of the cycle before
        #: the monotonic times of this cycle's SYNC and of the next one (set by the loop)
        self.cycle_times: tuple[float, float] | None = None
        #: (monotonic time of the SYNC that latched it, target): the last target the drive
        #: surely latched (a re-anchor never puts its demand behind it, :meth:`_resume`)
        self._latched: tuple[float, float] | None = None
        self._sent_reach = 0.0  # UT1 at which the drive reaches _sent (the cycle's t)
        self.resumes = 0  # re-anchorings after gaps (_resume)
        self._resumed_planner = False  # the planner was re-planned from the anchor this cycle
        self._last_demand: tuple[float, float] | None = None  # (SYNC UT1, drive demand) last cycle
        self._sent: float | None = None  # the last setpoint sent (for _limit_step)
        self._sent_velocity = 0.0        # and its step / T
        self.clamped_steps = 0  # setpoint steps cut to the velocity limit
        self._running = False  # follower in charge (also while it brakes after an abort)
        self._run_cause = None  # the RUN=1 whose trajectory events (29-32) are sent
        self._fault: TcsError | None = None
        self._ack_pending = False  # ERROR_STATE=0 asked for a fault reset
        self._ack_since = 0.0
        self._ack_future = None
        self._drive_reboots = 0
        self._discrete_target: int | None = None
        self._discrete_sent = False
        self._jog: tuple | None = None  # (speed, direction, future) of the last move_toward
        self._after_homing = False  # a homing run ended early: wait for CSP and standstill
        self._pending: dict[str, tuple[asyncio.Future, Any]] = {}
        self._joined: dict[str, list[asyncio.Future]] = {}  # later requests ending with _pending's
        self._completions: list[tuple[asyncio.Future, TcsError | None]] = []
        #: the safety envelope's guard of a main axis (tcs.pointing.envelope.Envelope.guard),
        #: installed by the POINTING module: judges TARGETPOS, OFFSET, RUN and moves
        #: (``guard(axis, kind, value, **kw)``, raises TcsError 9); None: software limits only
        self.envelope: Callable[..., Any] | None = None
        #: how this axis's homing run searches (:func:`homing_search` of its drive section, set
        #: by the telescope): the envelope bounds the search; None: the run does not move
        self.homing_search: tuple[tuple[int, ...], float, float] | None = None
        self._homing_border: tuple | None = None   # (lo, hi, acceleration) the run is watched at
        self._homing_stopped: TcsError | None = None  # why the watch halted the run

    # ================================================================ asyncio side

    def bind_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    @property
    def cyclic(self) -> float:
        return self.section.cyclic

    @property
    def current_position(self) -> float:
        return self.real_position - self.offset

    @property
    def target_distance(self) -> float:
        d = self.target_position - self.current_position
        c = self.section.cyclic
        if c:
            d = (d + c / 2) % c - c / 2
        return d

    @property
    def power_timeout(self) -> float:
        """s a POWER request may take: :data:`POWER_TIMEOUT`, or longer when the drive's own
        enable/disable time-out (``[drives.x] enable_timeout`` …) needs more."""
        return max(POWER_TIMEOUT, getattr(self.drive, "power_timeout", 0.0) + POWER_MARGIN)

    @property
    def trajectory_running(self) -> bool:
        return bool(self.motion_state & TRAJECTORY)

    def _future(self) -> asyncio.Future:
        loop = self._loop or asyncio.get_running_loop()
        self._loop = loop
        return loop.create_future()

    def _send(self, kind: str, value: Any = None, future: asyncio.Future | None = None) -> None:
        with self._lock:
            self._commands.append((kind, value, future, current_cause.get()))

    def _require(self, *, powered: bool = True, referenced: bool = True, what: str = "move") -> None:
        if self._fault is not None:
            raise TcsError(f"{self.module_name}: cannot {what}: {self._fault.message}", self._fault.number)
        if powered and self.power_state != 1.0:
            raise TcsError(f"{self.module_name}: cannot {what}: power is off", ErrorNumber.INVMODE)
        if referenced and self.referenced < 1.0:
            why = "referencing in progress" if self._homing or self._settle else "not referenced (REINIT first)"
            raise TcsError(f"{self.module_name}: cannot {what}: {why}", ErrorNumber.INVMODE)

    def set_power(self, value: int):
        """``POWER`` (long-running)."""
        return self.power(bool(int(value)))

    def power(self, on: bool):
        if on and not self.main_power():
            raise TcsError(f"{self.module_name}: main power (CABINET.POWER) is off", ErrorNumber.INVMODE)
        if on and self._fault is not None:
            if self._ack_pending:
                raise TcsError(f"{self.module_name}: {self._fault.message}; the fault reset of "
                               f"ERROR_STATE=0 has not completed", self._fault.number)
            if getattr(self._fault, "remedy_in_message", False):  # a configuration mismatch
                raise TcsError(f"{self.module_name}: {self._fault.message}", self._fault.number)
            raise TcsError(f"{self.module_name}: {self._fault.message}; acknowledge with "
                           f"ERROR_STATE=0 first", self._fault.number)
        future = self._future()
        self._send("power", on, future)
        return future

    def set_target(self, value: float, *, checked: bool = False):
        """``TARGETPOS`` (long-running; a newer target supersedes this one with 10).
        ``checked``: the caller planned the path against the envelope already (routes): the
        axis goes to ``value`` on exactly that turn. Otherwise a cyclic axis's turn (the
        cable-wrap choice) is resolved here, once, by the planner's rule from where the demand
        is now; the envelope judges that turn and the planner is handed it as it is."""
        self._require(what="move")
        value = float(value)
        if self.discrete:
            index = round(value)
            if abs(value - index) > 1e-9 or index not in self.positions:
                raise RangeRefused(f"{self.module_name}: positions are {sorted(self.positions)}")
        elif not self.limits.contains(value + self.offset):
            raise RangeRefused(f"{self.module_name}: {value} (+ offset {self.offset}) is outside "
                               f"[{self.section.min}, {self.section.max}]")
        else:
            if not checked and self.section.cyclic:
                # from where the axis is: its fresh readback (this runs on the event loop; the
                # loop's own setpoint is not kept here when the loop runs in the control
                # process, and resolving from its initial 0 took the far turn: 262 from 200 went
                # to -98). The planner is handed the result unchanged, so the turn judged is the
                # turn driven whichever base is used.
                here = float(self.real_position)
                base = here if math.isfinite(here) else self._sp.position
                value = self.planner.resolve_target(value, self.offset, base) - self.offset
            if self.envelope is not None and not checked:
                self.envelope(self, "target", value)
        future = self._future()
        self._send("target", value, future)
        return future

    def set_offset(self, value: float):
        """``OFFSET`` (long-running)."""
        self._require(what="apply an offset")
        if self.discrete:
            raise RequestRefused(f"{self.module_name} moves between discrete positions: no offset")
        value = float(value)
        base = self.target_position
        c = self.section.cyclic
        if c and abs(value) >= c / 2:
            # more than half a turn is a turn the cable-wrap choice would take back: never a
            # pointing offset (600 on the AZ wrap moved the mount 71 deg while tracking)
            raise RangeRefused(f"{self.module_name}: |offset| {value:g} is half a turn ({c / 2:g}) or more")
        if not c and abs(value) > self.section.max - self.section.min:
            raise RangeRefused(f"{self.module_name}: |offset| {value:g} is wider than the range "
                               f"[{self.section.min:g}, {self.section.max:g}]")
        if not self.trajectory_running and not self.limits.contains(base + value):
            raise RangeRefused(f"{self.module_name}: offset {value} puts the target outside the limits")
        # while a trajectory runs, the loop side checks path + OFFSET over the queued path
        # before it takes the offset (RANGE, the offset keeps its value)
        if self.envelope is not None:
            self.envelope(self, "offset", value)
        future = self._future()
        self._send("offset", value, future)
        return future

    def abort_request(self, cause, awaitable=None) -> None:
        """TPL2 ``ABORT`` of the command ``cause`` (the session's (connection, id, serial)):
        the motion that command started here (TARGETPOS, OFFSET, TRAJECTORY.RUN, a MoveAxis)
        ends with the normal controlled stop. Motion another command started since (it
        superseded this one) is left alone. Returns at once."""
        self._send("abort", cause)

    def move_toward(self, direction: int, speed: float, lo: float | None = None,
                    hi: float | None = None, *, sky: bool = False):
        """Move at ``speed`` (axis units/s, at most the axis maximum; CURRSPEED is neither
        used nor changed) in ``direction`` (+1: increasing position) until the software
        limit on that side, or ``hi``/``lo`` (drive frame) when those are nearer — never
        folded modulo a cycle, never the other way. Long-running like TARGETPOS (a newer
        target or STOP supersedes it).

        Raises
        ------
        RangeRefused
            The axis stands at or beyond that end already (it would have to move back).
        """
        self._require(what="move")
        if self.discrete:
            raise RequestRefused(f"{self.module_name} moves between discrete positions only")
        speed = float(speed)
        if not 0 < speed <= self.section.max_velocity * (1 + 1e-12):
            raise RangeRefused(f"{self.module_name}: speed must be in (0, {self.section.max_velocity}]")
        border = None
        if self.envelope is not None:   # stop at the envelope's border (sky: the horizon too)
            border = self.envelope(self, "jog", 1 if direction > 0 else -1, sky=sky, speed=speed)
            if border is not None and direction > 0:
                hi = border if hi is None else min(hi, border)
            elif border is not None:
                lo = border if lo is None else max(lo, border)
        if direction > 0:
            goal = self.section.max if hi is None else min(hi, self.section.max)
        else:
            goal = self.section.min if lo is None else max(lo, self.section.min)
        if (goal - self.real_position) * direction <= max(self.section.tolerance, 1e-9):
            if border is not None and goal == border:
                raise RangeRefused(f"{self.module_name}: at the safety envelope's border {goal:g} already "
                                   "(Sun cone, horizon or keep-out)")
            raise RangeRefused(f"{self.module_name}: at the {'upper' if direction > 0 else 'lower'} "
                               f"limit {goal:g} already")
        future = self._future()
        speed = min(speed, self.section.max_velocity)
        self._send("jog", (float(goal), speed, 1 if direction > 0 else -1), future)
        if self.envelope is not None:   # (the other axis's judgements predict this move)
            self.envelope(self, "moving", (float(goal), speed, 1 if direction > 0 else -1), sky=sky)
        return future

    def _brakes_before(self, sp, value: float, direction: int) -> bool:
        """Whether the setpoint ``sp`` moving in ``direction`` can come to rest before
        ``value`` with the normal deceleration: v²/2a plus what the jerk-limited ramps of the
        acceleration add (≤ |v|·a/j, and more while it still accelerates) — conservative."""
        d = self.dynamics
        if (value - sp.position) * direction <= 0:
            return False
        v, a, j = abs(sp.velocity), d.max_acceleration, d.max_jerk
        ramp = (v * a + abs(sp.acceleration) * (v + sp.acceleration ** 2 / j)) / j if j else 0.0
        rest = sp.position + direction * (v * v / (2.0 * a) + ramp)
        return (value - rest) * direction > 0

    def limit_move(self, goal: float) -> None:
        """The safety envelope brings the end of a running :meth:`move_toward` nearer (the
        other axis's motion changed): the move ends at rest at ``goal`` (drive frame) at its
        speed, or stops at once when it cannot brake before ``goal`` with its normal
        deceleration; never further, never the other way. Anything else running is left
        alone. Returns at once."""
        self._send("bound", float(goal))

    def set_stop(self, value: int) -> None:
        """``STOP``: quick stop, cancel targets and trajectories (returns at once)."""
        self.stop()

    def stop(self) -> None:
        self._send("stop")
        if self.envelope is not None:   # the other axis's running move is judged again
            try:
                self.envelope(self, "stop")
            except Exception:   # (a STOP is never refused)
                log.exception("%s: the envelope's judgement after STOP failed", self.module_name)

    def shutdown(self) -> None:
        """Service stopping: stop, then power off (no reply is waited for)."""
        self._send("stop")
        self._send("power", False)

    def set_speed(self, value: float) -> None:
        """``CURRSPEED`` written: lowers the speed of new motion."""
        value = float(value)
        if not 0 < value <= self.section.max_velocity:
            raise RangeRefused(f"{self.module_name}: speed must be in (0, {self.section.max_velocity}]")
        self._send("speed", value)

    def set_reinit(self, value: int) -> None:
        """``REINIT``: 0 = reference if not referenced, 1 = force (returns at once)."""
        self.reference(bool(int(value)), wait=False)

    @property
    def cyclic_mode(self) -> Mode:
        """The mode trajectories are streamed in: the drive's (CSP, IP or CSV; see
        tcs.drivers.eds.choose_mode — it may change at the drive's first boot, when the drive
        itself tells its modes), CSP for drives that do not say."""
        return getattr(self.drive, "cyclic_mode", None) or Mode.CSP

    @property
    def absolute(self) -> bool:
        """The drive's axis is referenced by configuration (an absolute encoder): no homing
        run ever, on any drive (``[drives.x] absolute``)."""
        return bool(getattr(self.drive, "referenced_by_configuration", False))

    def reference(self, force: bool = False, wait: bool = True):
        """Start homing; the future completes when referenced (cabinet REINIT awaits it)."""
        if self._fault is not None:
            raise TcsError(f"{self.module_name}: cannot reference: {self._fault.message}", self._fault.number)
        if self.power_state != 1.0:
            raise TcsError(f"{self.module_name}: cannot reference: power is off", ErrorNumber.INVMODE)
        future = self._future()
        if self.referenced >= 1.0 and not force:
            future.set_result(None)
        else:
            if self.motion_state & 1 and not self._homing:
                raise TcsError(f"{self.module_name}: cannot reference while moving (STOP first)",
                               ErrorNumber.INVMODE)
            bounds = None if self._homing else self._homing_bounds()
            self.referenced = 0.0  # from now on, until the new run has ended (read at once)
            self._send("reference", force if bounds is None else (force, bounds), future)
        if not wait:
            future.add_done_callback(lambda f: f.cancelled() or f.exception())
        return future

    def _homing_bounds(self) -> tuple | None:
        """The safety envelope on the homing search (main axes): each way the search may
        sweep (:data:`HOMING_DIRECTIONS`), with the other axis where it stands, judged up to
        the software limit at the search speed. A border within the run's stopping distance
        refuses the referencing (``EnvelopeError``, 9 SOFTLIMIT, nothing starts); farther
        ones are returned as ``(lo, hi, acceleration)`` (``(position, words)`` or None each),
        where the control loop halts the run (:meth:`_watch_homing_border`)."""
        if self.envelope is None or self.discrete or self.homing_search is None:
            return None
        directions, speed, acc = self.homing_search
        if speed <= 0.0 or acc <= 0.0:
            return None
        reach = speed * speed / (2.0 * acc) + speed * max(0.1, 5.0 * self.dt)
        lo = hi = None
        for direction in directions:
            border = self.envelope(self, "homing", direction, speed=speed, reach=reach)
            if direction > 0:
                hi = border
            else:
                lo = border
        if lo is None and hi is None:
            return None
        return lo, hi, acc

    def set_run(self, value: int, shift: float | None = None):
        """``TRAJECTORY.RUN``: 1 runs (long-running until the queue ran empty or was
        aborted), 0 aborts and frees the buffers (done within one cycle: the awaitable ends
        when the buffers are free, so a GET of FREEPOINTS after the reply sees them).
        ``shift``: whole cycles to add to the queued path of a cyclic axis, chosen by the
        caller (POINTING's cable-wrap choice); ``None``: the follower chooses."""
        if value == 0:
            future = self._future()
            self._send("run", False, future)
            return future
        self._require(what="run a trajectory")
        if self.envelope is not None and shift is None:   # a client's trajectory (POINTING
            self.envelope(self, "run")                    # passes its cable-wrap shift)
        future = self._future()
        self._send("run", True if shift is None else (True, float(shift)), future)
        return future

    def acknowledge_errors(self, value: int):
        """``ERROR_STATE=0``: as every module, plus the drive: with a drive fault it is
        long-running — it completes when the drive's fault reset is done (POWER=1 may follow at
        once) and fails when the reset cannot be done (the drive offline, the reset refused)."""
        self._ack_future = None
        super().acknowledge_errors(value)
        future, self._ack_future = self._ack_future, None
        return future

    @property
    def fault(self) -> TcsError | None:
        """The drive fault that stopped this axis and is not yet acknowledged, if any."""
        return self._fault

    def give_up(self, error: TcsError) -> None:
        """Another axis of the mount faulted (control loop): stop this one — the drive makes a
        controlled stop — and power it off; an explicit POWER=1 brings it back."""
        self._send("give up", error)

    def on_acknowledge(self) -> None:
        """ERROR_STATE=0: forget a drive fault once the drive is reset (never re-enables)."""
        future = None
        if self._fault is not None:
            try:
                future = self._future()
            except RuntimeError:  # no event loop (tests driving the axis by hand)
                future = None
            if future is not None:  # (CABINET.ERROR_STATE=0 does not wait for it)
                future.add_done_callback(lambda f: f.cancelled() or f.exception())
        self._ack_future = future
        self._send("acknowledge", None, future)

    def drive_status(self) -> DriveStatus | None:
        return self.last_status

    def emit(self, level: str, number: int, text: str = "", cause=None) -> None:
        if self._events is not None:
            self._events.emit(level, self.module_name, number, text, cause)

    # ================================================================ control-loop side

    def _resolve(self, key: str, error: TcsError | None = None) -> None:
        for future in self._joined.pop(key, ()):
            self._complete(future, error)
        entry = self._pending.pop(key, None)
        if entry is None:
            return
        future, _ = entry
        self._complete(future, error)

    def _complete(self, future: asyncio.Future | None, error: TcsError | None = None) -> None:
        """Queue a completion; :meth:`_flush` hands them to the event loop at the end of the
        cycle, after the readbacks were published (so a client that gets ``DATA OK`` reads
        the new state) and after this cycle's events."""
        if future is not None:
            self._completions.append((future, error))

    def _flush(self) -> None:
        if not self._completions or self._loop is None:
            return
        batch, self._completions = self._completions, []
        try:
            self._loop.call_soon_threadsafe(complete_futures, batch)
        except RuntimeError:  # loop closed at shutdown
            pass

    def _hold(self, key: str, future, cause) -> None:
        old = self._pending.get(key)
        if old is not None:
            self._complete(old[0], TcsError(f"{self.module_name}: target changed", ErrorNumber.TARGETCHANGE))
            self.emit(ERROR, ErrorNumber.TARGETCHANGE, "target changed", old[1])
        if future is not None:
            self._pending[key] = (future, cause)

    def _fail_motion(self, error: TcsError) -> None:
        for key in ("target", "offset"):
            self._resolve(key, error)
        self._resolve("run", error if error.number not in (ErrorNumber.TARGETCHANGE,) else None)

    def cycle(self, t: float, now: float, measured: float | None = None) -> None:
        """One control cycle: ``t`` is the UT1 time the drive reaches this cycle's setpoint,
        ``now`` the monotonic time, ``measured`` the UT1 time the drive's status was sampled
        (this cycle's SYNC; default ``t``). Control-loop thread only."""
        st = self.drive.status()
        self.last_status = st
        with self._lock:
            commands = list(self._commands)
            self._commands.clear()
        for kind, value, future, cause in commands:
            try:
                self._apply(kind, value, future, cause, st, t, now)
            except TcsError as exc:
                self._complete(future, exc)
        self._watch_drive(st, now)
        sync = t if measured is None else measured
        demand = self._demand(st)
        if self.cycle_resumed:
            self._resume(st, t, sync, demand)
            self._latched = None
        elif self._sent is not None and self.cycle_times is not None:
            self._latched = (self.cycle_times[0], self._sent)
        setpoint = self._motion(st, t)
        if setpoint is not None:
            setpoint = self._limit_step(setpoint, st.position, st.velocity)
            self.drive.set_setpoint(setpoint.position, setpoint.velocity)
            self._sent_reach = t
        else:
            self._sent, self._latched = None, None
        if self.cycle_fresh and self._fresh_before:  # (else it may be an older SYNC's)
            self._last_demand = (sync, demand)
        self._fresh_before = self.cycle_fresh
        self.drive.step()
        self.sample = (sync, st.position, t, None if setpoint is None else setpoint.position)
        self._publish(st, sync)
        self._flush()

    def _demand(self, st: DriveStatus) -> float:
        """Where the drive's demand is by this cycle's readback: position actual + following
        error (0x60F4 = demand − actual) in CSP/IP; the actual position in CSV (the drive has
        no position demand there; the following error is the TCS's own)."""
        if st.mode == Mode.CSV or not math.isfinite(st.following_error):
            return st.position
        return st.position + st.following_error

    def _resume(self, st: DriveStatus, t: float, sync: float, demand: float) -> None:
        """The cycle after a gap: re-anchor the base of :meth:`_limit_step` on where the
        drive's demand really is.

        The drive bridged the gap by itself (held its last setpoint, extrapolated it at the
        stream's speed, or in CSV kept its last velocity), and the setpoint made before the
        gap never reached it (the cycle source dropped it). Both bridgings are known exactly
        from the stream itself: extrapolated, the demand is the last setpoint sent carried on
        at its speed to this SYNC (for the drive's RPDO deadline at most,
        ``drive.bridging_limit``); held, it is the last target the drive latched. A readback
        whose synchronous TPDOs (of this cycle and the one before) all came in time says
        "held" when its demand (position actual + following error 0x60F4) lies within
        :data:`HELD_SHARE` of the way from the held target to the extrapolated stream — a
        readback that lags the gap looks like a hold — and the base is then the held target,
        or the motor where it ran on past it while braking at its own limit (no step back for
        the motor); in CSV the base is the actual position and velocity. Otherwise the base is
        the readback's demand (fresh or not) kept between those two bridgings, moving on at
        the stream's speed: a drive that bridged only part of the gap is joined where it is.
        The base is carried on to the next SYNC (which latches this cycle's setpoint). From
        that base the step to
        the planner's or follower's setpoint is cut to the axis's speed, acceleration and
        stop deceleration (:meth:`_limit_step`); the planner is planned again from the anchor
        (:meth:`MotionPlanner.resume`), the follower's path is sampled by time and met by
        the step limit's catch-up. Nothing to do while no setpoint streams."""
        if self._sent is None or not st.enabled or self._homing or self.discrete:
            return
        last = self._last_demand
        vmax = self.dynamics.max_velocity
        trusted = self.cycle_fresh and self._fresh_before
        way = 1.0 if self._sent_velocity >= 0 else -1.0
        interval = self.dt if self.cycle_times is None else self.cycle_times[1] - self.cycle_times[0]
        interval = max(0.0, interval)
        # the two things a drive does without setpoints, each known exactly from the stream:
        # it extrapolated at the stream's speed (E), or it held the last target it latched (H)
        velocity, how = self._sent_velocity, "extrapolated setpoint"
        # (a drive extrapolates for its RPDO deadline at most, then stops by itself: a gap
        # longer than that is its fault reaction's, and the stream goes on from where the
        # extrapolation ended — a drive whose own clock stalled with this host's, as the
        # in-process simulator's does, bridged no longer either)
        bridged = max(0.0, sync - self._sent_reach)
        bound = getattr(self.drive, "bridging_limit", None)
        if bound is not None:
            bridged = min(bridged, bound)
        position = self._sent + velocity * bridged
        held = self._latched[1] if self._latched else self._sent
        if trusted and st.mode == Mode.CSV:
            position, velocity, how = st.position, st.velocity, "actual position"
        elif (trusted and math.isfinite(st.following_error)
              and abs(demand - held) < HELD_SHARE * abs(position - held)):
            # the readback says it held: join the motor where it is if it ran on past the
            # target while braking at its own limit (no step back for it), else the target
            if way * (st.position - held) > 0.0 and way * st.velocity >= 0.0:
                position, velocity, how = st.position, st.velocity, "motor (the drive held)"
            else:
                position, velocity, how = held, 0.0, "held target"
        elif st.mode != Mode.CSV and math.isfinite(demand) and self._sent_velocity != 0.0:
            # on from the drive's demand at the stream's speed, kept between the two
            # bridgings: a drive that bridged only part of the gap (the in-process simulator
            # leaves its own stalls out of its physics) was 47-51 deg behind the stream
            # extrapolated over 0.29-0.36 s stalls at 130-160 deg/s, and a stale readback is
            # a step back of its age at most
            lo, hi = sorted((held, position))
            joined = min(hi, max(lo, demand))
            if joined != position:
                position, how = joined, "demand (it bridged part of the gap)"
        # (the speed is always the stream's, and "held" needs a demand near the held target:
        # on a busy host a readback mixes TPDOs or lags the gap — a speed measured over the gap
        # was off by 1.5 deg/s and a stream re-anchored on it ran 0.5 deg past a horizon bound
        # it braked to; a stale one looks like a hold)
        velocity = max(-vmax, min(vmax, velocity))
        anchor = Setpoint(position + velocity * interval, velocity)
        log.info("%s: a gap of %.3f s in the setpoint stream; re-anchored on the drive's %s "
                 "%.5f at %.4f/s (the stream had sent %.5f; the readback: demand %.5f, motor "
                 "%.5f at %.4f/s%s)", self.module_name,
                 sync - last[0] if last else float("nan"), how, position, velocity, self._sent,
                 demand, st.position, st.velocity, "" if trusted else ", not fresh")
        self._sent, self._sent_velocity = anchor.position, velocity
        self.resumes += 1
        if not self._running:  # (a move goes on from the drive, not back to the old profile)
            self.planner.resume(anchor)
            self._resumed_planner = True

    def _limit_step(self, sp: Setpoint, measured: float, measured_velocity: float = 0.0) -> Setpoint:
        """The last line of the speed and acceleration limits: the drive interpolates from one
        setpoint to the next over one SYNC period whenever they arrive, so the step between
        two sent setpoints must stay within ``max_velocity·T`` and change from the step before
        by no more than the acceleration limit × T² (``max_acceleration`` speeding up,
        ``quick_stop_acceleration`` slowing down), whatever the cycle's lateness: a trajectory
        sampled after skipped SYNC slots asks for several cycles' travel in one (7.8°/s against
        5 was measured, and a one-period jump of the speed is an acceleration of v/T).

        A setpoint within both limits is sent as it is (the planner's profiles and a trajectory
        sampled on the SYNC grid are). A cut one aims back at the axis's own setpoint: the speed
        of its path plus a catch-up that can be braked within the limits (√(a·|e|)), then held to
        the limits; it replaces the axis's setpoint, so the follower re-intercepts its path from
        there. Counted in ``clamped_steps``."""
        T = self.dt
        dyn = self.dynamics
        if self._sent is None:
            p0, v0 = measured, measured_velocity
        else:
            p0, v0 = self._sent, self._sent_velocity
        v_want = (sp.position - p0) / T
        vmax = dyn.max_velocity
        acc = dyn.max_acceleration
        dec = max(acc, dyn.quick_stop_acceleration or acc)
        hi = v0 + (acc if v0 >= 0 else dec) * T
        lo = v0 - (dec if v0 > 0 else acc) * T
        slack = 1e-6 * max(vmax, abs(v0)) + 1e-9 / T
        if lo - slack <= v_want <= hi + slack and abs(v_want) <= vmax * (1 + 1e-6):
            self._sent, self._sent_velocity = sp.position, v_want
            return sp
        lag = sp.position - (p0 + sp.velocity * T)   # where the path will be, moving at its speed
        v = sp.velocity + math.copysign(min(abs(lag) / T, math.sqrt(acc * abs(lag))), lag)
        v = max(-vmax, min(vmax, max(lo, min(hi, v))))
        self.clamped_steps += 1
        clamped = Setpoint(p0 + v * T, v, 0.0, 0.0)
        self._sp = clamped
        self._sent, self._sent_velocity = clamped.position, v
        return clamped

    def _apply(self, kind, value, future, cause, st: DriveStatus, t: float, now: float) -> None:
        if kind == "power":
            if bool(value) == self._powered and self._want_power is None:
                self._complete(future)  # already there
                return
            self._hold("power", future, cause)
            self._want_power = value
            self._power_since = now
            if value:
                self.drive.set_mode(Mode.PP if self.discrete else self.cyclic_mode)
                self.drive.enable()
            else:
                self._stop_motion(TcsError(f"{self.module_name}: power off", ErrorNumber.INVMODE))
                self.drive.disable()
        elif kind == "target":
            self._hold("target", future, cause)
            if self.discrete:
                self._discrete_target = int(round(value))
                self.target_position = float(self._discrete_target)
                self.drive.move_to(self.positions[self._discrete_target])
                self._discrete_sent = True  # this cycle's status is the previous move's
            else:
                if self._running:  # direct positioning cancels the trajectory (spec §5.1)
                    self.follower.abort()
                    self._running = False
                    self._resolve("run")
                    self.emit(INFO, ErrorNumber.TRAJ_STOP, "cancelled by TARGETPOS", self._run_cause)
                    self.planner.take_over(self._sp)  # from the follower's (moving) setpoint
                elif not self.planner.moving:
                    self.planner.take_over(self._sp)
                self.planner.set_target(value, resolve=False)   # (the turn set_target chose)
            self.emit(INFO, ErrorNumber.MOTIONCHANGE, f"moving to {value:g}", cause)
        elif kind == "offset":
            # checked before anything changes: a refused offset (RANGE) keeps the old one and
            # leaves a pending OFFSET alone
            if self._running:
                self.follower.check_offset(value, t)
            elif not self.limits.contains(self.planner.target + value):
                raise RangeRefused(f"{self.module_name}: offset {value:g} puts the target outside the limits")
            self._hold("offset", future, cause)
            if self._running:
                self.follower.set_offset(value)
            else:
                self.planner.set_offset(value)
            self.offset = value
        elif kind == "abort":
            keys = [k for k in ("target", "offset", "run")
                    if value is not None and k in self._pending and self._pending[k][1] == value]
            if keys:
                self._stop_motion(TcsError(f"{self.module_name}: aborted", ErrorNumber.TARGETCHANGE),
                                  quick=False)
                self.emit(INFO, ErrorNumber.MOTIONCHANGE, "aborted: stopping", value)
            if (self._homing and value is not None and "reference" in self._pending
                    and self._pending["reference"][1] == value):
                # the referencing this command started (READY=1): the drive ends the homing
                # run with its normal deceleration; the REFERENCE request fails (halted)
                self.drive.halt()
                self.emit(INFO, ErrorNumber.MOTIONCHANGE, "aborted: referencing stops", value)
        elif kind == "jog":
            goal, speed, direction = value
            if (goal - self._sp.position) * direction <= 0:  # never the other way
                self._complete(future, RangeRefused(f"{self.module_name}: at the limit {goal:g} already"))
                return
            self._hold("target", future, cause)
            if self._running:
                self.follower.abort()
                self._running = False
                self._resolve("run")
                self.emit(INFO, ErrorNumber.TRAJ_STOP, "cancelled by a move", self._run_cause)
                self.planner.take_over(self._sp)
            elif not self.planner.moving:
                self.planner.take_over(self._sp)
            sp = self.planner.setpoint
            if sp.velocity * direction > 0 and not self._brakes_before(sp, goal, direction):
                # already running this way faster than it can brake before the goal (a border
                # the other axis's motion brought near): stop now — a move_to would overshoot
                # the goal and come back
                self.planner.stop(quick=True)
            else:
                self.planner.move_to(goal, speed)
            self._jog = (speed, direction, future)
            self.emit(INFO, ErrorNumber.MOTIONCHANGE, f"moving towards {goal:g} at {speed:g}/s", cause)
        elif kind == "bound":   # the envelope brings a running move_toward's end nearer
            jog = self._jog
            pending = self._pending.get("target")
            if (jog is None or pending is None or pending[0] is not jog[2] or self._running
                    or not self.planner.moving):
                return
            speed, direction, _future = jog
            if (self.planner.demanded_target - value) * direction <= 1e-12:
                return   # (ends there or nearer already)
            sp = self.planner.setpoint
            if not self._brakes_before(sp, value, direction):
                self.planner.stop(quick=True)
            else:
                self.planner.move_to(value, speed)
            self.emit(INFO, ErrorNumber.MOTIONCHANGE, f"safety envelope: the move ends at "
                      f"{self.planner.demanded_target:g}", cause)
        elif kind == "stop":
            self._stop_motion(TcsError(f"{self.module_name}: stopped", ErrorNumber.TARGETCHANGE))
            if self._homing:  # STOP ends referencing too (CABINET.STOP during a REINIT)
                self.drive.halt()
                if not self._homing_started:
                    # the drive may never show this run in progress now: end it here, or a
                    # new request (Alpaca Halt, then Move) would join the stopped run and fail
                    # with it after HOMING_START_TIMEOUT ("homing did not start")
                    self._homing, self._after_homing, self.referenced = False, True, 0.0
                    error = TcsError(f"{self.module_name}: referencing stopped", ErrorNumber.TARGETCHANGE)
                    self._resolve("reference", error)
                    self.emit(ERROR, ErrorNumber.REFERENCE_BAD, error.message, self._reference_cause)
        elif kind == "give up":
            self._stop_motion(value)
            if self._powered or self._want_power:
                self.emit(ERROR, ErrorNumber.POWERCHANGE, value.message)
                self._resolve("power", value)
                self._want_power, self._power_since = False, now
                self.drive.disable()  # (quick stop first while it moves: the driver's rule)
        elif kind == "speed":
            self.planner.set_speed(value)
            if self.follower is not None:
                self.follower.set_speed(value)
        elif kind == "reference":
            bounds = value[1] if isinstance(value, tuple) else None
            if future is not None:  # a request while homing runs joins it and ends with it
                if "reference" in self._pending:
                    self._joined.setdefault("reference", []).append(future)
                else:
                    self._pending["reference"] = (future, cause)
            if self._homing:
                return
            if self.absolute:  # referenced by configuration: nothing runs on the drive
                self.emit(INFO, ErrorNumber.REFERENCE_EXECUTE, "referencing", cause)
                self._reference_cause = cause
                self._referenced_now()
                return
            self._homing = True
            self._homing_started = False
            self._homing_since = now
            self._homing_border, self._homing_stopped = bounds, None
            self._reference_cause = cause
            self.referenced = 0.0
            self.drive.start_homing()
            self.emit(INFO, ErrorNumber.REFERENCE_EXECUTE, "referencing", cause)
        elif kind == "run":
            if not value:
                if self._running:
                    self.follower.abort()
                self._resolve("run")
                self.queue.clear()
                self._complete(future)
                return
            self.follower.set_offset(self.offset)
            # (raises nopoints before changing anything: a move in progress goes on)
            dropped = self.follower.start(t, self._sp, value[1] if isinstance(value, tuple) else None)
            self._hold("run", future, cause)
            self._run_cause = cause
            if "target" in self._pending:  # the trajectory supersedes direct positioning
                self._hold("target", None, None)
                del self._pending["target"]
            if self.planner.moving:
                self.planner.stop(quick=False)  # (not stepped while following; taken over after)
            self._running = True
            if dropped:
                self.emit(INFO, POINTS_DROPPED, f"{dropped} trajectory points in the past dropped", cause)
        elif kind == "acknowledge":
            if self._fault is None:
                self._complete(future)
            elif st.state is DriveState.OFFLINE:
                why = st.fault.message if st.fault else "the drive is offline (being booted again)"
                self._complete(future, TcsError(f"{self.module_name}: cannot reset: {why}",
                                                (st.fault or self._fault).number))
            elif st.fault is None:  # gone already (a heartbeat that came back, a rebooted drive)
                self._forget_fault()
                self._complete(future)
            else:  # reset it; _watch_drive forgets it once the drive left Fault
                self._ack_pending = True
                self._ack_since = now
                self._hold("acknowledge", future, cause)
                self.drive.fault_reset()

    def _forget_fault(self) -> None:
        self._fault = None
        self._ack_pending = False
        self._resolve("acknowledge")
        if self.conditions().get("drive fault", (0, False))[1]:
            self.clear_condition("drive fault")

    def _stop_motion(self, error: TcsError, quick: bool = True) -> None:
        """Quick stop (``quick``; else the normal deceleration) of whatever moves the axis;
        pending SETs end with ``error``. A running trajectory is braked by the follower itself
        (from its own setpoint: the planner's state is stale while the follower is in charge);
        :meth:`_motion` hands the axis back to the planner when the follower has ended."""
        if self._running:
            self.follower.abort(quick=quick)
        else:
            self.planner.stop(quick=quick)
        if self.discrete and self._powered:
            # a profile-position move (filter wheel, M3) runs in the drive: its halt bit
            # brakes it with the profile deceleration; the planner has nothing to stop
            self.drive.halt()
            self._discrete_target = None
        self._fail_motion(error)
        self._resolve("run")
        self.queue.clear()

    def _watch_drive(self, st: DriveStatus, now: float) -> None:
        fault = st.fault
        if fault is not None and self._fault is None:
            self._fault = fault
            self._powered = False
            self._want_power = None
            self.raise_condition("drive fault", ERROR_BIT, fault.message)
            self.emit(ERROR, fault.number, fault.message)
            self._stop_motion(fault)
            for key in ("power", "reference"):
                self._resolve(key, fault)
            self._homing = False
            if self._settle:  # (homed, not yet on its port: referenced all the same)
                self._settle, self.referenced = False, 1.0
            self.drive.disable()
        if self._ack_pending and st.state is DriveState.FAULT_REACTION_ACTIVE and st.request_error is None:
            # (the drive still brakes — its fault reaction — and resets once in Fault: the
            # time-out counts from there; the driver bounds the reaction itself)
            self._ack_since = now
        if self._ack_pending and now - self._ack_since > ACK_TIMEOUT:
            self._ack_pending = False
            self._resolve("acknowledge", st.request_error or TcsError(
                f"{self.module_name}: the drive's fault reset did not complete within "
                f"{ACK_TIMEOUT:g} s (state {st.state.value})", ErrorNumber.TIMEOUT))
        if st.reboots != self._drive_reboots:
            self._drive_reboots = st.reboots
            if self.referenced > 0.0 and not self._homing and not self.absolute:
                # relative encoders: position lost
                self.referenced = 0.0
                self.emit(ERROR, ErrorNumber.REFERENCE_BAD, "drive rebooted: reference lost")
        if self._fault is not None and st.fault is None and st.state is DriveState.SWITCH_ON_DISABLED:
            # the drive was reset: the condition's cause is gone; after an acknowledge the
            # axis may be powered again (it is never re-enabled by itself)
            if self._ack_pending:
                self._forget_fault()
            elif self.conditions().get("drive fault", (0, False))[1]:
                self.clear_condition("drive fault")
        # power
        if self._want_power is True and st.enabled and not self._powered and (
                self.discrete or st.mode == self.cyclic_mode and (
                    st.mode != Mode.IP or st.statusword & 0x1000)):  # IP: "IP active" shown
            self._powered = True
            self._want_power = None
            self._after_homing = False
            self._sp = Setpoint(st.position)
            self.planner.take_over(self._sp)
            if self.referenced < 1.0 and st.homed:
                self.referenced = 1.0
            self.emit(INFO, ErrorNumber.POWERCHANGE, "power on", self._pending.get("power", (0, None))[1])
            self._resolve("power")
        elif self._want_power is False and not st.enabled and st.state is not DriveState.QUICK_STOP_ACTIVE:
            if self._powered or "power" in self._pending:
                self._powered = False
                self.emit(INFO, ErrorNumber.POWERCHANGE, "power off", self._pending.get("power", (0, None))[1])
                self._resolve("power")
            self._want_power = None
        elif self._want_power is not None and now - self._power_since > self.power_timeout:
            error = st.request_error or TcsError(
                f"{self.module_name}: drive did not reach {'on' if self._want_power else 'off'} "
                f"within {self.power_timeout:g} s (state {st.state.value})", ErrorNumber.TIMEOUT)
            self._resolve("power", error)
            self._want_power = None
        if self._powered and not st.enabled and not self._homing and self._fault is None:
            if self._want_power is False:  # on its way off as asked (POWER=0, given up)
                self._powered = False
                self._stop_motion(TcsError(f"{self.module_name}: drive left operation enabled",
                                           ErrorNumber.LIMIT))
                self.emit(ERROR, ErrorNumber.POWERCHANGE, f"drive {st.state.value}")
            else:
                self._power_lost(st)
        # homing: the status shows the drive's previous run (done, long ago) until the drive
        # took this request; only an end seen after "in progress" is this run's
        if self._homing and not self._homing_started:
            if st.homing is Progress.RUNNING:
                self._homing_started = True
            elif now - self._homing_since > HOMING_START_TIMEOUT:
                if st.homing is Progress.FAILED:  # the drive refused it: reported below
                    self._homing_started = True
                else:
                    self._homing, self._after_homing = False, True
                    self.drive.halt()   # (a late start must not search on unwatched)
                    error = TcsError(f"{self.module_name}: homing did not start", ErrorNumber.TIMEOUT)
                    self._resolve("reference", error)
                    self.emit(ERROR, ErrorNumber.REFERENCE_BAD, error.message, self._reference_cause)
        if self._homing and self._homing_border is not None and self._homing_stopped is None:
            self._watch_homing_border(st)
        if self._homing and not self._homing_started:
            self.referenced = 0.0
        elif self._homing:
            if st.homing is Progress.DONE:
                self._homing = False
                self._sp = Setpoint(st.position)
                self.planner.take_over(self._sp)
                if self.discrete:  # the nearest port is the target; settle on it (bit 3 there)
                    nearest = min(self.positions, key=lambda k: abs(self.positions[k] - st.position))
                    self._discrete_target = nearest
                    self.target_position = float(nearest)
                    if abs(st.position - self.positions[nearest]) > max(self.section.tolerance, 1e-9):
                        # homing stops past the index (a wheel 0.125 deg off its port was seen):
                        # the profile move a TARGETPOS of that port makes ends the referencing
                        try:
                            self.drive.move_to(self.positions[nearest])
                        except TcsError as exc:  # referenced all the same, not on target
                            log.warning("%s: cannot settle on port %d after homing: %s",
                                        self.module_name, nearest, exc.message)
                        else:
                            self._settle, self._settle_since, self._settle_started = True, now, False
                            self.referenced = 0.99
                if not self._settle:
                    self._referenced_now()
            elif st.homing is Progress.FAILED:
                self._homing = False
                self._after_homing = True
                self.referenced = 0.0
                error = self._homing_stopped or st.request_error or TcsError(
                    f"{self.module_name}: homing failed", ErrorNumber.TIMEOUT)
                self._resolve("reference", error)
                self.emit(ERROR, ErrorNumber.REFERENCE_BAD, error.message, self._reference_cause)
            else:
                self.referenced = min(0.99, st.homing_progress)
        if self._settle:
            self._watch_settle(st, now)

    def _watch_homing_border(self, st: DriveStatus) -> None:
        """A homing run heading for a border of the safety envelope (:meth:`_homing_bounds`)
        is halted where the drive's homing deceleration stops it before the border (the
        distance it still runs at this speed, plus three cycles of latency); the reference
        request fails with 9 SOFTLIMIT naming the border."""
        lo, hi, acc = self._homing_border
        v = st.velocity
        reach = v * v / (2.0 * acc) + abs(v) * 3.0 * self.dt + max(self.section.tolerance, 1e-9)
        for edge, direction in ((hi, 1), (lo, -1)):
            if edge is None:
                continue
            border, words = edge
            left = (border - st.position) * direction
            if left <= reach and (v * direction > 0.0 or left <= 0.0):
                text = (f"referencing stopped at the safety envelope's border: the homing search "
                        f"would have entered {words}")
                self._homing_stopped = TcsError(f"{self.module_name}: {text}", ErrorNumber.SOFTLIMIT)
                self.drive.halt()
                self.emit(ERROR, ErrorNumber.SOFTLIMIT, text, self._reference_cause)
                return

    def _referenced_now(self) -> None:
        self.referenced = 1.0
        self._resolve("reference")
        self.emit(INFO, ErrorNumber.REFERENCE_GOOD, "referenced", self._reference_cause)

    def _watch_settle(self, st: DriveStatus, now: float) -> None:
        """A discrete axis homed off its nearest port moves onto it; REFERENCED reaches 1 (and
        event 19 is sent) when it stands there, or when the move ended or never started (then
        it is referenced but not on target: MOTION_STATE bit 3 stays 0)."""
        if st.move is Progress.RUNNING:
            self._settle_started = True
            return
        on_port = abs(st.position - self.positions[self._discrete_target]) <= max(self.section.tolerance, 1e-9)
        if on_port or self._settle_started or not self._powered or \
                now - self._settle_since > HOMING_START_TIMEOUT:
            self._settle = False
            self._referenced_now()

    def _power_lost(self, st: DriveStatus) -> None:
        """The drive dropped out of Operation enabled by itself, without a fault (a quick stop
        of its own, a reaction to a lost master): latched like a fault — ERROR_STATE shows it,
        STATUS.LIST records it, and only ERROR_STATE=0, then POWER=1, bring the axis back."""
        error = TcsError(f"drive left operation enabled by itself (now {st.state.value})",
                         ErrorNumber.LIMIT)  # (no module prefix: the messages add it)
        self._powered = False
        self._fault = error
        self._want_power = None
        self.raise_condition("drive fault", ERROR_BIT, error.message)
        self._stop_motion(error)
        self.emit(ERROR, ErrorNumber.POWERCHANGE, f"drive {st.state.value}")
        self.drive.disable()

    def _motion(self, st: DriveStatus, t: float) -> Setpoint | None:
        if self._after_homing and st.mode == self.cyclic_mode and abs(st.velocity) <= self._standstill:
            # a homing run that ended early (STOP, ABORT, time-out, refused, stopped at the
            # envelope's border): the planner starts from where the drive came to rest — never
            # from the setpoint it held before the run (a return slew nobody asked for)
            self._after_homing = False
            self._sp = Setpoint(st.position)
            self.planner.take_over(self._sp)
        if not self._powered or self._homing or self.discrete or not st.enabled or self._after_homing:
            # (after a homing run that ended early the drive brakes in HM while the mode
            # switches back: the setpoint follows where it stands, never a stale one)
            if not self._homing:
                self._sp = Setpoint(st.position)
                if self.planner.moving or self._after_homing:
                    # power lost mid-move, a homing run that ended: the demand is where it stands
                    self.planner.take_over(self._sp)
                if self._running:  # (the follower was aborted by _stop_motion)
                    self._running = False
                    self.planner.take_over(self._sp)
            return None
        if self._running:
            step = self.follower.step(t, self._sp)
            self._sp = step.setpoint
            for number in step.events:
                self.emit(ERROR if number == ErrorNumber.SOFTLIMIT else INFO, number,
                          self.follower.end_reason or "", self._run_cause)
            if self.follower.state.value == "ended":
                self._running = False
                # the path's points are executed (``t`` is past the end a cycle or two before
                # the clock is): free them now, so FREEPOINTS reads the whole capacity as soon
                # as RUN=1 answered (points added meanwhile for later stay)
                self.queue.drop_before(t)
                if self.follower.end_reason == "softlimit":
                    self._resolve("run", TcsError(f"{self.module_name}: trajectory stopped at the "
                                                  f"software limit", ErrorNumber.SOFTLIMIT))
                else:
                    self._resolve("run")
                self.planner.take_over(self._sp)
        else:
            # (after a gap the planner moves on by the SYNC periods that passed: the drive
            # bridged them, so its path goes on from where the drive is, not one step after
            # the last setpoint sent)
            periods = self.cycle_periods if self.cycle_resumed and not self._resumed_planner else 1
            self._resumed_planner = False
            self._sp = self.planner.step(periods)
            if self.planner.softlimit is not None and ("target" in self._pending or "offset" in self._pending):
                self._fail_motion(TcsError(f"{self.module_name}: software limit {self.planner.softlimit}",
                                           ErrorNumber.SOFTLIMIT))
                self.emit(ERROR, ErrorNumber.SOFTLIMIT, f"software limit {self.planner.softlimit}")
        return self._sp

    def _publish(self, st: DriveStatus, t: float) -> None:
        """Readbacks of this cycle; ``t`` is when ``st`` was measured, so that during a
        trajectory TARGETPOS is the path at that time and TARGETDISTANCE the following error
        (the path where the setpoint is heading would add velocity × 2 cycles to it)."""
        prev_motion, prev_limit = self.motion_state, self.limit_state
        # a move sent this cycle: ``st`` (read before it) still shows the previous move's end
        # (a halted one: FAILED), which is not this move's; the next cycle's status is
        fresh, self._discrete_sent = self._discrete_sent, False
        self.measured_ut1 = t
        sp = self._sp
        if st.state is DriveState.OFFLINE:
            why = st.fault.message if st.fault is not None else "drive offline"
            self.stale = CommunicationError(self.module_name, f"no fresh data ({why})")
        else:
            self.stale = None
        if self.discrete:
            self.real_position = self._discrete_position(st.position)
        else:
            self.real_position = st.position
        self.current_speed = st.velocity
        self.current_acc = sp.acceleration
        self.current_jerk = sp.jerk
        error = abs(st.position - sp.position)
        # power state
        self.power_state = 1.0 if self._powered else 0.0
        # target position in the user frame: where the axis is going; at rest with nothing
        # to go to (never powered, never referenced, a port not reached), where it is
        if self._running:
            if len(self.queue):  # (empty while stopping after RUN=0: keep the last demand)
                self.target_position = self.follower.path_position(t) - self.offset
        elif self.discrete:
            at_rest = st.move is not Progress.RUNNING and not self._homing
            if self._discrete_target is None and at_rest:
                rp = self.real_position
                if self._powered and self.referenced >= 1.0 and rp.is_integer() and int(rp) in self.positions:
                    self._discrete_target = int(rp)  # settled on a port after homing: on target
                self.target_position = rp
        elif self._powered and not self._homing:
            self.target_position = self.planner.target
        else:  # the planner is not in charge (power off, homing): the demand is where it stands
            self.target_position = self.real_position - self.offset
        # MOVING (bit 0) comes from the commanded motion, which is free of noise: a slow
        # trajectory (sidereal rate) measures close to _standstill and would make the bit and
        # its MOTIONCHANGE event flap every few cycles. A measured velocity alone (pushed,
        # drifting, a drive still settling) sets it after MEASURED_MOVING_CYCLES in a row and
        # keeps it while it lasts.
        self._drift_cycles = self._drift_cycles + 1 if abs(st.velocity) > self._standstill else 0
        measured = self._drift_cycles >= (1 if prev_motion & MOVING else MEASURED_MOVING_CYCLES)
        commanded = not self.discrete and self._powered and (self.planner.moving or abs(sp.velocity) > 1e-9)
        motion = 0
        if measured or commanded or (self.discrete and st.move is Progress.RUNNING) or self._homing or self._settle:
            motion |= MOVING
        if self._running:
            # bit 1 while the path is executed; after RUN=0 or STOP (queue freed) the axis may
            # still brake, but no trajectory is executed any more
            if len(self.queue):
                motion |= TRAJECTORY
                if self.follower.on_path:
                    motion |= ON_TARGET
            if self.follower.limited:
                motion |= LIMITED
        elif self.discrete:
            if self._discrete_target is not None and st.move is not Progress.RUNNING and not fresh and \
                    abs(st.position - self.positions[self._discrete_target]) <= max(self.section.tolerance, 1e-9):
                motion |= ON_TARGET
        elif self._powered and self.planner.at_target and error <= self.section.tolerance:
            motion |= ON_TARGET
        if not self.discrete and self.planner.limited:
            motion |= LIMITED
        limit = 0
        if st.limit_negative:
            limit |= HW_MIN
        if st.limit_positive:
            limit |= HW_MAX
        if limit and (self._fault is not None or not st.enabled):
            limit |= HW_BLOCKING
        if not self.discrete:
            tol = max(self.section.tolerance, 1e-9)
            if st.position <= self.section.min + tol or self.planner.softlimit == "min":
                limit |= SW_MIN
            if st.position >= self.section.max - tol or self.planner.softlimit == "max":
                limit |= SW_MAX
            if self.planner.softlimit is not None or (self.follower and self.follower.softlimit):
                limit |= SW_BLOCKING
        if limit & (HW_MIN | HW_MAX | HW_BLOCKING):
            motion |= BLOCKED
        self.motion_state, self.limit_state = motion, limit
        # completions
        if motion & ON_TARGET and not motion & MOVING:
            self._resolve("target")
            self._resolve("offset")
        elif motion & ON_TARGET and self._running and error <= self.section.tolerance:
            self._resolve("offset")  # an OFFSET while tracking: back on the path
        if self.discrete and st.move is Progress.FAILED and "target" in self._pending and not fresh:
            self._resolve("target", st.request_error or TcsError(f"{self.module_name}: move failed",
                                                                ErrorNumber.TIMEOUT))
        # events
        if (motion ^ prev_motion) & (MOVING | TRAJECTORY | BLOCKED):
            self.emit(INFO, ErrorNumber.MOTIONCHANGE, "moving" if motion & MOVING else "stopped")
        if limit != prev_limit:
            hw, prev_hw = limit & (HW_MIN | HW_MAX), prev_limit & (HW_MIN | HW_MAX)
            hit = hw & ~prev_hw  # a switch that became active (not the blocking bit changing)
            self.emit(ERROR if hit else INFO, ErrorNumber.LIMITCHANGE, limit_text(limit))
            if hit:
                self.raise_condition("limit switch", WARNING, "hardware limit switch active")
                self._fail_motion(TcsError(f"{self.module_name}: limit switch", ErrorNumber.LIMIT))
            elif prev_hw and not hw:
                self.clear_condition("limit switch")

    def _discrete_position(self, drive_position: float) -> float:
        """REALPOS of a discrete axis: the integer position within tolerance, else an
        interpolation between the neighbouring positions."""
        items = sorted(self.positions.items(), key=lambda kv: kv[1])
        tol = max(self.section.tolerance, 1e-6)
        for index, pos in items:
            if abs(drive_position - pos) <= tol:
                return float(index)
        xs = [p for _, p in items]
        i = bisect.bisect_left(xs, drive_position)
        if i == 0 or i == len(xs):
            return float(items[0][0] if i == 0 else items[-1][0])
        (i0, p0), (i1, p1) = items[i - 1], items[i]
        return i0 + (i1 - i0) * (drive_position - p0) / (p1 - p0)

