"""How well the main axes follow a target's path: an offline run of the real follower.

How it works
------------
:func:`follow` samples a target (:mod:`tcs.pointing.targets`) the way the tracker does —
points ``spacing`` seconds apart (UT1 = UTC here), AZ unwrapped onto the planned turn — into
the axes' own :class:`~tcs.axes.trajectory.TrajectoryQueue` and runs their
:class:`~tcs.axes.follower.TrajectoryFollower` cycle by cycle (10 ms) in simulated time,
within the axes' speed, acceleration and jerk limits. Each setpoint is compared with the
target's exact path at that instant (``target.observed``; for a planned satellite with a
keyhole bridge that is the planned path, and :attr:`FollowResult.sky_rms` is against the
satellite itself). No pointing model (the demand is the observed Az/ZD): what is measured is
sampling, interpolation and following. Used by ``tests/test_targets.py`` and
``tools/bench/satellite_pass.py``.

What may touch it: anything (pure computation, no clock, no I/O).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcs.axes.follower import TrajectoryFollower
from tcs.axes.limits import SoftLimits
from tcs.axes.profile import AxisDynamics, Setpoint
from tcs.axes.trajectory import TrajectoryQueue

__all__ = ["FollowResult", "follow", "separation_arcsec"]


def separation_arcsec(az1, zd1, az2, zd2):
    """Angle between two Az/ZD directions (degrees in), arcsec; exact at small angles."""
    a1, z1, a2, z2 = (np.radians(np.asarray(x, float)) for x in (az1, zd1, az2, zd2))
    v1 = np.stack([np.sin(z1) * np.cos(a1), np.sin(z1) * np.sin(a1), np.cos(z1)])
    v2 = np.stack([np.sin(z2) * np.cos(a2), np.sin(z2) * np.sin(a2), np.cos(z2)])
    cross = np.linalg.norm(np.cross(v1, v2, axis=0), axis=0)
    return np.degrees(np.arctan2(cross, (v1 * v2).sum(axis=0))) * 3600.0


@dataclass(frozen=True)
class FollowResult:
    """Errors of the followed path (arcsec on the sky), and what the axes used."""

    rms: float
    max: float
    sky_rms: float          # against the target itself (differs only inside a keyhole bridge)
    sky_max: float
    max_az_rate: float      # of the setpoints, °/s
    max_zd_rate: float
    limited_cycles: int     # cycles an axis could not follow the path (its limits)
    cycles: int


def follow(target, astrometry, t0: float, t1: float, *, az: AxisDynamics, zd: AxisDynamics,
           az_start: float | None = None, spacing: float | None = None,
           dt: float = 0.01) -> FollowResult:
    """Follow ``target`` from UTC ``t0`` to ``t1`` (see the module docstring); the axes start
    on the path. ``az_start``: AZ (mechanical) at ``t0`` on the chosen cable-wrap turn."""
    spacing = spacing or target.spacing or 1.0
    pad = 4 * spacing
    times = np.arange(t0 - pad, t1 + pad + spacing / 2, spacing)
    obs = target.observed(astrometry, times)
    p_az = np.unwrap(np.asarray(obs.az, float), period=360.0)
    if az_start is not None:
        i0 = int(np.searchsorted(times, t0))
        p_az += 360.0 * round((az_start - p_az[i0]) / 360.0)
    p_zd = np.asarray(obs.zd, float)
    lanes = []
    for path, dyn, cyclic in ((p_az, az, 360.0), (p_zd, zd, None)):
        q = TrajectoryQueue(times.size + 8, cycle=cyclic)
        q.add_points(list(times), list(path), None)
        f = TrajectoryFollower(q, dyn, SoftLimits(cycle=cyclic), dt)
        p, v, a = q.sample(t0)
        cur = Setpoint(p, v, a)
        f.start(t0, cur, shift=0.0)
        lanes.append([f, cur])
    steps = np.arange(t0 + dt, t1, dt)
    out = np.empty((2, steps.size))
    limited = 0
    for i, t in enumerate(steps):
        for k, lane in enumerate(lanes):
            step = lane[0].step(float(t), lane[1])
            lane[1] = step.setpoint
            out[k, i] = step.setpoint.position
        limited += lanes[0][0].limited or lanes[1][0].limited
    exact = target.observed(astrometry, steps)
    err = separation_arcsec(out[0], out[1], exact.az, exact.zd)
    sky = target.sky(astrometry, steps) if hasattr(target, "sky") else exact
    err_sky = separation_arcsec(out[0], out[1], sky.az, sky.zd)
    rates = np.abs(np.diff(out, axis=1)) / dt
    return FollowResult(float(math.sqrt(np.mean(err ** 2))), float(err.max()),
                        float(math.sqrt(np.mean(err_sky ** 2))), float(err_sky.max()),
                        float(rates[0].max()), float(rates[1].max()), int(limited), int(steps.size))
