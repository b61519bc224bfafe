"""Physics of one simulated servo axis as a pure function of time (no clock, no thread, no I/O).

Everything here is in physical user units (degrees or mm, seconds). The axis has a motor
position ``x`` and velocity ``v`` at time ``t``; :meth:`Axis.advance` moves it to a later time.

How it moves: the drive's motion generator (profile position, profile velocity, homing, quick
stop, CSP interpolation) produces a **reference** — a :class:`Profile`, a list of segments of
constant acceleration — and the axis follows it through a position loop limited by the
motor's maximum velocity and acceleration:

* while the axis is *locked* on the reference (same position and velocity) and the reference
  is within the motor's limits, the axis *is* the reference and is evaluated in closed form —
  a slew of an hour costs a few segment evaluations;
* otherwise (a CSP target stream asking for more than the motor can do, a new reference that
  starts away from the axis) the loop is integrated in steps of at most :data:`SUBSTEP`
  (velocity command = reference velocity + the error closed at the rate the acceleration
  allows, clamped to the limits) until it locks again. The difference reference − axis is the
  following error.

:meth:`Axis.advance` stops early at the first **event**: a watched position (a
:class:`Threshold`: limit switch, home switch, index pulse) crossed, the following error
outside its window for longer than the time-out, or an alarm time reached; the caller reacts
(new reference, fault) and advances again. Within a segment the motion is monotonic (profiles
split at velocity reversals), so a crossing time is solved exactly in closed form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

INF = math.inf
#: Longest integration step of the position loop (s).
SUBSTEP = 1e-3
#: Position difference (units) under which the axis counts as on the reference.
LOCK_POSITION = 1e-9


@dataclass(frozen=True)
class Segment:
    """Constant acceleration ``a`` from ``(t0, x0, v0)`` until ``t1``."""

    t0: float
    x0: float
    v0: float
    a: float
    t1: float

    def state(self, t: float) -> tuple[float, float]:
        dt = t - self.t0
        return self.x0 + self.v0 * dt + 0.5 * self.a * dt * dt, self.v0 + self.a * dt


@dataclass(frozen=True)
class Profile:
    """A reference trajectory: contiguous segments, the last one open-ended (t1 = inf)."""

    segments: tuple[Segment, ...]

    def segment_at(self, t: float) -> Segment:
        for seg in self.segments:
            if t < seg.t1:
                return seg
        return self.segments[-1]

    def state(self, t: float) -> tuple[float, float]:
        seg = self.segment_at(t)
        if t < seg.t0:
            return seg.x0, seg.v0
        return seg.state(t)

    @property
    def end_time(self) -> float:
        """When the last (open-ended) segment starts: the profile's motion is over if v = 0."""
        return self.segments[-1].t0

    @property
    def final_position(self) -> float:
        return self.segments[-1].x0

    @property
    def max_speed(self) -> float:
        return max(max(abs(s.v0), abs(s.state(s.t1)[1]) if s.t1 < INF else abs(s.v0)) for s in self.segments)


class _Builder:
    """Appends constant-acceleration pieces, splitting at velocity reversals."""

    def __init__(self, t: float, x: float, v: float):
        self.t, self.x, self.v = t, x, v
        self.segments: list[Segment] = []

    def ramp(self, v_to: float, rate: float) -> None:
        """Change velocity to ``v_to`` at ``rate`` (> 0), via 0 if the sign changes."""
        if self.v * v_to < 0:
            self.ramp(0.0, rate)
        dv = v_to - self.v
        if dv == 0 or rate <= 0:
            return
        self.piece(math.copysign(rate, dv), abs(dv) / rate)
        self.v = v_to

    def piece(self, a: float, duration: float) -> None:
        if duration <= 0:
            return
        seg = Segment(self.t, self.x, self.v, a, self.t + duration)
        self.segments.append(seg)
        self.t = seg.t1
        self.x, self.v = seg.state(seg.t1)

    def finish(self, v_final: float = 0.0, x_final: float | None = None) -> Profile:
        x = self.x if x_final is None else x_final
        self.segments.append(Segment(self.t, x, v_final, 0.0, INF))
        return Profile(tuple(self.segments))


