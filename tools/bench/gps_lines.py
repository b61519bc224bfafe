"""Benchmark of the GPS reader (issue 43): what judging a sentence costs, and the time's delay.

Run: ``python3 tools/bench/gps_lines.py [--seconds 10]``. Prints the figures, then (last line)
one JSON object with them.

* **cost per sentence** — :meth:`GpsReader.feed` of a u-blox-like burst (UBX bytes before the
  sentences, GNGGA, GNRMC, GNGSV, GNZDA), per sentence, against the baseline measured in the
  same run: ``pynmea2.parse`` alone, which is what the reader did per line before the judging.
* **time delay** — a writer on a pty sends an RMC+ZDA burst every 50 ms, each naming the
  writer's time; the reader stamps each line at its arrival. The delay is the stamp minus the
  write (both on the monotonic clock): what ``GPS.TIME`` lags the receiver by, besides the
  receiver's own output delay. p50, p95, max; and the baseline of the same run: a bare
  ``add_reader`` callback stamping each read of the same writer's lines.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import sys
import time
import tty
from datetime import datetime, timezone
from pathlib import Path

import pynmea2

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from tcs.config.gps import GpsSection  # noqa: E402
from tcs.drivers.gps import GpsReader  # noqa: E402
from tcs.sim.gps import UBX_BLOB, checksum  # noqa: E402


def line(body: str) -> bytes:
    return f"${body}*{checksum(body)}\r\n".encode()


BURST = [
    "GNGGA,094112.00,5231.04821,N,01323.51215,E,1,12,0.58,41.6,M,44.3,M,,",
    "GNRMC,094112.00,A,5231.04821,N,01323.51215,E,0.012,,020621,,,A,V",
    "GPGSV,3,1,11,02,21,046,33,05,11,313,27,07,32,256,40,08,49,068,44",
    "GNZDA,094112.00,02,06,2021,00,00",
]


def cost(rounds: int = 3000) -> dict:
    data = b"".join(UBX_BLOB + line(b) for b in BURST)
    texts = [line(b).decode().strip() for b in BURST]
    reader = GpsReader(GpsSection(url="unused"))
    t0 = time.perf_counter()
    for _ in range(rounds):
        reader.feed(data)
    new = (time.perf_counter() - t0) / (rounds * len(BURST))
    t0 = time.perf_counter()
    for _ in range(rounds):
        for text in texts:
            pynmea2.parse(text, check=True)
    base = (time.perf_counter() - t0) / (rounds * len(BURST))
    assert reader.status.sentences >= rounds * 3, reader.status
    return {"sentence_us": new * 1e6, "baseline_parse_us": base * 1e6, "ratio": new / base}


async def bare_delay(seconds: float) -> dict:
    """Baseline: the same writer, read by a bare ``add_reader`` callback that stamps each read."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    os.set_blocking(slave, False)
    loop = asyncio.get_running_loop()
    delays: list[float] = []
    pending: list[float] = []

    def readable():
        stamp = time.monotonic()
        try:
            os.read(slave, 4096)
        except BlockingIOError:
            return
        if pending:
            delays.append(stamp - pending.pop())

    loop.add_reader(slave, readable)
    end = loop.time() + seconds
    try:
        while loop.time() < end:
            pending[:] = [time.monotonic()]
            os.write(master, line("GPRMC,094112.00,A,5231.04821,N,01323.51215,E,0.0,0.0,020621,,,A"))
            await asyncio.sleep(0.05)
    finally:
        loop.remove_reader(slave)
        os.close(master)
        os.close(slave)
    ms = sorted(d * 1e3 for d in delays)
    return {"bare_p50_ms": statistics.median(ms), "bare_p95_ms": ms[int(0.95 * (len(ms) - 1))]}


async def delay(seconds: float) -> dict:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    reader = GpsReader(GpsSection(url=os.ttyname(slave), position_timeout=0.5, time_timeout=0.5))
    await reader.start()
    written: dict[float, float] = {}
    delays: list[float] = []
    loop = asyncio.get_running_loop()
    end = loop.time() + seconds
    try:
        await asyncio.sleep(0.3)
        while loop.time() < end:
            now = time.time()
            t = round(now - now % 0.01, 2)
            dt = datetime.fromtimestamp(t, tz=timezone.utc)
            hms = dt.strftime("%H%M%S.") + f"{dt.microsecond // 10000:02d}"
            data = (line(f"GPGGA,{hms},5231.04821,N,01323.51215,E,1,09,0.9,41.6,M,44.3,M,,")
                    + line(f"GPRMC,{hms},A,5231.04821,N,01323.51215,E,0.0,0.0,{dt:%d%m%y},,,A"))
            written[t] = time.monotonic()
            os.write(master, data)
            try:
                st = await reader.wait_for(lambda s: s.time is not None and abs(s.time - t) < 1e-6, 2.0)
                delays.append(st.time_received - written[t])
            except asyncio.TimeoutError:
                pass
            await asyncio.sleep(0.05)
    finally:
        await reader.stop()
        os.close(master)
        os.close(slave)
    delays.sort()
    ms = [d * 1e3 for d in delays]
    return {"samples": len(ms), "delay_p50_ms": statistics.median(ms),
            "delay_p95_ms": ms[int(0.95 * (len(ms) - 1))], "delay_max_ms": ms[-1]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    c = cost()
    print(f"cost per sentence: {c['sentence_us']:.1f} µs (read, find, parse, judge); "
          f"pynmea2.parse alone {c['baseline_parse_us']:.1f} µs; ratio {c['ratio']:.2f}")
    d = asyncio.run(delay(args.seconds))
    print(f"time delay write -> stamp over a pty: p50 {d['delay_p50_ms']:.2f} ms, "
          f"p95 {d['delay_p95_ms']:.2f} ms, max {d['delay_max_ms']:.2f} ms ({d['samples']} bursts)")
    d.update(asyncio.run(bare_delay(args.seconds)))
    print(f"baseline, a bare add_reader on the same pty: p50 {d['bare_p50_ms']:.2f} ms, "
          f"p95 {d['bare_p95_ms']:.2f} ms")
    print(json.dumps({**c, **d}))


if __name__ == "__main__":
    main()
