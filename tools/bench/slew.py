"""Slew and tracking benchmark of the simulated telescope (hwconfig/sim.toml), over TPL2.

The real service runs in this process with its simulated CiA-402 drives; a TPL2 client powers
and references AZ and ZD, then

* **slews** AZ by 1°, 10°, 90°, 180° and ZD by 10°, 45° (AZ and ZD moves run side by side),
  each from rest, and compares with the theoretical minimum time of the axis's configured
  speed/acceleration/jerk (:func:`tcs.axes.profile.theoretical_minimum_time`). Three times per
  move: ``setpoints`` — the planner's setpoint stream from its first to its last change (what
  the axis layer decides; whole cycles); ``settled`` — from sending the SET to the drive's position staying
  within the axis tolerance (what the telescope does: includes the command's way to the loop,
  the drive's interpolation period and the position report); ``tpl2`` — from sending the SET
  to its COMMAND COMPLETE (what a client waits). Goal: within 2 % of the minimum.
* **tracks** two trajectories uploaded through TRAJECTORY.BUFFER/ADDPOINTS/RUN at the same
  time: a sidereal-rate path on AZ (15″/s, points every 2 s, as clients send them) and a fast
  sinusoid on ZD (2° amplitude, 10 s period: 1.26°/s, points every 0.5 s). Errors against the
  analytic path, RMS and max in arcsec, after the first 2 s: of the setpoint stream (each
  at the time the drive reaches it) and of the drive's actual position (at its SYNC).

Control-loop figures come from a cycle callback added after the control loop's own (see
``axes_common.LoopRecorder``). The last line is one JSON object with the figures.

    python3 tools/bench/slew.py
"""

from __future__ import annotations

import asyncio
import json
import math
import time

from axes_common import ARCSEC, Client, LoopRecorder, error_stats, power_and_reference, start_service

from tcs.axes.profile import AxisDynamics, theoretical_minimum_time

AZ_MOVES = [1.0, 10.0, 90.0, -180.0]
ZD_MOVES = [10.0, -45.0]  # from 30 (where the simulated ZD homes): 40, then -5


def dynamics(axis) -> AxisDynamics:
    s = axis.section
    return AxisDynamics(s.max_velocity, s.max_acceleration, s.max_jerk)


def settled_from(rows, target: float, tol: float) -> int | None:
    """Index from which every sample stays within ``tol`` of ``target``."""
    last_out = None
    for i, (_, p) in enumerate(rows):
        if abs(p - target) > tol:
            last_out = i
    if last_out is None or last_out + 1 >= len(rows):
        return None
    return last_out + 1


async def slews(port: int, rec: LoopRecorder, module: str, moves: list[float], service) -> list[dict]:
    c = await Client.connect(port)
    axis = rec.axes[module]
    dt = service.telescope.can.cycle.period
    dyn = dynamics(axis)
    out = []
    try:
        for delta in moves:
            await c.until(f"{module}.MOTION_STATE", lambda v: not int(v) & 1)
            await asyncio.sleep(0.3)  # at rest for a while: a clean start
            start = await c.num(f"{module}.REALPOS")
            target = start + delta
            n_sp, n_act = len(rec.planned[module]), len(rec.actual[module])
            ut1_send = service.telescope.local.ut1()
            t_send = time.perf_counter()
            lines = await c.command(f"SET {module}.TARGETPOS={target!r}")
            t_tpl2 = time.perf_counter() - t_send
            if f"DATA OK {module}.TARGETPOS" not in " ".join(lines):
                raise SystemExit(f"{module} move to {target} failed: {lines}")
            await asyncio.sleep(0.5)  # the settling check needs samples after arrival
            sp = rec.planned[module][n_sp:]
            act = rec.actual[module][n_act:]
            i0 = next((i for i, (_, p) in enumerate(sp) if p != start), None)
            i1 = settled_from(sp, target, 0.0)
            j1 = settled_from(act, target, axis.section.tolerance)
            minimum = theoretical_minimum_time(delta, dyn)
            t_sp = sp[i1][0] - sp[i0][0] + dt if i0 is not None and i1 is not None else float("nan")
            t_settled = act[j1][0] - ut1_send if j1 is not None else float("nan")
            row = {"axis": module, "move_deg": delta, "minimum_s": round(minimum, 4),
                   "setpoints_s": round(t_sp, 4), "settled_s": round(t_settled, 4),
                   "tpl2_s": round(t_tpl2, 4),
                   "ratio_setpoints": round(t_sp / minimum, 4),
                   "ratio_settled": round(t_settled / minimum, 4),
                   "ratio_tpl2": round(t_tpl2 / minimum, 4)}
            out.append(row)
            print(f"{module:3s} {delta:+7.1f}°  minimum {minimum:7.3f} s   setpoints {t_sp:7.3f} s "
                  f"({row['ratio_setpoints']:.4f})   settled {t_settled:7.3f} s ({row['ratio_settled']:.4f})"
                  f"   TPL2 {t_tpl2:7.3f} s ({row['ratio_tpl2']:.4f})", flush=True)
    finally:
        await c.close()
    return out


