"""Benchmark of fast targets: LEO passes planned and followed by the axes' own follower.

Run: ``python3 tools/bench/satellite_pass.py [--config hwconfig/sim.toml] [--spacing 0.5]``.
Prints the figures, then (last line) one JSON object with them.

For four passes of the ISS (the element set of skyfield's documentation, January 2014:
culminations at 59°, 72°, 82° and 86°) over the site of the hardware file, with the AZ and ZD
limits of its ``[axes.az]`` / ``[axes.zd]``:

* **plan** (:meth:`tcs.pointing.targets.SatelliteTarget.plan`): rise, duration, highest
  altitude, largest rate on the sky and of AZ, cable-wrap turn (AZ at rise and set), keyhole
  (AZ leads on a bridge; its largest pointing error), feasible; and the time it takes;
* **following** (:func:`tcs.pointing.follow_check.follow`): the whole pass sampled every
  ``--spacing`` s as the tracker does, followed cycle by cycle (10 ms) by
  :class:`~tcs.axes.follower.TrajectoryFollower` within the axes' speed, acceleration and jerk:
  error of the setpoints against the planned path (RMS, max, arcsec; goal < 1″ RMS) and
  against the satellite itself (differs inside a keyhole bridge only), cycles an axis was
  limited; wall time of the simulation.
* **cost** of the target's path per sample (SGP4 + skyfield + the observed place).
"""

from __future__ import annotations

import argparse
import json
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np

from tcs.axes.profile import AxisDynamics
from tcs.pointing.astrometry import Astrometry, Site, TimeBase
from tcs.pointing.follow_check import follow
from tcs.pointing.targets import SatelliteTarget

ISS = ("1 25544U 98067A   14020.93268519  .00009878  00000-0  18200-3 0  5082",
       "2 25544  51.6498 109.4756 0003572  55.9686 274.8005 15.50377579 39831")
CULMINATIONS = (1390214651.47, 1390470877.9, 1390185227.8, 1390524930.27)


def main() -> None:
    warnings.simplefilter("ignore")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(Path(__file__).parents[2] / "hwconfig" / "sim.toml"))
    ap.add_argument("--spacing", type=float, default=SatelliteTarget.spacing)
    ap.add_argument("--min-altitude", type=float, default=15.0)
    args = ap.parse_args()
    cfg = tomllib.loads(Path(args.config).read_text())
    site = Site(cfg["site"]["latitude"], cfg["site"]["longitude"], cfg["site"]["height"])
    az, zd = cfg["axes"]["az"], cfg["axes"]["zd"]
    dyn_az = AxisDynamics(az["max_velocity"], az["max_acceleration"], az["max_jerk"])
    dyn_zd = AxisDynamics(zd["max_velocity"], zd["max_acceleration"], zd["max_jerk"])
    ast = Astrometry(site, TimeBase(35.0, 0.0))
    sat = SatelliteTarget(line1=ISS[0], line2=ISS[1], name="ISS")
    rows = []
    print(f"site {site.latitude:.4f} {site.longitude:.4f} {site.height:.0f} m; AZ {az['max_velocity']}°/s "
          f"{az['max_acceleration']}°/s² {az['max_jerk']}°/s³, range {az['min']}…{az['max']}; "
          f"ZD {zd['max_velocity']}°/s; points every {args.spacing} s")
    for culm in CULMINATIONS:
        t0 = time.perf_counter()
        plan = sat.plan(ast, zd_limit=90.0 - args.min_altitude, utc=culm - 1500.0,
                        az_range=(az["min"], az["max"]),
                        az_limits=(az["max_velocity"], az["max_acceleration"], az["max_jerk"]),
                        zd_limits=(zd["max_velocity"], zd["max_acceleration"], zd["max_jerk"]))
        t_plan = time.perf_counter() - t0
        target = sat.planned(plan, 0.0)
        t0 = time.perf_counter()
        res = follow(target, ast, plan.rise, plan.set, az=dyn_az, zd=dyn_zd, az_start=plan.az_start,
                     spacing=args.spacing)
        t_follow = time.perf_counter() - t0
        row = dict(max_alt=round(plan.max_altitude, 2), duration=round(plan.duration, 1),
                   max_rate=round(plan.max_rate, 3), max_az_rate=round(plan.max_az_rate, 3),
                   az_start=round(plan.az_start, 2), az_end=round(plan.az_end, 2),
                   keyhole=plan.keyhole, keyhole_error_deg=round(plan.keyhole_error, 3),
                   feasible=plan.feasible, plan_s=round(t_plan, 3),
                   rms_arcsec=round(res.rms, 4), max_arcsec=round(res.max, 4),
                   sky_rms_arcsec=round(res.sky_rms, 2), limited_cycles=res.limited_cycles,
                   cycles=res.cycles, follow_s=round(t_follow, 2))
        rows.append(row)
        print(f"pass {row['max_alt']:5.1f}°: {row['duration']:5.0f} s, sky {row['max_rate']:.2f}°/s, "
              f"AZ ≤ {row['max_az_rate']:.2f}°/s, AZ {row['az_start']:+.1f} → {row['az_end']:+.1f}, "
              f"keyhole {'yes' if plan.keyhole else 'no'} ({row['keyhole_error_deg']}°), feasible {plan.feasible}; "
              f"followed: {row['rms_arcsec']}″ RMS, {row['max_arcsec']}″ max of the planned path, "
              f"{row['sky_rms_arcsec']}″ RMS of the satellite, {row['limited_cycles']} limited cycles; "
              f"plan {row['plan_s']} s, simulation {row['follow_s']} s")
    t = CULMINATIONS[0] + np.arange(0.0, 100.0, args.spacing)
    t0 = time.perf_counter()
    for _ in range(5):
        sat.observed(ast, t)
    cost = (time.perf_counter() - t0) / (5 * t.size) * 1e6
    print(f"path cost: {cost:.1f} µs per sample ({t.size} samples per call)")
    print(json.dumps({"passes": rows, "path_us_per_sample": round(cost, 2), "spacing": args.spacing}))


if __name__ == "__main__":
    main()
