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
way and are in the JSON's ``fixture_runs`` (in-process bus only).

``--bus socketcand`` runs the simulated drives in a second process (this script with
``--serve-sim``: a :class:`~tcs.sim.socketcand_server.SocketcandServer` bridging their virtual
bus, as ``tcs-sim`` does) and connects the TCS to it with python-can's socketcand client, as
``tcs-server --config hwconfig/sim-remote.toml`` does; the frames (counted by the server as
they pass) and the missed-setpoint counters then live in that process, and the CPU share is
this process's only. Both processes freeze their heap once up, as the services do.

Run: ``python3 tools/bench/can_cycle.py [--bus virtual|socketcand] [--drives 6] [--seconds 10]
[--periods 0.01 0.004]``. The last line of output is one JSON object with every figure. Goal:
no missed setpoint at 10 ms with 6 axes in-process (fixture drives too); no TPDO time-out and
no missed setpoint with 7 drives at 10 ms over socketcand.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import math
import sys
import time
import uuid
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import can  # noqa: E402
import canopen  # noqa: E402

from tcs.app import freeze_heap, thaw_heap  # noqa: E402
from tcs.config.can import CanSection, DriveSection, HomingSection, IdentitySection  # noqa: E402
from tcs.drivers.can_system import CanDrives  # noqa: E402
from tcs.drivers.drive import DriveState  # noqa: E402
from tcs.sim.cia402_drive import SimDrive, SimDriveParams  # noqa: E402
from tcs.sim.drive_network import SimDriveNetwork  # noqa: E402
from tcs.sim.socketcand_server import SocketcandServer  # noqa: E402

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


class LocalSims:
    """The simulated drives and the bus-load tap in this process, on a virtual channel."""

    def __init__(self, drives: int, fixtures: bool = False):
        self.channel = f"bench-{uuid.uuid4().hex[:8]}"
        self.bus = can.Bus(interface="virtual", channel=self.channel)
        self.tap = can.Bus(interface="virtual", channel=self.channel)
        params = [SimDriveParams(increments_per_unit=SCALE) for _ in range(drives)]
        if fixtures:  # drive i behaves as fixture i (cycling): the same EDS on both sides
            for i, (kind, (_, sim_changes)) in enumerate(fixture_kinds(drives)):
                params[i] = replace(params[i], eds=str(FIXTURES / f"{kind}.eds"), **sim_changes)
        self.sims = [SimDrive(self.bus, i + 1, params[i]) for i in range(drives)]
        self.frames: dict[int, int] = {}

    def can_section(self, period: float) -> CanSection:
        return CanSection(interface="virtual", channel=self.channel, sync_period=period,
                          heartbeat_period=0.1, boot_timeout=5.0)

    def start(self) -> None:
        for sim in self.sims:
            sim.start()

    def mark(self) -> None:
        """Forget the frames seen so far."""
        while self.tap.recv(0) is not None:
            pass
        self.frames = {}

    def drain(self, wait: float) -> None:
        msg = self.tap.recv(wait)
        while msg is not None:
            self.frames[len(msg.data)] = self.frames.get(len(msg.data), 0) + 1
            msg = self.tap.recv(0)

    def missed(self) -> int:
        return sum(s.rpdo_missed for s in self.sims)

    def stop(self) -> None:
        for sim in self.sims:
            sim.stop()
        self.bus.shutdown()
        self.tap.shutdown()


