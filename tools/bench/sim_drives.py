"""Benchmark: the cost of N simulated CiA-402 drives in CSP, seen from a raw master.

It starts N simulated drives (``tcs.sim.start_sim_drives``: one bus of their own, one receive
and one timer thread for all) on a fresh ``virtual`` channel, and a bare python-can master on
the same channel that configures them by SDO (canopen), starts them, enables them in CSP
through RPDO1 and streams a ramp: every period it sends N RPDO1 frames and one SYNC, and
records the TPDO1 answers. No TCS code is involved, so the figures are the simulator's own.

Figures per SYNC period:

* CPU share of the simulator's threads (receive + timer) over the streaming phase, and its
  CPU time per SYNC (µs) — what the simulated cabinet costs the CAN benchmark;
* SYNC → last TPDO1 latency (p50 / p99 / max, ms): how quickly the drives answer;
* setpoints missed at the drives (sum of ``rpdo_missed``) and drives not in Operation enabled.

Run: ``python3 tools/bench/sim_drives.py [--drives 6] [--seconds 5] [--periods 0.01 0.004]``.
The last line of output is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import threading
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import canopen  # noqa: E402

from tcs.sim import DEFAULT_EDS, SimDriveParams, start_sim_drives  # noqa: E402


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def thread_cpu(threads: list[threading.Thread]) -> float:
    total = 0.0
    for t in threads:
        try:
            total += time.clock_gettime(time.pthread_getcpuclockid(t.ident))
        except (OSError, TypeError):
            pass
    return total


def run(drives: int, seconds: float, period: float) -> dict:
    channel = f"bench-sim-{uuid.uuid4().hex[:8]}"
    before = set(threading.enumerate())
    sims = start_sim_drives({"interface": "virtual", "channel": channel},
                            {n: SimDriveParams() for n in range(1, drives + 1)})
    sim_threads = [t for t in threading.enumerate() if t not in before]
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    latencies: list[float] = []
    pending = {"sync": 0.0, "left": 0}
    lock = threading.Lock()

    def on_tpdo(cob: int, data: bytearray, stamp: float) -> None:
        with lock:
            if pending["left"] > 0:
                pending["left"] -= 1
                if pending["left"] == 0:
                    latencies.append(time.perf_counter() - pending["sync"])

    try:
        for n in range(1, drives + 1):
            node = network.add_node(n, str(DEFAULT_EDS))
            node.sdo[0x6060].raw = 8
            node.sdo[0x60C2][1].raw = round(period * 1000)
            network.subscribe(0x180 + n, on_tpdo)
        network.nmt.send_command(0x01)
        time.sleep(0.05)
        cycles = int(seconds / period)
        cpu0, wall0 = thread_cpu(sim_threads), time.perf_counter()
        missed0 = sum(s.rpdo_missed for s in sims.values())
        start = time.perf_counter()
        for k in range(cycles):
            cw = 0x06 if k < 2 else 0x07 if k < 4 else 0x0F
            target = round(k * period * 1000.0)          # 0.1 unit/s at 10,000 increments/unit
            for n in range(1, drives + 1):
                network.send_message(0x200 + n, struct.pack("<Hi", cw, target))
            with lock:
                pending["sync"], pending["left"] = time.perf_counter(), drives
            network.send_message(0x080, b"")
            delay = start + (k + 1) * period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        wall = time.perf_counter() - wall0
        cpu = thread_cpu(sim_threads) - cpu0
        missed = sum(s.rpdo_missed for s in sims.values()) - missed0
        not_enabled = sum(s.state != "OPERATION ENABLED" for s in sims.values())
    finally:
        network.disconnect()
        sims.stop()
    return {
        "period_ms": period * 1000, "drives": drives, "cycles": cycles,
        "sim_cpu_share": round(cpu / wall, 4),
        "sim_cpu_per_sync_us": round(cpu / cycles * 1e6, 1),
        "latency_p50_ms": round(percentile(latencies, 0.5) * 1000, 3),
        "latency_p99_ms": round(percentile(latencies, 0.99) * 1000, 3),
        "latency_max_ms": round(max(latencies, default=float("nan")) * 1000, 3),
        "answered_syncs": len(latencies),
        "setpoints_missed": missed, "drives_not_enabled": not_enabled,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--drives", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--periods", type=float, nargs="+", default=[0.01, 0.004])
    args = parser.parse_args()
    results = []
    for period in args.periods:
        r = run(args.drives, args.seconds, period)
        results.append(r)
        print(f"{r['drives']} drives at {r['period_ms']:g} ms: simulator CPU {r['sim_cpu_share']:.1%} "
              f"({r['sim_cpu_per_sync_us']} µs per SYNC), SYNC→last TPDO p50 {r['latency_p50_ms']} ms "
              f"p99 {r['latency_p99_ms']} ms max {r['latency_max_ms']} ms, "
              f"setpoints missed {r['setpoints_missed']}, not enabled {r['drives_not_enabled']}")
    print(json.dumps({"benchmark": "sim_drives", "results": results}))


if __name__ == "__main__":
    main()
