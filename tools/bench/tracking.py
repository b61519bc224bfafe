"""Benchmark of POINTING.TRACK: a star tracked in the simulated telescope for T seconds.

Run: ``python3 tools/bench/tracking.py [--seconds 60] [--config hwconfig/sim.toml]
[--mode csp,ip,csv,ip/csv]``. Prints the figures, then (last line) one JSON object with them.

``--mode`` runs the benchmark once per item, one after the other, and prints the figures side
by side: an item is the drive mode of both axes (``csp``, ``ip``, ``csv``: ``[drives.x] mode``
of the first two axes' drives) or ``AZMODE/ZDMODE`` (``ip/csv``: AZ in IP, ZD in CSV). The
control loop runs as a thread of the service here (the record callback and the simulated
drives' counters need it in this process); **missed setpoints** are the SYNCs at which a
simulated drive enabled in a streaming mode had no fresh RPDO (``rpdo_missed``).

The service runs in-process (simulated CiA-402 drives on a virtual CAN bus, the real control
loop); the benchmark powers and references the axes, tracks a star near where they stand and,
once both axes follow the path, records every control cycle for T seconds (a callback on the
cycle source, after the control loop's):

* **setpoint path error** — the setpoints sent to AZ and ZD (minus the follower's cable-wrap
  shift and OFFSET) against the ideal astrometric path at the setpoint's own UT1 time, computed
  independently per sample with ``erfa.atco13`` (full context per sample, same site, DUT1 and
  refraction, no pointing model): the angle on the sky, RMS and max, arcsec. Goal < 0.01″ RMS.
  It sums the tracker's fast astrometry (cached contexts), the trajectory queue's
  interpolation between points and the follower.
* **following error** — the encoders (REALPOS at each SYNC) against the same ideal path at the
  SYNC time: what the telescope really does (drive dynamics, encoder resolution), RMS/max.
* **cost per computed sample** — CPU µs per sample of the tracker's computation
  (``Pipeline.demand``: astrometry + orientation + model) for a refill batch, and of the
  astrometry alone; ``erfa.atco13`` per sample for comparison. Goal < 10 µs (astrometry).
* **CPU share** — process CPU time over wall time while tracking (simulated drives, control
  loop, tracker together), and the tracker's own share (time inside its point computation).
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import math
import tempfile
import time
import uuid
from pathlib import Path

import erfa
import numpy as np

from tcs.app import Service
from tcs.config import DEFAULT_CONFIG, load_config
from tcs.config.sections import StateSection
from tcs.pointing.astrometry import HUMIDITY, WAVELENGTH_UM

ARCSEC = 3600.0


def make_config(path: Path, state: Path, modes: tuple[str, str] | None = None):
    config = load_config(path)
    changes = dict(server=dataclasses.replace(config.server, port=0, opentsi_port=-1),
                   web=dataclasses.replace(config.web, port=-1), indi=dataclasses.replace(config.indi, port=-1),
                   alpaca=dataclasses.replace(config.alpaca, port=-1),
                   state=StateSection(path=str(state)))
    if config.can is not None and config.can.interface == "virtual":
        changes["can"] = dataclasses.replace(config.can, channel=f"bench-{uuid.uuid4().hex[:8]}",
                                             control_process=False)
    # a loaded machine delays the loop thread's heartbeat now and then: the drives wait 5 s
    drives = {name: dataclasses.replace(d, heartbeat_consumer_timeout=max(
        d.heartbeat_consumer_timeout, 5.0)) for name, d in config.drives.items()}
    changes["drives"] = drives
    if modes is not None:
        mount = [a for a in config.axes.values() if a.module in ("AZ", "ZD", "HA", "DEC")]
        for axis, mode in zip(mount[:2], modes):
            drives[axis.drive] = dataclasses.replace(drives[axis.drive], mode=mode)
        changes["drives"] = drives
    new = dataclasses.replace(config, **changes)
    object.__setattr__(new, "source", config.source)
    return new


def ideal_azzd(pointing, ra_h, dec, utc):
    """The reference: erfa.atco13 per sample, degrees (az, zd)."""
    a = pointing.astrometry()
    site, tb = a.site, a.timebase
    phpa, tc = a.refraction.conditions(site.height)
    days = np.floor(utc / 86400.0)
    d1, d2 = 2440587.5 + days, (utc - days * 86400.0) / 86400.0
    az, zd, *_ = erfa.atco13(ra_h * math.pi / 12.0, math.radians(dec), 0.0, 0.0, 0.0, 0.0,
                             d1, d2, tb.ut1_utc, math.radians(site.longitude),
                             math.radians(site.latitude), site.height, 0.0, 0.0, phpa, tc,
                             HUMIDITY, WAVELENGTH_UM)
    return np.degrees(az), np.degrees(zd)


def sky_error(az, zd, ref_az, ref_zd):
    """Angle on the sky (degrees) between (az, zd) and the reference, small-angle form."""
    daz = (az - ref_az + 180.0) % 360.0 - 180.0
    return np.hypot(daz * np.sin(np.radians(ref_zd)), zd - ref_zd)


def cpu_us(fn, n: int) -> float:
    best = math.inf
    for _ in range(5):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, (time.process_time() - t0) / n)
    return best * 1e6


async def run(seconds: float, config_path: Path, modes: tuple[str, str] | None = None) -> dict:
    with tempfile.TemporaryDirectory() as state:
        service = Service(make_config(config_path, Path(state), modes))
        await service.start()
        tel = service.telescope
        try:
            return await track(tel, seconds)
        finally:
            await service.stop()


async def track(tel, seconds: float) -> dict:
    p = tel.pointing
    az_axis, zd_axis = p.axis1, p.axis2
    await tel.cabinet.set_power(1)
    tel.cabinet.set_reinit(0)
    t_deadline = time.monotonic() + 300.0
    while min(az_axis.referenced, zd_axis.referenced) < 1.0:  # (the others may still home)
        assert time.monotonic() < t_deadline, "the axes were not referenced"
        await asyncio.sleep(0.1)
    # a star near where the axes stand (short slew), 35° from the zenith
    utc0 = time.time() + 10.0
    ra, dec = p.astrometry().icrs_from_observed((az_axis.real_position + 20.0) % 360.0, 35.0, utc0)
    p.target.set_ra(ra)
    p.target.set_dec(dec)
    done = p.set_track(1)
    session = p._session
    spent = [0.0, 0]
    original = session._points

    def timed(*args, **kw):       # instrumentation: CPU time inside the point computation
        t0 = time.process_time()
        out = original(*args, **kw)
        spent[0] += time.process_time() - t0
        spent[1] += out.times.size
        return out

    session._points = timed
    t_deadline = time.monotonic() + 120.0
    while not all(a.follower.state.value == "following" for a in (az_axis, zd_axis)):
        assert time.monotonic() < t_deadline, "the axes never reached the path"
        await asyncio.sleep(0.1)
    await asyncio.sleep(2.0)
    rows: list[tuple] = []
    ut1, mono = tel.local.ut1, time.monotonic
    period = tel.control_loop.reach_delay

    def record(cycle) -> None:   # after the control loop's step, same thread
        now = mono()
        u = ut1()
        t_sp = u + (cycle.next_sync - now) + period          # the loop's setpoint time
        t_meas = u - (now - cycle.sync_time)                  # the SYNC the positions belong to
        rows.append((t_sp, az_axis._sp.position, zd_axis._sp.position, t_meas,
                     az_axis.real_position, zd_axis.real_position,
                     az_axis.follower.state.value == "following"
                     and zd_axis.follower.state.value == "following"))

    source = tel.can.cycle
    sims = list(tel.sims.values()) if tel.sims is not None else []
    missed0 = sum(s.rpdo_missed for s in sims)
    spent_before = spent[:]
    cpu0, wall0 = time.process_time(), time.monotonic()
    source.add_callback(record)
    try:
        await asyncio.sleep(seconds)
    finally:
        source.remove_callback(record)
    cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
    tracker_cpu = spent[0] - spent_before[0]
    missed = sum(s.rpdo_missed for s in sims) - missed0
    modes_used = [getattr(a.drive, "cyclic_mode", None) for a in (az_axis, zd_axis)]
    shift, off1, off2 = az_axis.follower.shift, az_axis.offset, zd_axis.offset
    p.set_track(0)
    await done
    data = np.array([r[:6] for r in rows])
    following = np.array([r[6] for r in rows])
    data = data[following]
    ut1_utc = p.ut1_utc
    ref_az, ref_zd = ideal_azzd(p, ra, dec, data[:, 0] - ut1_utc)
    sp_err = sky_error(data[:, 1] - shift - off1, data[:, 2] - off2, ref_az, ref_zd) * ARCSEC
    mref_az, mref_zd = ideal_azzd(p, ra, dec, data[:, 3] - ut1_utc)
    fol_err = sky_error(data[:, 4] - shift - off1, data[:, 5] - off2, mref_az, mref_zd) * ARCSEC
    # cost per computed sample, on the tracker's own objects
    pipe = p.pipeline()
    base = time.time()
    refill = int(round(tel.config.pointing.horizon - tel.config.pointing.refill_below
                       )) / tel.config.pointing.sample_spacing
    n_refill = max(2, int(refill))
    times = base + tel.config.pointing.sample_spacing * np.arange(n_refill)
    shift_t = [0.0]

    def demand_batch():
        shift_t[0] += n_refill * tel.config.pointing.sample_spacing
        pipe.demand(ra, dec, times + shift_t[0], False)

    def astro_batch():
        shift_t[0] += n_refill * tel.config.pointing.sample_spacing
        pipe.astrometry.observed(ra, dec, times + shift_t[0])

    demand_us = cpu_us(demand_batch, 200) / n_refill
    astro_us = cpu_us(astro_batch, 200) / n_refill
    atco_us = cpu_us(lambda: ideal_azzd(p, ra, dec, times), 20) / n_refill
    return {
        "seconds": round(wall, 2),
        "cycles": int(len(rows)),
        "cycles_following": int(following.sum()),
        "setpoint_error_rms_arcsec": float(np.sqrt(np.mean(sp_err ** 2))),
        "setpoint_error_max_arcsec": float(sp_err.max()),
        "following_error_rms_arcsec": float(np.sqrt(np.mean(fol_err ** 2))),
        "following_error_max_arcsec": float(fol_err.max()),
        "demand_us_per_sample": demand_us,
        "astrometry_us_per_sample": astro_us,
        "atco13_us_per_sample": atco_us,
        "refill_batch": n_refill,
        "process_cpu_share": cpu / wall,
        "tracker_cpu_share": tracker_cpu / wall,
        "tracker_points": spent[1],
        "target_zd_deg": float(ref_zd.mean()),
        "missed_setpoints": int(missed) if sims else None,
        "modes": "/".join(m.name if m is not None else "?" for m in modes_used),
    }


def side_by_side(runs: list[tuple[str, dict]]) -> None:
    """The figures of several runs in columns (the first run is the reference: ratios)."""
    rows = [("modes (AZ/ZD)", lambda r: r["modes"]),
            ("tracked s", lambda r: f"{r['seconds']:.1f}"),
            ("cycles following", lambda r: f"{r['cycles_following']}/{r['cycles']}"),
            ("path error RMS \"", lambda r: f"{r['setpoint_error_rms_arcsec']:.5f}"),
            ("path error max \"", lambda r: f"{r['setpoint_error_max_arcsec']:.5f}"),
            ("following error RMS \"", lambda r: f"{r['following_error_rms_arcsec']:.4f}"),
            ("following error max \"", lambda r: f"{r['following_error_max_arcsec']:.4f}"),
            ("missed setpoints", lambda r: str(r["missed_setpoints"])),
            ("process CPU %", lambda r: f"{100 * r['process_cpu_share']:.1f}")]
    ref = runs[0][1]
    rows.append((f"fol. RMS / {runs[0][0]}", lambda r: f"{r['following_error_rms_arcsec'] / max(ref['following_error_rms_arcsec'], 1e-12):.2f}"))
    rows.append((f"path RMS / {runs[0][0]}", lambda r: f"{r['setpoint_error_rms_arcsec'] / max(ref['setpoint_error_rms_arcsec'], 1e-12):.2f}"))
    width = max(14, *(len(item) + 2 for item, _ in runs))
    print(f"{'--mode':26s}" + "".join(f"{item:>{width}s}" for item, _ in runs))
    for label, fn in rows:
        print(f"{label:26s}" + "".join(f"{fn(r):>{width}s}" for _, r in runs))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="tracking time recorded")
    ap.add_argument("--config", default=str(DEFAULT_CONFIG), help="hardware file (simulated)")
    ap.add_argument("--mode", default="",
                    help="comma-separated runs, each csp|ip|csv (both axes) or AZ/ZD like "
                         "ip/csv; figures side by side (default: the file's modes, one run)")
    args = ap.parse_args()
    if args.mode:
        items = [m.strip().lower() for m in args.mode.split(",") if m.strip()]
        runs = []
        for item in items:
            pair = tuple(item.split("/")) if "/" in item else (item, item)
            if len(pair) != 2 or any(m not in ("csp", "ip", "csv", "auto") for m in pair):
                ap.error(f"--mode {item!r}: use csp, ip, csv or AZ/ZD like ip/csv")
            runs.append((item, asyncio.run(run(args.seconds, Path(args.config), pair))))
        side_by_side(runs)
        print(json.dumps({item: r for item, r in runs}))
        return
    r = asyncio.run(run(args.seconds, Path(args.config)))
    print(f"tracked {r['seconds']:.1f} s ({r['cycles_following']} of {r['cycles']} control cycles "
          f"following), target at ZD {r['target_zd_deg']:.1f}°")
    print(f"setpoint path vs atco13:  RMS {r['setpoint_error_rms_arcsec']:.5f}\"  "
          f"max {r['setpoint_error_max_arcsec']:.5f}\"   (goal RMS < 0.01\")")
    print(f"encoders vs atco13:       RMS {r['following_error_rms_arcsec']:.4f}\"  "
          f"max {r['following_error_max_arcsec']:.4f}\"")
    print(f"cost per sample ({r['refill_batch']}-point refill): demand {r['demand_us_per_sample']:.2f} µs, "
          f"astrometry {r['astrometry_us_per_sample']:.2f} µs (goal < 10 µs), "
          f"atco13 {r['atco13_us_per_sample']:.2f} µs")
    print(f"CPU: process {100 * r['process_cpu_share']:.1f} % of one core (drives, loop, tracker), "
          f"tracker {100 * r['tracker_cpu_share']:.4f} %")
    print(json.dumps(r))


if __name__ == "__main__":
    main()
