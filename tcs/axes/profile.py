"""Plain motion data and the one adapter to ruckig (community edition).

How it works
------------
Every motion in the axes layer is a stream of :class:`Setpoint` s, one per control cycle
(``dt``, default 10 ms). A setpoint is the *demanded drive position* with its velocity,
acceleration and the jerk of the stream (the finite difference of the acceleration over the
cycle: what the drive really sees).

Jerk-limited profiles come from ruckig through :class:`ProfileSolver`: a 1-DoF ``Ruckig``
with a reused ``InputParameter``, asked for a whole :class:`ruckig.Trajectory` that the
planners then *sample by time* (``Trajectory.at_time``, ~0.2 µs) instead of calling
``Ruckig.update`` every cycle. That makes a profile a pure function of elapsed time (a missed
control cycle does not stretch it) and lets the caller look at the whole profile before it is
used (duration, position extrema: ruckig community ignores position limits, so callers check
the extrema themselves — see :mod:`tcs.axes.limits`). Ruckig's intermediate waypoints (a
cloud service) are never used.

:func:`theoretical_minimum_time` is the closed form of the time-optimal rest-to-rest profile
(the 7-segment jerk-limited "double S"); ruckig's own duration for the same problem agrees to
better than 1e-9 s (tested), so benchmarks can compare a planner's slew with it.

Nothing here keeps time, threads or I/O; one :class:`ProfileSolver` per owner (it is not
thread-safe: it reuses its input object).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import NamedTuple

from tcs.errors import RangeRefused

from ruckig import (
    ControlInterface,
    DurationDiscretization,
    InputParameter,
    Result,
    Ruckig,
    RuckigError,
    Trajectory,
)

log = logging.getLogger(__name__)

class Setpoint(NamedTuple):
    """One cycle's demand: position (axis units), velocity (/s), acceleration (/s²), jerk (/s³)."""

    position: float
    velocity: float = 0.0
    acceleration: float = 0.0
    jerk: float = 0.0

    @property
    def at_rest(self) -> bool:
        """True when velocity and acceleration are both exactly zero."""
        return self.velocity == 0.0 and self.acceleration == 0.0


@dataclass(frozen=True, slots=True)
class AxisDynamics:
    """Kinematic limits of one axis (all > 0, axis units per s, s², s³).

    ``quick_stop_acceleration`` / ``quick_stop_jerk`` are what ``STOP`` may use ("may be higher
    than CURRACC!MAX and CURRJRK!MAX", spec §5.1); ``None`` means the normal maxima.
    """

    max_velocity: float
    max_acceleration: float
    max_jerk: float
    quick_stop_acceleration: float | None = None
    quick_stop_jerk: float | None = None

    def __post_init__(self):
        for name in ("max_velocity", "max_acceleration", "max_jerk",
                     "quick_stop_acceleration", "quick_stop_jerk"):
            value = getattr(self, name)
            if value is None and name.startswith("quick"):
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"AxisDynamics.{name} must be a finite number > 0, got {value!r}")
        if self.quick_stop_acceleration is not None and self.quick_stop_acceleration < self.max_acceleration:
            raise ValueError("AxisDynamics.quick_stop_acceleration must be >= max_acceleration")
        if self.quick_stop_jerk is not None and self.quick_stop_jerk < self.max_jerk:
            raise ValueError("AxisDynamics.quick_stop_jerk must be >= max_jerk")

    @property
    def stop_acceleration(self) -> float:
        """Deceleration of a quick stop."""
        return self.quick_stop_acceleration or self.max_acceleration

    @property
    def stop_jerk(self) -> float:
        """Jerk of a quick stop."""
        return self.quick_stop_jerk or self.max_jerk


def checked_speed(velocity: float, dynamics: "AxisDynamics") -> float:
    """A ``CURRSPEED`` value for ``dynamics``: ``velocity`` capped at the maximum.

    Raises
    ------
    RangeRefused
        ``velocity`` not in (0, max_velocity].
    """
    vmax = dynamics.max_velocity
    if not (math.isfinite(velocity) and 0.0 < velocity <= vmax * (1 + 1e-12)):
        raise RangeRefused(f"speed {velocity!r} is outside (0, {vmax:g}]")
    return min(float(velocity), vmax)


def theoretical_minimum_time(distance: float, dynamics: AxisDynamics) -> float:
    """Shortest time to move ``distance`` from rest to rest under the velocity, acceleration
    and jerk limits of ``dynamics`` (closed form of the time-optimal double-S profile).

    Three regimes, with ``V, A, J`` the limits and ``d = |distance|``:

    * cruise reached: ``T = d/V + t_v`` where ``t_v`` is the time to reach ``V`` from rest
      (``V/A + A/J`` if ``V·J >= A²``, else ``2·sqrt(V/J)``);
    * ``A`` reached but not ``V``: peak velocity ``vp`` solves ``d = vp·(vp/A + A/J)``,
      ``T = 2·(vp/A + A/J)``;
    * neither: pure jerk phases, ``T = 4·(d/(2J))^(1/3)``.

    Parameters
    ----------
    distance:
        Travel in axis units (sign ignored).
    dynamics:
        The limits (the quick-stop values are not used).

    Returns
    -------
    float
        Seconds; ``0.0`` for no travel.
    """
    d = abs(float(distance))
    if d == 0.0:
        return 0.0
    v, a, j = dynamics.max_velocity, dynamics.max_acceleration, dynamics.max_jerk
    # time and distance to reach V from rest and come back to rest
    t_v = v / a + a / j if v * j >= a * a else 2.0 * math.sqrt(v / j)
    if d >= v * t_v:
        return d / v + t_v
    # V not reached: is A reached? Threshold distance where the acceleration just touches A.
    d_a = 2.0 * a ** 3 / (j * j)
    if d >= d_a:
        vp = 0.5 * a * (-a / j + math.sqrt(a * a / (j * j) + 4.0 * d / a))
        return 2.0 * (vp / a + a / j)
    return 4.0 * (d / (2.0 * j)) ** (1.0 / 3.0)


