"""Benchmark: the control process stopped (SIGSTOP/SIGCONT) mid-slew — what the drive does.

For each mode (CSP, IP, CSV) and each gap (0.05, 0.1, 0.2, 0.3, 0.5 s) a fresh pair of
processes: this script hosts the simulated AZ drive of the simulated telescope
(``hwconfig/sim.toml``: ``[simulation.drives.az]``, the motor 8°/s and 10°/s²) on a virtual bus
behind a :class:`~tcs.sim.socketcand_server.SocketcandServer`, as ``tcs-sim`` does; a child
(this script with ``--master``) is the control process — the TCS's own CAN master
(:class:`~tcs.drivers.can_system.CanDrives` over python-can's socketcand client, as
``tcs-server --config hwconfig/sim-remote.toml`` has it), the AZ :class:`~tcs.axes.axis.Axis`
(``[axes.az]``: 5°/s, 2°/s², stop deceleration 4°/s²) and the
:class:`~tcs.axes.control_loop.ControlLoop` — with ``[drives.az]`` in the mode of the case.
The axis slews to +150°; once the motor cruises at 5°/s the child gets SIGSTOP, ``gap`` s later
SIGCONT, and 1.5 s after that the case ends. A thread of this process samples the simulated
drive every ~2 ms (its demand, motor position and speed, state: what a scope on the drive
would show; the drive and its clock never stop).

Printed per case:

* ``reversal`` — the largest step back of the drive's demand (while it follows it, Operation
  enabled) or of the motor against the slew, degrees (goal 0);
* ``peak speed`` — the motor's, against the axis's 5°/s (goal ≤);
* ``peak decel`` — the motor's largest deceleration over 20 ms windows, against the
  configured stop deceleration 4°/s² (goal ≤), over the whole case and after the drive left
  Operation enabled (its own stopping ramp);
* ``faults`` — the EMCY codes the drive sent, and its state at the end (goal: none for gaps
  shorter than the drive's RPDO deadline, 0.5 s — ``master_loss_timeout``; a controlled stop,
  EMCY 0x8250 and the ramp at 0x6085, for longer ones);
* ``resumes`` — cycles the master re-anchored after a gap (tcs.axes.axis).

``--bridging hold`` makes the simulated drive hold its last setpoint while setpoints are
missing instead of extrapolating them (``SimDriveParams.bridging``): the motor then brakes at
its own limit during the gap, which no master can prevent; the master's part is what follows.

Over socketcand when the socketcand client works here (it needs python-can's socketcand
interface); ``--bus virtual`` (or a failing socketcand) runs master and drive in one process on
the virtual bus and stops the master by holding its cycle thread instead — said in the
output. Run: ``python3 tools/bench/stall.py [--modes csp ip csv] [--gaps 0.05 0.1 0.2 0.3
0.5] [--bridging extrapolate|hold]``; ``--gaps 0`` is the baseline (the same slew, SIGSTOP and
SIGCONT at once); the last line is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from tcs.config import DEFAULT_CONFIG, load_config  # noqa: E402
from tcs.sim.cia402_drive import SimDrive  # noqa: E402
from tcs.sim.drive_network import params_from_config  # noqa: E402
from tcs.sim.socketcand_server import SocketcandServer  # noqa: E402

GOAL = 150.0
CRUISE = 4.99
STOPPED = ("QUICK STOP ACTIVE", "SWITCH ON DISABLED", "FAULT REACTION ACTIVE", "FAULT")


def sections(mode: str, can_kwargs: dict):
    """(can, drive, axis) sections of the simulated telescope's AZ, the drive in ``mode``."""
    config = load_config(DEFAULT_CONFIG)
    axis = config.axes["az"]
    drive = dataclasses.replace(config.drives["az"], mode=mode, absolute=True)
    try:  # 0x6085 at most the axis's stop deceleration, as the service has it
        from tcs.drivers.can_system import stop_decelerations
        drive = stop_decelerations({"az": drive}, {"az": axis})["az"]
    except (ImportError, TypeError, AttributeError):
        drive = dataclasses.replace(drive, quick_stop_deceleration=axis.stop_deceleration)
    can = dataclasses.replace(config.can, idle_sync_period=0.0, **can_kwargs)
    return config, can, drive, config.axes["az"]


class Events:
    def __getattr__(self, name):
        return lambda *a, **k: None


