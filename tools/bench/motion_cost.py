"""Benchmark of the axes motion core: CPU per control cycle, slew time, path error.

Run: ``python3 tools/bench/motion_cost.py``. Prints the figures, then (last line) one JSON
object with them. Goals: a planner or follower step well below 50 µs (6 axes share a 10 ms
cycle with the CAN traffic), slews within 2 % of the theoretical minimum time, and a setpoint
stream within 0.1″ of the ideal path.

Cases:

* ``planner_step_us`` — :meth:`MotionPlanner.step` during a long move (and ``planner_idle_us``
  at rest), ``planner_set_target_us`` — one new target (a ruckig calculation plus the limit
  check).
* ``follower_step_us`` — :meth:`TrajectoryFollower.step` while following a sidereal path far
  from the limits; ``follower_step_near_limit_us`` — the same within the braking distance of a
  limit (the guard computes an exact ruckig stop each cycle); ``follower_intercept_us`` —
  while on the intercept profile; ``follower_plan_us`` — the one cycle that plans a 90°
  intercept (ruckig profiles plus the path's dynamics over the horizon).
* ``slew`` — rest-to-rest moves of AZ (v=5°/s, a=2°/s², j=5°/s³) and ZD (v=3, a=1.5, j=4):
  planner cycles × dt against :func:`theoretical_minimum_time` (the planner's moves last a
  whole number of cycles, so the ratio is at most ``1 + dt/T``).
* ``intercept`` — time from rest onto a sidereal path 1° and 30° away against the minimum
  time of a rest-to-rest move of that distance.
* ``path error`` — setpoints while following against the analytic path (arcsec, RMS and max):
  a sidereal-rate track (15″/s with curvature) and a fast sinusoid (2°, period 60 s, 0.21°/s)
  with points every 2 s (and 1 s); "interior" leaves out the first and last 3 segments, where
  the derivative stencils are one-sided. For comparison, the interpolation error of a cubic Hermite with
  centred-difference (Catmull-Rom) slopes on the same sinusoid.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np

from tcs.axes import (
    AxisDynamics,
    FollowerState,
    MotionPlanner,
    Setpoint,
    SoftLimits,
    TrajectoryFollower,
    TrajectoryQueue,
    theoretical_minimum_time,
)

DT = 0.01
T0 = 1.7e9
AZ = AxisDynamics(5.0, 2.0, 5.0)
ZD = AxisDynamics(3.0, 1.5, 4.0)
ARCSEC = 1.0 / 3600.0


def best_us(fn, n: int, repeats: int = 5) -> float:
    """Best of ``repeats`` runs of ``fn(n)`` (which does n operations): µs of CPU per op."""
    best = math.inf
    for _ in range(repeats):
        t0 = time.process_time()
        fn(n)
        best = min(best, (time.process_time() - t0) / n * 1e6)
    return best


# -- CPU per cycle ------------------------------------------------------------------------------

def planner_costs() -> dict:
    def steps(n):
        p = MotionPlanner(AZ, SoftLimits(-270, 270), DT)
        p.set_target(260.0)                        # ~55 s: never finishes within n steps
        for _ in range(n):
            p.step()

    def idle(n):
        p = MotionPlanner(AZ, SoftLimits(-270, 270), DT)
        for _ in range(n):
            p.step()

    def targets(n):
        p = MotionPlanner(AZ, SoftLimits(-270, 270), DT)
        for i in range(n):
            p.set_target(10.0 + (i % 7))
            p.step()

    return {"planner_step_us": best_us(steps, 5000),
            "planner_idle_us": best_us(idle, 20000),
            "planner_set_target_us": best_us(targets, 2000)}


def sidereal(x):
    return 120.0 + 15.041 * ARCSEC * x + 2e-7 * x ** 2 - 1e-10 * x ** 3


def make_follower(f, duration, start_pos, limits=SoftLimits(-270, 270), spacing=2.0):
    q = TrajectoryQueue(5000)
    x = np.arange(0.0, duration + spacing / 2, spacing)
    q.add_points(T0 + x, f(x))
    fo = TrajectoryFollower(q, AZ, limits, DT, low_points_time=30.0)
    fo.start(T0, Setpoint(start_pos))
    return fo


def follower_costs() -> dict:
    def following(n, limits=SoftLimits(-270, 270)):
        fo = make_follower(sidereal, 3000.0, sidereal(0.0), limits)
        cur = Setpoint(sidereal(0.0))
        for k in range(1, 50):                      # onto the path first
            cur = fo.step(T0 + k * DT, cur).setpoint
        assert fo.state is FollowerState.FOLLOWING
        t0 = time.process_time()
        for k in range(50, 50 + n):
            cur = fo.step(T0 + k * DT, cur).setpoint
        return time.process_time() - t0

    def timed(fn, n):
        return min(fn(n) for _ in range(5)) / n * 1e6

    def near_limit(n):
        # limit 1.3 s of path ahead: from 0.5 s on the cheap bound no longer clears it and
        # the guard computes the exact stop each cycle; the stop point reaches it at ~1.1 s
        limits = SoftLimits(-270, sidereal(1.3))
        total = 0.0
        for _ in range(n // 50):
            fo = make_follower(sidereal, 100.0, sidereal(0.0), limits)
            cur = Setpoint(sidereal(0.0))
            for k in range(1, 50):
                cur = fo.step(T0 + k * DT, cur).setpoint
            t0 = time.process_time()
            for k in range(50, 100):
                cur = fo.step(T0 + k * DT, cur).setpoint
            total += time.process_time() - t0
            assert fo.state is FollowerState.FOLLOWING
        return total

    def plan(n):
        total = 0.0
        for _ in range(n):
            fo = make_follower(sidereal, 600.0, 30.0)      # first cycle plans a 90° intercept
            t0 = time.process_time()
            fo.step(T0 + DT, Setpoint(30.0))
            total += time.process_time() - t0
        return total

    def intercepting(n):
        total = 0.0
        done = 0
        while done < n:
            fo = make_follower(sidereal, 600.0, 30.0)   # a 90° slew onto the path: ~21 s
            cur = Setpoint(30.0)
            t0 = time.process_time()
            k = 0
            while fo.state is FollowerState.INTERCEPTING and done < n:
                k += 1
                cur = fo.step(T0 + k * DT, cur).setpoint
                done += 1
            total += time.process_time() - t0
        return total

    return {"follower_step_us": timed(following, 20000),
            "follower_step_near_limit_us": timed(near_limit, 2000),
            "follower_plan_us": timed(plan, 200),
            "follower_intercept_us": timed(intercepting, 2000)}


# -- slews and intercepts -----------------------------------------------------------------------

def slew(dyn: AxisDynamics, distance: float) -> tuple[float, float]:
    p = MotionPlanner(dyn, SoftLimits(), DT)
    p.set_target(distance)
    n = 0
    while p.moving:
        p.step()
        n += 1
    return n * DT, theoretical_minimum_time(distance, dyn)


def intercept_time(distance: float) -> tuple[float, float]:
    fo = make_follower(sidereal, 600.0, sidereal(0.0) - distance)
    cur = Setpoint(sidereal(0.0) - distance)
    k = 0
    while fo.state is not FollowerState.FOLLOWING:
        k += 1
        cur = fo.step(T0 + k * DT, cur).setpoint
    return k * DT, theoretical_minimum_time(distance, AZ)


# -- path error ---------------------------------------------------------------------------------

def stream_error(f, duration: float, spacing: float = 2.0) -> dict:
    fo = make_follower(f, duration, float(f(0.0)), SoftLimits(), spacing)
    cur = Setpoint(float(f(0.0)))
    errs, ts = [], []
    k = 0
    while fo.state is not FollowerState.ENDED:
        k += 1
        t = T0 + k * DT
        cur = fo.step(t, cur).setpoint
        if fo.state is FollowerState.FOLLOWING:
            errs.append(cur.position - float(f(t - T0)))
            ts.append(t - T0)
    e = np.abs(np.array(errs)) / ARCSEC
    ts = np.array(ts)
    inner = (ts > 3 * spacing) & (ts < duration - 3 * spacing)
    return {"rms": float(np.sqrt(np.mean(e[inner] ** 2))), "max": float(e[inner].max()),
            "max_all": float(e.max())}


def catmull_rom_error(f, duration: float, spacing: float = 2.0) -> float:
    """Interior max error (arcsec) of a cubic Hermite with centred-difference slopes."""
    x = np.arange(0.0, duration + spacing / 2, spacing)
    y = f(x)
    m = np.gradient(y, x)                      # centred differences inside
    xq = np.linspace(3 * spacing, duration - 3 * spacing, 20001)
    i = np.searchsorted(x, xq) - 1
    h = x[i + 1] - x[i]
    s = (xq - x[i]) / h
    h00, h10 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s
    h01, h11 = -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
    yq = h00 * y[i] + h10 * h * m[i] + h01 * y[i + 1] + h11 * h * m[i + 1]
    return float(np.abs(yq - f(xq)).max() / ARCSEC)


def main() -> None:
    figures: dict = {}
    figures.update(planner_costs())
    figures.update(follower_costs())
    for k in ("planner_step_us", "planner_idle_us", "planner_set_target_us", "follower_step_us",
              "follower_step_near_limit_us", "follower_intercept_us", "follower_plan_us"):
        print(f"{k:30s} {figures[k]:8.2f} µs")

    slews = {}
    print("\nslew                    planner s   minimum s   ratio")
    for name, dyn, distances in (("AZ", AZ, (1.0, 10.0, 90.0, 180.0)),
                                 ("ZD", ZD, (1.0, 10.0, 45.0, 90.0))):
        for d in distances:
            t, tmin = slew(dyn, d)
            slews[f"{name}_{d:g}"] = {"time_s": round(t, 3), "min_s": round(tmin, 4),
                                      "ratio": round(t / tmin, 5)}
            print(f"{name} {d:6g}°              {t:9.3f}   {tmin:9.4f}   {t / tmin:.5f}")
    figures["slew"] = slews
    figures["slew_worst_ratio"] = max(s["ratio"] for s in slews.values())

    intercepts = {}
    print("\nintercept onto a sidereal path   time s   rest-to-rest minimum s   ratio")
    for d in (1.0, 30.0):
        t, tmin = intercept_time(d)
        intercepts[f"{d:g}deg"] = {"time_s": round(t, 3), "min_s": round(tmin, 4),
                                   "ratio": round(t / tmin, 4)}
        print(f"{d:5g}°                           {t:7.3f}   {tmin:9.4f}            {t / tmin:.4f}")
    figures["intercept"] = intercepts

    w = 2 * math.pi / 60.0
    sinus = lambda x: 2.0 * np.sin(w * x)     # noqa: E731 - a path, named for the print
    figures["error_sidereal_arcsec"] = stream_error(sidereal, 1200.0)
    figures["error_sinusoid_arcsec"] = stream_error(sinus, 600.0)
    figures["error_sinusoid_1s_arcsec"] = stream_error(sinus, 600.0, spacing=1.0)
    figures["catmull_rom_sinusoid_max_arcsec"] = catmull_rom_error(sinus, 600.0)
    print("\nsetpoints vs ideal path (arcsec)    rms         max interior   max incl. ends")
    for k, label in (("error_sidereal_arcsec", "sidereal 15\"/s, 2 s points"),
                     ("error_sinusoid_arcsec", "sinusoid 2°/60 s, 2 s points"),
                     ("error_sinusoid_1s_arcsec", "sinusoid 2°/60 s, 1 s points")):
        e = figures[k]
        print(f"{label:34s} {e['rms']:.3e}   {e['max']:.3e}      {e['max_all']:.3e}")
    print(f"(Catmull-Rom cubic on the same sinusoid, 2 s points: max "
          f"{figures['catmull_rom_sinusoid_max_arcsec']:.3f}\")")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