class ProfileSolver:
    """ruckig behind three questions: move to a state, stop, and how long would it take.

    Parameters
    ----------
    dt:
        Control cycle in seconds (ruckig's ``delta_time``; with ``discrete=True`` durations
        are rounded up to whole cycles so a move ends exactly on a cycle).
    """

    __slots__ = ("dt", "_ruckig", "_inp")

    def __init__(self, dt: float):
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"control cycle dt must be > 0 s, got {dt!r}")
        self.dt = float(dt)
        self._ruckig = Ruckig(1, self.dt)
        self._inp = InputParameter(1)

    def move(self, start: Setpoint, position: float, velocity: float = 0.0,
             acceleration: float = 0.0, *, max_velocity: float, max_acceleration: float,
             max_jerk: float, minimum_duration: float | None = None,
             discrete: bool = True) -> Trajectory:
        """Time-optimal (or at least ``minimum_duration`` long) profile from ``start`` to the
        state (``position``, ``velocity``, ``acceleration``).

        Raises
        ------
        ValueError
            ruckig refused the input (e.g. a target velocity above ``max_velocity``).
        """
        inp = self._inp
        inp.control_interface = ControlInterface.Position
        inp.target_position = [position]
        inp.target_velocity = [velocity]
        inp.target_acceleration = [acceleration]
        inp.minimum_duration = minimum_duration
        return self._calculate(start, max_velocity, max_acceleration, max_jerk, discrete)

    def stop(self, start: Setpoint, *, max_velocity: float, max_acceleration: float,
             max_jerk: float, discrete: bool = True) -> Trajectory:
        """Shortest profile from ``start`` to rest (velocity and acceleration zero)."""
        return self.reach_velocity(start, 0.0, max_velocity=max_velocity,
                                   max_acceleration=max_acceleration, max_jerk=max_jerk,
                                   discrete=discrete)

    def reach_velocity(self, start: Setpoint, velocity: float, acceleration: float = 0.0, *,
                       max_velocity: float, max_acceleration: float, max_jerk: float,
                       discrete: bool = True) -> Trajectory:
        """Shortest profile from ``start`` to the state (``velocity``, ``acceleration``),
        wherever that leaves the position."""
        inp = self._inp
        inp.control_interface = ControlInterface.Velocity
        inp.target_velocity = [velocity]
        inp.target_acceleration = [acceleration]
        inp.minimum_duration = None
        return self._calculate(start, max_velocity, max_acceleration, max_jerk, discrete)

    def _calculate(self, start, vmax, amax, jmax, discrete) -> Trajectory:
        inp = self._inp
        inp.current_position = [start.position]
        inp.current_velocity = [start.velocity]
        inp.current_acceleration = [start.acceleration]
        inp.max_velocity = [vmax]
        inp.max_acceleration = [amax]
        inp.max_jerk = [jmax]
        inp.duration_discretization = (DurationDiscretization.Discrete if discrete
                                       else DurationDiscretization.Continuous)
        trajectory = Trajectory(1)
        try:
            result = self._ruckig.calculate(inp, trajectory)
        except RuckigError as exc:
            if not discrete:
                raise ValueError(f"ruckig refused the motion: {str(exc).strip()}") from None
            # ruckig's time synchronisation to whole cycles fails on a few degenerate starts:
            # the last phase of every jerk-limited stop (v = a²/2j exactly), from which a
            # repeated OFFSET was refused ("error in step 2 … t sync"). The continuous profile
            # is the same motion; the planner ends it exactly on its last cycle.
            log.debug("ruckig: no whole-cycle profile (%s); continuous duration", str(exc).strip())
            return self._calculate(start, vmax, amax, jmax, discrete=False)
        if result not in (Result.Working, Result.Finished):
            raise ValueError(f"ruckig could not calculate the motion ({result})")
        return trajectory


def sample(trajectory: Trajectory, time: float) -> tuple[float, float, float]:
    """Position, velocity, acceleration of a 1-DoF ruckig trajectory at ``time`` (s)."""
    p, v, a = trajectory.at_time(time)
    return p[0], v[0], a[0]


def extrema(trajectory: Trajectory) -> tuple[float, float]:
    """Lowest and highest position a 1-DoF ruckig trajectory passes through."""
    e = trajectory.position_extrema[0]
    return e.min, e.max
