"""Jerk-limited point-to-point motion of one axis: :class:`MotionPlanner`.

How it works
------------
The planner owns the axis's *demanded drive position* while the axis is in direct
positioning (``TARGETPOS``). The drive is commanded to ``target + offset`` (notes, "Axis
semantics"), so the planner runs ONE ruckig channel on that sum: a new target and a new
offset are both just a new goal for the same channel, planned from the current setpoint
(position, velocity, acceleration), so the stream stays continuous in acceleration whatever
arrives when, and target and offset together never exceed the axis dynamics.

Each command computes a whole ruckig profile (:mod:`tcs.axes.profile`), checks its position
extrema against the software limits (ruckig ignores them) and then :meth:`MotionPlanner.step`
samples it once per control cycle. The duration is rounded up to whole cycles, so a move ends
exactly on the target, on a cycle.

States (``PlannerState``) and what moves between them::

    state      event                                   next
    any        set_target / set_offset                 MOVING      (planned from the current
                                                                    setpoint, whatever it is)
    MOVING     profile finished                        IDLE        (at_target)
    any        the direct profile would cross a limit  BRAKING     (stop first, move afterwards)
    BRAKING    at rest                                 MOVING      (the pending goal)
    any        heading for the goal faster than the    SLOWING     (down to the move's speed
               move's speed (a slower MoveAxis)                     first, never the other way)
    SLOWING    at the move's speed                     MOVING      (the pending goal)
    any        stop(quick)                             STOPPING    (target := where it will rest)
    MOVING     resume(anchor) after a gap              MOVING      (from the anchor; braking up
                                                                    to the stop deceleration
                                                                    not to pass the goal)
    any        take_over(moving setpoint)              STOPPING    (normal deceleration)
    STOPPING   at rest                                 IDLE
    any        a setpoint beyond a limit (guard)       LIMIT       (braking to rest at the limit,
                                                                    ``softlimit`` = "min"/"max")
    LIMIT      at rest                                 IDLE

``CURRSPEED`` (:meth:`MotionPlanner.set_speed`) lowers the velocity limit of motion planned
afterwards; a running move keeps its profile. ``STOP`` uses the quick-stop deceleration and
jerk of :class:`AxisDynamics`.

Used by the axis module from the control-loop thread only (not thread-safe); about 1.5 µs per
:meth:`MotionPlanner.step`, 5 µs per new target (see ``tools/bench/motion_cost.py``).
"""

from __future__ import annotations

import enum
import math

from tcs.axes.limits import LimitGuard, SoftLimits
from tcs.axes.profile import (
    AxisDynamics,
    ProfileSolver,
    checked_speed,
    extrema,
    Setpoint,
    sample,
    theoretical_minimum_time,
)
from tcs.errors import RangeRefused

__all__ = ["AxisDynamics", "MotionPlanner", "PlannerState", "Setpoint", "SoftLimits",
           "theoretical_minimum_time"]


class PlannerState(enum.Enum):
    IDLE = "idle"
    MOVING = "moving"
    BRAKING = "braking"
    SLOWING = "slowing"
    STOPPING = "stopping"
    LIMIT = "limit"


#: a velocity or acceleration within this fraction of its limit counts as "limited" (bit 4)
SATURATION = 0.99
#: A move longer than about this many seconds goes in legs this long (ruckig plans at most
#: ~7,600 s: a MoveAxis at a guiding rate towards a far limit was refused with -101).
LEG_SECONDS = 1000.0


