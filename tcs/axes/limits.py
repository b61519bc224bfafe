"""Software limits of one axis: target resolution (RANGE, cyclic axes, cable wrap) and the
guard that checks every setpoint.

How it works
------------
``REALPOS!MIN`` / ``!MAX`` are software limits on the *mechanical* (demanded drive) position
(spec §5.1, notes "Axis semantics"). Two things enforce them:

1. :meth:`SoftLimits.resolve` turns a requested position into the one the axis will go to, or
   raises :class:`tcs.errors.RangeRefused` before anything moves. On a cyclic axis
   (``cycle=360``) every ``target + k·cycle`` means the same direction; among those inside the
   limits the one with the shortest travel from the current position is taken. With limits
   wider than one cycle (an azimuth cable wrap, e.g. −270…+270) that is the cable-wrap choice,
   and since the limits are one interval, the straight travel between two points inside them
   never crosses a limit. Ties go to the candidate nearer the middle of the range (keeps the
   wrap centred), then to the lower one.

2. :class:`LimitGuard` filters every produced setpoint. ruckig community ignores position
   limits, and a trajectory may run beyond a limit, so the guard asks of each proposed setpoint:
   "if the axis braked as hard as it may (normal maximum acceleration and jerk) from here,
   would it stay inside?". A cheap closed-form bound answers most cycles; only near a limit an
   exact ruckig stop profile is computed. The first proposal that fails is replaced by a
   braking profile *from the previous setpoint* (whose stop was checked inside last cycle) to
   rest exactly at the limit; from then on the guard keeps braking, ignores proposals, and
   reports which limit it hit (``tripped``) until :meth:`LimitGuard.reset`. An axis already
   outside a limit may move back in but not further out.

Owned by one planner or trajectory follower each (not thread-safe).
:func:`limit_text` (pure) words a ``LIMIT_STATE`` for events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tcs.axes.profile import AxisDynamics, ProfileSolver, Setpoint, extrema, sample
from tcs.errors import RangeRefused


def _eps(value: float) -> float:
    """Numerical tolerance for a limit comparison at ``value`` (1e-9 relative, in axis units)."""
    return 1e-9 * (1.0 + abs(value))


@dataclass(frozen=True, slots=True)
class SoftLimits:
    """Software position limits of an axis (``None``: no limit on that side) and its cycle.

    Parameters
    ----------
    minimum, maximum:
        ``REALPOS!MIN`` / ``!MAX`` in axis units; ``None`` = unlimited in that direction.
    cycle:
        Period of a rotary axis (``CYCLIC``, e.g. 360.0); ``None`` for a linear axis.
    """

    minimum: float | None = None
    maximum: float | None = None
    cycle: float | None = None

    def __post_init__(self):
        for name in ("minimum", "maximum"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise ValueError(f"SoftLimits.{name} must be finite or None, got {v!r}")
        if self.minimum is not None and self.maximum is not None and self.minimum > self.maximum:
            raise ValueError(f"SoftLimits: minimum {self.minimum} is above maximum {self.maximum}")
        if self.cycle is not None and not (math.isfinite(self.cycle) and self.cycle > 0):
            raise ValueError(f"SoftLimits.cycle must be > 0 or None, got {self.cycle!r}")

    def contains(self, position: float) -> bool:
        """True if ``position`` is inside the limits (with a 1e-9 relative tolerance)."""
        lo, hi = self.minimum, self.maximum
        return ((lo is None or position >= lo - _eps(lo))
                and (hi is None or position <= hi + _eps(hi)))

    def side(self, position: float) -> str | None:
        """``"min"`` / ``"max"`` if ``position`` is at or beyond that limit, else ``None``."""
        if self.minimum is not None and position <= self.minimum + _eps(self.minimum):
            return "min"
        if self.maximum is not None and position >= self.maximum - _eps(self.maximum):
            return "max"
        return None

    def resolve(self, position: float, current: float, what: str = "target") -> float:
        """The position the axis shall go to for a request of ``position``.

        Linear axis: ``position`` itself if inside the limits. Cyclic axis: the
        ``position + k·cycle`` inside the limits with the shortest travel from ``current``.

        Raises
        ------
        RangeRefused
            No allowed position (``what`` names the request in the message).
        """
        if not math.isfinite(position):
            raise RangeRefused(f"{what} {position!r} is not a finite number")
        lo, hi = self.minimum, self.maximum
        if self.cycle is None:
            if self.contains(position):
                return float(position)
            raise RangeRefused(f"{what} {position:g} is outside the software limits "
                               f"[{_fmt(lo)}, {_fmt(hi)}]")
        c = self.cycle
        k_lo = -math.inf if lo is None else math.ceil((lo - _eps(lo) - position) / c)
        k_hi = math.inf if hi is None else math.floor((hi + _eps(hi) - position) / c)
        if k_lo > k_hi:
            raise RangeRefused(f"{what} {position:g} (modulo {c:g}) is outside the software "
                               f"limits [{_fmt(lo)}, {_fmt(hi)}]")
        k_near = (current - position) / c
        centre = (lo + hi) / 2 if lo is not None and hi is not None else current
        best = None
        for k in (math.floor(k_near), math.ceil(k_near)):
            k = min(max(k, k_lo), k_hi)
            cand = position + k * c
            key = (round(abs(cand - current), 9), round(abs(cand - centre), 9), cand)
            if best is None or key < best[0]:
                best = (key, cand)
        return float(best[1])


def _fmt(v: float | None) -> str:
    return "none" if v is None else f"{v:g}"


class LimitGuard:
    """Checks setpoints against :class:`SoftLimits`, braking to rest at a limit when needed.

    Parameters
    ----------
    limits:
        The software limits (may be replaced later through the ``limits`` attribute).
    dynamics:
        Braking uses ``max_acceleration`` / ``max_jerk`` (the quick-stop margin stays in
        reserve).
    dt:
        Control cycle in seconds.
    """

    def __init__(self, limits: SoftLimits, dynamics: AxisDynamics, dt: float):
        self.limits = limits
        self.dynamics = dynamics
        self.dt = float(dt)
        self._solver = ProfileSolver(dt)
        self._brake = None          # ruckig Trajectory while braking
        self._brake_steps = 0
        self._brake_end: Setpoint | None = None
        #: ``"min"`` / ``"max"`` once a proposal would have crossed that limit, until reset().
        self.tripped: str | None = None

    @property
    def braking(self) -> bool:
        """True while the guard's own braking profile is running."""
        return self._brake is not None

    def reset(self) -> None:
        """Forget a trip (a new command was given from a state at rest or inside the limits)."""
        self._brake = None
        self._brake_end = None
        self.tripped = None

    # -- checks ------------------------------------------------------------------------------

    def allowed(self, start: float) -> tuple[float, float]:
        """The position range a motion starting at ``start`` may use: the limits, widened to
        ``start`` when the axis is already beyond one (it may come back, not go further)."""
        lo, hi = self.limits.minimum, self.limits.maximum
        lo = -math.inf if lo is None else min(lo, start)
        hi = math.inf if hi is None else max(hi, start)
        return lo, hi

    def crossing(self, trajectory, start: float) -> str | None:
        """Which limit a whole ruckig profile starting at ``start`` would cross, or ``None``."""
        lo, hi = self.allowed(start)
        low, high = extrema(trajectory)
        if high > hi + _eps(hi):
            return "max"
        if low < lo - _eps(lo):
            return "min"
        return None

    def _stop_bound(self, sp: Setpoint) -> float:
        """Upper bound of how far the axis may travel (either way) while braking from ``sp``."""
        d = self.dynamics
        A, J = d.max_acceleration, d.max_jerk
        a = abs(sp.acceleration)
        v_peak = abs(sp.velocity) + a * a / (2.0 * J)
        return v_peak * ((a + A) / J + v_peak / A + A / J)

    def _kw(self, start: Setpoint) -> dict:
        d = self.dynamics
        return dict(max_velocity=max(d.max_velocity, abs(start.velocity)),
                    max_acceleration=d.max_acceleration, max_jerk=d.max_jerk)

    def stop_extent(self, sp: Setpoint) -> tuple[float, float]:
        """Lowest and highest position of the quickest normal stop from ``sp`` (exact, ruckig)."""
        if sp.velocity == 0.0 and sp.acceleration == 0.0:
            return sp.position, sp.position
        return extrema(self._solver.stop(sp, discrete=False, **self._kw(sp)))

    def violation(self, previous: Setpoint, proposed: Setpoint) -> str | None:
        """Which limit (``"min"``/``"max"``) a quickest stop from ``proposed`` would cross, or
        ``None``. An axis already beyond a limit at ``previous`` may come back, not go further.
        """
        lo, hi = self.limits.minimum, self.limits.maximum
        if lo is None and hi is None:
            return None
        p = proposed.position
        bound = self._stop_bound(proposed)
        if (lo is None or p - bound >= lo) and (hi is None or p + bound <= hi):
            return None                                    # far from both limits: done
        lo, hi = self.allowed(previous.position)
        low, high = self.stop_extent(proposed)
        if high > hi + _eps(hi):
            return "max"
        if low < lo - _eps(lo):
            return "min"
        return None

    def brake_profile(self, start: Setpoint, side: str | None = None):
        """A profile from ``start`` to rest that stays inside the limits when that is possible.

        With ``side`` (the limit being approached) and ``start`` inside the limits: rest exactly
        at that limit if ruckig can get there without overshooting; otherwise the quickest stop.

        Returns
        -------
        (ruckig.Trajectory, float)
            The profile and the position where it comes to rest.
        """
        kw = self._kw(start)
        if side is not None and self.limits.contains(start.position):
            limit = self.limits.maximum if side == "max" else self.limits.minimum
            try:
                traj = self._solver.move(start, limit, **kw)
            except ValueError:
                traj = None
            if traj is not None and self.crossing(traj, start.position) is None:
                return traj, float(limit)
        traj = self._solver.stop(start, **kw)
        return traj, sample(traj, traj.duration)[0]

    # -- the filter --------------------------------------------------------------------------

    def filter(self, previous: Setpoint, proposed: Setpoint, verified: bool = False) -> Setpoint:
        """The setpoint to send this cycle: ``proposed`` if safe, else the guard's braking.

        Parameters
        ----------
        previous:
            The setpoint sent last cycle.
        proposed:
            What the planner or follower wants to send now.
        verified:
            ``proposed`` comes from a profile whose extrema were checked with :meth:`crossing`:
            only its position is checked (a quick stop near a limit must not be second-guessed
            with the normal deceleration).
        """
        if self._brake is None:
            if verified:
                lo, hi = self.allowed(previous.position)
                p = proposed.position
                side = ("max" if p > hi + _eps(hi) else "min" if p < lo - _eps(lo) else None)
            else:
                side = self.violation(previous, proposed)
            if side is None:
                return proposed
            self.tripped = side
            self._brake, end = self.brake_profile(previous, side)
            self._brake_steps, self._brake_end = 0, Setpoint(end)
        return self._brake_step(previous)

    def _brake_step(self, previous: Setpoint) -> Setpoint:
        traj = self._brake
        if traj is None:            # braking finished: hold at rest where it ended
            return self._brake_end
        self._brake_steps += 1
        t = self._brake_steps * self.dt
        if t >= traj.duration - 1e-9:
            self._brake = None
            return Setpoint(self._brake_end.position, 0.0, 0.0, -previous.acceleration / self.dt)
        p, v, a = sample(traj, t)
        return Setpoint(p, v, a, (a - previous.acceleration) / self.dt)


_LIMIT_BITS = ((0, "hardware min limit"), (1, "hardware max limit"), (7, "hardware blocking"),
               (8, "software min limit"), (9, "software max limit"), (15, "software blocking"))


def limit_text(bits: int) -> str:
    """``LIMIT_STATE`` in words for the LIMITCHANGE (22) event: ``"hardware min limit,
    hardware blocking"``; ``"limits clear"`` for 0 (spec §5.1: bits 0/1, 7, 8/9, 15)."""
    words = [name for bit, name in _LIMIT_BITS if bits >> bit & 1]
    rest = bits & ~sum(1 << bit for bit, _ in _LIMIT_BITS)
    if rest:
        words.append(f"other bits 0x{rest:x}")
    return ", ".join(words) if words else "limits clear"
