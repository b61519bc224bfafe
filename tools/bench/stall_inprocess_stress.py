"""Stress run: the in-process service as the tests start it, AZ slewing at full speed while the
host is loaded — does a stall of the shared process end in a drive's following-error stop?

Starts ``tests/hw_axes_fast.toml`` with :class:`support.live.LiveService` (the service in a
thread of this process, the simulated drives on the in-process virtual bus, as ``tests/``
do), makes AZ ready and moves it 260 / −80 / 150° in turn (160°/s) while a second TPL2 client
polls ``AZ.REALPOS`` as fast as it answers (the tests' watcher). A move that ends with an error
is counted; for it the simulated AZ drive's last latched setpoints (time, target, step,
continuous) and the last log lines on re-anchors, dropped frames and drive faults are printed;
the axis is made ready again. Not a benchmark with a baseline: run it on two versions under
the same load (several at once, with CPU burners) and compare the counts.

Run: ``python3 tools/bench/stall_inprocess_stress.py [--tests tests] [--moves 30]``.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


class Watch(logging.Handler):
    """Keeps the log lines on re-anchors, dropped frames and drive faults."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if ("error code" in message or "re-anchored" in message or "dropped" in message):
            self.lines.append(f"{time.monotonic():.3f} {record.name} {message}")


async def ready(c) -> None:
    await c.set("CABINET.POWER=1", 60)
    await c.set("AZ.POWER=1", 30)
    if float(await c.value("AZ.REFERENCED")) < 1:
        await c.set("AZ.REINIT=1", 30)
        await c.wait("AZ.REFERENCED", lambda v: float(v) == 1.0, 60)


def dump(live, watch: Watch) -> None:
    targets = list(live.telescope.sims[1].csp_targets)[-30:]
    end = targets[-1][0] if targets else 0.0
    print("  AZ drive's latched setpoints (s before the last, target, step, continuous):")
    previous = None
    for t, x, continuous in targets:
        step = "" if previous is None else f"{x - previous:+.4f}"
        print(f"    {t - end:+.3f} {x:.4f} {step} {continuous}")
        previous = x
    for line in watch.lines[-10:]:
        print("  >", line[:300])


async def run(live, moves: int, watch: Watch) -> int:
    from support.opentci_client import Client
    c = await Client.connect(live.port)
    watcher = await Client.connect(live.port)
    failed = 0
    try:
        await ready(c)
        for i in range(moves):
            target = (260, -80, 150)[i % 3]
            task = asyncio.ensure_future(c.set(f"AZ.TARGETPOS={target}", 60))
            while not task.done():
                await watcher.value("AZ.REALPOS")
            lines = await task
            if not lines[-1].endswith("COMPLETE") or any("ERROR" in x for x in lines):
                failed += 1
                print(f"move {i} to {target} failed: {lines[-3:]}", flush=True)
                dump(live, watch)
                await asyncio.sleep(1.0)
                await c.set("CABINET.ERROR_STATE=0", 30)
                await c.set("AZ.ERROR_STATE=0", 30)
                await ready(c)
    finally:
        await c.close()
        await watcher.close()
    return failed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tests", type=Path, default=ROOT / "tests", help="the tests folder")
    parser.add_argument("--moves", type=int, default=30)
    args = parser.parse_args()
    sys.path.insert(0, str(args.tests))
    from support.live import LiveService

    watch = Watch()
    logging.getLogger().addHandler(watch)
    logging.getLogger().setLevel(logging.INFO)
    logging.getLogger("tcs.drivers.cycle").setLevel(logging.DEBUG)
    live = LiveService(args.tests / "hw_axes_fast.toml", Path(tempfile.mkdtemp()) / "state").start()
    try:
        failed = asyncio.run(run(live, args.moves, watch))
        stats = live.telescope.cabinet.loop_stats()
        resumes = getattr(live.telescope.axis("AZ"), "resumes", None)
        print(f"moves {args.moves} failed {failed}; cycles {stats['cycles']}, late {stats['late']}, "
              f"missed {stats['missed']}; AZ re-anchors {resumes}")
    finally:
        live.stop()


if __name__ == "__main__":
    main()
