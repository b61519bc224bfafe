"""Benchmark: the dome, cover and sensor modules over TPL2 against the simulated PLCs.

Starts the service of ``hwconfig/sim.toml`` in this process (PLCs simulated on free ports,
polled at the file's 10 Hz) and a TPL2 client, then measures:

* ``get_ms``: round trip of one GET of 8 PLC-backed variables (sensors, dome, cover, switch),
  p50/p99 — reads come from the last poll, so this is the server's own cost;
* ``completion_lag_ms``: for slit moves (``DOME[1].TARGETPOS``), the time from the moment the
  simulated slit actually arrives (its motion profile's end, same clock) to the client
  receiving ``COMMAND COMPLETE``, p50/max — bounded by one poll interval plus a poll;
* ``poll_cost_us``: CPU time the modules' poll listeners take per poll cycle of the dome PLC
  (every DOME[] part, sensors and the interlock), mean.

Run: ``python3 tools/bench/enclosure.py [--moves 10] [--gets 300]``. The last output line is one
JSON object with every figure.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from support.opentci_client import Client  # noqa: E402
from tcs.app import Service  # noqa: E402
from tcs.config import load_config  # noqa: E402
from tcs.config.sections import StateSection  # noqa: E402

GET = ["SENSOR[0].VALUE", "SENSOR[3].VALUE", "DOME[0].REALPOS", "DOME[1].REALPOS",
       "DOME[1].MOTION_STATE", "COVER.REALPOS", "COVER.LIMIT_STATE", "SWITCH[0].VALUE"]


def pct(values, q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))] if values else float("nan")


async def main(moves: int, gets: int) -> dict:
    config = load_config()
    with tempfile.TemporaryDirectory() as state:
        cfg = dataclasses.replace(config, server=dataclasses.replace(config.server, port=0, opentsi_port=-1), web=dataclasses.replace(config.web, port=-1), indi=dataclasses.replace(config.indi, port=-1),
                                  alpaca=dataclasses.replace(config.alpaca, port=-1),
                                  state=StateSection(path=state))
        object.__setattr__(cfg, "source", config.source)
        service = Service(cfg)
        port = await service.start()
        try:
            return await measure(service, port, moves, gets)
        finally:
            await service.stop()


async def measure(service, port: int, moves: int, gets: int) -> dict:
    peripherals = service.telescope.peripherals
    driver = peripherals.drivers["dome"]
    listeners = list(driver._poll_listeners)
    spent: list[float] = []

    def timed(snapshot) -> None:
        t0 = time.thread_time()
        for cb in listeners:
            cb(snapshot)
        spent.append(time.thread_time() - t0)

    driver._poll_listeners[:] = [timed]  # the same listeners, timed as one
    slit = peripherals.sims.plcs["dome"].axes["slit"]
    c = await Client.connect(port)
    try:
        lines = await c.set("CABINET.POWER=1", 120)
        assert lines[-1].endswith("COMPLETE"), lines
        get_ms = []
        for i in range(gets):
            t0 = time.perf_counter()
            await c.command(i + 1, "GET " + ";".join(GET))
            get_ms.append((time.perf_counter() - t0) * 1000)
        lags = []
        for i in range(moves):
            target = 5.0 + (i * 3.7) % 10.0 if i % 2 == 0 else 0.0  # durations not whole polls
            lines = await c.set(f"DOME[1].TARGETPOS={target}", 120)
            done = time.monotonic()
            assert lines[-2].endswith("DATA OK DOME[1].TARGETPOS"), lines
            lags.append((done - slit.profile.end) * 1000)
        poll = driver.section.poll_interval
        return {
            "get_vars": len(GET),
            "get_ms_p50": round(pct(get_ms, 0.5), 3), "get_ms_p99": round(pct(get_ms, 0.99), 3),
            "completion_lag_ms_p50": round(pct(lags, 0.5), 1), "completion_lag_ms_max": round(max(lags), 1),
            "poll_interval_ms": poll * 1000,
            "poll_cost_us_mean": round(1e6 * sum(spent) / max(1, len(spent)), 1),
            "poll_cycles": len(spent),
        }
    finally:
        await c.close()


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--moves", type=int, default=12)
    p.add_argument("--gets", type=int, default=300)
    args = p.parse_args()
    figures = asyncio.run(main(args.moves, args.gets))
    print(f"GET of {figures['get_vars']} PLC variables: p50 {figures['get_ms_p50']} ms, "
          f"p99 {figures['get_ms_p99']} ms")
    print(f"TARGETPOS completion after the slit arrived: p50 {figures['completion_lag_ms_p50']} ms, "
          f"max {figures['completion_lag_ms_max']} ms (poll every {figures['poll_interval_ms']:g} ms)")
    print(f"module poll listeners: {figures['poll_cost_us_mean']} µs CPU per dome-PLC poll "
          f"({figures['poll_cycles']} polls)")
    print(json.dumps(figures))