def hold(t: float, x: float) -> Profile:
    """Stand still at ``x`` from ``t`` on."""
    return Profile((Segment(t, x, 0.0, 0.0, INF),))


def velocity_profile(t: float, x: float, v: float, v_target: float, acc: float, dec: float) -> Profile:
    """Ramp from velocity ``v`` to ``v_target`` (``acc`` speeding up, ``dec`` slowing down)."""
    b = _Builder(t, x, v)
    if v * v_target < 0 or abs(v_target) < abs(v):
        b.ramp(0.0 if v * v_target < 0 else v_target, dec)
    b.ramp(v_target, acc)
    return b.finish(v_target)


def stop_profile(t: float, x: float, v: float, dec: float) -> Profile:
    """Brake to standstill at ``dec``."""
    return velocity_profile(t, x, v, 0.0, dec, dec)


def position_profile(t: float, x: float, v: float, target: float, vmax: float, acc: float,
                     dec: float) -> Profile:
    """The time-optimal trapezoid from ``(x, v)`` to rest at ``target``.

    Speeds are limited to ``vmax``; when the axis cannot stop before the target (or moves
    away from it) it brakes first and comes back.
    """
    vmax, acc, dec = abs(vmax), abs(acc), abs(dec)
    if vmax <= 0 or acc <= 0 or dec <= 0:
        return stop_profile(t, x, v, max(dec, acc, 1e-9))
    b = _Builder(t, x, v)
    d = target - x
    stopping = v * abs(v) / (2 * dec)  # signed braking distance
    if (v != 0 and (d == 0 or math.copysign(1, v) != math.copysign(1, d))) or abs(stopping) > abs(d) + 1e-12:
        b.ramp(0.0, dec)  # moving away, or too fast to stop in time: brake first
        d = target - b.x
    if abs(d) < 1e-15 and b.v == 0:
        return b.finish(0.0, target)
    s = math.copysign(1.0, d)
    u = s * b.v  # speed towards the target, >= 0
    if u > vmax:
        b.ramp(s * vmax, dec)
        u = vmax
    dist = abs(target - b.x)
    peak = math.sqrt(max(0.0, (dist + u * u / (2 * acc)) / (1 / (2 * acc) + 1 / (2 * dec))))
    if peak > vmax:
        cruise = dist - (vmax * vmax - u * u) / (2 * acc) - vmax * vmax / (2 * dec)
        b.ramp(s * vmax, acc)
        b.piece(0.0, cruise / vmax)
    else:
        b.ramp(s * max(peak, u), acc)
    b.ramp(0.0, dec)
    return b.finish(0.0, target)


def linear_profile(t: float, x: float, target: float, duration: float,
                   extrapolate: float = 0.0, trend: float | None = None) -> Profile:
    """Straight line from ``x`` to ``target`` in ``duration``, then on at ``trend`` units/s
    (default: the line's speed) for ``extrapolate`` s more (a drive bridging missing
    setpoints), then hold (CSP interpolation)."""
    if duration <= 0:
        return hold(t, target)
    v = (target - x) / duration
    if extrapolate <= 0:
        return Profile((Segment(t, x, v, 0.0, t + duration),
                        Segment(t + duration, target, 0.0, 0.0, INF)))
    w = v if trend is None else trend
    t1, t2 = t + duration, t + duration + extrapolate
    return Profile((Segment(t, x, v, 0.0, t1), Segment(t1, target, w, 0.0, t2),
                    Segment(t2, target + w * extrapolate, 0.0, 0.0, INF)))


@dataclass(frozen=True)
class Threshold:
    """A watched position: ``name`` and the side it is on are reported when it is crossed."""

    name: str
    position: float


