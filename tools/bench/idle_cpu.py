"""Idle cost of the simulated telescope: CPU of every process of the service, nothing connected.

Two set-ups, one after the other, each measured from ``/proc/<pid>/stat`` (user + system time
of every process of the service: ``tcs-server`` and all its descendants, i.e. the control
process; and ``tcs-sim`` where it runs) over a window of ``--seconds`` after ``--settle``
seconds of start-up, with no client connected and nothing moving:

* ``default`` — ``tcs-server`` with no arguments: the bundled simulated telescope (the seven
  simulated drives in the control process beside the control loop, PLCs and GPS simulated in
  the service). Goal: at most 10 % of one core, all processes together.
* ``remote`` — ``hwconfig/sim-remote.toml``: the drives, PLCs and GPS in ``tcs-sim``, the
  service talking to them over socketcand and Modbus TCP as to real hardware. Goal: the
  service alone (main + control process) at most 5 % of one core; ``tcs-sim`` reported beside.

The control loop's counters (``CABINET.CORE.CYCLE``, read by one short TPL2 login just before
and after the window) give the cycles run: on a starved machine a loop that misses cycles also
costs less, so the service's CPU per cycle is printed beside the percentages.

Per thread figures are printed too (``/proc/<pid>/task``), so the thread that costs can be
named. The machine may be shared: the load average is printed with the figures. The last line
is one JSON object with every figure.

    python3 tools/bench/idle_cpu.py [--seconds 20] [--settle 8] [--only default|remote]
                                    [--idle-sync-period 0] [--set KEY=VALUE ...]

The shipped files slow the SYNC of a resting telescope to ``[can] idle_sync_period`` (50 ms,
:mod:`tcs.drivers.idle_sync`) 2 s after the last drive came to rest; ``--idle-sync-period 0``
measures the same code with the SYNC at its full rate (the A/B of the fourth pass), and the
cycles expected in the window follow the period in effect.

Where the idle time goes (issue 27; py-spy ``record --gil`` of the default simulated telescope,
shares of the samples holding each process's interpreter lock):

* main process (7 % of a core before): the two simulated PLCs and their drivers — pymodbus
  server and client, 10 Hz polls each, every point re-encoded on every request — 75 %; the
  control process's readbacks (100 pickled batches a second, applied to 7 axes) 14 %; the
  rest timers and the event loop. The simulated PLC now reuses the words of an unchanged
  value (one dome poll 567 -> 223 us of CPU): about 5.5 % of a core after.
* control process (18-20 % of a core): the seven simulated drives beside the loop about half
  (python-can's virtual bus deep-copies every frame for every other bus, the drives' PDO and
  state-machine work per SYNC), the control loop's step of 7 axes ~20 %, the canopen
  notifier ~9 %, sending the readbacks to the service ~10 %. Not changed here: the drives'
  simulation and the loop (issue 27 item 4 is someone else's), and the readbacks stay one per
  cycle (their age is the status's freshness).
* second pass (2026-11-26): an axis whose readbacks are unchanged but for their times sends
  only ``(measured_ut1, sample)`` and batches are pickled by ``pickle.dumps`` itself (the
  readback thread of the main process 1.3 -> 0.7 % of a core, the sender 4.0 -> 3.2 %). What
  remains is per frame and per cycle: 100 SYNCs, 700 RPDOs and 700-1400 TPDOs a second through
  python-can and canopen in Python (the notifier thread and the cycle thread, each a few
  percent), a thread wake-up per frame, and on the default set-up the simulated drives and
  python-can's virtual bus in the same process.
* ``remote``: the service's control process talks socketcand (python-can's client parses the
  ASCII frames in Python): 7-13 % of a core for 7 drives at 10 ms; tcs-sim 13-24 %.
* third pass (2026-11-26, yappi with a CPU clock in the control process, shares of its CPU):
  python-can's ``VirtualBus.send`` deep-copied every frame (``copy.deepcopy`` of the message
  and its bytearray through ``copyreg``): 16 %; the simulated drives (SYNC: RPDOs applied,
  the model advanced, TPDOs packed and sent; the 10 ms poll: supervision and event TPDOs) about
  half; the TCS's cycle of 7 axes (drive step, axis step, snapshot) a quarter; thread hand-overs
  of the two receive threads the rest. Changed: frames are copied by the ``Message``
  constructor (``tcs.virtual_can``), a synchronous RPDO no longer advances the drive model
  when it arrives (the SYNC does), and quiet readback batches go every 5th cycle (20 a second,
  not 100; a change at once). The simulator alone (``sim_drives.py``, 7 drives in CSP) costs
  8.4-9.7 % of a core, the whole budget of the goal: ≤ 10 % for the default telescope needs
  the simulated drives out of Python or a slower idle cycle (see tools/bench/README.md).
* fourth pass (2026-11-26): the slower idle cycle, done as real drives need it — the idle
  SYNC (``[can] idle_sync_period``; each drive told its 0x1006 and RPDO deadlines by SDO first,
  the full rate and the boot's values back before any power stage). Per second at rest: 20
  SYNCs, 140 RPDOs and 140-280 TPDOs, and 20 steps of the loop and of the simulated drives'
  SYNC work. The control process of the default telescope 14-15 % -> 5.7-6.6 %, of the
  remote service 12-13 % -> 3.5-3.7 %, tcs-sim 20-22 % -> 10-11 %. What is left: the main
  process (5 % default, 3.3 % remote), three quarters of it the two PLCs' Modbus polls (10 Hz,
  6-7 requests each through pymodbus and asyncio, ~150 requests a second with the simulated
  PLCs' server side in the same process in the default set-up), and the simulated drives'
  10 ms supervision poll (a third of the default control process: heartbeats, consumer
  windows, event TPDOs packed to see whether they changed).
* fifth pass (2026-11-26 evening): the PLCs' idle poll (``[plcs.<name>] idle_poll_interval``,
  0.5 s in the shipped files, :mod:`tcs.drivers.modbus`): a PLC whose axes neither move nor
  are commanded and that nothing was written to for 2 s is polled at that interval. The main
  process 3.9-4.6 % -> 1.5-1.7 % (default, the simulated PLCs' server side included) and
  2.3-2.6 % -> 0.9-1.3 % (remote); ``--set 'plcs.*.idle_poll_interval=0'`` is the A/B. What
  is left is the control process: in the remote set-up 2.8-3.5 % (yappi: the cycle thread
  0.98 s and python-can's socketcand receive thread 0.57 s of CPU in 15 s — per SYNC the
  seven drives' step, status and readback snapshot, per frame the ASCII parse and canopen's
  dispatch, nothing above 5 % of it alone); ``--set can.idle_sync_period=0.1`` would take it
  to 2.0-2.3 %.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tpl2_load import free_port, loop_counters, wait_port  # tools/bench/tpl2_load.py

ROOT = Path(__file__).resolve().parents[2]
TICK = os.sysconf("SC_CLK_TCK")




def _stat(path: str) -> tuple[str, int, float] | None:
    """(name, parent pid, CPU seconds) of a /proc stat file, None when it is gone."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError:
        return None
    name = text[text.index("(") + 1:text.rindex(")")]
    fields = text.rpartition(")")[2].split()
    return name, int(fields[1]), (int(fields[11]) + int(fields[12])) / TICK


