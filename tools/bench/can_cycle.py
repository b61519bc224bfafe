"""Benchmark: N simulated CiA-402 drives streamed in CSP by the TCS driver on the virtual bus.

For each SYNC period (10 ms and 4 ms by default) it starts N simulated drives (``tcs.sim``,
one python-can bus of their own) and the TCS's :class:`~tcs.drivers.can_system.CanDrives` on
the same virtual channel, boots and enables every drive, then streams a sine in CSP for T
seconds: the cycle callback sets one setpoint per drive and steps it (one RPDO each). A third
bus on the channel records every frame for the bus-load figure.

Figures per period:

* cycle lateness — SYNC send time minus its ideal slot (p50 / p99 / max, ms), and the time
  from SYNC to the end of the callbacks (p99 / max, ms) — it must stay below the period;
* ``late`` / ``missed`` cycles of the runner, TPDO barrier time-outs;
* setpoints missed at the drives per 10,000 (sum of the sims' ``rpdo_missed`` over
  drives × cycles);
* CPU share: process CPU time / wall time over the streaming phase (it includes the
  simulated drives, which run in this process), and the cycle thread's own share;
* bus load on a 1 Mbit/s bus: bits of the frames actually seen per cycle, each frame counted
  with worst-case bit stuffing (standard 11-bit identifier: 8n + 47 + ⌊(34 + 8n − 1)/4⌋ bits
  for n data bytes, interframe space included).

A last run at 10 ms uses the vendor-like fixture drives of ``tests/vcan/eds/`` (each drive
behaving as another EDS: no 0x1016, no 0x607D, 0x6066 limited, no homing, rpm units, 0x603F
not mappable, another revision; ``--no-fixtures`` skips it): its figures are printed the same
way and are in the JSON's ``fixture_runs``.

Run: ``python3 tools/bench/can_cycle.py [--drives 6] [--seconds 10] [--periods 0.01 0.004]``.
The last line of output is one JSON object with every figure. Goal: no missed setpoint at
10 ms with 6 axes (fixture drives too).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import uuid
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import can  # noqa: E402
import canopen  # noqa: E402

from tcs.config.can import CanSection, DriveSection, HomingSection, IdentitySection  # noqa: E402
from tcs.drivers.can_system import CanDrives  # noqa: E402
from tcs.drivers.drive import DriveState  # noqa: E402
from tcs.sim.cia402_drive import SimDrive, SimDriveParams  # noqa: E402

SCALE = 10000.0
FIXTURES = Path(__file__).resolve().parents[2] / "tests" / "vcan" / "eds"
RPM = 60.0  # rpm per unit/s of the rpm fixture (10000 counts per revolution)
#: fixture -> (drive section changes, simulated drive changes)
FIXTURE_DRIVES = {
    "vendor-no-hbconsumer": ({}, {}),
    "vendor-no-softlimits": ({}, {}),
    "vendor-fe-limited": ({"following_error_timeout": 0.0}, {}),
    "vendor-no-homing": ({"absolute": True}, {}),
    "vendor-rpm": ({"velocity_factor": RPM, "acceleration_factor": RPM},
                   {"velocity_scale": RPM / SCALE, "acceleration_scale": RPM / SCALE}),
    "vendor-pdo-restricted": ({}, {}),
    "vendor-revision": ({"identity": IdentitySection(vendor=0xABC, product=0x00402001)},
                        {"identity": (0xABC, 0x00402001, 0x00020003, 1)}),
}


def frame_bits(dlc: int) -> int:
    """Worst-case bits of a standard data frame with ``dlc`` bytes, stuffing and IFS included."""
    return 8 * dlc + 47 + (34 + 8 * dlc - 1) // 4


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def section(node_id: int) -> DriveSection:
    return DriveSection(
        node_id=node_id, identity=IdentitySection(vendor=0xABC, product=0x00402001, revision=0x00010000),
        increments_per_unit=SCALE, min_position=-100.0, max_position=100.0,
        following_error_window=0.5, max_velocity=4.0, max_acceleration=4.0,
        heartbeat_period=0.1, heartbeat_consumer_timeout=0.5, homing=HomingSection())


def run(period: float, drives: int, seconds: float, fixtures: bool = False) -> dict:
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    can_section = CanSection(interface="virtual", channel=channel, sync_period=period,
                             heartbeat_period=0.1, boot_timeout=5.0)
    names = [f"axis{i + 1}" for i in range(drives)]
    sim_bus = can.Bus(interface="virtual", channel=channel)
    tap = can.Bus(interface="virtual", channel=channel)
    sections = {n: section(i + 1) for i, n in enumerate(names)}
    params = [SimDriveParams(increments_per_unit=SCALE) for _ in range(drives)]
    if fixtures:  # drive i behaves as fixture i (cycling): the same EDS on both sides
        kinds = list(FIXTURE_DRIVES)
        for i, n in enumerate(names):
            kind = kinds[i % len(kinds)]
            drive_changes, sim_changes = FIXTURE_DRIVES[kind]
            eds = str(FIXTURES / f"{kind}.eds")
            sections[n] = replace(sections[n], eds=eds, **drive_changes)
            params[i] = replace(params[i], eds=eds, **sim_changes)
    sims = [SimDrive(sim_bus, i + 1, params[i]) for i in range(drives)]
    system = CanDrives(can_section, sections)
    state = {"t0": None, "streaming": False, "thread_cpu": None}
    amplitude, sine_period = 1.0, 5.0

    def on_cycle(cycle) -> None:
        if state["streaming"]:
            if state["t0"] is None:
                state["t0"] = cycle.sync_time
                state["thread_cpu0"] = time.thread_time()
                state["base"] = {d.name: d.status().position for d in system.drives.values()}
            t = cycle.sync_time - state["t0"]
            offset = amplitude * math.sin(2 * math.pi * t / sine_period)
            for drive in system.drives.values():
                drive.set_setpoint(state["base"][drive.name] + offset)
            state["thread_cpu"] = time.thread_time()
        system.step_all(cycle)

    try:
        for sim in sims:
            sim.start()
        system.open()
        failures = system.boot()
        if failures:
            raise SystemExit(f"boot failed: {failures}")
        system.cycle.add_callback(on_cycle)
        system.start()
        for drive in system.drives.values():
            drive.enable()
        deadline = time.monotonic() + 10
        while not all(d.status().state is DriveState.OPERATION_ENABLED for d in system.drives.values()):
            if time.monotonic() > deadline:
                raise SystemExit("drives did not enable: " + str({d.name: d.status().state for d in system.drives.values()}))
            time.sleep(0.01)
        # Discard the set-up phase: counters and lateness from here on.
        while tap.recv(0) is not None:
            pass
        missed0 = sum(s.rpdo_missed for s in sims)
        stats0 = system.cycle.stats()
        system.cycle.lateness.clear()
        system.cycle.callback_time.clear()
        state["streaming"] = True
        wall0, cpu0 = time.monotonic(), time.process_time()
        frames: dict[int, int] = {}
        end = wall0 + seconds
        while time.monotonic() < end:  # drain the tap as we go (bounded memory)
            msg = tap.recv(0.05)
            while msg is not None:
                frames[len(msg.data)] = frames.get(len(msg.data), 0) + 1
                msg = tap.recv(0)
        state["streaming"] = False
        wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
        stats = system.cycle.stats()
        missed = sum(s.rpdo_missed for s in sims) - missed0
        faults = {d.name: str(d.status().fault) for d in system.drives.values() if d.status().fault}
        following = max(abs(d.status().following_error) for d in system.drives.values())
        lateness = list(system.cycle.lateness)
        callback = list(system.cycle.callback_time)
        thread_cpu = (state["thread_cpu"] - state["thread_cpu0"]) if state["thread_cpu"] else float("nan")
    finally:
        system.close()
        for sim in sims:
            sim.stop()
        sim_bus.shutdown()
        tap.shutdown()

    cycles = stats.cycles - stats0.cycles
    bits = sum(frame_bits(dlc) * n for dlc, n in frames.items())
    per_cycle_bits = bits / max(cycles, 1)
    return {
        "period_ms": period * 1e3, "drives": drives, "seconds": round(wall, 2), "cycles": cycles,
        "lateness_p50_ms": round(percentile(lateness, 0.5) * 1e3, 3),
        "lateness_p99_ms": round(percentile(lateness, 0.99) * 1e3, 3),
        "lateness_max_ms": round(max(lateness, default=float("nan")) * 1e3, 3),
        "callback_end_p99_ms": round(percentile(callback, 0.99) * 1e3, 3),
        "callback_end_max_ms": round(max(callback, default=float("nan")) * 1e3, 3),
        "late_cycles": stats.late - stats0.late, "missed_cycles": stats.missed - stats0.missed,
        "tpdo_timeouts": stats.tpdo_timeouts - stats0.tpdo_timeouts,
        "setpoints_missed": missed,
        "missed_per_10k": round(missed / max(cycles * drives, 1) * 1e4, 3),
        "cpu_share": round(cpu / wall, 3),
        "cycle_thread_cpu_share": round(thread_cpu / wall, 3),
        "frames_per_cycle": round(sum(frames.values()) / max(cycles, 1), 2),
        "bits_per_cycle": round(per_cycle_bits, 1),
        "bus_load_1mbit": round(per_cycle_bits / period / 1e6, 3),
        "max_following_error": following, "faults": faults,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drives", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--periods", type=float, nargs="+", default=[0.010, 0.004])
    parser.add_argument("--no-fixtures", action="store_true",
                        help="skip the run with the vendor-like fixture drives")
    args = parser.parse_args(argv)
    canopen.Network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.5
    results, fixture_results = [], []
    runs = [(p, False) for p in args.periods] + ([] if args.no_fixtures else [(0.010, True)])
    for period, fixtures in runs:
        r = run(period, args.drives, args.seconds, fixtures)
        (fixture_results if fixtures else results).append(r)
        kind = " (vendor-like fixture drives, tests/vcan/eds)" if fixtures else ""
        print(f"{r['drives']} drives{kind}, SYNC {r['period_ms']:g} ms, {r['cycles']} cycles in {r['seconds']} s")
        print(f"  SYNC lateness p50 {r['lateness_p50_ms']} ms, p99 {r['lateness_p99_ms']} ms, "
              f"max {r['lateness_max_ms']} ms; SYNC->callbacks done p99 {r['callback_end_p99_ms']} ms, "
              f"max {r['callback_end_max_ms']} ms")
        print(f"  late cycles {r['late_cycles']}, missed cycles {r['missed_cycles']}, "
              f"TPDO barrier time-outs {r['tpdo_timeouts']}")
        print(f"  setpoints missed at the drives: {r['setpoints_missed']} "
              f"({r['missed_per_10k']} per 10,000)")
        print(f"  CPU share {r['cpu_share']:.1%} (incl. simulated drives), cycle thread "
              f"{r['cycle_thread_cpu_share']:.1%}")
        print(f"  {r['frames_per_cycle']} frames / {r['bits_per_cycle']} bits per cycle -> "
              f"{r['bus_load_1mbit']:.1%} of 1 Mbit/s")
        if r["faults"]:
            print(f"  FAULTS: {r['faults']}")
    ok = all(r["setpoints_missed"] == 0 for r in results + fixture_results
             if abs(r["period_ms"] - 10) < 1e-9)
    print(json.dumps({"benchmark": "can_cycle", "goal_no_missed_at_10ms": ok, "runs": results,
                      "fixture_runs": fixture_results}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
