"""Benchmark: polling simulated PLCs over Modbus TCP on loopback with the TCS's PLC driver.

The simulated PLCs (the simulated telescope's dome map: 31 points, 5 read requests per poll
cycle) run in a child process (``--serve K``), so the figures are those of the TCS side; the
child competes for the same CPU cores, as a real PLC would not.

Figures:

* one PLC at 10 Hz: request round trip (one read request, p50/p99, ms) and poll cycle time
  (all 5 requests, p50/p99, ms), TCS CPU per cycle;
* one PLC polled as fast as possible: cycles per second;
* k PLCs at 10 Hz for k = 1, 2, 4, 8 …: achieved poll rate (lowest driver and mean), slots
  missed, lateness of the cycle start (p99, ms), the TCS process' CPU share (and per cycle)
  and the simulators' process' CPU share (when both near the machine's cores, the limit is
  the machine, not the driver). A step "keeps
  up" when every driver achieves ≥ 95 % of 10 Hz and the p99 lateness stays below one period;
  ``max_plcs_at_10hz`` is the last k that kept up.

Run: ``python3 tools/bench/plc_poll.py [--seconds 3] [--max-plcs 256]``. The last output line is
one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from tcs.config import load_config  # noqa: E402
from tcs.drivers.modbus import PlcDriver  # noqa: E402

RATE = 10.0


def pct(values, q: float) -> float:
    values = sorted(values)
    if not values:
        return float("nan")
    return values[min(len(values) - 1, int(q * len(values)))]


def ms(x: float) -> float:
    return round(x * 1000.0, 3)


# ------------------------------------------------------------------ the child: k simulated PLCs


async def serve(k: int) -> None:
    from tcs.sim.plc import SimPlc
    section = load_config().plcs["dome"]
    sims = [SimPlc(f"plc{i}", section, port=0) for i in range(k)]
    for s in sims:
        await s.start()
    print(json.dumps([s.port for s in sims]), flush=True)
    loop = asyncio.get_running_loop()
    while await loop.run_in_executor(None, sys.stdin.readline):  # "cpu" until stdin closes
        print(json.dumps(time.process_time()), flush=True)
    for s in sims:
        await s.stop()


class SimProcess:
    def __init__(self, k: int):
        self.k = k
        self.proc: asyncio.subprocess.Process | None = None
        self.ports: list[int] = []

    async def __aenter__(self) -> SimProcess:
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "--serve", str(self.k),
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE)
        line = await asyncio.wait_for(self.proc.stdout.readline(), 120)
        self.ports = json.loads(line)
        return self

    async def cpu(self) -> float:
        """CPU seconds the simulators' process has used so far."""
        self.proc.stdin.write(b"cpu\n")
        await self.proc.stdin.drain()
        return json.loads(await asyncio.wait_for(self.proc.stdout.readline(), 60))

    async def __aexit__(self, *exc) -> None:
        self.proc.stdin.close()
        try:
            await asyncio.wait_for(self.proc.wait(), 30)
        except asyncio.TimeoutError:
            self.proc.kill()
            await self.proc.wait()


# ------------------------------------------------------------------ the TCS side


def drivers_for(ports: list[int], interval: float) -> list[PlcDriver]:
    section = load_config().plcs["dome"]
    return [PlcDriver(f"plc{i}", dataclasses.replace(section, port=p, poll_interval=interval,
                                                     timeout=2.0))
            for i, p in enumerate(ports)]


async def run_window(drivers: list[PlcDriver], seconds: float, sims: SimProcess) -> dict:
    for d in drivers:
        await d.start()
    await asyncio.gather(*(d.wait_connected(60) for d in drivers))
    await asyncio.sleep(0.5)  # warm-up
    start = [(d.stats.cycles, d.stats.missed, len(d.stats.lateness), len(d.stats.cycle_times),
              len(d.stats.latencies)) for d in drivers]
    s0 = await sims.cpu()
    t0, c0 = time.perf_counter(), time.process_time()
    await asyncio.sleep(seconds)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    sim_cpu = await sims.cpu() - s0
    rates, missed, late, cycles, rtts = [], 0, [], [], []
    for d, (c, m, nl, nc, nr) in zip(drivers, start):
        rates.append((d.stats.cycles - c) / wall)
        missed += d.stats.missed - m
        late.extend(list(d.stats.lateness)[nl:])
        cycles.extend(list(d.stats.cycle_times)[nc:])
        rtts.extend(list(d.stats.latencies)[nr:])
    lost = sum(1 for d in drivers if not d.connected)
    for d in drivers:
        await d.stop()
    total_cycles = sum(rates) * wall
    return {"rates": rates, "missed": missed, "lateness": late, "cycle_times": cycles,
            "latencies": rtts, "cpu_share": cpu / wall, "cpu_per_cycle": cpu / max(total_cycles, 1),
            "sim_cpu_share": sim_cpu / wall, "lost": lost}