class MotionPlanner:
    """Point-to-point motion of one axis, one :class:`Setpoint` per :meth:`step`.

    Parameters
    ----------
    dynamics:
        Velocity, acceleration, jerk limits (and quick-stop values).
    limits:
        Software limits and cycle of the axis.
    dt:
        Control cycle in seconds.
    position:
        Initial position (the axis at rest there); use :meth:`take_over` to start from a
        moving state.
    """

    def __init__(self, dynamics: AxisDynamics, limits: SoftLimits = SoftLimits(),
                 dt: float = 0.01, position: float = 0.0):
        self.dt = float(dt)
        self.dynamics = dynamics
        self._solver = ProfileSolver(dt)
        self._guard = LimitGuard(limits, dynamics, dt)
        self._speed = dynamics.max_velocity
        self._offset = 0.0
        self._sp = Setpoint(float(position))
        self._target = float(position)
        self._state = PlannerState.IDLE
        self._traj = None
        self._k = 0
        self._n = 0
        self._end = 0.0
        self._end_velocity = 0.0   # (a SLOWING profile ends at the move's speed, not at rest)
        self._pending: float | None = None
        self._pending_speed: float | None = None  # speed limit of the move planned (and pending)
        self._softlimit: str | None = None
        self._verified = True

    # -- read-only state ---------------------------------------------------------------------

    @property
    def limits(self) -> SoftLimits:
        return self._guard.limits

    @property
    def state(self) -> PlannerState:
        return self._state

    @property
    def setpoint(self) -> Setpoint:
        """The setpoint produced by the last :meth:`step` (or the initial state)."""
        return self._sp

    @property
    def target(self) -> float:
        """Target in the user frame (``TARGETPOS``): the resolved one, i.e. on a cyclic axis
        the chosen ``request + k·cycle``; after a stop, where the axis comes to rest."""
        return self._target

    @property
    def offset(self) -> float:
        return self._offset

    @property
    def demanded_target(self) -> float:
        """Where the drive is going: ``target + offset``."""
        return self._target + self._offset

    @property
    def speed(self) -> float:
        """Velocity limit used for new motion (``CURRSPEED`` as written, else the maximum)."""
        return self._speed

    @property
    def moving(self) -> bool:
        """``MOTION_STATE`` bit 0: a profile is running or the setpoint is not at rest."""
        return self._state is not PlannerState.IDLE or not self._sp.at_rest

    @property
    def at_target(self) -> bool:
        """``MOTION_STATE`` bit 3 (of the demand): at rest exactly on ``target + offset``."""
        return (self._state is PlannerState.IDLE and self._sp.at_rest
                and self._sp.position == self.demanded_target)

    @property
    def limited(self) -> bool:
        """``MOTION_STATE`` bit 4: moving with velocity or acceleration at its limit."""
        if self._state is PlannerState.IDLE:
            return False
        sp = self._sp
        return (abs(sp.velocity) >= SATURATION * self._speed
                or abs(sp.acceleration) >= SATURATION * self.dynamics.max_acceleration)

    @property
    def softlimit(self) -> str | None:
        """``"min"`` / ``"max"`` if motion was stopped at that software limit (stays set until
        the next target, offset or take-over), else ``None``."""
        return self._softlimit

    @property
    def remaining_time(self) -> float:
        """Seconds until the running profile ends (braking, slowing down or a leg of a long
        move: plus an estimate of the pending move at its speed); 0 when idle."""
        if self._state is PlannerState.IDLE:
            return 0.0
        if self._state is PlannerState.LIMIT:
            return 0.0 if self._guard._brake is None else max(
                0.0, self._guard._brake.duration - self._guard._brake_steps * self.dt)
        left = max(0.0, (self._n - self._k) * self.dt)
        if self._pending is not None:   # (at the pending move's own speed: a MoveAxis's)
            d = self.dynamics
            speed = min(self._pending_speed or self._speed, d.max_velocity)
            left += theoretical_minimum_time(self._pending - self._end,
                                             AxisDynamics(speed, d.max_acceleration, d.max_jerk))
        return left

    # -- commands ----------------------------------------------------------------------------

    def set_limits(self, limits: SoftLimits) -> None:
        """Replace the software limits (after referencing or commissioning). The running
        profile was checked against the old limits, so until the next command every setpoint
        gets the guard's full stopping-distance check (it stops at a new limit in time)."""
        self._guard.limits = limits
        self._verified = False

    def set_speed(self, velocity: float) -> None:
        """``CURRSPEED`` written: the velocity limit for motion planned from now on.

        Raises
        ------
        RangeRefused
            ``velocity`` not in (0, max_velocity].
        """
        self._speed = checked_speed(velocity, self.dynamics)

    def set_target(self, position: float, resolve: bool = True) -> float:
        """``TARGETPOS`` written: move so that the drive reaches ``position + offset``.

        On a cyclic axis, ``position + k·cycle`` inside the limits with the shortest travel
        is taken (cable wrap: never through a limit) — :meth:`resolve_target`. ``resolve``
        False: ``position`` is that turn already (the axis resolved it once, when the safety
        envelope judged the path, so the turn judged is the turn driven) and is taken as it is.

        Returns
        -------
        float
            The resolved target in the user frame (what :attr:`target` reads).

        Raises
        ------
        RangeRefused
            The target (plus offset) is outside the software limits; nothing changes.
        """
        if resolve:
            demanded = self.resolve_target(position, self._offset, self._sp.position)
        else:
            demanded = float(position) + self._offset
            if not (math.isfinite(demanded) and self.limits.contains(demanded)):
                raise RangeRefused(f"target position (with offset) {demanded!r} is outside the "
                                   "software limits")
        self._target = demanded - self._offset
        self._plan_to(demanded)
        return self._target

    def resolve_target(self, position: float, offset: float, current: float) -> float:
        """The drive position a ``TARGETPOS`` of ``position`` goes to with ``offset``, from the
        drive position ``current``: the cable-wrap choice of :meth:`SoftLimits.resolve`
        (pure: callable from any thread; the one rule both the planner and the safety
        envelope's judgement use)."""
        return self.limits.resolve(float(position) + float(offset), float(current),
                                   what="target position (with offset)")

    def move_to(self, demanded: float, speed: float) -> None:
        """Move to rest at the drive position ``demanded`` (no cyclic resolution: a MoveAxis
        towards a limit goes the way it was asked) at most at ``speed`` — for this move only,
        ``CURRSPEED`` (:attr:`speed`) is left as it is.

        Raises
        ------
        RangeRefused
            ``demanded`` is outside the software limits; nothing changes.
        """
        demanded = float(demanded)
        if not (math.isfinite(demanded) and self.limits.contains(demanded)):
            raise RangeRefused(f"position {demanded!r} is outside the software limits")
        self._target = demanded - self._offset
        self._plan_to(demanded, min(float(speed), self.dynamics.max_velocity))

    def set_offset(self, offset: float) -> None:
        """``OFFSET`` written: move smoothly so the drive reaches ``target + offset``.

        Raises
        ------
        RangeRefused
            ``target + offset`` is outside the software limits; nothing changes.
        """
        offset = float(offset)
        if not math.isfinite(offset):
            raise RangeRefused(f"offset {offset!r} is not a finite number")
        demanded = self._target + offset
        if not self.limits.contains(demanded):
            raise RangeRefused(f"offset {offset:g} puts target {self._target:g} at {demanded:g}, "
                               f"outside the software limits")
        self._offset = offset
        self._plan_to(demanded)

    def stop(self, quick: bool = True) -> None:
        """``STOP``: decelerate to rest now (quick: with the quick-stop deceleration and jerk),
        cancelling the target; :attr:`target` becomes where the axis will rest."""
        self._pending = None
        if self._state is PlannerState.IDLE and self._sp.at_rest:
            return
        d = self.dynamics
        acc, jerk = (d.stop_acceleration, d.stop_jerk) if quick else (d.max_acceleration, d.max_jerk)
        traj = self._solver.stop(self._sp, max_velocity=max(d.max_velocity, abs(self._sp.velocity)),
                                 max_acceleration=acc, max_jerk=jerk)
        side = self._guard.crossing(traj, self._sp.position)
        if side is not None:                       # only when already heading past a limit
            traj, _ = self._guard.brake_profile(self._sp, side)
        self._guard.reset()
        self._start(traj, PlannerState.STOPPING, sample(traj, traj.duration)[0])
        self._target = self._end - self._offset

    def take_over(self, setpoint: Setpoint) -> None:
        """Continue from ``setpoint`` (e.g. after a trajectory or at power-on): hold there if
        at rest, else brake to rest with the normal dynamics. Clears ``softlimit``."""
        self._sp = Setpoint(*setpoint)
        self._pending = None
        self._softlimit = None
        self._guard.reset()
        if self._sp.at_rest:
            self._idle()
            self._target = self._sp.position - self._offset
        else:
            self.stop(quick=False)

    def resume(self, setpoint: Setpoint) -> None:
        """After a gap in the setpoint stream (the drive bridged it by itself): go on from
        ``setpoint`` — where the drive's demand really is — to the same goal within the
        limits: a move is planned again from there (braking first if it would now cross a
        limit), a stop stops from there with the stop deceleration; never chased back to the
        path computed before the gap.

        A move that was braking to its goal when the gap came is ahead of its path now (the
        drive ran on at the stream's speed meanwhile, and the anchor starts at zero
        acceleration): planned again with the normal deceleration it would run past its goal
        and come back — a MoveAxis lowering ZD ran 2.7° below its horizon bound after a
        30 ms gap. The goal is a bound (the horizon, the envelope's end of a MoveAxis), so
        such a move brakes to it instead with the least deceleration that stops there, up to
        the stop deceleration (:meth:`_brake_to`); only a gap so long that even that runs
        past it stops at once (quick stop) and comes back to the goal afterwards."""
        state = self._state
        if state is PlannerState.IDLE and setpoint.at_rest:
            return
        # (a path that was braking goes on braking as hard as it did: the drive's demand ran
        # on at its speed through the gap, and a deceleration unwound to zero would first
        # have to build up again at the jerk limit — 0.13 s at 28°/s, 1.9° more for ZD)
        before = self._sp
        braking = (state is not PlannerState.IDLE and before.acceleration * setpoint.velocity < 0.0
                   and before.velocity * setpoint.velocity > 0.0)
        acc = max(-self.dynamics.stop_acceleration,
                  min(self.dynamics.stop_acceleration, before.acceleration)) if braking else 0.0
        self._sp = Setpoint(setpoint.position, setpoint.velocity, acc)
        goal = None
        if state is PlannerState.MOVING:
            goal = self.demanded_target
        elif state in (PlannerState.BRAKING, PlannerState.SLOWING) and self._pending is not None:
            # (braking or slowing down before the move: plan it from there, which brakes or
            # slows down first again if it still has to)
            goal = self._pending
        if goal is None:
            softlimit = self._softlimit
            self.stop(quick=True)
            self._softlimit = softlimit
            return
        self._plan_to(goal, self._pending_speed)
        if self._state is PlannerState.MOVING and self._passes(self._traj, self._sp, goal):
            self._brake_to(self._sp, goal)

    @staticmethod
    def _passes(traj, sp: Setpoint, goal: float) -> bool:
        """``traj`` from ``sp``, heading for ``goal``, runs past it on the way."""
        way = goal - sp.position
        if traj is None or way * sp.velocity <= 0.0:
            return False
        lo, hi = extrema(traj)
        tol = 1e-9 * max(1.0, abs(goal))
        return hi > goal + tol if way > 0 else lo < goal - tol

    def _brake_to(self, sp: Setpoint, goal: float) -> None:
        """From ``sp`` heading for ``goal`` too fast to stop there with the normal deceleration:
        brake to rest on ``goal`` with the least deceleration (between the normal one and the
        stop deceleration, its jerk scaled alike) that does, never faster than now (MOVING);
        when even the stop deceleration runs past it, stop with it (BRAKING) and move back to
        ``goal`` afterwards."""
        d = self.dynamics
        a0, a1 = d.max_acceleration, d.stop_acceleration
        j0, j1 = d.max_jerk, d.stop_jerk
        vmax = max(d.max_velocity, abs(sp.velocity))
        way = 1.0 if goal > sp.position else -1.0

        def limits(a: float) -> tuple[float, float]:
            share = 1.0 if a1 <= a0 else (a - a0) / (a1 - a0)
            return a, j0 + (j1 - j0) * share

        def stops_short(a: float) -> bool:
            acc, jerk = limits(a)
            rest = self._solver.stop(sp, max_velocity=vmax, max_acceleration=acc, max_jerk=jerk,
                                     discrete=False)
            return (goal - sample(rest, rest.duration)[0]) * way >= 0.0

        if stops_short(a1):
            lo, hi = a0, a1
            for _ in range(24):   # (bisection: the least deceleration that stops in time)
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if stops_short(mid) else (mid, hi)
            acc, jerk = limits(hi)
            traj = self._solver.move(sp, goal, max_velocity=max(abs(sp.velocity), 1e-9),
                                     max_acceleration=acc, max_jerk=jerk)
            if not self._passes(traj, sp, goal) and self._guard.crossing(traj, sp.position) is None:
                self._start(traj, PlannerState.MOVING, goal)
                return
        traj = self._solver.stop(sp, max_velocity=vmax, max_acceleration=a1, max_jerk=j1)
        side = self._guard.crossing(traj, sp.position)
        if side is not None:
            traj, _ = self._guard.brake_profile(sp, side)
        self._start(traj, PlannerState.BRAKING, sample(traj, traj.duration)[0])
        self._pending = goal

    # -- the cycle ---------------------------------------------------------------------------

    def step(self, periods: int = 1) -> Setpoint:
        """Advance one control cycle — ``periods`` cycles' time after a gap in the cycle (the
        drive bridged them) — and return the setpoint to send."""
        state = self._state
        prev = self._sp
        if state is PlannerState.IDLE:
            return prev
        guard = self._guard
        if state is PlannerState.LIMIT:
            sp = guard.filter(prev, prev)
            if not guard.braking:
                self._sp = sp
                self._idle()
                return sp
            self._sp = sp
            return sp
        self._k += max(1, int(periods))
        finished = self._k >= self._n
        if finished:
            proposed = Setpoint(self._end, self._end_velocity, 0.0, -prev.acceleration / self.dt)
        else:
            p, v, a = sample(self._traj, self._k * self.dt)
            proposed = Setpoint(p, v, a, (a - prev.acceleration) / self.dt)
        sp = guard.filter(prev, proposed, verified=self._verified)
        self._sp = sp
        if guard.tripped is not None:
            self._softlimit = guard.tripped
            self._state = PlannerState.LIMIT
            self._pending = None
            self._target = guard._brake_end.position - self._offset
            if not guard.braking:
                self._idle()
        elif finished:
            if self._pending is not None:   # (braked, slowed down, or a leg of a long move)
                pending, self._pending = self._pending, None
                self._plan_to(pending, self._pending_speed)
            else:
                self._idle()
        return sp

    # -- internals ---------------------------------------------------------------------------

    def _idle(self) -> None:
        self._state = PlannerState.IDLE
        self._traj = None
        self._sp = Setpoint(self._sp.position)
        self._k = self._n = 0

    def _start(self, traj, state: PlannerState, end: float, velocity: float = 0.0) -> None:
        self._traj = traj
        self._verified = True
        self._k = 0
        self._n = max(1, math.ceil(traj.duration / self.dt - 1e-9))
        self._end = float(end)
        self._end_velocity = float(velocity)
        self._state = state

    def _unwound(self, sp: Setpoint, demanded: float) -> Setpoint:
        """``sp`` with an acceleration against the way to ``demanded`` cut so that the new
        move never goes the other way first. Braking hard (towards an earlier goal on the
        other side), a jerk-limited unwinding of the deceleration takes ``a/j`` seconds and
        loses ``a²/2j`` of velocity: more than the axis has left, and the axis would reverse
        — a MoveAxis(+) at 2.9°/s with −120°/s² (jerk 1000) went back 0.07° at −3.1°/s. The
        acceleration steps to ``√(2·j·|v|)`` at most (where unwinding at the jerk limit
        ends exactly at rest): one step of jerk above the limit (the next setpoint reports it),
        never a motion nobody asked for."""
        way = demanded - sp.position
        if way * sp.velocity < 0 or way * sp.acceleration >= 0:
            return sp
        cap = math.sqrt(2.0 * self.dynamics.max_jerk * abs(sp.velocity))
        if abs(sp.acceleration) <= cap:
            return sp
        return Setpoint(sp.position, sp.velocity, math.copysign(cap, sp.acceleration), 0.0)

    def _slow_down(self, sp: Setpoint, demanded: float, speed: float) -> float | None:
        """A move from ``sp`` heading for ``demanded`` faster than its ``speed`` (a MoveAxis
        slower than the motion it replaces, CURRSPEED lowered under a running move): ruckig
        given ``max_velocity=speed`` first brakes the velocity down to ``speed`` pushing the
        deceleration further, then unwinds that deceleration at the jerk limit and loses
        ``a²/2j`` more — below zero: from 20°/s a MoveAxis(1) of AZ stepped back 10 mdeg, from
        1.6°/s a MoveAxis(0.7) 2 mdeg (a motion nobody asked for). The same when the velocity is
        below ``speed`` but an acceleration towards the goal would carry it above (its peak,
        ``|v| + a²/2j``).

        Instead the planner slows down to ``speed`` first (ruckig's velocity control to
        (speed, 0) with the normal deceleration and jerk: never below the smaller of the two
        speeds, the acceleration being :meth:`_unwound`), in state SLOWING, and plans the move
        from there (:meth:`step`). When the goal is too near for that (it would have to brake
        from ``speed`` past it), the move is planned with the velocity limit it has now, which
        the profile never exceeds: it brakes straight to the goal.

        Returns
        -------
        float or None
            The velocity limit for the direct move; ``None`` when SLOWING was started.
        """
        way = demanded - sp.position
        if way == 0.0 or sp.velocity * way < 0.0:
            return speed
        d = self.dynamics
        direction = 1.0 if way > 0 else -1.0
        # the speed it reaches when its acceleration (towards the goal) is unwound at once
        peak = abs(sp.velocity) + (sp.acceleration ** 2 / (2.0 * d.max_jerk)
                                   if sp.acceleration * direction > 0 else 0.0)
        if peak <= speed * (1.0 + 1e-9):
            return speed
        slow = self._solver.reach_velocity(sp, direction * speed,
                                           max_velocity=max(d.max_velocity, abs(sp.velocity)),
                                           max_acceleration=d.max_acceleration, max_jerk=d.max_jerk)
        n = max(1, math.ceil(slow.duration / self.dt - 1e-9))
        end, velocity, _a = sample(slow, n * self.dt)
        rest = self._solver.stop(Setpoint(end, velocity), max_velocity=max(d.max_velocity, speed),
                                 max_acceleration=d.max_acceleration, max_jerk=d.max_jerk,
                                 discrete=False)
        rest_at = sample(rest, rest.duration)[0]
        if (demanded - rest_at) * direction >= 0.0 and self._guard.crossing(slow, sp.position) is None:
            self._start(slow, PlannerState.SLOWING, end, velocity)
            self._pending = demanded
            return None
        return max(speed, min(peak, d.max_velocity))   # (near the goal: braking from its speed)

    def _plan_to(self, demanded: float, speed: float | None = None) -> None:
        """Plan from the current setpoint to rest at ``demanded`` (drive frame), at most at
        ``speed`` (default: :attr:`speed`)."""
        d = self.dynamics
        sp = self._unwound(self._sp, demanded)
        self._softlimit = None
        self._guard.reset()
        self._pending = None
        if sp.at_rest and sp.position == demanded:
            self._idle()
            return
        speed = self._speed if speed is None else speed
        self._pending_speed = speed
        vmax = self._slow_down(sp, demanded, speed)
        if vmax is None:
            return
        way = demanded - sp.position
        if abs(way) > (vmax + abs(sp.velocity)) * LEG_SECONDS:
            # (a long slow move — a MoveAxis at a guiding rate towards a far limit — lasts
            # longer than ruckig can plan (~7,600 s: it answers -101): it goes in legs of
            # LEG_SECONDS at its speed, each ending at that speed on the way, the next
            # planned from there as one ends, the last one to rest at ``demanded``)
            leg = math.copysign(vmax * LEG_SECONDS, way)
            traj = self._solver.move(sp, sp.position + leg, math.copysign(vmax, way),
                                     max_velocity=max(vmax, abs(sp.velocity)),
                                     max_acceleration=d.max_acceleration, max_jerk=d.max_jerk)
            if self._guard.crossing(traj, sp.position) is None:
                self._start(traj, PlannerState.MOVING, sp.position + leg, math.copysign(vmax, way))
                self._pending = demanded
                return
        traj = self._solver.move(sp, demanded, max_velocity=vmax,
                                 max_acceleration=d.max_acceleration, max_jerk=d.max_jerk)
        side = self._guard.crossing(traj, sp.position)
        if side is None:
            self._start(traj, PlannerState.MOVING, demanded)
            return
        # The direct way overshoots a limit (moving fast towards it): come to rest first.
        traj, end = self._guard.brake_profile(sp)
        if self._guard.crossing(traj, sp.position) is not None:
            traj, end = self._guard.brake_profile(sp, side)
        self._start(traj, PlannerState.BRAKING, end)
        self._pending = demanded