class Master:
    """The control process's stack for AZ: CanDrives, Axis, ControlLoop."""

    def __init__(self, mode: str, can_kwargs: dict):
        from tcs.axes.axis import Axis
        from tcs.axes.control_loop import ControlLoop
        from tcs.drivers.can_system import CanDrives
        config, can, drive, axis = sections(mode, can_kwargs)
        self.system = CanDrives(can, {"az": drive}, resolve=config.resolve)
        self.system.open()
        failures = self.system.boot()
        if failures:
            raise SystemExit(f"boot failed: {failures}")
        self.drive = self.system.drives["az"]
        self.axis = Axis("az", axis, self.drive, Events(), time.time, can.sync_period)
        self.loop = ControlLoop([self.axis], self.system.cycle, time.time)
        self.hold = 0.0
        self.system.cycle.add_callback(self._held)
        self.system.start()

    def _held(self, cycle) -> None:  # (the in-process stand-in for SIGSTOP)
        if self.hold:
            hold, self.hold = self.hold, 0.0
            time.sleep(hold)

    def command(self, kind: str, value) -> None:
        with self.axis._lock:
            self.axis._commands.append((kind, value, None, None))

    def power(self) -> None:
        self.command("power", True)
        deadline = time.monotonic() + 30
        while self.axis.power_state != 1.0:
            if time.monotonic() > deadline:
                raise SystemExit(f"AZ did not power on: {self.drive.status()}")
            time.sleep(0.02)

    def report(self) -> dict:
        st = self.drive.status()
        return {"resumes": getattr(self.axis, "resumes", None), "fault": None if self.axis.fault is None
                else self.axis.fault.message, "state": st.state.value,
                "stats": dict(self.loop.stats(), loop_time_hist=None, lateness_hist=None)}

    def close(self) -> None:
        self.system.close()


def serve_master(mode: str, port: int) -> int:
    """``--master``: the control process over socketcand; commands on stdin, JSON replies."""
    master = Master(mode, {"interface": "socketcand", "host": "127.0.0.1", "port": port,
                           "channel": "can0"})
    try:
        master.power()
        print(json.dumps({"pid": os.getpid()}), flush=True)
        for line in sys.stdin:
            words = line.split()
            if not words:
                break
            if words[0] == "slew":
                master.command("target", float(words[1]))
                print("{}", flush=True)
            elif words[0] == "report":
                print(json.dumps(master.report()), flush=True)
    finally:
        master.close()
    return 0


class Sampler:
    """(time, demand, speed, state, motor position) of the simulated drive every ~2 ms."""

    def __init__(self, sim: SimDrive):
        self.sim, self.samples = sim, []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            with self.sim.lock:
                lg = self.sim._now()
                self.samples.append((lg.axis.t, lg.axis.demand()[0], lg.axis.v, lg.state.value,
                                     lg.axis.x))
            time.sleep(0.002)

    def stop(self) -> list:
        self._stop.set()
        self._thread.join(5)
        return self.samples


def reversal(samples) -> float:
    worst = 0.0
    for values in ([d for _, d, _, s, _ in samples if s == "OPERATION ENABLED"],
                   [x for *_, x in samples]):
        top = -float("inf")
        for value in values:
            top = max(top, value)
            worst = max(worst, top - value)
    return worst


def peak_decel(samples, window: float = 0.02) -> float:
    worst, j = 0.0, 0
    for i in range(len(samples)):
        while j < len(samples) and samples[j][0] - samples[i][0] < window:
            j += 1
        if j >= len(samples):
            break
        (t0, _, v0, *_), (t1, _, v1, *_) = samples[i], samples[j]
        if v0 > 0:
            worst = max(worst, (v0 - v1) / (t1 - t0))
    return worst


def wait(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.01)