@dataclass(frozen=True)
class Event:
    """Why :meth:`Axis.advance` stopped early."""

    kind: str  # "crossing", "following_error" or "alarm"
    time: float
    threshold: Threshold | None = None
    upward: bool = False


@dataclass
class Axis:
    """The motor of one simulated axis following a reference (see the module docstring)."""

    x: float = 0.0
    v: float = 0.0
    t: float = 0.0
    max_velocity: float = 5.0
    max_acceleration: float = 5.0
    #: Watched positions, set by the drive logic.
    thresholds: list[Threshold] = field(default_factory=list)
    #: Following error window (units) and time-out (s); window <= 0 switches the check off.
    fe_window: float = 0.0
    fe_timeout: float = 0.0
    #: Advance stops with an "alarm" event at this time (None = no alarm).
    alarm: float | None = None
    reference: Profile = field(default=None)  # type: ignore[assignment]
    locked: bool = True
    _fe_since: float | None = None

    def __post_init__(self) -> None:
        if self.reference is None:
            self.reference = hold(self.t, self.x)

    # -- commands ----------------------------------------------------------------------------
    def set_reference(self, profile: Profile) -> None:
        """Follow ``profile`` from now on (the axis locks if it starts where the axis is)."""
        self.reference = profile
        r, vr = profile.state(self.t)
        self.locked = (abs(r - self.x) <= LOCK_POSITION and abs(vr - self.v) <= self.max_acceleration * SUBSTEP
                       and self._threshold_between(self.x, r) is None)
        if self.locked:
            self.x, self.v = r, vr

    def demand(self) -> tuple[float, float]:
        """Reference position and velocity now."""
        return self.reference.state(self.t)

    @property
    def following_error(self) -> float:
        return self.reference.state(self.t)[0] - self.x

    # -- time --------------------------------------------------------------------------------
    def advance(self, t_end: float) -> Event | None:
        """Move to ``t_end``, or to the first event before it (returned; ``self.t`` is its time)."""
        while self.t < t_end:
            if self.alarm is not None and self.alarm <= self.t:
                alarm, self.alarm = self.alarm, None
                return Event("alarm", self.t)
            stop = t_end if self.alarm is None else min(t_end, self.alarm)
            if self.locked and abs(self.reference.segment_at(self.t).v0) <= self.max_velocity * (1 + 1e-9) \
                    and self._segment_feasible(self.reference.segment_at(self.t)):
                event = self._advance_locked(stop)
            else:
                event = self._integrate(stop)
            if event is not None:
                return event
        if self.alarm is not None and self.alarm <= self.t:
            self.alarm = None
            return Event("alarm", self.t)
        return None

    def _segment_feasible(self, seg: Segment) -> bool:
        if abs(seg.a) > self.max_acceleration * (1 + 1e-9):
            return False
        if seg.t1 < INF and abs(seg.state(seg.t1)[1]) > self.max_velocity * (1 + 1e-9):
            return False
        return True

    def _advance_locked(self, stop: float) -> Event | None:
        seg = self.reference.segment_at(self.t)
        t_next = min(stop, seg.t1)
        x_new, v_new = seg.state(t_next)
        event = self._crossing(seg, self.t, t_next)
        if event is not None:
            _, self.v = seg.state(event.time)
            self.x = _just_past(event)
            self.t = event.time
            return event
        self.t, self.x, self.v = t_next, x_new, v_new
        self._fe_since = None
        if t_next >= seg.t1:
            nxt = self.reference.segment_at(self.t)
            if abs(nxt.v0 - self.v) > self.max_acceleration * SUBSTEP or abs(nxt.x0 - self.x) > LOCK_POSITION:
                self.locked = False
            else:
                self.v = nxt.v0
                return self._snap(nxt.x0)
        return None

    def _threshold_between(self, xa: float, xb: float) -> tuple[Threshold, bool] | None:
        """A threshold crossed going from ``xa`` to ``xb``, and whether upward."""
        for th in self.thresholds:
            if xa < th.position <= xb:
                return th, True
            if xa >= th.position > xb:
                return th, False
        return None

    def _snap(self, x: float) -> Event | None:
        """Put the axis on its reference at ``x`` (a rounding step away), crossing what lies between.

        The last increment of a segment ends a rounding error short of where the next one starts;
        a switch exactly there (a whole number of increments, as CSP targets are) is crossed by this
        step and by no motion after it.
        """
        crossed = self._threshold_between(self.x, x)
        if crossed is None:
            self.x = x
            return None
        event = Event("crossing", self.t, *crossed)
        self.x = _just_past(event)
        return event

    def _crossing(self, seg: Segment, ta: float, tb: float) -> Event | None:
        """First threshold crossed on ``seg`` between ``ta`` and ``tb`` (motion is monotonic)."""
        xa = self.x
        xb, _ = seg.state(tb)
        best: Event | None = None
        for th in self.thresholds:
            up = xa < th.position <= xb
            down = xa >= th.position > xb
            if not (up or down):
                continue
            tc = _solve_time(seg, th.position, ta, tb)
            if best is None or tc < best.time:
                best = Event("crossing", tc, th, up)
        return best

    def _integrate(self, stop: float) -> Event | None:
        dt = min(SUBSTEP, stop - self.t)
        t_new = self.t + dt
        e = self.reference.state(self.t)[0] - self.x
        r, vr = self.reference.state(t_new)
        correction = min(abs(e) / (2 * SUBSTEP), math.sqrt(2 * self.max_acceleration * abs(e)))
        v_cmd = vr + math.copysign(correction, e)
        v_cmd = max(-self.max_velocity, min(self.max_velocity, v_cmd))
        dv_max = self.max_acceleration * dt
        v_new = self.v + max(-dv_max, min(dv_max, v_cmd - self.v))
        x_new = self.x + 0.5 * (self.v + v_new) * dt
        for th in self.thresholds:
            up = self.x < th.position <= x_new
            down = self.x >= th.position > x_new
            if up or down:
                frac = (th.position - self.x) / (x_new - self.x)
                tc = self.t + frac * dt
                self.v = self.v + (v_new - self.v) * frac
                event = Event("crossing", tc, th, up)
                self.x, self.t = _just_past(event), tc
                self.locked = False
                return event
        self.x, self.v, self.t = x_new, v_new, t_new
        err = r - self.x
        if abs(err) <= LOCK_POSITION * 100 and abs(v_new - vr) <= dv_max and abs(vr) <= self.max_velocity:
            self.v, self.locked = vr, True
            self._fe_since = None
            return self._snap(r)
        if self.fe_window > 0 and abs(err) > self.fe_window:
            if self._fe_since is None:
                self._fe_since = self.t
            elif self.t - self._fe_since >= self.fe_timeout:
                self._fe_since = None
                return Event("following_error", self.t)
        else:
            self._fe_since = None
        return None


def _just_past(event: Event) -> float:
    """The position just on the far side of a crossed threshold (so it fires only once)."""
    p = event.threshold.position
    return p if event.upward else math.nextafter(p, -INF)


def _solve_time(seg: Segment, x: float, ta: float, tb: float) -> float:
    """The time in [ta, tb] at which the monotonic ``seg`` passes ``x``."""
    a, v0, c = 0.5 * seg.a, seg.v0, seg.x0 - x
    if abs(a) < 1e-15:
        dt = -c / v0 if v0 else 0.0
    else:
        disc = max(0.0, v0 * v0 - 4 * a * c)
        root = math.sqrt(disc)
        candidates = [(-v0 + root) / (2 * a), (-v0 - root) / (2 * a)]
        lo, hi = ta - seg.t0 - 1e-12, tb - seg.t0 + 1e-12
        inside = [c for c in candidates if lo <= c <= hi]
        dt = min(inside) if inside else min(candidates, key=lambda c: abs(c - (ta - seg.t0)))
    return min(max(seg.t0 + dt, ta), tb)
