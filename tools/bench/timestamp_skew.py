"""Benchmark of the telemetry time stamps (issue 29): demand and actual of a tracking run.

Run: ``python3 tools/bench/timestamp_skew.py [--seconds 30] [--config hwconfig/sim.toml]``.
Prints the figures, then (last line) one JSON object with them.

The simulated telescope runs in-process as shipped (the control loop in its control process),
powers and references AZ and ZD, tracks a star 35° from the zenith and, once both axes follow
the path, records every readback batch the service receives from the control process for T
seconds (the receiver's batch handler is wrapped: what the status page, ``/status.json`` and
``/metrics`` read). Each axis's ``sample`` there is (SYNC UT1 ``S`` at which the position was
measured, that position, UT1 ``D`` at which this cycle's setpoint is reached, the setpoint),
stamped in the control process (:attr:`tcs.axes.axis.Axis.sample`).

* **demand/actual skew** — a CSP drive latches the setpoint of cycle k at the next SYNC and
  reaches it one interpolation period (= the SYNC period T) later, so the true time of demand
  k is ``S[k+1] + T``, with ``S[k+1]`` the measurement stamp of the next cycle (same clock,
  same process). The skew is ``D[k] − (S[k+1] + T)``: how far the demand's stamp is from the
  moment the actual position stamped on the same clock shows it (late SYNCs and a preempted
  clock read make it; goal ≤ 1 ms p99). Pairs of consecutive cycles only (a batch coalesced by
  a slow receiver leaves a gap, counted).
* **grouped stamp error** — for comparison, the error of stamping each sample with the time
  the service received it (what grouping samples under one receive stamp does): receive UT1
  minus ``S``.
* **tracking error seen** — the actual positions against the demand series interpolated at
  their stamps (RMS, max, arcsec on the axis): with the SYNC stamps, and with the receive
  stamps (the spikes the wrong stamps put into a tracking plot).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import tempfile
from pathlib import Path

import numpy as np

from tcs.app import Service
from tcs.axes.control_core import READBACKS
from tcs.config import DEFAULT_CONFIG
from web_load import make_config, start_tracking  # tools/bench/web_load.py

ARCSEC = 3600.0
SAMPLE = 1 + READBACKS.index("sample")


async def track(tel, seconds: float) -> dict:
    p = tel.pointing
    az, zd = p.axis1, p.axis2
    process = tel.can
    if not hasattr(process, "_batch"):
        raise SystemExit("this benchmark needs [can] control_process = true (the shipped sim.toml)")
    done = await start_tracking(tel)
    await asyncio.sleep(2.0)
    rows: list[tuple] = []
    ut1 = tel.local.ut1
    index = {az.index: 0, zd.index: 1}
    original = process._batch

    def recorded(snapshots, items, stats):   # the receiver thread, before the axes see it
        received = ut1()
        for i, snap in snapshots.items():
            if i in index and snap[SAMPLE] is not None:
                rows.append((index[i], received, *snap[SAMPLE]))
        original(snapshots, items, stats)

    cycles0 = dict(process.stats)
    process._batch = recorded
    try:
        await asyncio.sleep(seconds)
    finally:
        del process._batch  # (the instance attribute goes: the method is back)
    cycles1 = dict(process.stats)
    p.set_track(0)
    await done
    period = tel.config.can.sync_period
    out = {"seconds": seconds, "period_ms": period * 1e3,
           "missed_cycles": cycles1.get("missed", 0) - cycles0.get("missed", 0),
           "late_cycles": cycles1.get("late", 0) - cycles0.get("late", 0)}
    for k, name in enumerate(("AZ", "ZD")):
        data = np.array([r[1:] for r in rows if r[0] == k and r[5] is not None], dtype=float)
        recv, sync, actual, dtime, demand = data.T
        order = np.argsort(sync)
        recv, sync, actual, dtime, demand = (x[order] for x in (recv, sync, actual, dtime, demand))
        gap = np.diff(sync)
        pair = (gap > 0.5 * period) & (gap < 1.5 * period)
        skew = (dtime[:-1] - (sync[1:] + period))[pair] * 1e3
        grouped = (recv - sync) * 1e3
        seen_sync = (actual - np.interp(sync, dtime, demand)) * ARCSEC
        seen_recv = (actual - np.interp(recv, dtime, demand)) * ARCSEC
        inside = (sync > dtime[0]) & (recv < dtime[-1])
        out[name] = {
            "samples": int(len(sync)), "pairs": int(pair.sum()), "gaps": int((~pair).sum()),
            "skew_ms_p50": float(np.percentile(np.abs(skew), 50)),
            "skew_ms_p99": float(np.percentile(np.abs(skew), 99)),
            "skew_ms_max": float(np.abs(skew).max()),
            "grouped_ms_p50": float(np.percentile(grouped, 50)),
            "grouped_ms_p99": float(np.percentile(grouped, 99)),
            "grouped_ms_max": float(grouped.max()),
            "seen_error_sync_rms_arcsec": float(np.sqrt(np.mean(seen_sync[inside] ** 2))),
            "seen_error_sync_max_arcsec": float(np.abs(seen_sync[inside]).max()),
            "seen_error_recv_rms_arcsec": float(np.sqrt(np.mean(seen_recv[inside] ** 2))),
            "seen_error_recv_max_arcsec": float(np.abs(seen_recv[inside]).max()),
            "speed_arcsec_s": float(np.median(np.abs(np.diff(demand) / np.diff(dtime))) * ARCSEC),
        }
    return out


async def run(seconds: float, config_path: Path) -> dict:
    with tempfile.TemporaryDirectory() as state:
        service = Service(make_config(config_path, Path(state), web_port=-1))
        await service.start()
        try:
            return await track(service.telescope, seconds)
        finally:
            await service.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    args = ap.parse_args()
    r = asyncio.run(run(args.seconds, args.config))
    print(f"tracking {r['seconds']:g} s, SYNC period {r['period_ms']:g} ms; missed cycles "
          f"{r['missed_cycles']}, late {r['late_cycles']}")
    for name in ("AZ", "ZD"):
        a = r[name]
        print(f"{name}: {a['samples']} samples ({a['pairs']} consecutive pairs, {a['gaps']} gaps), "
              f"{a['speed_arcsec_s']:.1f}\"/s")
        print(f"  demand/actual skew (SYNC stamps):  p50 {a['skew_ms_p50']:.3f} ms  p99 "
              f"{a['skew_ms_p99']:.3f} ms  max {a['skew_ms_max']:.3f} ms   (goal p99 <= 1 ms)")
        print(f"  stamped on receipt instead:        p50 {a['grouped_ms_p50']:.3f} ms  p99 "
              f"{a['grouped_ms_p99']:.3f} ms  max {a['grouped_ms_max']:.3f} ms")
        print(f"  actual - demand at the stamps: SYNC RMS {a['seen_error_sync_rms_arcsec']:.4f}\" max "
              f"{a['seen_error_sync_max_arcsec']:.4f}\";  receipt RMS {a['seen_error_recv_rms_arcsec']:.4f}\" "
              f"max {a['seen_error_recv_max_arcsec']:.4f}\"")
    print(json.dumps(r))


if __name__ == "__main__":
    main()