class RemoteSims:
    """The simulated drives in another process (``--serve-sim``), reached over socketcand."""

    def __init__(self, drives: int):
        self.proc = subprocess.Popen([sys.executable, __file__, "--serve-sim", "--drives", str(drives)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline()
        if not line.startswith("PORT "):
            self.stop()
            raise SystemExit(f"simulator process did not start: {line!r}")
        self.port = int(line.split()[1])
        self.frames: dict[int, int] = {}

    def _ask(self, command: str) -> dict:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def can_section(self, period: float) -> CanSection:
        return CanSection(interface="socketcand", channel="can0", host="127.0.0.1", port=self.port,
                          sync_period=period, heartbeat_period=0.1, boot_timeout=5.0)

    def start(self) -> None:
        pass

    def mark(self) -> None:
        self._ask("mark")

    def drain(self, wait: float) -> None:
        time.sleep(wait)

    def missed(self) -> int:
        reply = self._ask("count")
        self.frames = {int(k): v for k, v in reply["frames"].items()}
        return reply["missed"]

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.close()
                self.proc.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
        self.proc.stdout.close()


class CountingServer(SocketcandServer):
    """The socketcand server, counting every frame of the bus by length as it passes: the
    drives' frames on their way out, the master's on their way in (no tap, no queue)."""

    def __init__(self, channel: str):
        super().__init__(channel)
        self.frames: dict[int, int] = {}

    def _count(self, msg: can.Message) -> None:
        n = len(msg.data)
        self.frames[n] = self.frames.get(n, 0) + 1

    def _on_bus_frame(self, msg: can.Message) -> None:  # notifier thread
        if not msg.is_error_frame:
            self._count(msg)
        super()._on_bus_frame(msg)

    def from_client(self, client, msg: can.Message) -> None:
        self._count(msg)
        super().from_client(client, msg)


def serve_sim(drives: int) -> int:
    """``--serve-sim``: simulated drives behind a socketcand server; commands on stdin.

    Prints ``PORT n`` when ready; then answers ``mark`` (forget the frames seen so far) and
    ``count`` (``{"missed": …, "frames": {dlc: n}}``) with one JSON line each; ends at EOF.
    """
    async def main() -> None:
        channel = f"bench-{uuid.uuid4().hex[:8]}"
        server = CountingServer(channel)
        port = await server.start()
        network = await asyncio.to_thread(
            SimDriveNetwork, {"interface": "virtual", "channel": channel},
            {i + 1: SimDriveParams(increments_per_unit=SCALE) for i in range(drives)})
        freeze_heap()  # as tcs-sim does once it is up
        print(f"PORT {port}", flush=True)
        try:
            while True:
                line = (await asyncio.to_thread(sys.stdin.readline)).strip()
                if not line:
                    break
                if line == "mark":
                    server.frames = {}
                    print("{}", flush=True)
                elif line == "count":
                    missed = sum(network[n].rpdo_missed for n in network)
                    print(json.dumps({"missed": missed, "frames": dict(server.frames)}), flush=True)
        finally:
            thaw_heap()
            await asyncio.to_thread(network.stop)
            await server.stop()

    asyncio.run(main())
    return 0


def fixture_kinds(drives: int) -> list[tuple[str, tuple[dict, dict]]]:
    """The fixture each of ``drives`` drives behaves as (cycling through FIXTURE_DRIVES)."""
    kinds = list(FIXTURE_DRIVES.items())
    return [kinds[i % len(kinds)] for i in range(drives)]


def run(period: float, drives: int, seconds: float, bus: str = "virtual",
        fixtures: bool = False) -> dict:
    sim = RemoteSims(drives) if bus == "socketcand" else LocalSims(drives, fixtures)
    can_section = sim.can_section(period)
    names = [f"axis{i + 1}" for i in range(drives)]
    sections = {n: section(i + 1) for i, n in enumerate(names)}
    if fixtures:
        for n, (kind, (drive_changes, _)) in zip(names, fixture_kinds(drives)):
            sections[n] = replace(sections[n], eds=str(FIXTURES / f"{kind}.eds"), **drive_changes)
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
        freeze_heap()  # as tcs-server does once it serves
        # Discard the set-up phase: counters and lateness from here on.
        sim.mark()
        missed0 = sim.missed()
        sim.mark()
        stats0 = system.cycle.stats()
        system.cycle.lateness.clear()
        system.cycle.callback_time.clear()
        state["streaming"] = True
        wall0, cpu0 = time.monotonic(), time.process_time()
        end = wall0 + seconds
        while time.monotonic() < end:  # drain the tap as we go (bounded memory)
            sim.drain(0.05)
        state["streaming"] = False
        wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
        stats = system.cycle.stats()
        missed = sim.missed() - missed0
        frames = sim.frames
        faults = {d.name: str(d.status().fault) for d in system.drives.values() if d.status().fault}
        following = max(abs(d.status().following_error) for d in system.drives.values())
        lateness = list(system.cycle.lateness)
        callback = list(system.cycle.callback_time)
        thread_cpu = (state["thread_cpu"] - state["thread_cpu0"]) if state["thread_cpu"] else float("nan")
    finally:
        thaw_heap()
        system.close()
        sim.stop()

    cycles = stats.cycles - stats0.cycles
    bits = sum(frame_bits(dlc) * n for dlc, n in frames.items())
    per_cycle_bits = bits / max(cycles, 1)
    return {
        "bus": bus, "period_ms": period * 1e3, "drives": drives, "seconds": round(wall, 2), "cycles": cycles,
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
    parser.add_argument("--bus", choices=["virtual", "socketcand"], default="virtual",
                        help="virtual: drives in this process; socketcand: in a second process")
    parser.add_argument("--drives", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--periods", type=float, nargs="+", default=[0.010, 0.004])
    parser.add_argument("--no-fixtures", action="store_true",
                        help="skip the run with the vendor-like fixture drives")
    parser.add_argument("--serve-sim", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.serve_sim:
        return serve_sim(args.drives)
    canopen.Network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.5
    results, fixture_results = [], []
    runs = [(p, False) for p in args.periods]
    if args.bus == "virtual" and not args.no_fixtures:
        runs.append((0.010, True))
    for period, fixtures in runs:
        r = run(period, args.drives, args.seconds, args.bus, fixtures)
        (fixture_results if fixtures else results).append(r)
        kind = " (vendor-like fixture drives, tests/vcan/eds)" if fixtures else ""
        print(f"{r['bus']} bus, {r['drives']} drives{kind}, SYNC {r['period_ms']:g} ms, "
              f"{r['cycles']} cycles in {r['seconds']} s")
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
    at_10ms = [r for r in results + fixture_results if abs(r["period_ms"] - 10) < 1e-9]
    ok = all(r["setpoints_missed"] == 0 for r in at_10ms)
    figures = {"benchmark": "can_cycle", "bus": args.bus, "goal_no_missed_at_10ms": ok}
    if args.bus == "socketcand":
        figures["goal_no_tpdo_timeout_at_10ms"] = all(r["tpdo_timeouts"] == 0 for r in at_10ms)
    print(json.dumps({**figures, "runs": results, "fixture_runs": fixture_results}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