async def main(args) -> dict:
    out: dict = {}
    # One PLC at 10 Hz, then as fast as it goes.
    async with SimProcess(1) as sims:
        r = await run_window(drivers_for(sims.ports, 1.0 / RATE), args.seconds, sims)
        out["single"] = {
            "requests_per_cycle": len(drivers_for(sims.ports, 0.1)[0].blocks),
            "rtt_p50_ms": ms(pct(r["latencies"], 0.5)), "rtt_p99_ms": ms(pct(r["latencies"], 0.99)),
            "cycle_p50_ms": ms(pct(r["cycle_times"], 0.5)), "cycle_p99_ms": ms(pct(r["cycle_times"], 0.99)),
            "tcs_cpu_per_cycle_ms": ms(r["cpu_per_cycle"]),
            "rate_hz": round(statistics.fmean(r["rates"]), 2)}
        fast = await run_window(drivers_for(sims.ports, 0.001), min(args.seconds, 2.0), sims)
        out["single"]["max_rate_hz"] = round(fast["rates"][0], 1)
    s = out["single"]
    print(f"one PLC at 10 Hz: {s['requests_per_cycle']} requests/cycle, round trip p50 "
          f"{s['rtt_p50_ms']} ms p99 {s['rtt_p99_ms']} ms; cycle p50 {s['cycle_p50_ms']} ms "
          f"p99 {s['cycle_p99_ms']} ms; TCS CPU {s['tcs_cpu_per_cycle_ms']} ms/cycle; "
          f"flat out {s['max_rate_hz']} cycles/s", flush=True)

    steps = []
    best = 0
    k = 1
    while k <= args.max_plcs:
        async with SimProcess(k) as sims:
            r = await run_window(drivers_for(sims.ports, 1.0 / RATE), args.seconds, sims)
        step = {"plcs": k, "min_rate_hz": round(min(r["rates"]), 2),
                "mean_rate_hz": round(statistics.fmean(r["rates"]), 2), "missed": r["missed"],
                "lateness_p99_ms": ms(pct(r["lateness"], 0.99)),
                "cycle_p99_ms": ms(pct(r["cycle_times"], 0.99)),
                "rtt_p99_ms": ms(pct(r["latencies"], 0.99)),
                "tcs_cpu_share": round(r["cpu_share"], 3), "sim_cpu_share": round(r["sim_cpu_share"], 3),
                "tcs_cpu_per_cycle_ms": ms(r["cpu_per_cycle"]), "lost": r["lost"]}
        step["keeps_up"] = (min(r["rates"]) >= 0.95 * RATE and pct(r["lateness"], 0.99) < 1.0 / RATE
                            and r["lost"] == 0)
        steps.append(step)
        print(f"{k:4d} PLCs: rate min {step['min_rate_hz']} mean {step['mean_rate_hz']} Hz, "
              f"missed {step['missed']}, lateness p99 {step['lateness_p99_ms']} ms, cycle p99 "
              f"{step['cycle_p99_ms']} ms, CPU TCS {100 * step['tcs_cpu_share']:.0f} % "
              f"({step['tcs_cpu_per_cycle_ms']} ms/cycle), simulators {100 * step['sim_cpu_share']:.0f} % -> "
              f"{'keeps up' if step['keeps_up'] else 'FALLS BEHIND'}", flush=True)
        if not step["keeps_up"]:
            break
        best = k
        k = k * 2 if k < 16 else k + 16 if k < 64 else k + 32
    out["scaling"] = steps
    out["max_plcs_at_10hz"] = best
    out["seconds_per_step"] = args.seconds
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring window per step")
    parser.add_argument("--max-plcs", type=int, default=256, help="largest k tried")
    parser.add_argument("--serve", type=int, default=0, help=argparse.SUPPRESS)
    a = parser.parse_args()
    if a.serve:
        asyncio.run(serve(a.serve))
    else:
        result = asyncio.run(main(a))
        print(f"max PLCs polled at 10 Hz by one TCS: {result['max_plcs_at_10hz']}")
        print(json.dumps(result))
