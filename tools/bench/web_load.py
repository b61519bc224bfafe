"""Benchmark of the web port (issue 29): what the status page and /metrics cost the service.

Run: ``python3 tools/bench/web_load.py [--seconds 20] [--rounds 2] [--config hwconfig/sim.toml]``.
Prints the figures, then (last line) one JSON object with them.

The simulated telescope runs in-process as shipped (the control loop in its control process)
with its web port on a free loopback port, AZ and ZD powered, referenced and tracking a star
(the loop busy as at night). Then, ``rounds`` times, two windows of T seconds each:

* **idle** — nobody reads the web port (its sampler takes one snapshot a second);
* **scraped** — a client in another process scrapes ``/metrics`` and ``/status.json`` once a
  second (Prometheus at 1 Hz plus a script) while one status page is open (``/events``,
  4 snapshots a second).

Per window: the service process's CPU time over wall time (% of one core; the control process
is counted apart), the web server's own CPU (taking and encoding snapshots, writing metrics:
measured around that code), and the control loop's missed and late cycles. Goal: no more missed
cycles when scraped, and < 2 % of a core for the web port at 1 Hz scraping.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

from tcs.app import Service
from tcs.config import DEFAULT_CONFIG, load_config
from tcs.config.sections import StateSection

CLIENT = r"""
import sys, threading, time, urllib.request
base, seconds = sys.argv[1], float(sys.argv[2])
end = time.monotonic() + seconds
def page():
    with urllib.request.urlopen(base + "/events", timeout=30) as r:
        while time.monotonic() < end:
            if not r.readline():
                break
threading.Thread(target=page, daemon=True).start()
n = 0
while time.monotonic() < end:
    t = time.monotonic()
    for path in ("/metrics", "/status.json"):
        with urllib.request.urlopen(base + path, timeout=30) as r:
            r.read()
    n += 1
    time.sleep(max(0.0, 1.0 - (time.monotonic() - t)))
