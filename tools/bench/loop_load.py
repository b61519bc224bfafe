"""Control-loop timing under TPL2 load, abusive load included (architecture rule 5: no client
may make the loop miss a cycle; issue 14 item 5).

The real service runs in this process on the simulated telescope (hwconfig/sim.toml, its
``[server]`` limits as shipped); AZ and ZD are powered, referenced and follow sidereal-rate
trajectories for the whole run, so every cycle does the follower's work. Windows of the same
length, in the same run: first **baseline** (idle: no client but the one that set things up),
then one per load *profile*, each played by a separate process:

* ``pollers`` — 200 well-behaved status pollers (20 axis variables, ``--rate`` Hz each);
* ``pipeline`` — 30 clients pipelining 200-variable GETs without ever reading a reply;
* ``slowloris`` — 200 connections that never log in and trickle one byte a second;
* ``huge`` — 10 clients GETting 1000 variables per command (~25 kB replies), reading them;
* ``logins`` — 50 connections guessing passwords as fast as they are answered (last: it locks
  the loopback address out, as it should);
* ``hogs`` — no client at all: 2 × the CPUs busy-loop processes for the window (a compile on
  the same machine; issue 27 item 4). Run it with ``--realtime-priority 40`` for the cabinet
  computer's set-up, without for a development machine.

During every profile a **probe** client GETs ``AZ.REALPOS`` every 0.1 s: its latency is what an
operator's tool sees. Per window, from the cycle source (``lateness``: SYNC send time minus its
ideal slot; ``callback_time``: SYNC to the end of the control loop's work; ``stats()``: late and
missed cycles): cycles, late, missed, lateness p50/p99/max, loop time p99/max, the probe's
latency and what the abusive clients saw (dropped, refused …). The last line is one JSON
object with every figure. On a shared machine the figures are noisy: the load average is
printed with them.

    python3 tools/bench/loop_load.py [--profiles pollers,pipeline,...] [--seconds 10]
                                     [--clients 200] [--rate 5] [--realtime-priority 40]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time

from tcs.app import freeze_heap, thaw_heap

VARIABLES = [f"{ax}.{v}" for ax in ("AZ", "ZD") for v in (
    "REALPOS", "CURRPOS", "TARGETPOS", "TARGETDISTANCE", "MOTION_STATE", "LIMIT_STATE",
    "POWER_STATE", "REFERENCED", "CURRSPEED", "OFFSET")]


# ------------------------------------------------------------------ the load (child process)

PROFILES = ("pollers", "pipeline", "slowloris", "huge", "logins", "hogs")
HELP = {
    "pollers": "{clients} clients each GET 20 axis variables {rate:g} times a second",
    "pipeline": "30 clients pipeline 200-variable GETs as fast as the server reads, never reading replies",
    "slowloris": "200 connections never log in and send one byte a second (reconnecting when closed)",
    "huge": "10 clients GET 1000 variables per command (~25 kB replies) back to back, reading them",
    "logins": "50 connections guess passwords as fast as answered (reconnecting when dropped)",
    "hogs": "2 x the CPUs busy-loop processes keep every core busy",
}

HOG = "import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end: pass\n"


async def hogs(seconds: float) -> None:
    """Every core busy for ``seconds`` (the processes end by themselves)."""
    procs = [await asyncio.create_subprocess_exec(sys.executable, "-c", HOG.format(seconds=seconds))
             for _ in range(2 * (os.cpu_count() or 2))]
    await asyncio.gather(*(p.wait() for p in procs))


async def _open(port: int, login: bool = True):
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    greeting = await reader.readline()
    if b"AUTH PLAIN" not in greeting:
        writer.close()
        raise ConnectionError(f"refused: {greeting!r}")
    if login:
        writer.write(b'AUTH PLAIN "admin" "admin"\n')
        line = await reader.readline()
        if not line.startswith(b"AUTH OK"):
            writer.close()
            raise ConnectionError(f"login failed: {line!r}")
    return reader, writer


def _close(writer) -> None:
    try:
        writer.close()
    except Exception:
        pass


async def poller(conn, end: float, rate: float, latencies: list[float]) -> None:
    reader, writer = conn
    request = ("1 GET " + ";".join(VARIABLES) + "\n").encode()
    period = 1.0 / rate
    tick = time.perf_counter() + period * (hash(id(writer)) % 1000) / 1000  # spread the phases
    while tick < end:
        delay = tick - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        t0 = time.perf_counter()
        writer.write(request)
        while not (await reader.readline()).startswith(b"1 COMMAND COMPLETE"):
            pass
        latencies.append(time.perf_counter() - t0)
        tick += period
    _close(writer)


async def pipeliner(port: int, end: float, counts: dict) -> None:
    """Writes 200-variable GETs as fast as the server takes them and never reads."""
    request = ("1 GET " + ";".join(VARIABLES * 10) + "\n").encode()
    while time.perf_counter() < end:
        try:
            reader, writer = await _open(port)
        except (ConnectionError, OSError):
            counts["refused"] = counts.get("refused", 0) + 1
            await asyncio.sleep(0.5)
            continue
        try:
            while time.perf_counter() < end:
                writer.write(request)
                counts["sent"] = counts.get("sent", 0) + 1
                await asyncio.wait_for(writer.drain(), max(0.01, end - time.perf_counter()))
        except asyncio.TimeoutError:
            pass
        except (ConnectionError, OSError):
            counts["dropped"] = counts.get("dropped", 0) + 1
        _close(writer)


async def slowloris(port: int, end: float, counts: dict) -> None:
    while time.perf_counter() < end:
        try:
            reader, writer = await _open(port, login=False)
        except (ConnectionError, OSError):
            counts["refused"] = counts.get("refused", 0) + 1
            await asyncio.sleep(1.0)
            continue
        try:
            while time.perf_counter() < end:
                writer.write(b"A")
                await writer.drain()
                if reader.at_eof():
                    raise ConnectionError("closed")
                try:
                    if await asyncio.wait_for(reader.read(1), 1.0) == b"":
                        raise ConnectionError("closed")
                except asyncio.TimeoutError:
                    pass
        except (ConnectionError, OSError):
            counts["closed"] = counts.get("closed", 0) + 1
        _close(writer)


async def huge(port: int, end: float, counts: dict) -> None:
    reader, writer = await _open(port)
    request = ("1 GET " + ";".join(VARIABLES * 50) + "\n").encode()
    while time.perf_counter() < end:
        writer.write(request)
        size = 0
        while True:
            line = await reader.readline()
            size += len(line)
            if line.startswith(b"1 COMMAND COMPLETE") or not line:
                break
        counts["replies"] = counts.get("replies", 0) + 1
        counts["bytes"] = counts.get("bytes", 0) + size
    _close(writer)


async def guesser(port: int, end: float, counts: dict) -> None:
    n = 0
    while time.perf_counter() < end:
        try:
            reader, writer = await _open(port, login=False)
        except (ConnectionError, OSError):
            counts["refused"] = counts.get("refused", 0) + 1
            await asyncio.sleep(0.2)
            continue
        try:
            while time.perf_counter() < end:
                n += 1
                writer.write(f'AUTH PLAIN "admin" "guess{n}"\n'.encode())
                line = await asyncio.wait_for(reader.readline(), max(0.01, end - time.perf_counter()))
                if not line:
                    raise ConnectionError("dropped")
                counts["guesses"] = counts.get("guesses", 0) + 1
                if line.startswith(b"AUTH OK"):
                    counts["cracked"] = counts.get("cracked", 0) + 1
        except asyncio.TimeoutError:
            pass
        except (ConnectionError, OSError):
            counts["dropped"] = counts.get("dropped", 0) + 1
        _close(writer)


async def probe(port: int, end: float, latencies: list[float]) -> None:
    """One well-behaved client: a GET of AZ.REALPOS every 0.1 s (what an operator's tool sees)."""
    reader, writer = await _open(port)
    while time.perf_counter() < end:
        t0 = time.perf_counter()
        writer.write(b"9 GET AZ.REALPOS\n")
        while not (await reader.readline()).startswith(b"9 COMMAND COMPLETE"):
            pass
        latencies.append(time.perf_counter() - t0)
        await asyncio.sleep(0.1)
    _close(writer)


def _ms(xs: list[float]) -> dict:
    xs = sorted(xs)
    if not xs:
        return {"p50": None, "p99": None, "max": None}
    return {"p50": round(xs[len(xs) // 2] * 1e3, 2), "p99": round(xs[min(len(xs) - 1, int(len(xs) * 0.99))] * 1e3, 2),
            "max": round(xs[-1] * 1e3, 2)}


async def load(port: int, profile: str, clients: int, seconds: float, rate: float) -> None:
    probe_lat: list[float] = []
    latencies: list[float] = []
    counts: dict = {}
    conns = []
    if profile == "pollers":  # everybody logs in before the window starts
        conns = [await _open(port) for _ in range(clients)]
    print("ready", flush=True)
    sys.stdin.readline()  # the parent says when
    end = time.perf_counter() + seconds
    work = {"pollers": lambda: [poller(c, end, rate, latencies) for c in conns],
            "pipeline": lambda: [pipeliner(port, end, counts) for _ in range(30)],
            "slowloris": lambda: [slowloris(port, end, counts) for _ in range(200)],
            "huge": lambda: [huge(port, end, counts) for _ in range(10)],
            "logins": lambda: [guesser(port, end, counts) for _ in range(50)],
            "hogs": lambda: [hogs(seconds)]}[profile]()
    results = await asyncio.gather(probe(port, end, probe_lat), *work, return_exceptions=True)
    errors = [repr(r) for r in results if isinstance(r, BaseException)]
    out = {"profile": profile, "probe_ms": _ms(probe_lat), "counts": counts, "errors": errors[:3],
           "n_errors": len(errors)}
    if latencies:
        out["gets"] = len(latencies)
        out["latency_ms"] = _ms(latencies)
    print(json.dumps(out), flush=True)


# ------------------------------------------------------------------ the service (this process)

def window(loop, s0) -> dict:
    """The figures of the cycles since :func:`mark` (the control loop in this process or in
    the control process: ``samples`` answers the same)."""
    from axes_common import percentile
    late, times, s1 = loop.samples()
    ms = lambda xs, q: round(percentile(xs, q) * 1e3, 3)  # noqa: E731
    return {"cycles": s1["cycles"] - s0["cycles"], "late": s1["late"] - s0["late"],
            "missed": s1["missed"] - s0["missed"],
            "tpdo_timeouts": s1["tpdo_timeouts"] - s0["tpdo_timeouts"],
            "lateness_ms": {"p50": ms(late, 50), "p99": ms(late, 99), "max": ms(late, 100)},
            "loop_ms": {"p50": ms(times, 50), "p99": ms(times, 99), "max": ms(times, 100)}}


def mark(loop) -> dict:
    """Start a window: empty the (bounded) histories, keep the counters."""
    return loop.samples(clear=True)[2]


async def main(profiles: list[str], clients: int, seconds: float, rate: float,
               realtime_priority: int = 0, server: dict | None = None, process: bool = False) -> dict:
    from axes_common import Client, power_and_reference, start_service

    print(f"control loop: {'in the control process' if process else 'a thread of the service'}", flush=True)
    service, port, state = await start_service(
        can={"realtime_priority": realtime_priority, "control_process": process}, **(server or {}))
    freeze_heap()  # as tcs-server does once it serves
    child = None
    results: dict = {}
    try:
        c = await Client.connect(port)
        print("powering and referencing AZ and ZD …", flush=True)
        await power_and_reference(c, "AZ", "ZD")
        total = (1 + len(profiles)) * (seconds + 15) + 60
        t0 = await c.num("LOCAL.UT1") + 1.0
        for ax in ("AZ", "ZD"):  # sidereal-rate paths for the whole run, points every 2 s
            p0 = await c.num(f"{ax}.REALPOS")
            n = int(total / 2) + 1
            for first in range(0, n, 200):
                parts = []
                for i in range(first, min(n, first + 200)):
                    parts += [f"{ax}.TRAJECTORY.BUFFER[{i}].TIME={t0 + 2 * i!r}",
                              f"{ax}.TRAJECTORY.BUFFER[{i}].TARGETPOS={p0 + 15 / 3600 * 2 * i!r}"]
                await c.set(";".join(parts))
            await c.set(f"{ax}.TRAJECTORY.ADDPOINTS={n}")
            await c.start(f"SET {ax}.TRAJECTORY.RUN=1")
        await c.until("AZ.MOTION_STATE", lambda v: int(v) & 2)
        await c.until("ZD.MOTION_STATE", lambda v: int(v) & 2)
        await asyncio.sleep(2.0)
        source = service.telescope.control_loop
        realtime = bool(source.stats().get("realtime"))

        print(f"baseline: {seconds:g} s without load …", flush=True)
        s0 = mark(source)
        await asyncio.sleep(seconds)
        results["baseline"] = {"window": window(source, s0)}

        for profile in profiles:
            print(f"{profile}: {HELP[profile].format(clients=clients, rate=rate)} (another process) …", flush=True)
            child = await asyncio.create_subprocess_exec(
                sys.executable, __file__, "--serve-load", str(port), "--profile", profile,
                "--clients", str(clients), "--seconds", str(seconds), "--rate", str(rate),
                stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            line = await asyncio.wait_for(child.stdout.readline(), 120)
            if line.strip() != b"ready":
                raise SystemExit(f"load process: {line!r}")
            s0 = mark(source)
            child.stdin.write(b"go\n")
            await child.stdin.drain()
            out = await asyncio.wait_for(child.stdout.readline(), seconds + 120)
            w = window(source, s0)
            await child.wait()
            child = None
            results[profile] = {"window": w, "clients": json.loads(out),
                                "connections_after": len(service.server.sessions),
                                "drive_errors": [await c.num(f"{ax}.ERROR_STATE") for ax in ("AZ", "ZD")]}
            if any(results[profile]["drive_errors"]):
                print("  errors:", (await c.get("CABINET.STATUS.LIST"))[0][:600], flush=True)
            await asyncio.sleep(min(5.0, service.config.server.login_timeout))  # let the dust settle
        following = [await c.num(f"{ax}.MOTION_STATE") for ax in ("AZ", "ZD")]
        await c.close()
    finally:
        if child is not None and child.returncode is None:
            child.kill()
            await child.wait()
        await service.stop()
        thaw_heap()
        state.cleanup()
    print()
    print(f"{'profile':10s} {'cycles':>6s} {'late':>5s} {'missed':>6s}  lateness ms p50/p99/max   "
          f"loop ms p99/max   probe GET ms p50/p99/max   what the clients saw")
    for name, r in results.items():
        w = r["window"]
        lat, lp = w["lateness_ms"], w["loop_ms"]
        cl = r.get("clients", {})
        pr = cl.get("probe_ms", {})
        seen = dict(cl.get("counts", {}))
        if "gets" in cl:
            seen["gets"] = cl["gets"]
            seen["get_p99_ms"] = cl["latency_ms"]["p99"]
        if cl.get("n_errors"):
            seen["client_errors"] = cl["n_errors"]
        if any(r.get("drive_errors") or ()):
            seen["drive_errors"] = r["drive_errors"]
        probe_text = f"{pr.get('p50')}/{pr.get('p99')}/{pr.get('max')}" if pr else "-"
        print(f"{name:10s} {w['cycles']:6d} {w['late']:5d} {w['missed']:6d}  "
              f"{lat['p50']:.3f}/{lat['p99']:.3f}/{lat['max']:.3f}   {lp['p99']:.3f}/{lp['max']:.3f}   "
              f"{probe_text:>22s}   {seen}")
    print(f"trajectories still running at the end: {all(int(m) & 2 for m in following)}")
    print(f"control loop real-time priority: {realtime_priority if realtime else 'no'}")
    print(f"load average at the end: {os.getloadavg()} on {os.cpu_count()} CPUs (shared machine: noisy)")
    return {"results": results, "realtime_priority": realtime_priority if realtime else 0,
            "control_process": process,
            "n_clients": clients, "rate_hz": rate, "seconds": seconds}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profiles", default=",".join(PROFILES),
                    help=f"comma-separated, in this order (default all: {','.join(PROFILES)})")
    ap.add_argument("--clients", type=int, default=200, help="clients of the pollers profile")
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each window")
    ap.add_argument("--rate", type=float, default=5.0, help="GETs per second per poller")
    ap.add_argument("--realtime-priority", type=int, default=0,
                    help="can.realtime_priority for the control loop (0: normal scheduling)")
    ap.add_argument("--mode", choices=("thread", "process", "both"), default="both",
                    help="the control loop as a thread of the service (the old way, the baseline), "
                         "in the control process ([can] control_process), or both one after the other")
    ap.add_argument("--switch-interval", type=float, default=0.0,
                    help="sys.setswitchinterval for this process, s (0: Python's default, 5 ms)")
    ap.add_argument("--work-rest", type=float, help="[server] work_rest (default: the file's)")
    ap.add_argument("--work-slice", type=float, help="[server] work_slice, s (default: the file's)")
    ap.add_argument("--serve-load", type=int, metavar="PORT", help=argparse.SUPPRESS)
    ap.add_argument("--profile", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve_load:
        asyncio.run(load(args.serve_load, args.profile, args.clients, args.seconds, args.rate))
    else:
        chosen = [p for p in args.profiles.split(",") if p]
        unknown = [p for p in chosen if p not in PROFILES]
        if unknown:
            raise SystemExit(f"unknown profiles {unknown}; known: {list(PROFILES)}")
        if args.switch_interval:
            sys.setswitchinterval(args.switch_interval)
        print(f"interpreter switch interval: {sys.getswitchinterval() * 1e3:g} ms", flush=True)
        overrides = {k: v for k, v in (("work_rest", args.work_rest), ("work_slice", args.work_slice)) if v is not None}
        modes = {"thread": [False], "process": [True], "both": [False, True]}[args.mode]
        results = [asyncio.run(main(chosen, args.clients, args.seconds, args.rate,
                                    args.realtime_priority, overrides, process)) for process in modes]
        print(json.dumps(results if len(results) > 1 else results[0]))