async def upload(c: Client, module: str, points: list[tuple[float, float]]) -> None:
    for k in range(0, len(points), 30):  # BUFFER holds trajectory_buffer points; 30 per SET
        batch = points[k:k + 30]
        parts = []
        for i, (t, p) in enumerate(batch):
            parts += [f"{module}.TRAJECTORY.BUFFER[{i}].TIME={t!r}",
                      f"{module}.TRAJECTORY.BUFFER[{i}].TARGETPOS={p!r}"]
        await c.set(";".join(parts))
        await c.set(f"{module}.TRAJECTORY.ADDPOINTS={len(batch)}")


async def track(port: int, rec: LoopRecorder, module: str, path, t0: float, t1: float,
                step: float) -> dict:
    c = await Client.connect(port)
    try:
        points = [(t0 + k * step, path(t0 + k * step)) for k in range(int(round((t1 - t0) / step)) + 1)]
        await upload(c, module, points)
        n_sp, n_act = len(rec.setpoints[module]), len(rec.actual[module])
        lines = await c.command(f"SET {module}.TRAJECTORY.RUN=1", timeout=t1 - t0 + 120)
        if f"DATA OK {module}.TRAJECTORY.RUN" not in " ".join(lines):
            raise SystemExit(f"{module} trajectory failed: {lines}")
        window = (t0 + 2.0, t1)
        return {"setpoints": error_stats(rec.setpoints[module][n_sp:], path, *window),
                "actual": error_stats(rec.actual[module][n_act:], path, *window)}
    finally:
        await c.close()


async def main() -> dict:
    # the recorder reads every cycle's setpoints in-process: the loop as a thread here
    service, port, state = await start_service(can={"control_process": False})
    try:
        c = await Client.connect(port)
        print("powering and referencing AZ and ZD …", flush=True)
        await power_and_reference(c, "AZ", "ZD")
        with LoopRecorder(service, ["AZ", "ZD"]) as rec:
            az, zd = await asyncio.gather(slews(port, rec, "AZ", AZ_MOVES, service),
                                          slews(port, rec, "ZD", ZD_MOVES, service))
            # tracking: AZ at the sidereal rate, ZD a fast sinusoid, side by side
            az0, zd0 = await c.num("AZ.REALPOS"), await c.num("ZD.REALPOS")
            t0 = await c.num("LOCAL.UT1") + 4.0
            rate, amp, period = 15.0 / ARCSEC, 2.0, 10.0

            def sidereal(t):
                return az0 + rate * (t - t0)

            toward_zenith = -1.0 if zd0 > 0 else 1.0

            def sinusoid(t):
                return zd0 + toward_zenith * amp * (1 - math.cos(2 * math.pi * (t - t0) / period))

            print("tracking: AZ at 15″/s for 30 s, ZD a 2°/10 s sinusoid for 20 s …", flush=True)
            sid, sin = await asyncio.gather(track(port, rec, "AZ", sidereal, t0, t0 + 30.0, 2.0),
                                            track(port, rec, "ZD", sinusoid, t0, t0 + 20.0, 0.5))
        await c.close()
        stats = service.telescope.control_loop.stats()
    finally:
        await service.stop()
        state.cleanup()
    for name, r in (("AZ sidereal 15″/s", sid), ("ZD sinusoid 2°, 10 s", sin)):
        print(f"{name:22s} setpoints rms {r['setpoints']['rms_arcsec']:.4f}″ max "
              f"{r['setpoints']['max_arcsec']:.4f}″   drive rms {r['actual']['rms_arcsec']:.3f}″ "
              f"max {r['actual']['max_arcsec']:.3f}″")
    rows = az + zd
    worst = {k: max(r[k] for r in rows) for k in ("ratio_setpoints", "ratio_settled", "ratio_tpl2")}
    print(f"worst ratio to the minimum: setpoints {worst['ratio_setpoints']:.4f}, settled "
          f"{worst['ratio_settled']:.4f}, TPL2 {worst['ratio_tpl2']:.4f} (goal ≤ 1.02)")
    print(f"control loop: {stats['cycles']} cycles, {stats['late']} late, {stats['missed']} missed, "
          f"max step {stats['max_step_ms']:.2f} ms")
    return {"slews": rows, "worst": worst, "goal_ratio": 1.02,
            "tracking": {"az_sidereal_15arcsec_s": sid, "zd_sinusoid_2deg_10s": sin},
            "loop": {k: stats[k] for k in ("cycles", "late", "missed")}}


if __name__ == "__main__":
    result = asyncio.run(main())
    print(json.dumps(result))
