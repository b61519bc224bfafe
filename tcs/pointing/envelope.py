"""The safety envelope the TCS owns: Sun cone, horizon table, keep-out zones — on whole paths.

How it works
------------
:class:`Envelope` judges *paths* of the two main axes (mechanical angles, OFFSET included:
what the drives will really do) sampled in time, against three kinds of border:

* **Sun cone** (``[envelope] sun_avoidance``, default 30°, 0 only when written): the angle
  between the tube and the Sun. The Sun is a low-precision one (:func:`sun_icrs`): the
  geocentric direction from ``erfa.epv00`` (the Earth's heliocentric position, VSOP87-based,
  a few milli-arcseconds), then the project's ICRS → observed astrometry (annual aberration,
  precession-nutation, refraction) as for a star. Left out: light time (20″, which the
  aberration of a star does not cancel for the Sun), solar parallax (≤ 8.8″) and the light
  deflection near the limb: the position is good to better than 1′ — ample for a cone of
  degrees (checked against astropy: ~10″). Samples are interpolated from Sun directions
  300 s apart (within 0.004°).
* **Horizon table** (``[envelope] horizon`` ``[[az, min_alt], …]``): linear in azimuth,
  wrapping at 360°; ``[pointing] min_altitude`` stays the floor.
* **Keep-out zones** (``[[envelope.keepout]]``): rectangles of the mechanical axis angles
  (axis 1 modulo 360°): pier, dome ring.

The sky direction of a mechanical position is read twice (:meth:`Envelope.readings`): the bare
axis angles (AZ-ZD through :func:`~tcs.pointing.orientation.to_normal`, RA-DEC through it and
``erfa.hd2ae``) and, with a pointing model, the same through the active model's inverse (where
the model says the tube points). A sample must be clear of the Sun cone and the horizon in
both: neither a large right model nor a wrong one (IE = 9° written at operator level, a bad
Alpaca sync) brings the tube into the cone.

**Margins and escape.** A sample's margin is its distance (degrees) inside the allowed
region, the smallest over the borders. A path is good while every margin is ≥ the margin
asked for (``margin`` for planned slews, 0 for tracked paths). A path that *starts* outside
(the Sun rose onto a parked telescope, a table edited) may leave: leading samples that are
not deeper than the first are allowed; once out, it may not re-enter (``escape``).

**Paths as the axes run them.** :func:`move_samples` predicts a TARGETPOS-like move of both
axes *simultaneously* — each axis its own time-optimal ruckig profile from its current state,
as :class:`~tcs.axes.motion.MotionPlanner` plans them (the axes are not synchronised: the
shorter move ends first) — sampled every ``STEP`` degrees of the faster axis.
:func:`plan_route` judges the direct slew and, when that enters the envelope, detours:
axis 2 (ZD/Dec) first then axis 1, axis 1 first, or axis 2 to an intermediate angle, axis 1,
then the rest — the quickest detour that stays out wins, else :class:`EnvelopeError` (FAILED 9
on OpenTCI) names the border. Routes are executed by :meth:`Envelope.run_route` as
consecutive TARGETPOS moves of both axes.

**Guards.** :meth:`Envelope.guard` is installed on the main axes (``Axis.envelope``) and
judges every other motion request before the axis takes it: TARGETPOS (on the cable-wrap turn
the axis resolved with the planner's rule and will drive) and OFFSET (Sun cone and keep-outs —
engineering moves keep the software limits as before, no horizon); an OFFSET while tracking
(:func:`offset_path`: the offset move and the queued path with it, all borders); a client
TRAJECTORY run (the whole queued path, all borders); ``move_toward`` (Alpaca MoveAxis, jogs:
the move is bounded to stop at the border — while the other axis moves, on the pair's
simultaneous path and on both axes braking from every point of it, :func:`pair_bound`; when
one axis of a pair is stopped, the other's running move is judged again and
``Axis.limit_move`` brings its end nearer); a homing search (each way
its method may sweep, at its search speed, the other axis where it stands, all borders: refused
when a border is within its stopping distance, else the border where the axis halts the run). The other axis is
predicted as it will move: its approved move (recorded here, jogs at their speed), its queued
trajectory, its planner target, or at rest. docs/safety-envelope.md says it for users.

What may touch it
-----------------
The event loop (the POINTING module, the axes' asyncio-side methods, operations). The pure
functions (:func:`sun_icrs`, :func:`move_samples`, :func:`plan_route`) are safe anywhere.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass
from typing import Callable

import erfa
import numpy as np

from tcs.axes.profile import AxisDynamics, ProfileSolver, Setpoint, theoretical_minimum_time
from tcs.errors import ErrorNumber, TcsError, gather_all
from tcs.pointing.orientation import to_normal

__all__ = ["Envelope", "EnvelopeError", "Judgement", "Route", "sun_icrs", "move_samples",
           "plan_route", "pair_bound", "offset_path", "STEP"]

#: degrees between the samples of a predicted slew (along the faster axis)
STEP = 0.25
#: s an axis told to stop (STOP, MoveAxis rate 0) may run on at its speed before its stop
#: starts, as the other axis's running move is judged again (each but 0 at least 5 control
#: cycles; the nearest bound): the control loop takes the stop at its next cycle, from its
#: setpoint, ahead of the reading — on a busy host later. :data:`BRAKE_DELAYS` covers them.
STOP_LEADS = (0.0, 0.1, 0.25)
_SUN_GRID = 300.0         # s between the Sun directions that are interpolated (1.25° apart:
#                           the chord of linear interpolation is within 0.004° of the arc)
_TOL = 1e-6
_WAYPOINT_STEP = 5.0      # degrees between the intermediate axis-2 angles a detour may use
_MODEL_ITERATIONS = 4     # steps of the model's fixed-point inverse: exact for the index terms
#                           (IA, IE); with a badly aligned mount's others (NPAE, CA 3′, AN, AW
#                           6′) within 0.0002° from 3° off the mount's pole on (nearer, the
#                           azimuth means little)


class EnvelopeError(TcsError):
    """A path would enter the envelope (OpenTCI FAILED 9 / SOFTLIMIT)."""

    def __init__(self, message: str):
        super().__init__(message, ErrorNumber.SOFTLIMIT)


# ----------------------------------------------------------------------------------- the Sun

def sun_icrs(utc, tai_utc: float = 37.0):
    """Geocentric direction of the Sun as an ICRS (RA hours, Dec degrees) for Unix ``utc``.

    ``erfa.epv00`` (the Earth's heliocentric position) reversed; fed to the observed-place
    astrometry like a star it gives the Sun's observed place to better than 1′ (see the
    module docstring: light time, parallax and limb deflection are left out).
    """
    t = np.atleast_1d(np.asarray(utc, float))
    tt = (t + tai_utc + 32.184) / 86400.0 + (2440587.5 - 2451545.0)
    pvh, _pvb = erfa.epv00(2451545.0, tt)
    ra, dec = erfa.c2s(-pvh["p"])
    return np.mod(ra, 2 * math.pi) * (12.0 / math.pi), np.degrees(dec)


def _unit(az_deg, alt_deg) -> np.ndarray:
    az, alt = np.radians(az_deg), np.radians(alt_deg)
    return np.stack([np.cos(alt) * np.cos(az), np.cos(alt) * np.sin(az), np.sin(alt)], axis=-1)


# ------------------------------------------------------------------------------ judgements

@dataclass(frozen=True)
class Judgement:
    """Outcome of :meth:`Envelope.judge`: ``good`` leading samples (all of them when the path
    is inside), and why sample ``good`` is not (``reason``: "sun", "horizon", "keepout:NAME")."""

    good: int
    size: int
    reason: str = ""
    text: str = ""

    @property
    def ok(self) -> bool:
        return self.good >= self.size


@dataclass(frozen=True)
class Route:
    """A slew: ``waypoints`` (mechanical (axis1, axis2)) visited one after another before the
    final move to the end; ``duration`` predicted; ``kind`` in words."""

    waypoints: tuple[tuple[float, float], ...]
    end: tuple[float, float]
    duration: float
    kind: str = "direct"


# ------------------------------------------------------------------------- path prediction

def _evaluate(traj, times: np.ndarray) -> np.ndarray:
    """Positions of a 1-DoF ruckig trajectory at ``times`` (vectorised over its 7 phases)."""
    return _states(traj, times)[0]


def _evaluate_many(trajs, times: np.ndarray) -> np.ndarray:
    """Positions of many 1-DoF ruckig trajectories, row ``i`` of ``times`` on ``trajs[i]``
    (vectorised over them; as :func:`_evaluate`)."""
    k = len(trajs)
    cum = np.zeros((k, 8))
    p, v, a, j = (np.zeros((k, 7)) for _ in range(4))
    slow = []
    for i, traj in enumerate(trajs):
        prof = traj.profiles[0][0]
        if prof.brake.duration > 0.0 or len(traj.profiles[0]) != 1:
            slow.append(i)
            continue
        cum[i, 1:] = np.cumsum(prof.t)
        p[i], v[i], a[i], j[i] = prof.p[:7], prof.v[:7], prof.a[:7], prof.j[:7]
    tt = np.clip(times, 0.0, cum[:, -1:])
    phase = np.clip((tt[:, :, None] >= cum[:, None, 1:]).sum(axis=2), 0, 6)
    rows = np.arange(k)[:, None]
    d = tt - cum[rows, phase]
    out = p[rows, phase] + v[rows, phase] * d + a[rows, phase] * d * d / 2.0 + j[rows, phase] * d ** 3 / 6.0
    for i in slow:
        out[i] = _evaluate(trajs[i], times[i])
    return out


def _states(traj, times: np.ndarray):
    """(positions, velocities, accelerations) of a 1-DoF ruckig trajectory at ``times``
    (held at its ends; vectorised over its 7 phases)."""
    prof = traj.profiles[0][0]
    if prof.brake.duration > 0.0 or len(traj.profiles[0]) != 1:
        pva = [traj.at_time(min(max(float(t), 0.0), traj.duration)) for t in times]
        return tuple(np.array([x[i][0] for x in pva]) for i in range(3))
    cum = np.concatenate(([0.0], np.cumsum(prof.t)))
    p, v, a, j = (np.asarray(x, float) for x in (prof.p, prof.v, prof.a, prof.j))
    tt = np.clip(times, 0.0, cum[-1])
    k = np.clip(np.searchsorted(cum, tt, side="right") - 1, 0, 6)
    d = tt - cum[k]
    return (p[k] + v[k] * d + a[k] * d * d / 2.0 + j[k] * d ** 3 / 6.0,
            v[k] + a[k] * d + j[k] * d * d / 2.0, a[k] + j[k] * d)


_SOLVER = ProfileSolver(0.01)


def _traj(start: Setpoint, target: float, dyn: AxisDynamics, speed: float | None):
    return _SOLVER.move(start, target, max_velocity=speed or dyn.max_velocity,
                        max_acceleration=dyn.max_acceleration, max_jerk=dyn.max_jerk,
                        discrete=False)


def move_samples(starts, targets, dynamics, speeds=(None, None), step: float = STEP):
    """Both axes from ``starts`` (Setpoints) to rest at ``targets`` at once, each on its own
    time-optimal profile (as the motion planner runs a TARGETPOS): (times from the start,
    axis-1 positions, axis-2 positions, duration). Sampled every ``step`` degrees of the
    faster axis; the last sample is the end."""
    trajs = [_traj(s, float(t), d, v) for s, t, d, v in zip(starts, targets, dynamics, speeds)]
    duration = max(tr.duration for tr in trajs)
    vmax = max((v or d.max_velocity) for d, v in zip(dynamics, speeds))
    dt = max(min(step / vmax, 1.0), 1e-3)
    n = max(2, int(math.ceil(duration / dt)) + 1)
    times = np.linspace(0.0, duration, n)
    return times, _evaluate(trajs[0], times), _evaluate(trajs[1], times), duration


# --------------------------------------------------------------------------------- envelope

class Envelope:
    """The envelope of one telescope; see the module docstring.

    Parameters
    ----------
    section : the ``[envelope]`` table.
    mount : "AZ-ZD" or "RA-DEC".
    floor : () -> ``[pointing] min_altitude`` (degrees).
    astrometry : () -> the current :class:`~tcs.pointing.astrometry.Astrometry` (site, time).
    utc : () -> now (Unix seconds); ``ut1_utc`` () -> UT1−UTC (the axes' clocks are UT1).
    """

    def __init__(self, section, mount: str, *, floor: Callable[[], float],
                 astrometry: Callable, utc: Callable[[], float] = _time.time,
                 ut1_utc: Callable[[], float] = lambda: 0.0,
                 model: Callable[[], object] | None = None):
        self.section = section
        #: () -> the active :class:`~tcs.pointing.model.PointingModel` (None: no model)
        self._model = model
        self.mount = mount
        self._floor = floor
        self._astrometry = astrometry
        self.utc = utc
        self.ut1_utc = ut1_utc
        rows = sorted((float(az) % 360.0, float(alt)) for az, alt in section.horizon)
        self._haz = np.array([r[0] for r in rows])
        self._halt = np.array([r[1] for r in rows])
        self.keepouts = [(k.name, float(k.axis1[0]), float(k.axis1[1]), float(k.axis2[0]),
                          float(k.axis2[1])) for k in section.keepout]
        self._sun_cache: dict[tuple[int, int], np.ndarray] = {}
        #: id(axis) -> the move approved last: (ut1 t0, trajectory, target (drive frame),
        #: speed, jog) — ``jog`` (direction, sky) for a move_toward, else None
        self._approved: dict[int, tuple] = {}
        self.axes: tuple = ()

    # -- borders --------------------------------------------------------------------------------
    @property
    def sun_radius(self) -> float:
        return float(self.section.sun_avoidance)

    @property
    def margin(self) -> float:
        return float(self.section.margin)

    def min_altitude(self, az) -> np.ndarray:
        """The horizon: the table at ``az`` (degrees), never below ``[pointing] min_altitude``."""
        az = np.mod(np.asarray(az, float), 360.0)
        floor = float(self._floor())
        if not self._haz.size:
            return np.full_like(az, floor)
        table = np.interp(az, self._haz, self._halt, period=360.0)
        return np.maximum(table, floor)

    def model(self):
        """The active pointing model when it has a term that is not 0, else None."""
        model = self._model() if self._model is not None else None
        if model is None or not any(v != 0.0 for v in model.coefficients.values()):
            return None
        return model

    def readings(self, a1, a2) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every sky (az, alt) the tube may point to at mechanical ``a1``, ``a2``: the bare
        axis angles, and — with a pointing model — the angles through the model's inverse
        (where the model says the tube points). A sample must be clear of the borders in
        both: a wrong model (IE = 9° written by hand) cannot bring the tube into the cone,
        nor can a right one whose terms are large."""
        out = [self.sky(a1, a2)]
        model = self.model()
        if model is not None:
            m1, m2 = np.asarray(a1, float), np.asarray(a2, float)
            i1, i2 = m1, m2
            for _ in range(_MODEL_ITERATIONS):   # the model's fixed-point inverse, a few steps
                d1, d2 = model.corrections(i1, i2)
                i1, i2 = m1 - d1, m2 - d2
            out.append(self.sky(i1, i2))
        return out

    def sky(self, a1, a2):
        """(az, alt) degrees of mechanical axis angles (pointing model left out: see
        :meth:`readings`)."""
        n1, n2, _rev = to_normal(np.asarray(a1, float), np.asarray(a2, float), self.mount)
        if self.mount == "AZ-ZD":
            return np.mod(n1, 360.0), 90.0 - np.asarray(n2)
        lat = math.radians(self._astrometry().site.latitude)
        az, alt = erfa.hd2ae(np.radians(n1), np.radians(n2), lat)
        return np.degrees(az), np.degrees(alt)

    def sun_vectors(self, utc) -> np.ndarray:
        """Unit vectors (east-of-north az frame) of the observed Sun at ``utc``."""
        utc = np.asarray(utc, float)
        astro = self._astrometry()
        key_site = hash((astro.site, astro.timebase))
        lo, hi = math.floor(utc.min() / _SUN_GRID), math.floor(utc.max() / _SUN_GRID) + 1
        grid = np.arange(lo, hi + 1)
        vecs = np.empty((grid.size, 3))
        missing = [i for i, g in enumerate(grid) if (key_site, int(g)) not in self._sun_cache]
        if missing:
            if len(self._sun_cache) > 4000:
                self._sun_cache.clear()
                missing = list(range(grid.size))
            tg = grid[missing] * _SUN_GRID
            ra, dec = sun_icrs(tg, astro.timebase.tai_utc)
            obs = astro.observed(ra, dec, tg)
            v = _unit(obs.az, 90.0 - np.asarray(obs.zd))
            for i, vec in zip(missing, v):
                self._sun_cache[(key_site, int(grid[i]))] = vec
        for i, g in enumerate(grid):
            vecs[i] = self._sun_cache[(key_site, int(g))]
        x = utc / _SUN_GRID - lo
        i = np.clip(np.floor(x).astype(int), 0, grid.size - 2)
        f = (x - i)[..., None]
        out = vecs[i] * (1 - f) + vecs[i + 1] * f
        return out / np.linalg.norm(out, axis=-1, keepdims=True)

    def sun_altaz(self, utc) -> tuple[float, float]:
        """(az, alt) degrees of the Sun now-ish (for texts and tests)."""
        v = self.sun_vectors(np.array([float(utc)]))[0]
        return math.degrees(math.atan2(v[1], v[0])) % 360.0, math.degrees(math.asin(v[2]))

    def margins(self, a1, a2, utc, *, horizon: bool = True, sun: bool = True,
                keepouts: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Per sample: degrees inside the allowed region (negative: inside a border) and which
        border is nearest (an index into :meth:`reasons`: "sun", "horizon", "keepout:NAME")."""
        a1 = np.atleast_1d(np.asarray(a1, float))
        a2 = np.atleast_1d(np.asarray(a2, float))
        m = np.full(a1.shape, np.inf)
        why = np.zeros(a1.shape, dtype=np.int8)
        need_sun = sun and self.sun_radius > 0.0
        readings = self.readings(a1, a2) if horizon or need_sun else []
        for az, alt in readings:
            if horizon:
                h = np.asarray(alt) - self.min_altitude(az)
                worse = h < m
                m = np.where(worse, h, m)
                why[worse] = 1
        if need_sun:
            utc = np.broadcast_to(np.asarray(utc, float), a1.shape)
            s = self.sun_vectors(utc).reshape(-1, 3)
            for az, alt in readings:
                t = _unit(az, alt)
                sep = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", s, t.reshape(-1, 3)),
                                                   -1.0, 1.0))).reshape(a1.shape)
                d = sep - self.sun_radius
                worse = d < m
                m = np.where(worse, d, m)
                why[worse] = 2
        if keepouts:
            for i, (_name, lo1, hi1, lo2, hi2) in enumerate(self.keepouts):
                width = (hi1 - lo1) % 360.0 or 360.0
                centre = lo1 + width / 2.0
                dx = np.abs(np.remainder(a1 - centre + 180.0, 360.0) - 180.0) - width / 2.0
                dy = np.abs(a2 - (lo2 + hi2) / 2.0) - (hi2 - lo2) / 2.0
                k = np.maximum(dx, dy)
                worse = k < m
                m = np.where(worse, k, m)
                why[worse] = 3 + i
        return m, why

    def reason(self, code: int) -> str:
        """The name of a border code of :meth:`margins`."""
        code = int(code)
        if code >= 3:
            return f"keepout:{self.keepouts[code - 3][0]}"
        return ("", "horizon", "sun")[code]

    def describe(self, reason: str, a1: float, a2: float) -> str:
        """Words for a border."""
        if reason == "sun":
            return f"the Sun avoidance cone ({self.sun_radius:g}° around the Sun)"
        if reason == "horizon":
            az, _alt = self.sky(a1, a2)
            return f"the horizon limit ({float(self.min_altitude(az)):.1f}° altitude at azimuth {float(az):.1f}°)"
        if reason.startswith("keepout:"):
            return f"the keep-out zone {reason.split(':', 1)[1]!r}"
        return reason

    def judge(self, a1, a2, utc, *, margin: float = 0.0, escape: bool = True, **which) -> Judgement:
        """How many leading samples of the path (a1, a2 at Unix ``utc``) are inside the
        envelope by at least ``margin`` degrees (escape rule: module docstring)."""
        a1 = np.atleast_1d(np.asarray(a1, float))
        a2 = np.atleast_1d(np.asarray(a2, float))
        m, why = self.margins(a1, a2, utc, **which)
        bad = m < margin - _TOL
        n = a1.size
        if not bad.any():
            return Judgement(n, n)
        first = 0
        if escape and bad[0]:
            deeper = m < m[0] - 1e-3
            out = np.flatnonzero(~bad)
            leave = int(out[0]) if out.size else n
            deep = np.flatnonzero(deeper[:leave])
            if deep.size:
                first = int(deep[0])
            else:
                rest = np.flatnonzero(bad[leave:])
                if not rest.size:
                    return Judgement(n, n)
                first = leave + int(rest[0])
        else:
            first = int(np.flatnonzero(bad)[0])
        reason = self.reason(why[first])
        return Judgement(first, n, reason, self.describe(reason, a1[first], a2[first]))

    # -- planning -------------------------------------------------------------------------------
    def check_move(self, t0_utc: float, starts, targets, dynamics, speeds=(None, None), *,
                   margin: float | None = None, escape: bool = True, **which) -> Judgement:
        """Judge the simultaneous move of both axes (see :func:`move_samples`)."""
        times, p1, p2, _d = move_samples(starts, targets, dynamics, speeds)
        return self.judge(p1, p2, t0_utc + times, margin=self.margin if margin is None else margin,
                          escape=escape, **which)

    # -- guards of the axes ---------------------------------------------------------------------
    def attach(self, axis1, axis2) -> None:
        """Install :meth:`guard` on the main axes."""
        self.axes = (axis1, axis2)
        axis1.envelope = self.guard
        axis2.envelope = self.guard

    def _engineering(self) -> dict:
        on = bool(self.section.engineering_sun)
        return dict(horizon=False, sun=on, keepouts=on)

    def _state(self, axis) -> Setpoint:
        return Setpoint(float(axis.real_position), float(axis.current_speed), 0.0)

    def _predict(self, axis, times_ut1: np.ndarray) -> np.ndarray:
        """Where ``axis`` (mechanical frame) will be at ``times_ut1`` when left alone."""
        return self._prediction(axis, float(times_ut1[0]))[0](times_ut1)

    def _prediction(self, axis, t0: float):
        """(positions at UT1 times, UT1 when the motion ends) of ``axis`` left alone from
        ``t0``: its approved move (a young one as approved, an older one re-planned from where
        the axis is, at its speed), its queued trajectory, its planner target, or at rest."""
        record = self._approved.get(id(axis))
        if record is not None:
            start, traj, target, speed, _jog = record
            young = t0 - start < 1.0    # (the loop may not have published the target yet)
            if start + traj.duration > t0 - 1.0 and (
                    young or abs(axis.target_position + axis.offset - target) < 1e-6):
                if young:
                    return (lambda t, s=start, tr=traj: _evaluate(tr, np.asarray(t) - s)), start + traj.duration
                if not axis.motion_state & 1:
                    here = float(axis.real_position)
                    return (lambda t: np.full(np.shape(t), here)), t0
                tr = _traj(self._state(axis), target, axis.dynamics, speed)
                return (lambda t, tr=tr: _evaluate(tr, np.asarray(t) - t0)), t0 + tr.duration
            self._approved.pop(id(axis), None)
        if axis.trajectory_running and len(axis.queue):
            return (lambda t: self._queued(axis, np.asarray(t, float))), float(axis.queue.end_time)
        if axis.motion_state & 1:
            tr = _traj(self._state(axis), axis.target_position + axis.offset, axis.dynamics, _speed(axis))
            return (lambda t, tr=tr: _evaluate(tr, np.asarray(t) - t0)), t0 + tr.duration
        here = float(axis.real_position)
        return (lambda t: np.full(np.shape(t), here)), t0

    @staticmethod
    def _queued(axis, times_ut1: np.ndarray) -> np.ndarray:
        q = axis.queue
        start, end = q.start_time, q.end_time
        t = np.clip(times_ut1, start, end)
        out = np.array([q.sample(float(x))[0] for x in t]) + axis.offset
        follower = axis.follower
        shift = getattr(follower, "shift", 0.0) if follower is not None else 0.0
        if axis.section.cyclic and not axis.trajectory_running:
            # not yet running: the follower will take the turn nearest the axis
            c = axis.section.cyclic
            shift = c * round((axis.real_position - out[0]) / c)
        return out + (shift or 0.0)

    def _refuse(self, axis, what: str, j: Judgement, a1, a2) -> None:
        raise EnvelopeError(f"{axis.module_name}: {what} would enter {j.text}")

    def guard(self, axis, kind: str, value=None, **kw):
        """Judge a motion request of ``axis`` (one of the main axes) before it is taken;
        raises :class:`EnvelopeError`. ``kind``: "target" (TARGETPOS value, offset excluded),
        "offset", "run" (the queued TRAJECTORY), "points" (value: (times, positions) added by
        ADDPOINTS to a running trajectory), "jog" (value: direction; returns the
        (lo, hi) drive bound where the move must stop; ``sky=True``: the horizon too),
        "homing" (value: a direction the homing search may sweep; see :meth:`_homing_bound`)."""
        a_first = axis is self.axes[0]
        other = self.axes[1] if a_first else self.axes[0]
        ut1 = self.utc() + self.ut1_utc()
        if kind == "homing":
            return self._homing_bound(axis, other, int(value), ut1, kw.get("speed"), kw.get("reach", 0.0))
        if kind == "jog":
            return self._jog_bound(axis, other, int(value), ut1, bool(kw.get("sky")), kw.get("speed"))
        if kind == "moving":   # the move_toward accepted: (goal, speed, direction)
            goal, speed, direction = value
            self.moving(axis, goal, speed, direction, bool(kw.get("sky")))
            return None
        if kind == "stop":
            self.stopping(axis)
            return None
        if kind == "points":   # ADDPOINTS while the trajectory runs: the new points
            which = dict(horizon=True, sun=True, keepouts=True)
            times = np.asarray(value[0], float)
            follower = axis.follower
            own = np.asarray(value[1], float) + axis.offset + (getattr(follower, "shift", 0.0) or 0.0)
            keep = times >= ut1
            times, own = times[keep], own[keep]
            if not times.size:
                return None
            path = self._predict(other, times)
            a1, a2 = (own, path) if a_first else (path, own)
            j = self.judge(a1, a2, times - self.ut1_utc(), margin=0.0, escape=False, **which)
            if not j.ok:
                raise EnvelopeError(f"{axis.module_name}: trajectory point {j.good} would enter {j.text}")
            return None
        if kind == "run":
            which = dict(horizon=True, sun=True, keepouts=True)
            what = "its trajectory"
            q = axis.queue
            if not len(q):
                return None
            t0, t1 = max(ut1, q.start_time), q.end_time
            if t1 <= t0:
                return None
            n = int(min(20000, max(2, (t1 - t0) / 0.5)))
            times = np.linspace(t0, t1, n)
            own = self._queued(axis, times)
            path = self._predict(other, times)
            # the intercept from where the axis stands: a straight line in axis angles
            lead = np.linspace(float(axis.real_position), float(own[0]), 20)
            lead_other = np.full(lead.shape, float(path[0]))
            own = np.concatenate((lead, own))
            path = np.concatenate((lead_other, path))
            times = np.concatenate((np.full(lead.shape, t0), times))
        else:
            which = self._engineering()
            if not (which["sun"] and self.sun_radius > 0.0) and not (which["keepouts"] and self.keepouts):
                return None
            if kind == "target":
                target = float(value) + axis.offset
                what = f"TARGETPOS {float(value):g}"
            else:   # offset: the target shifts by the change
                if axis.trajectory_running:
                    return self._tracked_offset(axis, other, float(value), ut1)
                target = axis.target_position + float(value)
                what = f"OFFSET {float(value):g}"
            traj = _traj(self._state(axis), target, axis.dynamics, _speed(axis))
            vmax = axis.dynamics.max_velocity
            n = max(2, int(math.ceil(traj.duration * vmax / STEP)) + 1)
            times = ut1 + np.linspace(0.0, traj.duration, n)
            own = _evaluate(traj, times - ut1)
            path = self._predict(other, times)
        a1, a2 = (own, path) if a_first else (path, own)
        j = self.judge(a1, a2, times - self.ut1_utc(), margin=0.0, **which)
        if not j.ok:
            self._refuse(axis, what, j, a1, a2)
        if kind in ("target", "offset"):
            self._approved[id(axis)] = (ut1, traj, target, _speed(axis), None)
        return None

    def _tracked_offset(self, axis, other, value: float, ut1: float) -> None:
        """An OFFSET while ``axis`` runs a trajectory (tracking), judged before it is applied:
        the offset move and the queued path with the new offset to its end
        (:func:`offset_path`), with the other axis as it will move; every border (a tracked
        path keeps the horizon too). Raises :class:`EnvelopeError` (FAILED 9)."""
        q = axis.queue
        if not len(q) or q.end_time is None:
            return None
        times, own = offset_path(lambda t: self._queued(axis, t), ut1, float(q.end_time),
                                 float(axis.offset), value, axis.dynamics)
        other_path = self._predict(other, times)
        a1, a2 = (own, other_path) if axis is self.axes[0] else (other_path, own)
        j = self.judge(a1, a2, times - self.ut1_utc(), margin=0.0,
                       horizon=True, sun=True, keepouts=True)
        if not j.ok:
            raise EnvelopeError(f"{axis.module_name}: OFFSET {value:g} while tracking would enter {j.text}")
        return None

    def approve(self, axis, target_mech: float) -> None:
        """Record a move this module planned itself (routes), so that the other axis's guard
        predicts it."""
        ut1 = self.utc() + self.ut1_utc()
        self._approved[id(axis)] = (ut1, _traj(self._state(axis), target_mech, axis.dynamics, None),
                                    target_mech, None, None)

    def _jog_bound(self, axis, other, direction: int, ut1: float, sky: bool, speed, brakes: bool = True):
        sec = axis.section
        here = float(axis.real_position)
        end = float(sec.max if direction > 0 else sec.min)
        if (end - here) * direction <= 0:
            return None
        which = dict(horizon=True, sun=True, keepouts=True) if sky else self._engineering()
        if not which["horizon"] and not (which["sun"] and self.sun_radius > 0.0) \
                and not (which["keepouts"] and self.keepouts):
            return None
        speed = float(speed or sec.max_velocity)
        other_path, other_end = self._prediction(other, ut1)
        probe = np.linspace(ut1, max(other_end, ut1), 50)
        still = float(other.real_position)
        if other_end > ut1 + 1e-3 and np.ptp(np.append(other_path(probe), still)) > 1e-6:
            return self._pair_bound(axis, direction, end, ut1, which, speed, other_path, other_end, brakes)
        n = int(abs(end - here) / (STEP / 2)) + 2
        pos = np.linspace(here, end, n)
        times = ut1 + np.abs(pos - here) / speed   # when the jog gets there (at least)
        fixed = np.full(pos.shape, float(other.real_position))
        a1, a2 = (pos, fixed) if axis is self.axes[0] else (fixed, pos)
        j = self.judge(a1, a2, times - self.ut1_utc(), margin=0.0, **which)
        if j.ok:
            return None
        if j.good == 0:
            raise EnvelopeError(f"{axis.module_name}: moving {'up' if direction > 0 else 'down'} "
                                f"would enter {j.text}")
        good, bad = float(pos[j.good - 1]), float(pos[j.good])
        first = axis is self.axes[0]
        still = float(other.real_position)
        floor = min(0.0, float(self.margins(*((here, still) if first else (still, here)),
                                            ut1 - self.ut1_utc(), **which)[0][0]))
        for _ in range(30):   # the border to ~1e-10 degrees (the move plans its stop there)
            mid = 0.5 * (good + bad)
            when = ut1 + abs(mid - here) / speed - self.ut1_utc()
            m = self.margins(*((mid, still) if first else (still, mid)), when, **which)[0][0]
            if m >= floor - _TOL and (floor < 0.0 or m >= 0.0):
                good = mid
            else:
                bad = mid
        return good

    def _homing_bound(self, axis, other, direction: int, ut1: float, speed, reach: float):
        """A homing (referencing) search of ``axis`` sweeping in ``direction`` at ``speed``
        from where it stands, the other axis where it is: every border (Sun cone, horizon,
        keep-outs) on the way up to the software limit. Returns None (none), or
        ``(border, words)``: the drive position where the sweep would enter and what it would
        enter (the axis stops the run there); raises :class:`EnvelopeError` when the border is
        within ``reach`` (the run's stopping distance) — refused before it starts."""
        way = "up" if direction > 0 else "down"
        try:
            border = self._jog_bound(axis, other, direction, ut1, True, speed)
        except EnvelopeError as exc:
            text = exc.message.split(" would enter ", 1)[-1]
            raise EnvelopeError(f"{axis.module_name}: referencing refused: its homing search ({way}) "
                                f"would enter {text} at once") from None
        if border is None:
            return None
        here, still = float(axis.real_position), float(other.real_position)
        beyond = border + direction * STEP / 2.0
        first = axis is self.axes[0]
        _m, why = self.margins(*((beyond, still) if first else (still, beyond)),
                               ut1 + STEP / 2.0 / float(speed or axis.section.max_velocity) - self.ut1_utc())
        words = self.describe(self.reason(why[0]), *((beyond, still) if first else (still, beyond)))
        if (border - here) * direction <= reach:
            raise EnvelopeError(f"{axis.module_name}: referencing refused: its homing search ({way}) "
                                f"would enter {words} {abs(border - here):.2f}° from here, within its "
                                f"stopping distance {reach:.2f}° (move the other axis away first)")
        return border, words

    def _pair_bound(self, axis, direction: int, end: float, ut1: float, which: dict, speed: float,
                    other_path, other_end: float, brakes: bool = True):
        """:func:`pair_bound` of a move of ``axis`` while the other axis moves."""
        try:
            return pair_bound(self, ut1, self._state(axis), axis.dynamics, direction, end, speed,
                              other_path, other_end, axis is self.axes[0], which,
                              other_dyn=self._other(axis).dynamics, brakes=brakes)
        except EnvelopeError as exc:
            raise EnvelopeError(f"{axis.module_name}: moving {'up' if direction > 0 else 'down'} "
                                f"while {self._other(axis).module_name} moves would enter "
                                f"{exc.message}") from None

    def _other(self, axis):
        if not self.axes:
            return None
        return self.axes[1] if axis is self.axes[0] else self.axes[0]

    def moving(self, axis, goal: float, speed: float, direction: int, sky: bool) -> None:
        """A move_toward of ``axis`` was accepted (to rest at the drive position ``goal`` at
        ``speed``): recorded, so that the other axis's judgements predict it."""
        ut1 = self.utc() + self.ut1_utc()
        self._approved[id(axis)] = (ut1, _traj(self._state(axis), goal, axis.dynamics, speed),
                                    float(goal), float(speed), (int(direction), bool(sky)))

    def stopping(self, axis) -> None:
        """``axis`` was told to stop (STOP, MoveAxis rate 0): the other axis's running
        move_toward was bounded on the pair's path with this one moving on; judged again with
        this one stopping where it does — from its reading, and from it run on at its speed for
        each of :data:`STOP_LEADS` (the stop starts from the setpoint when the loop takes it),
        the nearest bound — and its end brought nearer when that path would enter the envelope
        (never further)."""
        other = self._other(axis)
        if other is None:
            return
        ut1 = self.utc() + self.ut1_utc()
        state = self._state(axis)
        dyn = axis.dynamics

        def approve_stop(start: Setpoint) -> None:
            stop = _SOLVER.stop(start, max_velocity=max(dyn.max_velocity, abs(start.velocity)),
                                max_acceleration=dyn.stop_acceleration, max_jerk=dyn.stop_jerk,
                                discrete=False)
            self._approved[id(axis)] = (ut1, stop, float(stop.at_time(stop.duration)[0][0]), None, None)

        def bound_of_other() -> float | None:
            try:
                # (the other axis's stop is under way: its path is a stop, and the move of this
                # one to the bound, braking from anywhere, stays on it — fast, without judging
                # both braking from every point: the new end must reach the loop soon)
                return self._jog_bound(other, axis, direction, ut1, sky, speed, brakes=False)
            except EnvelopeError:
                return float(other.real_position)   # stop it now

        record = self._approved.get(id(other))
        if record is None or record[4] is None or not other.motion_state & 1 \
                or abs(other.target_position + other.offset - record[2]) > 1e-6:
            approve_stop(state)
            return
        _t0, _traj_o, goal, speed, (direction, sky) = record
        # (the stop starts where the axis's setpoint is when the control loop takes it: a cycle
        # or more later, ahead of the reading by the drive's lag — on a busy host more: judged
        # from the reading and from it run on at its speed for each lead, the nearest bound;
        # the reading's stop stays approved. The pair's path was bounded so that both axes can
        # brake from any point of it with the stop that late: the nearest bound is a goal)
        cycles = 5.0 * float(getattr(axis, "dt", 0.01))
        bounds = []
        for lead in STOP_LEADS[::-1]:
            run = abs(state.velocity) * (max(lead, cycles) if lead > 0.0 else 0.0)
            if lead > 0.0 and run <= 0.0:
                continue
            approve_stop(Setpoint(state.position + math.copysign(run, state.velocity), state.velocity, 0.0))
            bounds.append(bound_of_other())
        limited = [b for b in bounds if b is not None]
        bound = (min(limited) if direction > 0 else max(limited)) if limited else None
        if bound is not None and (goal - bound) * direction > 1e-9:
            self.moving(other, bound, speed, direction, sky)
            other.limit_move(bound)

    async def run_route(self, route: Route, axis1, axis2) -> None:
        """Move through ``route.waypoints`` (each a TARGETPOS of both axes, awaited) — the
        final move is the caller's (a tracking intercept or :meth:`goto`)."""
        for w1, w2 in route.waypoints:
            self.approve(axis1, w1)
            self.approve(axis2, w2)
            await gather_all(axis1.set_target(w1 - axis1.offset, checked=True),
                             axis2.set_target(w2 - axis2.offset, checked=True))

    def plan_goto(self, axis1, axis2, d1: float, d2: float, *, horizon: bool = False) -> Route:
        """The route of a goto of the main axes to TARGETPOS ``d1``/``d2`` (offset excluded)."""
        return plan_route(self, self.utc(), (self._state(axis1), self._state(axis2)),
                          (d1 + axis1.offset, d2 + axis2.offset),
                          (axis1.dynamics, axis2.dynamics),
                          ((axis1.section.min, axis1.section.max), (axis2.section.min, axis2.section.max)),
                          horizon=horizon, sun=True, keepouts=True)

    async def goto(self, axis1, axis2, d1: float, d2: float, *, horizon: bool = False) -> None:
        """A planned goto of both main axes (operations: horizontal goto, park, home)."""
        route = self.plan_goto(axis1, axis2, d1, d2, horizon=horizon)
        await self.run_route(route, axis1, axis2)
        self.approve(axis1, d1 + axis1.offset)
        self.approve(axis2, d2 + axis2.offset)
        await gather_all(axis1.set_target(d1, checked=True), axis2.set_target(d2, checked=True))


def _speed(axis) -> float | None:
    planner = getattr(axis, "planner", None)
    return float(planner.speed) if planner is not None else None


#: s the start of a move may lag behind its judgement (the command reaches the control loop a
#: cycle or more later; the other axis's state is a cycle old): the simultaneous path of two
#: axes is judged with each of these delays of the new move
PAIR_DELAYS = (0.0, 0.1, 0.25)
#: degrees a pair's path keeps from the borders: its samples are 0.25° apart along the faster
#: axis and the Sun's direction is interpolated (0.004°); a bound at the border itself would
#: graze it between samples (a 0.01° dip below a horizon table's corner was seen)
PAIR_MARGIN = 0.05
#: (this axis, the other) s by which each axis's braking may start late, as every point of a
#: pair's path is judged with both axes braking from it: a stop told to one axis reaches the
#: control loop a cycle or more later, and the other's move is bounded again only then (a
#: stalled host: later still; past the drives' RPDO deadline both brake by themselves)
BRAKE_DELAYS = (((0.0, 0.0),) + tuple((d, 0.0) for d in STOP_LEADS if d > 0.0)
                + tuple((0.0, d) for d in STOP_LEADS if d > 0.0))
#: at most this many points of a pair's path are judged for both axes braking from them (at
#: least every STEP degrees of the faster axis below that)
BRAKE_POINTS = 120
_BRAKE_LATE = sorted({d for pair in BRAKE_DELAYS for d in pair})   # each delay once
_BRAKE_SAMPLES = 16       # samples of the two axes braking from one point of the path
_FD = 0.02                # s: the finite differences that give the other axis's speed


def _stop_of(p: float, v: float, a: float, dyn: AxisDynamics):
    """The axis from (p, v, a) to rest with its normal deceleration and jerk (a quick stop
    brakes harder: its path is part of this one)."""
    a = max(-dyn.max_acceleration, min(dyn.max_acceleration, a))
    return _SOLVER.stop(Setpoint(p, v, a), max_velocity=max(dyn.max_velocity, abs(v)),
                        max_acceleration=dyn.max_acceleration, max_jerk=dyn.max_jerk, discrete=False)


def pair_bound(env: Envelope, ut1: float, state: Setpoint, dyn: AxisDynamics, direction: int,
               end: float, speed: float, other_path: Callable, other_end: float, first: bool,
               which: dict, delays=PAIR_DELAYS, *, other_dyn: AxisDynamics,
               brakes: bool = True) -> float | None:
    """The bound of a move of one main axis (axis 1 when ``first``) from ``state`` towards
    ``end`` at ``speed`` while the other axis moves (``other_path``: UT1 times -> its predicted
    positions, at rest after ``other_end``; ``other_dyn`` its limits): the farthest rest
    position ``g`` such that the two axes' simultaneous path — this axis on the profile the
    planner runs to rest at ``g`` (its own deceleration), the other on its own — stays out of
    the envelope, also when this move starts up to ``delays`` late, **and so does every way
    both axes can brake from any point of it** (each with its normal deceleration, either one
    starting up to :data:`BRAKE_DELAYS` later: a client stops one axis of the pair, the other
    is bounded again then; a stalled master; a lost link; ``brakes`` False: not judged) — None
    when ``end`` itself is good.
    The result is always a ``g`` whose path was judged good (the bisection keeps the good
    end). Raises :class:`EnvelopeError` (the border's words) when even braking now is not
    good."""
    brake = _SOLVER.stop(state, max_velocity=max(dyn.max_velocity, abs(state.velocity)),
                         max_acceleration=dyn.max_acceleration, max_jerk=dyn.max_jerk,
                         discrete=False)
    rest = float(brake.at_time(brake.duration)[0][0])
    lo = rest if (rest - state.position) * direction > 0 else float(state.position)
    ut1_utc = env.ut1_utc()
    probe = np.linspace(ut1, max(other_end, ut1 + 1e-3), 400)
    there = other_path(probe)
    other_speed = float(np.max(np.abs(np.diff(there)))) / (probe[1] - probe[0])
    vmax = max(speed, abs(state.velocity), 1.2 * other_speed, 1e-3)
    why = ["the envelope"]
    # the other axis's own path may run to a border (its move bounded there): the pair keeps
    # PAIR_MARGIN, or what the other's path alone keeps, if that is less
    still = np.full(probe.shape, float(state.position))
    alone, _w = env.margins(*((still, there) if first else (there, still)), probe - ut1_utc, **which)
    margin = max(0.0, min(PAIR_MARGIN, float(alone.min())))

    # (both axes braking from points of the path: the points, every STEP degrees of the faster
    # axis up to BRAKE_POINTS, to where the longest move to ``end`` and the other's both ended;
    # the other's braking from each, at each of its delays, is the same for every goal)
    if brakes:
        longest = max(_traj(state, end, dyn, speed).duration, _traj(state, lo, dyn, speed).duration)
        last = max(ut1 + longest, other_end)
        k = int(min(BRAKE_POINTS, max(2, math.ceil((last - ut1) * vmax / STEP) + 1)))
        points = np.linspace(ut1, last, k)
        late = _BRAKE_LATE
        reach = max(late) + 0.05
        other_brakes = {}
        for d in late:
            s = points + d
            p0, p1, p2 = other_path(s), other_path(s + _FD), other_path(s + 2 * _FD)
            v = (-3.0 * p0 + 4.0 * p1 - p2) / (2 * _FD)
            a = (p0 - 2.0 * p1 + p2) / (_FD * _FD)
            other_brakes[d] = (p0, v, [_stop_of(float(x), float(y), float(z), other_dyn)
                                       for x, y, z in zip(p0, v, a)])
        fast = max(speed, abs(state.velocity))
        span = reach + max(max(b.duration for _p, _v, bs in other_brakes.values() for b in bs),
                           _stop_of(state.position, fast * direction, dyn.max_acceleration * direction,
                                    dyn).duration)
        offsets = np.linspace(0.0, span, _BRAKE_SAMPLES)
        grid = points[:, None] + offsets[None, :]          # UT1 of every braking sample
        there_grid = other_path(grid.ravel()).reshape(grid.shape)
        final = float(other_path(np.array([max(other_end, ut1)]))[0])
        other_at = {}
        for d, (p0, v, stops) in other_brakes.items():
            pos = _evaluate_many(stops, np.broadcast_to(np.clip(offsets - d, 0.0, None), grid.shape))
            # (a stop with the normal deceleration from a point of a move to rest goes no further
            # than that move's end: its speed is known from differences only, held to the end)
            ahead = np.sign(v) * (final - p0) > 0.0
            pos = np.where((ahead & (v > 0))[:, None], np.minimum(pos, final), pos)
            pos = np.where((ahead & (v < 0))[:, None], np.maximum(pos, final), pos)
            other_at[d] = np.where(offsets[None, :] < d, there_grid, pos)

    def brakes_clear(traj) -> bool:
        own_grid = _evaluate(traj, (grid - ut1).ravel()).reshape(grid.shape)
        own_at = {}
        for d in late:
            ps, vs, accs = _states(traj, points + d - ut1)
            pos = np.repeat(ps[:, None], offsets.size, axis=1)   # (at rest: stays)
            moving = np.flatnonzero((np.abs(vs) > 1e-12) | (np.abs(accs) > 1e-12))
            if moving.size:
                stops = [_stop_of(float(ps[i]), float(vs[i]), float(accs[i]), dyn) for i in moving]
                pos[moving] = _evaluate_many(stops, np.broadcast_to(np.clip(offsets - d, 0.0, None),
                                                                     (moving.size, offsets.size)))
            own_at[d] = np.where(offsets[None, :] < d, own_grid, pos)
        for d_own, d_other in BRAKE_DELAYS:
            own, there = own_at[d_own], other_at[d_other]
            a1, a2 = (own, there) if first else (there, own)
            m, w = env.margins(a1.ravel(), a2.ravel(), grid.ravel() - ut1_utc, **which)
            m = m.reshape(grid.shape)
            # (from a point already inside a border — a pair leaving it — no deeper than there)
            need = np.minimum(margin, m[:, :1])
            bad = m < need - _TOL
            if bad.any():
                i = int(np.flatnonzero(bad.ravel())[0])
                why[0] = env.describe(env.reason(w[i]), a1.ravel()[i], a2.ravel()[i])
                return False
        return True

    def path_good(goal: float, brakes: bool = False) -> bool:
        traj = _traj(state, goal, dyn, speed)
        horizon = max(ut1 + traj.duration, other_end) + max(delays)
        n = max(2, int(math.ceil((horizon - ut1) * vmax / STEP)) + 1)
        times = np.linspace(ut1, horizon, n)
        there = other_path(times)
        for delay in delays:
            own = _evaluate(traj, np.clip(times - ut1 - delay, 0.0, None))
            a1, a2 = (own, there) if first else (there, own)
            j = env.judge(a1, a2, times - ut1_utc, margin=margin, **which)
            if not j.ok:
                why[0] = j.text
                return False
        return brakes_clear(traj) if brakes else True

    def good(goal: float) -> bool:
        return path_good(goal, brakes)

    def bisect(test, lo: float, hi: float) -> float:
        for _ in range(24):
            mid = 0.5 * (lo + hi)
            if test(mid):
                lo = mid
            else:
                hi = mid
            if abs(hi - lo) < 1e-4:
                break
        return lo

    if good(end):
        return None
    if not good(lo):
        raise EnvelopeError(why[0])
    # (the bound on the pair's path first, cheap; both axes braking from its points judged
    # at that bound, and only where they would enter, the bound on both from there: nearer)
    bound = bisect(path_good, lo, end)
    if not brakes or abs(bound - lo) < 1e-12 or good(bound):
        return bound
    return bisect(good, lo, bound)


def offset_path(path: Callable, ut1: float, end: float, old: float, new: float,
                dyn: AxisDynamics):
    """An OFFSET change from ``old`` to ``new`` on a tracked path (``path``: UT1 times -> the
    drive positions with ``old``, queued up to ``end``): (UT1 times, drive positions) from
    ``ut1`` to the path's end — the change as a rest-to-rest profile of the axis's dynamics
    added to the path (the follower's intercept of ``path + offset``), sampled every half
    ``STEP`` of the change while it moves, then every 0.5 s."""
    change = float(new) - float(old)
    blend = _traj(Setpoint(0.0), change, dyn, None)
    t_blend = blend.duration
    t1 = max(float(end), ut1 + t_blend)
    dense = np.linspace(ut1, ut1 + t_blend, max(2, int(math.ceil(abs(change) / (STEP / 2))) + 1))
    times = dense
    if t1 > ut1 + t_blend:
        sparse = np.linspace(ut1 + t_blend, t1, int(min(20000, max(2, (t1 - ut1 - t_blend) / 0.5))))
        times = np.concatenate((dense, sparse[1:]))
    return times, path(times) + _evaluate(blend, times - ut1)


def _leg_estimate(a: tuple[float, float], b: tuple[float, float], dynamics) -> float:
    return max(theoretical_minimum_time(b[0] - a[0], dynamics[0]),
               theoretical_minimum_time(b[1] - a[1], dynamics[1]))


def plan_route(env: Envelope, t0_utc: float, starts, end, dynamics, ranges, *, horizon: bool = True,
               sun: bool = True, keepouts: bool = True, margin: float | None = None) -> Route:
    """The quickest way from the axes' states ``starts`` (Setpoints, mechanical) to rest at
    ``end`` (mechanical (axis1, axis2)) that stays ``margin`` inside the envelope: the direct
    slew, else a detour (module docstring). ``ranges``: ((lo1, hi1), (lo2, hi2)) software
    limits the waypoints stay inside. Raises :class:`EnvelopeError` when no way is found (also
    when the end itself is outside)."""
    margin = env.margin if margin is None else margin
    which = dict(horizon=horizon, sun=sun, keepouts=keepouts)
    end = (float(end[0]), float(end[1]))
    here = (float(starts[0].position), float(starts[1].position))
    # the end itself (a tracked target's start is judged by its owner with margin 0)
    m_end, why_end = env.margins([end[0]], [end[1]], t0_utc, **which)
    if m_end[0] < 0.0:
        raise EnvelopeError(f"the target is inside {env.describe(env.reason(why_end[0]), *end)}")
    margin = min(margin, float(m_end[0]))   # (a target near a border: the path keeps its distance)
    first = margin
    if any(abs(st.velocity) > 1e-9 or abs(st.acceleration) > 1e-9 for st in starts):
        # the axes are moving (a slew superseded): their braking happens whatever comes next;
        # the first leg may go as deep as that brake would (it was judged when it was planned)
        brake = [_SOLVER.stop(st, max_velocity=max(d.max_velocity, abs(st.velocity)),
                              max_acceleration=d.max_acceleration, max_jerk=d.max_jerk, discrete=False)
                 for st, d in zip(starts, dynamics)]
        bt = np.linspace(0.0, max(b.duration for b in brake), 50)
        mb, _w = env.margins(_evaluate(brake[0], bt), _evaluate(brake[1], bt), t0_utc + bt, **which)
        first = min(margin, float(mb.min()))
    (lo1, hi1), (lo2, hi2) = ranges
    candidates: list[tuple[str, tuple]] = [("direct", ()), ("axis 2 first", ((here[0], end[1]),)),
                                           ("axis 1 first", ((end[0], here[1]),))]
    grid = np.arange(math.ceil(lo2 / _WAYPOINT_STEP) * _WAYPOINT_STEP, hi2 + 1e-9, _WAYPOINT_STEP)
    for w in grid:
        if abs(w - here[1]) > 1e-9 and abs(w - end[1]) > 1e-9:
            candidates.append((f"via axis 2 at {w:g}", ((here[0], float(w)), (end[0], float(w)))))
    # waypoints inside the envelope (or outside the limits) rule their candidate out at once
    flat = [w for _k, wps in candidates for w in wps]
    wm, _why = env.margins([w[0] for w in flat], [w[1] for w in flat], t0_utc, **which)
    good_wp = {w: (m >= margin and lo1 <= w[0] <= hi1 and lo2 <= w[1] <= hi2) for w, m in zip(flat, wm)}
    candidates = [(k, wps) for k, wps in candidates if all(good_wp[w] for w in wps)]
    scored = []
    for kind, wps in candidates:
        pts = (here,) + wps + (end,)
        est = sum(_leg_estimate(pts[i], pts[i + 1], dynamics) for i in range(len(pts) - 1))
        scored.append((est, kind, wps))
    scored.sort(key=lambda s: s[0])
    first_failure = None
    for _est, kind, wps in scored:
        t = t0_utc
        start = starts
        ok = True
        legs = wps + (end,)
        for i, goal in enumerate(legs):
            if not (lo1 <= goal[0] <= hi1 and lo2 <= goal[1] <= hi2):
                ok = False
                break
            times, p1, p2, duration = move_samples(start, goal, dynamics)
            j = env.judge(p1, p2, t + times, margin=first if i == 0 else margin, escape=(i == 0), **which)
            if not j.ok:
                if first_failure is None:
                    first_failure = j
                ok = False
                break
            t += duration
            start = (Setpoint(goal[0]), Setpoint(goal[1]))
        if ok:
            return Route(tuple(wps), end, t - t0_utc, kind)
    text = first_failure.text if first_failure is not None else "the envelope"
    raise EnvelopeError(f"no slew path stays out of {text}: refused (no detour found)")