def descendants(pid: int) -> list[int]:
    """``pid`` and every process below it."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            st = _stat(f"/proc/{entry}/stat")
            if st is not None:
                children.setdefault(st[1], []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return "?"


def snapshot(pids: list[int]) -> dict:
    """CPU seconds per process and per thread."""
    out = {}
    for pid in pids:
        st = _stat(f"/proc/{pid}/stat")
        if st is None:
            continue
        threads = {}
        try:
            for tid in os.listdir(f"/proc/{pid}/task"):
                tst = _stat(f"/proc/{pid}/task/{tid}/stat")
                if tst is not None:
                    threads[int(tid)] = (tst[0], tst[2])
        except OSError:
            pass
        out[pid] = (st[2], threads)
    return out


def idle_period(doc) -> float:
    """The SYNC period of a resting telescope in a parsed hardware file (the idle SYNC's, or
    the full one)."""
    can = doc["can"]
    return float(can.get("idle_sync_period", 0.0)) or float(can.get("sync_period", 0.01))


def hardware_file(name: str, state: str, overrides: dict[str, float]):
    """The parsed ``hwconfig/<name>`` with ``overrides`` applied: dotted keys such as
    ``can.idle_sync_period``; ``*`` stands for every table at that level
    (``plcs.*.poll_interval``)."""
    import tomlkit

    doc = tomlkit.parse((ROOT / "hwconfig" / name).read_text())
    for key, value in overrides.items():
        tables, leaf = [doc], key.split(".")
        for part in leaf[:-1]:
            tables = [t for table in tables
                      for t in (table.values() if part == "*" else [table.get(part)])
                      if hasattr(t, "get")]
        for table in tables:
            table[leaf[-1]] = value
    eds = Path(state) / "eds"
    if not eds.exists():
        eds.symlink_to(ROOT / "hwconfig" / "eds")
    return doc


def measure(roles: dict[str, int], seconds: float, port: int, period: float = 0.01) -> dict:
    """Percent of one core per role (a process and its descendants) and per process/thread,
    and the control loop's cycles meanwhile (a starved loop runs fewer cycles and so costs less:
    the CPU per cycle tells that apart)."""
    pids = {role: descendants(pid) for role, pid in roles.items()}
    every = [p for ps in pids.values() for p in ps]
    c0 = loop_counters(port)
    a, t0 = snapshot(every), time.monotonic()
    time.sleep(seconds)
    b, wall = snapshot(every), time.monotonic() - t0
    c1 = loop_counters(port)
    result: dict = {"roles": {}, "processes": []}
    for role, ps in pids.items():
        total = 0.0
        for p in ps:
            if p not in a or p not in b:
                continue
            cpu = b[p][0] - a[p][0]
            total += cpu
            threads = sorted(((b[p][1][t][0], 100 * (b[p][1][t][1] - a[p][1][t][1]) / wall)
                              for t in b[p][1] if t in a[p][1]), key=lambda x: -x[1])
            result["processes"].append({"role": role, "pid": p, "cmd": cmdline(p)[:90],
                                        "percent": 100 * cpu / wall,
                                        "threads": [(n, round(c, 2)) for n, c in threads if c > 0.05]})
        result["roles"][role] = 100 * total / wall
    result["seconds"] = wall
    cycles, missed, timeouts = (y - x for x, y in zip(c0, c1))
    result["loop"] = {"cycles": cycles, "missed": missed, "tpdo_timeouts": timeouts,
                      "expected_cycles": round(wall / period), "sync_period": period}
    service_cpu = result["roles"]["service"] * wall / 100
    result["service_cpu_us_per_cycle"] = 1e6 * service_cpu / max(1, cycles)
    return result


def run_default(seconds: float, settle: float, state: str, overrides: dict[str, float]) -> dict:
    import tomlkit

    port = free_port()
    env = dict(os.environ, XDG_STATE_HOME=state)
    doc = hardware_file("sim.toml", state, overrides)
    extra = []
    if overrides:  # (else no arguments at all: the README's first command)
        hwfile = Path(state) / "default.toml"
        hwfile.write_text(tomlkit.dumps(doc))
        extra = ["--config", str(hwfile)]
    server = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--log-level", "WARNING",
                               *extra, "--port", str(port), "--opentsi-port", "-1", "--alpaca-port", "-1",
                               "--web-port", "0"],
                              env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_port(port, 90.0)
        time.sleep(settle)
        return measure({"service": server.pid}, seconds, port, idle_period(doc))
    finally:
        server.terminate()
        server.wait(60)


def run_remote(seconds: float, settle: float, state: str, overrides: dict[str, float]) -> dict:
    import tomlkit

    doc = hardware_file("sim-remote.toml", state, overrides)
    port = free_port()
    doc["can"]["port"] = free_port()
    for plc in doc.get("plcs", {}).values():
        plc["port"] = free_port()
    if "gps" in doc:
        doc["gps"]["url"] = f"socket://127.0.0.1:{free_port()}"
    hwfile = Path(state) / "remote.toml"
    hwfile.write_text(tomlkit.dumps(doc))
    env = dict(os.environ, XDG_STATE_HOME=state)
    sim = subprocess.Popen([sys.executable, "-m", "tcs.cli.sim", "--config", str(hwfile)], env=env,
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    server = None
    try:
        line, deadline = "", time.monotonic() + 90
        while "ready" not in line and time.monotonic() < deadline and sim.poll() is None:
            line = sim.stderr.readline()
        if "ready" not in line:
            raise SystemExit(f"tcs-sim did not start: {line!r}")
        server = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--log-level", "WARNING",
                                   "--config", str(hwfile), "--port", str(port), "--opentsi-port", "-1",
                                   "--alpaca-port", "-1", "--web-port", "0"],
                                  env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_port(port, 90.0)
        time.sleep(settle)
        return measure({"service": server.pid, "tcs-sim": sim.pid}, seconds, port, idle_period(doc))
    finally:
        for proc in (server, sim):
            if proc is not None:
                proc.terminate()
                try:
                    proc.wait(60)
                except subprocess.TimeoutExpired:
                    proc.kill()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="measuring window")
    ap.add_argument("--settle", type=float, default=8.0, help="seconds after the port opens")
    ap.add_argument("--only", choices=("default", "remote"))
    ap.add_argument("--idle-sync-period", type=float, default=None,
                    help="replace [can] idle_sync_period of the hardware files (0 = off: the "
                         "SYNC at its full rate; the default run then gets --config)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="replace a number of both hardware files, e.g. plcs.*.poll_interval=0.5 "
                         "(repeatable; the default run then gets --config)")
    args = ap.parse_args()
    overrides = {}
    for item in args.set:
        key, _, value = item.partition("=")
        overrides[key.strip()] = float(value)
    if args.idle_sync_period is not None:
        overrides["can.idle_sync_period"] = args.idle_sync_period
    results = {}
    for name, fn in (("default", run_default), ("remote", run_remote)):
        if args.only and args.only != name:
            continue
        with tempfile.TemporaryDirectory() as state:
            r = results[name] = fn(args.seconds, args.settle, state, overrides)
        print(f"{name}: " + ", ".join(f"{role} {pct:.1f} %" for role, pct in r["roles"].items())
              + f" of one core; loop: {r['loop']['cycles']} cycles of {r['loop']['expected_cycles']} "
              f"at {r['loop']['sync_period'] * 1e3:g} ms "
              f"(missed {r['loop']['missed']}, TPDO time-outs {r['loop']['tpdo_timeouts']}), "
              f"service {r['service_cpu_us_per_cycle']:.0f} us CPU per cycle")
        for p in r["processes"]:
            print(f"    {p['role']:8s} {p['pid']:7d} {p['percent']:5.1f} %  {p['cmd']}")
            print(f"             threads: {p['threads']}")
    goals = {}
    if "default" in results:
        goals["default_total_le_10"] = sum(results["default"]["roles"].values()) <= 10.0
    if "remote" in results:
        goals["remote_service_le_5"] = results["remote"]["roles"]["service"] <= 5.0
    load = os.getloadavg()
    print(f"goals: {goals}; load average {load} on {os.cpu_count()} CPUs (shared machine: noisy)")
    print(json.dumps({"benchmark": "idle_cpu", **results, "goals": goals, "load_average": load}))


if __name__ == "__main__":
    main()