def run_case(mode: str, gap: float, bridging: str, bus: str) -> dict:
    config, _, _, _ = sections(mode, {})
    channel = f"stall-{uuid.uuid4().hex[:8]}"
    params = params_from_config(config)[config.drives["az"].node_id]
    if hasattr(params, "bridging"):  # (a baseline of code before it had the choice)
        params = dataclasses.replace(params, bridging=bridging)
    import can
    sim_bus = can.Bus(interface="virtual", channel=channel)
    sim = SimDrive(sim_bus, config.drives["az"].node_id, params)
    sim.start()
    loop = asyncio.new_event_loop()
    server = SocketcandServer(channel)
    proc = master = None
    try:
        if bus == "socketcand":
            threading.Thread(target=loop.run_forever, daemon=True).start()
            port = asyncio.run_coroutine_threadsafe(server.start(), loop).result(10)
            proc = subprocess.Popen([sys.executable, __file__, "--master", "--mode", mode,
                                     "--port", str(port)], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, text=True)
            line = proc.stdout.readline()
            if not line.startswith("{"):
                raise RuntimeError(f"master did not start: {line!r}")

            def ask(text: str) -> dict:
                proc.stdin.write(text + "\n")
                proc.stdin.flush()
                return json.loads(proc.stdout.readline())
        else:
            master = Master(mode, {"interface": "virtual", "channel": channel})
            master.power()

            def ask(text: str) -> dict:
                if text.startswith("slew"):
                    master.command("target", float(text.split()[1]))
                    return {}
                return master.report()
        ask(f"slew {GOAL}")
        wait(lambda: sim.velocity > CRUISE, 60, "cruising at 5°/s")
        rec = Sampler(sim)
        time.sleep(0.2)
        if proc is not None:
            os.kill(proc.pid, signal.SIGSTOP)
            time.sleep(gap)
            os.kill(proc.pid, signal.SIGCONT)
        else:
            master.hold = gap
            time.sleep(gap)
        time.sleep(1.5)
        samples = rec.stop()
        report = ask("report")
        stopped = [s for s in samples if s[3] in STOPPED]
        return {"mode": mode, "gap": gap, "reversal": round(reversal(samples), 5),
                "peak_speed": round(max(s[2] for s in samples), 4),
                "peak_decel": round(peak_decel(samples), 3),
                "stop_decel": round(peak_decel(stopped), 3) if stopped else None,
                "emcy": [f"0x{c:04X}" for c in sim.emcy_sent], "state": sim.state,
                "resumes": report.get("resumes"), "axis_fault": report.get("fault"),
                "dropped": report.get("stats", {}).get("dropped"),
                "missed": report.get("stats", {}).get("missed")}
    finally:
        if proc is not None:
            try:
                os.kill(proc.pid, signal.SIGCONT)
                proc.stdin.close()
                proc.wait(20)
            except (OSError, subprocess.TimeoutExpired):
                proc.kill()
        if master is not None:
            master.close()
        if loop.is_running():
            asyncio.run_coroutine_threadsafe(server.stop(), loop).result(10)
            loop.call_soon_threadsafe(loop.stop)
        sim.stop()
        sim_bus.shutdown()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", nargs="+", default=["csp", "ip", "csv"])
    ap.add_argument("--gaps", nargs="+", type=float, default=[0.05, 0.1, 0.2, 0.3, 0.5])
    ap.add_argument("--bridging", choices=["extrapolate", "hold"], default="extrapolate")
    ap.add_argument("--bus", choices=["socketcand", "virtual"], default="socketcand")
    ap.add_argument("--master", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--mode", default="csp", help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.master:
        return serve_master(args.mode, args.port)
    bus = args.bus
    if bus == "socketcand":
        try:
            import can
            can.Bus  # noqa: B018 (python-can's socketcand interface ships with python-can)
        except ImportError:
            bus = "virtual"
    print(f"stall bench: bus {bus} ({'SIGSTOP of the master process' if bus == 'socketcand' else 'the master cycle held, one process'}), "
          f"drive bridging {args.bridging}, load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"{'mode':5} {'gap s':>6} {'reversal°':>10} {'peak °/s':>9} {'decel °/s²':>10} "
          f"{'stop °/s²':>9}  faults / state / resumes", flush=True)
    results = []
    for mode in args.modes:
        for gap in args.gaps:
            try:
                r = run_case(mode, gap, args.bridging, bus)
            except Exception as exc:  # a case that could not run is reported, the rest go on
                r = {"mode": mode, "gap": gap, "error": repr(exc)}
                print(f"{mode:5} {gap:6.2f}  error: {exc!r}", flush=True)
                results.append(r)
                continue
            results.append(r)
            print(f"{mode:5} {gap:6.2f} {r['reversal']:10.5f} {r['peak_speed']:9.3f} "
                  f"{r['peak_decel']:10.2f} {str(r['stop_decel']):>9}  {r['emcy'] or 'none'} / "
                  f"{r['state']} / {r['resumes']}" + (f" / axis: {r['axis_fault']}"
                                                       if r['axis_fault'] else ""), flush=True)
    print(json.dumps({"bus": bus, "bridging": args.bridging, "axis_speed": 5.0,
                      "stop_deceleration": 4.0, "rpdo_deadline": 0.5,
                      "load": os.getloadavg()[0], "cases": results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