print(n)
"""


def make_config(path: Path, state: Path, web_port: int = 0):
    """``path`` on free ports (no OpenTSI, no Alpaca; the web port ``web_port``: 0 a free one,
    -1 off), its own virtual bus and state, tolerant drive heartbeats (a loaded machine)."""
    config = load_config(path)
    changes = dict(server=dataclasses.replace(config.server, port=0, opentsi_port=-1),
                   alpaca=dataclasses.replace(config.alpaca, port=-1),
                   web=dataclasses.replace(config.web, port=web_port), indi=dataclasses.replace(config.indi, port=-1),
                   state=StateSection(path=str(state)))
    if config.can is not None and config.can.interface == "virtual":
        changes["can"] = dataclasses.replace(config.can, channel=f"bench-{uuid.uuid4().hex[:8]}")
    changes["drives"] = {name: dataclasses.replace(d, heartbeat_consumer_timeout=max(
        d.heartbeat_consumer_timeout, 5.0)) for name, d in config.drives.items()}
    new = dataclasses.replace(config, **changes)
    object.__setattr__(new, "source", config.source)
    return new


async def start_tracking(tel):
    """Power and reference AZ/ZD, track a star 20° east of where AZ stands; returns TRACK=1's
    future once both axes follow the path."""
    p = tel.pointing
    az, zd = p.axis1, p.axis2
    await tel.cabinet.set_power(1)
    tel.cabinet.set_reinit(0)
    deadline = time.monotonic() + 300.0
    while min(az.referenced, zd.referenced) < 1.0:
        assert time.monotonic() < deadline, "the axes were not referenced"
        await asyncio.sleep(0.1)
    ra, dec = p.astrometry().icrs_from_observed((az.real_position + 20.0) % 360.0, 35.0, time.time() + 10.0)
    p.target.set_ra(ra)
    p.target.set_dec(dec)
    done = p.set_track(1)
    deadline = time.monotonic() + 120.0
    while not all(a.follower.state.value == "following" for a in (az, zd)):
        assert time.monotonic() < deadline, "the axes never reached the path"
        await asyncio.sleep(0.1)
    return done


def loop_counts(tel) -> tuple[int, int]:
    s = tel.control_loop.stats()
    return int(s.get("missed", 0)), int(s.get("late", 0))


async def window(service, seconds: float, scraped: bool) -> dict:
    tel, web = service.telescope, service.web_server
    proc = None
    if scraped:
        proc = subprocess.Popen([sys.executable, "-c", CLIENT, f"http://127.0.0.1:{web.port}", str(seconds)],
                                stdout=subprocess.PIPE, text=True)
    missed0, late0 = loop_counts(tel)
    cpu0, web0, snaps0, wall0 = time.process_time(), web.cpu, web.snapshots, time.monotonic()
    await asyncio.sleep(seconds)
    if proc is not None:
        while proc.poll() is None:
            await asyncio.sleep(0.05)
    wall = time.monotonic() - wall0
    cpu, web_cpu = time.process_time() - cpu0, web.cpu - web0
    missed1, late1 = loop_counts(tel)
    return {"kind": "scraped" if scraped else "idle", "wall_s": wall,
            "service_cpu_pct": 100.0 * cpu / wall, "web_cpu_pct": 100.0 * web_cpu / wall,
            "snapshots_per_s": (web.snapshots - snaps0) / wall,
            "scrapes": int(proc.stdout.read().strip() or 0) if proc is not None else 0,
            "missed": missed1 - missed0, "late": late1 - late0}


async def run(seconds: float, rounds: int, config_path: Path) -> dict:
    with tempfile.TemporaryDirectory() as state:
        service = Service(make_config(config_path, Path(state)))
        await service.start()
        try:
            await start_tracking(service.telescope)
            await asyncio.sleep(2.0)
            windows = []
            for _ in range(rounds):
                windows.append(await window(service, seconds, False))
                windows.append(await window(service, seconds, True))
            service.telescope.pointing.set_track(0)
            return {"seconds": seconds, "rounds": rounds, "load": os.getloadavg()[0], "windows": windows}
        finally:
            await service.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    args = ap.parse_args()
    r = asyncio.run(run(args.seconds, args.rounds, args.config))
    print(f"{r['rounds']} rounds of {r['seconds']:g} s idle / scraped (1 Hz /metrics + /status.json, "
          f"one page open); load average {r['load']:.1f}")
    print(f"{'window':>8} {'service CPU %':>14} {'web CPU %':>10} {'snapshots/s':>12} {'scrapes':>8} "
          f"{'missed':>7} {'late':>5}")
    for w in r["windows"]:
        print(f"{w['kind']:>8} {w['service_cpu_pct']:14.2f} {w['web_cpu_pct']:10.3f} {w['snapshots_per_s']:12.2f} "
              f"{w['scrapes']:8d} {w['missed']:7d} {w['late']:5d}")
    idle = [w for w in r["windows"] if w["kind"] == "idle"]
    busy = [w for w in r["windows"] if w["kind"] == "scraped"]
    mean = lambda ws, k: sum(w[k] for w in ws) / len(ws)  # noqa: E731
    r["service_cpu_added_pct"] = mean(busy, "service_cpu_pct") - mean(idle, "service_cpu_pct")
    r["web_cpu_scraped_pct"] = mean(busy, "web_cpu_pct")
    r["missed_idle"] = sum(w["missed"] for w in idle)
    r["missed_scraped"] = sum(w["missed"] for w in busy)
    print(f"added by scraping: service process {r['service_cpu_added_pct']:+.2f} % of a core "
          f"(web code itself {r['web_cpu_scraped_pct']:.3f} %); missed cycles idle {r['missed_idle']}, "
          f"scraped {r['missed_scraped']}   (goal: < 2 %, no more missed)")
    print(json.dumps(r))


if __name__ == "__main__":
    main()
