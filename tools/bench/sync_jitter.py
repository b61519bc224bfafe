"""Benchmark: a jittery SYNC during a 5°/s slew — the drive's speed over real time (issue 39
item 10).

The simulated telescope's AZ (``hwconfig/sim.toml``: the drive in CSP, ``[axes.az]`` 5°/s) in
one process on python-can's virtual bus, as ``tcs-server`` runs it: the TCS's CAN master
(:class:`~tcs.drivers.can_system.CanDrives`, the cycle runner sending SYNC itself), the AZ
:class:`~tcs.axes.axis.Axis` and :class:`~tcs.axes.control_loop.ControlLoop` (``Master`` of
``stall.py``), and the simulated drive. Once AZ cruises at 5°/s, the cycle runner's sleep to
each SYNC slot is made longer by a repeating pattern of lateness — as a busy host wakes a
thread late — for ``--cycles`` SYNCs, while a thread samples the simulated drive every ~2 ms
(its demand and motor position on its own clock).

Each pattern runs twice in the same process and hour: with the setpoints moved on by their
SYNC's lateness (``CycleSource.retime``, the default) and without (the baseline: setpoints
sent as the axis made them for the slot). Printed per run: the peak mean speed of the demand
and of the motor over 100 ms windows against the axis's 5°/s (goal ≤), and how many SYNCs
the host itself disturbed (``retime_delays``: the runner preempted between the setpoints'
retime and the SYNC; ``skips``: slots it skipped) — their windows are also judged apart
(``clean``). The last line is one JSON object with every figure.

Run: ``python3 tools/bench/sync_jitter.py [--patterns 0-9ms 7th6ms 15ms] [--cycles 300]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from stall import Master, Sampler, sections, wait  # noqa: E402

from tcs.drivers.cycle import RETIME_AGAIN  # noqa: E402
from tcs.sim.cia402_drive import SimDrive  # noqa: E402
from tcs.sim.drive_network import params_from_config  # noqa: E402

GOAL = 150.0
WINDOW = 0.1
#: SYNC lateness, s, repeated (lengths that do not divide the 100 ms window)
PATTERNS = {"0-9ms": [0.0, 0.004, 0.001, 0.009, 0.0, 0.002, 0.006, 0.0, 0.003, 0.008, 0.0,
                      0.005, 0.007],
            "7th6ms": [0.0] * 6 + [0.006],
            "15ms": [0.0] * 16 + [0.015]}


class LateWake(threading.Event):
    """The cycle runner's sleep, overslept by ``pattern`` (s, repeated)."""

    def __init__(self) -> None:
        super().__init__()
        self.pattern: list[float] = []
        self._k = 0

    def wait(self, timeout=None):
        if timeout is not None and self.pattern:
            timeout += self.pattern[self._k % len(self.pattern)]
            self._k += 1
        return super().wait(timeout)


def peak_speeds(samples, skip=()) -> tuple[float, float, int]:
    """Peak mean speed of (demand, motor) over WINDOW s, over windows clear of ``skip``."""
    s = [x for x in samples if x[3] == "OPERATION ENABLED"]
    best, judged, j = [0.0, 0.0], 0, 0
    for i in range(len(s)):
        while j < len(s) and s[j][0] - s[i][0] < WINDOW:
            j += 1
        if j >= len(s):
            break
        if any(a < s[j][0] and s[i][0] < b for a, b in skip):
            continue
        judged += 1
        dt = s[j][0] - s[i][0]
        best[0] = max(best[0], (s[j][1] - s[i][1]) / dt)
        best[1] = max(best[1], (s[j][4] - s[i][4]) / dt)
    return round(best[0], 4), round(best[1], 4), judged


#: each run's (retime, retime_again): without the retime (the baseline), retimed once before
#: the SYNC, and retimed again when the runner was preempted while sending
MODES = {"off": (False, 0), "once": (True, 0), "on": (True, RETIME_AGAIN)}


def run_case(pattern: str, mode: str, cycles: int) -> dict:
    retime, again = MODES[mode]
    config, _, _, _ = sections("csp", {})
    channel = f"jitter-{uuid.uuid4().hex[:8]}"
    params = params_from_config(config)[config.drives["az"].node_id]
    import can
    sim_bus = can.Bus(interface="virtual", channel=channel)
    sim = SimDrive(sim_bus, config.drives["az"].node_id, params)
    sim.start()
    master = None
    try:
        master = Master("csp", {"interface": "virtual", "channel": channel})
        source = master.system.cycle
        wake = source._stop = LateWake()  # (before the runner's next sleep; it only waits on it)
        source.retime, source.retime_again = retime, again
        master.power()
        master.command("target", GOAL)
        wait(lambda: sim.velocity > 4.99, 60, "cruising at 5°/s")
        source.retime_delays.clear()
        source.skips.clear()
        start = master.loop.cycles
        rec = Sampler(sim)
        wake.pattern = PATTERNS[pattern]
        wait(lambda: master.loop.cycles > start + cycles, 120, f"{cycles} cycles")
        wake.pattern = []
        samples = rec.stop()
        period = source.period
        irregular = [t for t, _ in source.retime_delays] + list(source.skips)
        skip = [(t - period, t + 6 * period) for t in irregular]
        demand, motor, _ = peak_speeds(samples)
        clean_demand, clean_motor, judged = peak_speeds(samples, skip)
        return {"pattern": pattern, "retime": mode, "demand": demand, "motor": motor,
                "clean_demand": clean_demand, "clean_motor": clean_motor, "clean_windows": judged,
                "preempted": len(source.retime_delays), "skipped": len(source.skips),
                "sent_again": source.stats().retimed_again,
                "fault": None if master.axis.fault is None else master.axis.fault.message,
                "emcy": [f"0x{c:04X}" for c in sim.emcy_sent]}
    finally:
        if master is not None:
            master.close()
        sim.stop()
        sim_bus.shutdown()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--patterns", nargs="+", default=list(PATTERNS), choices=list(PATTERNS))
    ap.add_argument("--cycles", type=int, default=300)
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    args = ap.parse_args(argv)
    results = []
    print(f"{'pattern':8} {'retime':6} {'demand':>7} {'motor':>7} {'clean d':>8} {'clean m':>8} "
          f"{'windows':>7} {'preempted':>9} {'skipped':>7} {'again':>5}   (deg/s over {WINDOW * 1e3:g} ms; "
          f"axis limit 5)")
    for pattern in args.patterns:
        for mode in args.modes:
            r = run_case(pattern, mode, args.cycles)
            results.append(r)
            print(f"{pattern:8} {mode:6} {r['demand']:7.3f} {r['motor']:7.3f} "
                  f"{r['clean_demand']:8.3f} {r['clean_motor']:8.3f} {r['clean_windows']:7d} "
                  f"{r['preempted']:9d} {r['skipped']:7d} {r['sent_again']:5d}"
                  + (f"   fault: {r['fault']}" if r["fault"] else ""), flush=True)
    print(json.dumps({"sync_jitter": results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
