"""Trajectory execution of one axis (``TRAJECTORY.RUN``): :class:`TrajectoryFollower`.

How it works
------------
The control loop calls :meth:`TrajectoryFollower.step` once per cycle with the cycle's time
(UT1 s, the time the setpoint applies) and the setpoint it sent last cycle; it gets back the
setpoint to send and the Appendix B events that happened. Nothing else runs in between.

The demanded drive position is ``path(t) + shift + offset``: ``path`` is the
:class:`~tcs.axes.trajectory.TrajectoryQueue` interpolation, ``shift`` a whole number of
cycles chosen at start on a cyclic axis (the wrap nearest the axis with every queued point
inside the limits, if there is one), ``offset`` the axis ``OFFSET``.

States::

    state         event                                               next
    IDLE          start()  (queue has a point after now, else nopoints) INTERCEPTING
    INTERCEPTING  error channel at rest: on the path                    FOLLOWING
    FOLLOWING     next path sample breaks v/a/j limits or continuity    INTERCEPTING
                  (path too fast: ``limited``, chase)
    FOLLOWING     set_offset()                                          INTERCEPTING
    INTERCEPTING  path start more than lead_time ahead                  (pre-position, wait)
    any running   t beyond the last point            TRAJ_STOP 32       STOPPING
                  (on or closing onto the path: to rest where the path's own stop from
                  its last state lands, its last point if it ends at rest — also after a
                  late cycle that stepped past the end; else a stop from where it is)
    any running   a setpoint would cross a limit     SOFTLIMIT 9, TRAJ_STOP 32  STOPPING
    any           abort()                                               STOPPING
    STOPPING      at rest                                               ENDED

Intercept, in the path's own frame. dependencies.md suggests an absolute ruckig profile to the
path's (position, velocity, acceleration) at an arrival time T found by iterating
``T = t0 + duration(current -> path(T))``, then ``minimum_duration = T - t0``. Tried here, that
fails in a way that matters: for a target with non-zero velocity ruckig has *blocked
durations* (no profile of exactly ``T - t0`` exists, it stretches to the next feasible one,
far later), so the arrival misses the path; a 0.01° guiding offset on a 0.2°/s path made a
0.17° excursion and took 2 s. Instead the follower plans the *error channel*
``e = setpoint - reference`` (``reference = path + shift + offset``): one ruckig profile
from the current error (position, velocity, acceleration differences) to rest at zero, with
limits equal to the axis dynamics minus what the path itself uses over the horizon
(:meth:`~tcs.axes.trajectory.TrajectoryQueue.usage`, +2 %). The setpoint is
``reference(t) + e(t - t0)``: it stays within the absolute limits, lands exactly on the path
(position, velocity and acceleration) without any arrival-time search, and the same code
serves the first slew onto the path, a new ``OFFSET`` (a rest-to-rest move of the error
channel: the "second ruckig channel for the offset") and recovery after a disturbance.
Slower only than the absolute optimum when the path comes towards the axis. The channel's
limits hold the sum only if the error starts inside them; an error that does not (an axis at
rest under a path at 4 of 5 °/s: error velocity 4, channel 0.7) is first *matched*: each cycle
an absolute ruckig profile towards the path's velocity and acceleration, position left free,
until the error is inside, then the channel plan closes the position.

After arrival the path is followed directly: each sample is checked against the velocity,
acceleration and jerk limits and against continuity with the last setpoint (position within
``jmax·dt³/6`` and velocity within ``jmax·dt²/2`` of the constant-acceleration prediction).
A sample that fails because the path is too fast sets ``limited`` (``MOTION_STATE`` bit 4);
while the path leaves the error channel less than 2 % of any limit, the axis *chases* it
(each cycle a ruckig profile towards the reference position, within the absolute limits;
it lags) until the next 10 s of path are feasible again. A path that starts more than
``lead_time`` ahead is met by moving to where its start extrapolates to ``lead_time`` before
it, waiting at rest, and intercepting from there.

Following quality: the error is ``|setpoint - (path + shift + offset)|``. ``on_path`` (bit 3)
is the instant test against ``good_threshold``; the TRAJ_GOOD (29) / TRAJ_LOOSE (30) events
report changes of a debounced state: good at once, loose only after ``loose_delay`` seconds
over the threshold (a guiding offset re-intercept of a few cycles does not flap the events).
TRAJ_LOWPOINTS (31) is sent once when less than ``low_points_time`` of path remains (again
after a refill). Every setpoint goes through :class:`~tcs.axes.limits.LimitGuard`.

Every method runs in the control-loop thread (the axis module passes commands through the
loop's command interface); only ``queue.add_points`` may be called from another thread.
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple

from tcs.axes.limits import LimitGuard, SoftLimits
from tcs.axes.profile import (AxisDynamics, ProfileSolver, Setpoint, checked_speed, extrema, sample,
                              theoretical_minimum_time)
from tcs.axes.trajectory import TrajectoryQueue
from tcs.errors import ErrorNumber, RangeRefused, TcsError

__all__ = ["FollowStep", "FollowerState", "TrajectoryFollower"]

_NO_EVENTS: tuple = ()
#: safety factor on the path's own velocity/acceleration/jerk when sharing the limits
_USAGE_MARGIN = 0.02
#: below this share of a limit left for the error channel, the path counts as too fast
_MIN_SHARE = 0.02
#: how far ahead a chased path must be feasible again before an intercept is tried, s
_CHASE_WINDOW = 10.0
#: relative slack of the continuity check of a followed path (rounding)
_TOL = 1e-3
#: the limits of a followed path are strict, up to rounding (jerk: a finite difference)
_STRICT = 1.0 + 1e-12
_STRICT_JERK = 1.0 + 1e-6


def _inside(err: Setpoint, rel: tuple[float, float, float]) -> bool:
    """Whether a ruckig profile of the error channel from ``err`` stays within ``rel``
    (velocity, acceleration, jerk): both inside, and the velocity the acceleration still
    adds, taken back at full jerk, keeps inside too."""
    v, a = err.velocity, err.acceleration
    return (abs(v) <= rel[0] and abs(a) <= rel[1]
            and abs(v + a * abs(a) / (2.0 * rel[2])) <= rel[0])


class FollowerState(enum.Enum):
    IDLE = "idle"
    INTERCEPTING = "intercepting"
    FOLLOWING = "following"
    STOPPING = "stopping"
    ENDED = "ended"


class FollowStep(NamedTuple):
    """What one :meth:`TrajectoryFollower.step` produced."""

    setpoint: Setpoint
    events: tuple[ErrorNumber, ...]


class TrajectoryFollower:
    """Runs one axis along its :class:`TrajectoryQueue`.

    Parameters
    ----------
    queue:
        The axis's point queue (filled by the axis module).
    dynamics, limits, dt:
        Axis limits and control cycle, as for :class:`~tcs.axes.motion.MotionPlanner`.
    good_threshold:
        Path error (axis units) below which the following is good; default 1″ in degrees.
    loose_delay:
        Seconds the error must stay above the threshold before TRAJ_LOOSE.
    low_points_time:
        TRAJ_LOWPOINTS when less path than this (s) remains.
    lead_time:
        A path starting more than this (s) later than it could be reached is pre-positioned.
    """

    def __init__(self, queue: TrajectoryQueue, dynamics: AxisDynamics,
                 limits: SoftLimits = SoftLimits(), dt: float = 0.01, *,
                 good_threshold: float = 1.0 / 3600.0, loose_delay: float = 0.5,
                 low_points_time: float = 60.0, lead_time: float = 2.0):
        self.queue = queue
        self.dynamics = dynamics
        self.dt = float(dt)
        self.good_threshold = float(good_threshold)
        self.loose_delay = float(loose_delay)
        self.low_points_time = float(low_points_time)
        self.lead_time = float(lead_time)
        self._solver = ProfileSolver(dt)
        self._guard = LimitGuard(limits, dynamics, dt)
        self._speed = dynamics.max_velocity
        self._offset = 0.0
        self.shift = 0.0
        self._state = FollowerState.IDLE
        self._reset_run()

    def _reset_run(self) -> None:
        self._plan = None            # ruckig Trajectory of the intercept / stop
        self._plan_t0 = 0.0
        self._plan_kind = ""  # "relative" | "preposition" | "wait" | "chase" | "match" | "stop"
        self._match_limits = (0.0, 0.0, 0.0)  # the error channel's limits a "match" aims inside
        self._t_last: float | None = None
        self._replan = False
        self.limited = False
        self.on_path = False
        self.path_error = math.inf
        self.good: bool | None = None
        self._loose_since: float | None = None
        self._low_sent = False
        self.end_reason: str | None = None

    # -- read-only state ---------------------------------------------------------------------

    @property
    def state(self) -> FollowerState:
        return self._state

    @property
    def running(self) -> bool:
        """``TRAJECTORY.RUN`` reads 1 (``MOTION_STATE`` bit 1)."""
        return self._state in (FollowerState.INTERCEPTING, FollowerState.FOLLOWING)

    @property
    def offset(self) -> float:
        return self._offset

    @property
    def limits(self) -> SoftLimits:
        return self._guard.limits

    @property
    def softlimit(self) -> str | None:
        """``"min"``/``"max"`` if the run was stopped at that software limit."""
        return self._guard.tripped

    def path_position(self, t: float) -> float:
        """Demanded position of the path at ``t`` (``TARGETPOS`` during a trajectory)."""
        return self.path_sample(t)[0]

    def path_sample(self, t: float) -> tuple[float, float]:
        """Demanded position and velocity of the path at ``t``."""
        p, v, _ = self.queue.sample(t)
        return p + self.shift + self._offset, v

    def runtime(self, t: float) -> float:
        """``RUNTIME``: seconds of path left after ``t``."""
        return self.queue.remaining(t) if self.running else 0.0

    # -- commands ----------------------------------------------------------------------------

    def set_offset(self, offset: float) -> None:
        """``OFFSET`` written: the path moves by the new offset, reached by a new intercept."""
        if not math.isfinite(offset):
            raise RangeRefused(f"offset {offset!r} is not a finite number")
        if offset != self._offset:
            self._offset = float(offset)
            self._replan = True

    def check_offset(self, offset: float, t: float) -> None:
        """Would ``offset`` keep the running path inside the limits? The path now and every
        queued point still ahead, plus the chosen wrap (``shift``), plus ``offset``.

        Raises
        ------
        RangeRefused
            Not a finite number, or a part of the path would leave the software limits.
        """
        if not math.isfinite(offset):
            raise RangeRefused(f"offset {offset!r} is not a finite number")
        lim = self.limits
        times, positions = self.queue.positions()
        ahead = [p for tt, p in zip(times, positions) if tt >= t]
        if times:
            ahead.append(self.queue.sample(t)[0])
        for p in ahead:
            if not lim.contains(p + self.shift + offset):
                raise RangeRefused(f"offset {offset:g} puts the queued path at {p + self.shift + offset:g}, "
                                   f"outside the software limits")

    def set_speed(self, velocity: float) -> None:
        """``CURRSPEED`` written: velocity limit for intercepts and the path check.

        Raises
        ------
        RangeRefused
            ``velocity`` not in (0, max_velocity].
        """
        self._speed = checked_speed(velocity, self.dynamics)

    def set_limits(self, limits: SoftLimits) -> None:
        self._guard.limits = limits

    def start(self, t: float, current: Setpoint, shift: float | None = None) -> int:
        """``RUN=1``: begin at time ``t`` from the axis state ``current``; ``shift`` (whole
        cycles added to the path) as given, or ``None`` to choose it (:meth:`_choose_shift`).

        Returns
        -------
        int
            Points dropped because they were already in the past.

        Raises
        ------
        TcsError
            nopoints (11): no path left after ``t``.
        """
        q = self.queue
        dropped = q.drop_before(t)
        end = q.end_time
        if end is None or end <= t or len(q) < 2:
            raise TcsError("trajectory cannot start: no points after now", ErrorNumber.NOPOINTS)
        self._reset_run()
        self._guard.reset()
        self.shift = self._choose_shift(t, current.position) if shift is None else float(shift)
        self._state = FollowerState.INTERCEPTING
        return dropped

    def abort(self, quick: bool = False) -> None:
        """``RUN=0`` (or ``STOP`` with ``quick``): stop smoothly, free the queue."""
        self.queue.clear()
        if self._state in (FollowerState.INTERCEPTING, FollowerState.FOLLOWING):
            self.end_reason = "aborted"
            self._state = FollowerState.STOPPING
            self._plan = None
            self._plan_kind = "stop-quick" if quick else "stop"

    # -- the cycle ---------------------------------------------------------------------------

    def step(self, t: float, current: Setpoint) -> FollowStep:
        """Advance to time ``t`` (UT1 s of the setpoint to produce) from ``current`` (the
        setpoint sent last cycle); returns the setpoint to send and the events."""
        state = self._state
        t_last = self._t_last
        self._t_last = t
        # (the time since the last step: longer after a gap in the cycle, up to the longest
        # a drive bridges before it stops by itself)
        dt = t - t_last if t_last is not None and 0.0 < t - t_last < 100 * self.dt else self.dt
        if state is FollowerState.IDLE or state is FollowerState.ENDED:
            return FollowStep(Setpoint(current.position), _NO_EVENTS)
        events: list = []
        if state is FollowerState.STOPPING:
            if self._plan is None and self._guard.tripped is None:   # first cycle after abort()
                events.append(ErrorNumber.TRAJ_STOP)
            sp = self._stop_step(t, current, dt, events)
            return FollowStep(sp, tuple(events) if events else _NO_EVENTS)
        q = self.queue
        end = q.end_time
        if end is None or t > end:
            events.append(ErrorNumber.TRAJ_STOP)
            self.end_reason = self.end_reason or "end"
            if end is not None and (state is FollowerState.FOLLOWING or self._plan_kind == "relative"):
                self._finish(t - dt, current, end)
            else:
                self._begin_stop(t - dt, current, quick=False)
            sp = self._stop_step(t, current, dt, events)
            return FollowStep(sp, tuple(events))

        proposed = None
        if not self._replan:
            if state is FollowerState.FOLLOWING:
                proposed = self._follow(t, current, dt)
            elif self._plan_kind:
                proposed = self._plan_step(t, current, dt)
        if proposed is None:                       # (re)plan from the current setpoint
            self._replan = False
            self._state = FollowerState.INTERCEPTING
            self._plan_intercept(t - dt, current)
            proposed = self._plan_step(t, current, dt)
            if proposed is None:                   # already on the path
                proposed = self._follow(t, current, dt) or self._toward_ref(t, current, dt)

        sp = self._guard.filter(current, proposed)
        if self._guard.tripped is not None:
            events += [ErrorNumber.SOFTLIMIT, ErrorNumber.TRAJ_STOP]
            self.end_reason = "softlimit"
            self._state = FollowerState.STOPPING
            self._plan = None
            return FollowStep(sp, tuple(events))
        self._classify(t, sp.position, events)
        if q.remaining(t) < self.low_points_time:
            if not self._low_sent:
                self._low_sent = True
                events.append(ErrorNumber.TRAJ_LOWPOINTS)
        else:
            self._low_sent = False
        return FollowStep(sp, tuple(events) if events else _NO_EVENTS)

    # -- following and intercepting ----------------------------------------------------------

    def _ref(self, t: float, freeze: bool = False) -> tuple[float, float, float]:
        """The reference ``path + shift + offset`` at ``t``; before the path's start, the start
        state extrapolated with constant velocity (so it can be met in motion). Not with
        constant acceleration: over ``lead_time`` a parabola can run far from the path (a path
        starting at rest with 0.8°/s² put the axis 1.6° away, moving the wrong way, and the
        intercept took 5 s); the acceleration step at the start is a short re-intercept."""
        q = self.queue
        start = q.start_time
        if t < start:
            p, v, _ = q.sample(start)
            return p + (t - start) * v + self.shift + self._offset, v, 0.0
        p, v, a = q.sample(t, freeze)
        return p + self.shift + self._offset, v, a

    def _follow(self, t: float, cur: Setpoint, dt: float) -> Setpoint | None:
        """The path sample at ``t`` if it is a continuous, feasible continuation of ``cur``."""
        p, v, a = self._ref(t, freeze=True)
        d = self.dynamics
        vmax, amax, jmax = self._speed * _STRICT, d.max_acceleration * _STRICT, d.max_jerk
        jerk = (a - cur.acceleration) / dt
        # within the limits, and not in a state that must overshoot vmax (accelerating outwards
        # faster than the jerk limit can take the acceleration back to zero)
        feasible = (abs(v) <= vmax and abs(a) <= amax and abs(jerk) <= jmax * _STRICT_JERK
                    and (a * v <= 0.0 or abs(v) + a * a / (2.0 * jmax) <= vmax))
        slack = jmax * (1 + _TOL)
        pred_p = cur.position + dt * (cur.velocity + 0.5 * dt * cur.acceleration)
        pred_v = cur.velocity + dt * cur.acceleration
        continuous = (abs(p - pred_p) <= slack * dt ** 3 / 6 + 1e-12 * (1 + abs(p))
                      and abs(v - pred_v) <= slack * dt * dt / 2 + 1e-12 * (1 + abs(v)))
        if feasible and continuous:
            self.limited = False
            self._state = FollowerState.FOLLOWING
            self._plan, self._plan_kind = None, ""
            return Setpoint(p, v, a, jerk)
        if not feasible:
            self.limited = True
        return None

    def _relative_limits(self, t0: float, t1: float) -> tuple[float, float, float] | None:
        """What the axis dynamics leave for the error channel while the path uses its share
        over ``[t0, t1]``; ``None`` if the path itself (nearly) uses it all."""
        uv, ua, uj = self.queue.usage(t0, t1)
        m = 1.0 + _USAGE_MARGIN
        d = self.dynamics
        rel = (self._speed - m * uv, d.max_acceleration - m * ua, d.max_jerk - m * uj)
        floor = _MIN_SHARE
        if rel[0] < floor * self._speed or rel[1] < floor * d.max_acceleration \
                or rel[2] < floor * d.max_jerk:
            return None
        return rel

    def _plan_intercept(self, t0: float, cur: Setpoint) -> None:
        """Plan from ``cur`` (the setpoint at ``t0``) onto the path: pre-position and wait if
        the path starts much later, else a ruckig profile of the error channel
        ``cur - reference`` to rest at zero (or a chase if the path is too fast)."""
        q = self.queue
        d = self.dynamics
        start = q.start_time
        self._plan_t0 = t0
        if start - t0 > self.lead_time + self.dt:
            p_go = self._ref(start - self.lead_time)[0]
            if cur.at_rest and abs(cur.position - p_go) <= 1e-12 * (1 + abs(p_go)):
                self._plan, self._plan_kind = None, "wait"
            else:
                self._plan = self._solver.move(cur, p_go, max_velocity=self._speed,
                                               max_acceleration=d.max_acceleration,
                                               max_jerk=d.max_jerk, discrete=False)
                self._plan_kind = "preposition"
            return
        rp, rv, ra = self._ref(t0)
        err = Setpoint(cur.position - rp, cur.velocity - rv, cur.acceleration - ra)
        horizon = (theoretical_minimum_time(err.position, d)
                   + (abs(err.velocity) + abs(err.acceleration)) / d.max_acceleration + 1.0)
        for _ in range(4):
            rel = self._relative_limits(t0, t0 + horizon)
            if rel is None:
                self.limited = True
                self._plan, self._plan_kind = None, "chase"
                return
            if not _inside(err, rel):
                self._plan, self._plan_kind, self._match_limits = None, "match", rel
                return
            traj = self._solver.move(err, 0.0, max_velocity=rel[0], max_acceleration=rel[1],
                                     max_jerk=rel[2], discrete=False)
            if traj.duration <= horizon:
                break
            horizon = 1.5 * traj.duration + 1.0
        self._plan, self._plan_kind = traj, "relative"

    def _plan_step(self, t: float, cur: Setpoint, dt: float) -> Setpoint | None:
        """The running plan's setpoint at ``t``; ``None`` when a new plan is needed."""
        kind = self._plan_kind
        tau = t - self._plan_t0
        if kind == "relative":
            traj = self._plan
            if tau >= traj.duration:
                return self._follow(t, cur, dt)
            ep, ev, ea = sample(traj, tau)
            rp, rv, ra = self._ref(t, freeze=True)
            a = ra + ea
            return Setpoint(rp + ep, rv + ev, a, (a - cur.acceleration) / dt)
        if kind == "wait":
            if t < self.queue.start_time - self.lead_time:
                return Setpoint(cur.position)
            return None
        if kind == "preposition":
            traj = self._plan
            if tau < traj.duration:
                p, v, a = sample(traj, tau)
                return Setpoint(p, v, a, (a - cur.acceleration) / dt)
            self._plan, self._plan_kind = None, "wait"
            return Setpoint(sample(traj, traj.duration)[0], 0.0, 0.0, -cur.acceleration / dt)
        if kind == "chase":
            return self._chase(t, cur, dt)
        if kind == "match":
            return self._match(t, cur, dt)
        return None

    def _match(self, t: float, cur: Setpoint, dt: float) -> Setpoint | None:
        """The error's velocity or acceleration is beyond what the error channel may use (an
        axis at rest under a fast path): a relative plan would brake it within the channel's
        small limits while the path's own velocity adds to it, over the absolute limits. So
        first, each cycle, an absolute ruckig profile towards the path's velocity and
        acceleration (position left free); ``None`` once the error is inside the channel's
        limits (then the intercept is planned)."""
        t0 = t - dt
        rp, rv, ra = self._ref(t0)
        if _inside(Setpoint(cur.position - rp, cur.velocity - rv, cur.acceleration - ra),
                   self._match_limits):
            self._plan_kind = ""
            return None
        d = self.dynamics
        rv, ra = self._ref(t)[1:]
        traj = self._solver.reach_velocity(cur, rv, ra, max_velocity=self._speed,
                                           max_acceleration=d.max_acceleration,
                                           max_jerk=d.max_jerk, discrete=False)
        p, v, a = sample(traj, min(dt, traj.duration))
        if dt > traj.duration:                 # reached: continue with the path's velocity
            p += (dt - traj.duration) * v
        return Setpoint(p, v, a, (a - cur.acceleration) / dt)

    def _chase(self, t: float, cur: Setpoint, dt: float) -> Setpoint | None:
        """Path too fast for the axis: each cycle, head for the path's state (clipped to the
        limits) with ruckig, within the absolute limits; ``None`` once the path is feasible
        again (then an intercept is planned)."""
        if self._relative_limits(t, t + _CHASE_WINDOW) is not None:
            self._plan_kind = ""
            return None
        return self._toward_ref(t, cur, dt)

    def _toward_ref(self, t: float, cur: Setpoint, dt: float) -> Setpoint:
        """One cycle of an absolute ruckig profile towards the reference position (to rest
        there: a moving target with a velocity the axis cannot match would make ruckig back
        up for a run-up; this runs after it at full speed and lags instead)."""
        d = self.dynamics
        traj = self._solver.move(cur, self._ref(t)[0], max_velocity=self._speed,
                                 max_acceleration=d.max_acceleration, max_jerk=d.max_jerk,
                                 discrete=False)
        p, v, a = sample(traj, min(dt, traj.duration))
        return Setpoint(p, v, a, (a - cur.acceleration) / dt)

    # -- stopping ----------------------------------------------------------------------------

    def _begin_stop(self, t0: float, cur: Setpoint, quick: bool) -> None:
        d = self.dynamics
        acc, jerk = (d.stop_acceleration, d.stop_jerk) if quick else (d.max_acceleration, d.max_jerk)
        traj = self._solver.stop(cur, max_velocity=max(d.max_velocity, abs(cur.velocity)),
                                 max_acceleration=acc, max_jerk=jerk, discrete=False)
        self._state = FollowerState.STOPPING
        self._plan, self._plan_t0, self._plan_kind = traj, t0, "stop"

    def _finish(self, t0: float, cur: Setpoint, end: float) -> None:
        """The path ended while the axis was on it (or closing onto it): come to rest where
        the path's own stop from its last state lands — its last point when it ends at rest —
        not where the last setpoint sent stands. They differ after a gap: a late cycle that
        stepped past the end (the drive bridged the gap, the axis re-anchored on its demand)
        would otherwise stop the axis the gap's worth of path short of the end (16″ at the end
        of a sinusoid). A move to that landing from ``cur`` at ``t0`` within the axis dynamics,
        if the path ends at rest (the landing is its last point, settled on from either side)
        or the landing lies beyond every point a stop from ``cur`` passes (the way it moves):
        else, or if it cannot be planned, the stop from ``cur`` — a path that ends moving is
        never moved back to."""
        d = self.dynamics
        p, v, a = self._ref(end)
        try:
            own = self._solver.stop(Setpoint(p, v, a), max_velocity=max(d.max_velocity, abs(v)),
                                    max_acceleration=d.max_acceleration, max_jerk=d.max_jerk,
                                    discrete=False)
            landing = sample(own, own.duration)[0]
            # (the stop from ``cur``: what _begin_stop plans, and the plan unless the landing
            # is beyond every point it passes, the way it goes — from rest, either way: a new
            # move. A path that ends at rest — its own stop within the on-path threshold of its
            # last point — is settled on that point from either side: an extrapolating drive
            # may have run past it during the gap)
            traj = self._solver.stop(cur, max_velocity=max(d.max_velocity, abs(cur.velocity)),
                                     max_acceleration=d.max_acceleration, max_jerk=d.max_jerk,
                                     discrete=False)
            lo, hi = extrema(traj)
            way = sample(traj, traj.duration)[0] - cur.position
            if abs(landing - p) <= self.good_threshold:
                beyond = True
            elif way > 0.0:
                beyond = landing >= hi
            elif way < 0.0:
                beyond = landing <= lo
            else:
                beyond = cur.velocity == 0.0 and cur.acceleration == 0.0
            if beyond:
                traj = self._solver.move(cur, landing, max_velocity=max(self._speed, abs(cur.velocity)),
                                         max_acceleration=d.max_acceleration, max_jerk=d.max_jerk,
                                         discrete=False)
        except ValueError:
            self._begin_stop(t0, cur, quick=False)
            return
        self._state = FollowerState.STOPPING
        self._plan, self._plan_t0, self._plan_kind = traj, t0, "stop"

    def _stop_step(self, t: float, cur: Setpoint, dt: float, events: list) -> Setpoint:
        guard = self._guard
        if guard.tripped is not None:
            sp = guard.filter(cur, cur)
            if not guard.braking:
                self._state = FollowerState.ENDED
            return sp
        if self._plan is None:                    # abort(): plan from the first state we see
            self._begin_stop(t - dt, cur, quick=self._plan_kind == "stop-quick")
        traj = self._plan
        tau = t - self._plan_t0
        if tau >= traj.duration:
            self._state = FollowerState.ENDED
            self._plan = None
            proposed = Setpoint(sample(traj, traj.duration)[0], 0.0, 0.0, -cur.acceleration / dt)
        else:
            p, v, a = sample(traj, tau)
            proposed = Setpoint(p, v, a, (a - cur.acceleration) / dt)
        sp = guard.filter(cur, proposed)
        if guard.tripped is not None:             # the stop itself would pass a limit
            events.append(ErrorNumber.SOFTLIMIT)
            self.end_reason = "softlimit"
            self._state = FollowerState.STOPPING if guard.braking else FollowerState.ENDED
        return sp

    # -- quality -----------------------------------------------------------------------------

    def _classify(self, t: float, position: float, events: list) -> None:
        q = self.queue
        if t < q.start_time:
            self.on_path, self.path_error = False, math.inf
            return
        err = abs(position - self._ref(t)[0])
        self.path_error = err
        self.on_path = err <= self.good_threshold
        if self.on_path:
            self._loose_since = None
            if self.good is not True:
                self.good = True
                events.append(ErrorNumber.TRAJ_GOOD)
        else:
            if self._loose_since is None:
                self._loose_since = t
            if t - self._loose_since >= self.loose_delay and self.good is not False:
                self.good = False
                events.append(ErrorNumber.TRAJ_LOOSE)

    # -- cyclic axes -------------------------------------------------------------------------

    def _choose_shift(self, t: float, position: float) -> float:
        """Whole cycles added to the path: nearest to ``position`` among the wraps that keep
        every queued point inside the limits (else those that keep the path's start inside,
        else simply the nearest)."""
        c = self.limits.cycle
        if c is None:
            return 0.0
        q = self.queue
        ref = self.queue.sample(max(t, q.start_time))[0] + self._offset
        _, ps = q.positions()
        lo_p, hi_p = min(ps) + self._offset, max(ps) + self._offset
        lim = self.limits
        k0 = round((position - ref) / c)
        ks = range(k0 - 3, k0 + 4)

        def inside(x_lo, x_hi, k):
            return lim.contains(x_lo + k * c) and lim.contains(x_hi + k * c)

        for test in (lambda k: inside(lo_p, hi_p, k), lambda k: inside(ref, ref, k), lambda k: True):
            good = [k for k in ks if test(k)]
            if good:
                return min(good, key=lambda k: abs(ref + k * c - position)) * c
        return 0.0  # pragma: no cover - the last test accepts every k
