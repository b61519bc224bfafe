"""Control-loop timing under TPL2 load (architecture rule 5: a burst of clients must not make
the loop miss a cycle).

The real service runs in this process on the simulated telescope (hwconfig/sim.toml); AZ and
ZD are powered, referenced and follow sidereal-rate trajectories for the whole run, so every
cycle does the follower's work. Two windows of the same length, in the same run:

1. **baseline**: no client but the one that set things up (idle);
2. **load**: 100 TPL2 clients in a *separate process* each GET 20 axis variables 10 times a
   second (1000 GETs, 20000 variables per second).

Per window, from the cycle source (``CycleSource.lateness``: SYNC send time minus its ideal
slot; ``callback_time``: SYNC to the end of the control loop's work; ``stats()``: late and
missed cycles): lateness p50/p99/max, loop time p50/p99/max, late and missed counts; and the
clients' GET latency. The last line is one JSON object with the figures.

    python3 tools/bench/loop_load.py [--clients 100] [--seconds 15] [--realtime-priority 40]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import time

from tcs.app import freeze_heap, thaw_heap

VARIABLES = [f"{ax}.{v}" for ax in ("AZ", "ZD") for v in (
    "REALPOS", "CURRPOS", "TARGETPOS", "TARGETDISTANCE", "MOTION_STATE", "LIMIT_STATE",
    "POWER_STATE", "REFERENCED", "CURRSPEED", "OFFSET")]


# ------------------------------------------------------------------ the load (child process)

async def poller(port: int, seconds: float, rate: float, latencies: list[float], go: asyncio.Event,
                 connected: list[int]) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    await reader.readline()
    writer.write(b'AUTH PLAIN "admin" "admin"\n')
    line = await reader.readline()
    if not line.startswith(b"AUTH OK"):
        raise SystemExit(f"login failed: {line!r}")
    connected.append(1)
    request = ("1 GET " + ";".join(VARIABLES) + "\n").encode()
    await go.wait()
    period = 1.0 / rate
    start = time.perf_counter()
    tick = start
    while tick < start + seconds:
        t0 = time.perf_counter()
        writer.write(request)
        while not (await reader.readline()).startswith(b"1 COMMAND COMPLETE"):
            pass
        latencies.append(time.perf_counter() - t0)
        tick += period
        delay = tick - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
    writer.close()
    try:
        await writer.wait_closed()
    except OSError:
        pass


async def load(port: int, clients: int, seconds: float, rate: float) -> None:
    latencies: list[float] = []
    connected: list[int] = []
    go = asyncio.Event()
    tasks = [asyncio.create_task(poller(port, seconds, rate, latencies, go, connected))
             for _ in range(clients)]
    while len(connected) < clients:
        await asyncio.sleep(0.01)
        for t in tasks:
            if t.done() and t.exception():
                raise t.exception()
    print("ready", flush=True)
    sys.stdin.readline()  # the parent says when
    go.set()
    t0 = time.perf_counter()
    await asyncio.gather(*tasks)
    elapsed = time.perf_counter() - t0
    latencies.sort()
    print(json.dumps({"gets": len(latencies), "gets_per_s": len(latencies) / elapsed,
                      "latency_ms": {"p50": latencies[len(latencies) // 2] * 1e3,
                                     "p99": latencies[int(len(latencies) * 0.99)] * 1e3,
                                     "max": latencies[-1] * 1e3}}), flush=True)


# ------------------------------------------------------------------ the service (this process)

def window(source, i0: int, i1: int, c0: int, c1: int, s0, s1) -> dict:
    from axes_common import percentile
    late = list(source.lateness)[i0:i1]
    loop = list(source.callback_time)[c0:c1]
    ms = lambda xs, q: round(percentile(xs, q) * 1e3, 3)  # noqa: E731
    return {"cycles": s1.cycles - s0.cycles, "late": s1.late - s0.late, "missed": s1.missed - s0.missed,
            "tpdo_timeouts": s1.tpdo_timeouts - s0.tpdo_timeouts,
            "lateness_ms": {"p50": ms(late, 50), "p99": ms(late, 99), "max": ms(late, 100)},
            "loop_ms": {"p50": ms(loop, 50), "p99": ms(loop, 99), "max": ms(loop, 100)}}


def snapshot(source) -> tuple[int, int, object]:
    """Where the lateness and loop-time histories are now, and the counters."""
    return len(source.lateness), len(source.callback_time), source.stats()


async def main(clients: int, seconds: float, rate: float, realtime_priority: int = 0) -> dict:
    from axes_common import Client, power_and_reference, start_service

    service, port, state = await start_service(max_connections=clients + 16,
                                               can={"realtime_priority": realtime_priority})
    freeze_heap()  # as tcs-server does once it serves
    child = None
    try:
        c = await Client.connect(port)
        print("powering and referencing AZ and ZD …", flush=True)
        await power_and_reference(c, "AZ", "ZD")
        total = 2 * seconds + 60
        t0 = await c.num("LOCAL.UT1") + 1.0
        for ax in ("AZ", "ZD"):  # sidereal-rate paths for the whole run, points every 2 s
            p0 = await c.num(f"{ax}.REALPOS")
            n = int(total / 2) + 1
            parts = []
            for i in range(n):
                parts += [f"{ax}.TRAJECTORY.BUFFER[{i}].TIME={t0 + 2 * i!r}",
                          f"{ax}.TRAJECTORY.BUFFER[{i}].TARGETPOS={p0 + 15 / 3600 * 2 * i!r}"]
            await c.set(";".join(parts))
            await c.set(f"{ax}.TRAJECTORY.ADDPOINTS={n}")
            await c.start(f"SET {ax}.TRAJECTORY.RUN=1")
        await c.until("AZ.MOTION_STATE", lambda v: int(v) & 2)
        await c.until("ZD.MOTION_STATE", lambda v: int(v) & 2)
        await asyncio.sleep(2.0)
        source = service.telescope.can.cycle
        realtime = source.realtime

        print(f"baseline: {seconds:g} s without load …", flush=True)
        a = snapshot(source)
        await asyncio.sleep(seconds)
        b = snapshot(source)
        baseline = window(source, a[0], b[0], a[1], b[1], a[2], b[2])

        print(f"load: {clients} clients × 20 variables × {rate:g} Hz in another process …", flush=True)
        child = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "--serve-load", str(port), "--clients", str(clients),
            "--seconds", str(seconds), "--rate", str(rate),
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        line = await asyncio.wait_for(child.stdout.readline(), 120)
        if line.strip() != b"ready":
            raise SystemExit(f"load process: {line!r}")
        a = snapshot(source)
        child.stdin.write(b"go\n")
        await child.stdin.drain()
        out = await asyncio.wait_for(child.stdout.readline(), seconds + 120)
        b = snapshot(source)
        await child.wait()
        loaded = window(source, a[0], b[0], a[1], b[1], a[2], b[2])
        clients_figures = json.loads(out)
        following = [await c.num(f"{ax}.MOTION_STATE") for ax in ("AZ", "ZD")]
        await c.close()
    finally:
        if child is not None and child.returncode is None:
            child.kill()
            await child.wait()
        await service.stop()
        thaw_heap()
        state.cleanup()
    for name, w in (("baseline", baseline), ("load", loaded)):
        print(f"{name:8s} {w['cycles']:5d} cycles  late {w['late']}  missed {w['missed']}  "
              f"lateness p50 {w['lateness_ms']['p50']:.3f} p99 {w['lateness_ms']['p99']:.3f} "
              f"max {w['lateness_ms']['max']:.3f} ms   loop p50 {w['loop_ms']['p50']:.3f} "
              f"p99 {w['loop_ms']['p99']:.3f} max {w['loop_ms']['max']:.3f} ms")
    cl = clients_figures
    print(f"clients: {cl['gets']} GETs ({cl['gets_per_s']:.0f}/s), latency p50 "
          f"{cl['latency_ms']['p50']:.2f} p99 {cl['latency_ms']['p99']:.2f} max {cl['latency_ms']['max']:.2f} ms")
    print(f"trajectories still running at the end: {all(int(m) & 2 for m in following)}")
    print(f"control loop real-time priority: {realtime_priority if realtime else 'no'}")
    return {"baseline": baseline, "load": loaded, "clients": cl, "n_clients": clients,
            "realtime_priority": realtime_priority if realtime else 0,
            "variables": len(VARIABLES), "rate_hz": rate, "seconds": seconds}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--rate", type=float, default=10.0, help="GETs per second per client")
    ap.add_argument("--realtime-priority", type=int, default=0,
                    help="can.realtime_priority for the control loop (0: normal scheduling)")
    ap.add_argument("--serve-load", type=int, metavar="PORT", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve_load:
        asyncio.run(load(args.serve_load, args.clients, args.seconds, args.rate))
    else:
        result = asyncio.run(main(args.clients, args.seconds, args.rate, args.realtime_priority))
        print(json.dumps(result))
