"""Alpaca HTTP load: 20 clients polling a telescope status as fast as they can, against a
minimal aiohttp JSON endpoint as the baseline, with the control loop's timing meanwhile.

The real service runs in this process on the simulated telescope (``hwconfig/sim.toml``, Alpaca
on a free port, no discovery); AZ and ZD are powered, referenced and **tracking a star** for the
whole run (so every control cycle does the follower's work). The baseline is a one-route aiohttp
application on the same event loop, answering a constant Alpaca-shaped JSON body: what aiohttp
itself costs. Three windows of the same length, in the same run:

1. **idle**: no client;
2. **baseline**: N clients (another process, one keep-alive connection each) GET the baseline
   endpoint in a loop;
3. **alpaca**: the same clients each poll RightAscension, Declination, Altitude, Azimuth,
   Slewing, Tracking and AtPark of ``telescope/0`` in turn, in a loop.

Per window: requests/s and per-request latency p50/p99/max seen by the clients; control-loop
lateness p50/p99/max, loop time, late and missed cycles (the cycle source's own figures, as
``loop_load.py``). The last line is one JSON object with the figures.

    python3 tools/bench/alpaca_load.py [--clients 20] [--seconds 10]

Where the time goes (issue 27; py-spy of the service, the samples inside the Alpaca handler,
and the handler timed alone with aiohttp's mocked requests): before, 8.5-18 us per request on
top of what the baseline's handler does — the sky place for RA/Dec/Alt/Az (recomputed every
10 ms while tracking: ~20 % of the handler), ``to_normal`` through numpy for one position,
``json.dumps`` (~20 %), per-request lookups (handler by name, the main axes, ``isawaitable``).
After: the reply text written directly, the handler looked up once per member, the main axes
cached, AZ-ZD alt/az without numpy, and a state read without parameters reusing the value
read for the same member while nothing changed (``[server] reuse_reply``, ``tcs.state_epoch``):
7.6-8.4 us per member, all of them, the rest being aiohttp's own work, as in the baseline.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
import uuid

MEMBERS = ["rightascension", "declination", "altitude", "azimuth", "slewing", "tracking", "atpark"]


# ------------------------------------------------------------------ the load (child process)

async def client(base: str, paths: list[str], seconds: float, latencies: list[float], errors: list[str],
                 go: asyncio.Event, ready: list[int]) -> None:
    import aiohttp

    async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=1)) as session:
        async with session.get(base + paths[0], params={"ClientID": "1", "ClientTransactionID": "1"}) as r:
            await r.read()
        ready.append(1)
        await go.wait()
        end = time.perf_counter() + seconds
        n = 0
        while time.perf_counter() < end:
            for path in paths:
                n += 1
                t0 = time.perf_counter()
                async with session.get(base + path, params={"ClientID": "1", "ClientTransactionID": str(n)}) as r:
                    body = await r.json(content_type=None)
                latencies.append(time.perf_counter() - t0)
                if r.status != 200 or body.get("ErrorNumber"):
                    errors.append(f"{path}: {r.status} {body.get('ErrorMessage')}")


async def load(base: str, paths: list[str], clients: int, seconds: float) -> None:
    latencies: list[float] = []
    errors: list[str] = []
    ready: list[int] = []
    go = asyncio.Event()
    tasks = [asyncio.create_task(client(base, paths, seconds, latencies, errors, go, ready))
             for _ in range(clients)]
    while len(ready) < clients:
        await asyncio.sleep(0.01)
        for t in tasks:
            if t.done() and t.exception():
                raise t.exception()
    print("ready", flush=True)
    sys.stdin.readline()
    go.set()
    t0 = time.perf_counter()
    await asyncio.gather(*tasks)
    elapsed = time.perf_counter() - t0
    latencies.sort()
    print(json.dumps({"requests": len(latencies), "requests_per_s": len(latencies) / elapsed,
                      "errors": len(errors), "first_error": errors[0] if errors else "",
                      "latency_ms": {"p50": latencies[len(latencies) // 2] * 1e3,
                                     "p99": latencies[int(len(latencies) * 0.99)] * 1e3,
                                     "max": latencies[-1] * 1e3}}), flush=True)


# ------------------------------------------------------------------ the service (this process)

def window(source, a, b) -> dict:
    """The cycles between two :func:`snapshot` s of the control loop (a thread of the service
    or the control process: ``samples`` answers the same)."""
    from axes_common import percentile

    late, loop, s0 = a
    late2, loop2, s1 = b
    late, loop = late2[len(late):], loop2[len(loop):]
    ms = lambda xs, q: round(percentile(xs, q) * 1e3, 3) if xs else 0.0  # noqa: E731
    return {"cycles": s1["cycles"] - s0["cycles"], "late": s1["late"] - s0["late"],
            "missed": s1["missed"] - s0["missed"],
            "lateness_ms": {"p50": ms(late, 50), "p99": ms(late, 99), "max": ms(late, 100)},
            "loop_ms": {"p50": ms(loop, 50), "p99": ms(loop, 99), "max": ms(loop, 100)}}


def snapshot(source):
    return source.samples()


async def start_baseline() -> tuple[object, int]:
    """A minimal aiohttp JSON endpoint (the same shape as an Alpaca reply) on a free port."""
    from aiohttp import web

    counter = iter(range(1, 1 << 62))

    async def handler(request: web.Request) -> web.Response:
        tid = request.query.get("ClientTransactionID", "0")
        return web.Response(text=json.dumps({"Value": 1.0, "ClientTransactionID": int(tid) if tid.isdigit() else 0,
                                             "ServerTransactionID": next(counter), "ErrorNumber": 0,
                                             "ErrorMessage": ""}), content_type="application/json")

    app = web.Application()
    app.router.add_get("/value", handler)
    runner = web.AppRunner(app, access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    return runner, site._server.sockets[0].getsockname()[1]


async def run_window(name: str, source, base: str, paths: list[str], clients: int, seconds: float) -> dict:
    print(f"{name}: {clients} clients for {seconds:g} s …", flush=True)
    child = await asyncio.create_subprocess_exec(
        sys.executable, __file__, "--serve-load", base, "--paths", ",".join(paths), "--clients", str(clients),
        "--seconds", str(seconds), stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        line = await asyncio.wait_for(child.stdout.readline(), 120)
        if line.strip() != b"ready":
            raise SystemExit(f"load process: {line!r}")
        a = snapshot(source)
        child.stdin.write(b"go\n")
        await child.stdin.drain()
        out = await asyncio.wait_for(child.stdout.readline(), seconds + 120)
        b = snapshot(source)
        await child.wait()
    finally:
        if child.returncode is None:
            child.kill()
            await child.wait()
    return {"clients": json.loads(out), "loop": window(source, a, b)}


async def main(clients: int, seconds: float) -> dict:
    from axes_common import Client, power_and_reference

    from tcs.app import Service, freeze_heap, thaw_heap
    from tcs.config import DEFAULT_CONFIG, load_config
    from tcs.config.sections import StateSection

    config = load_config(DEFAULT_CONFIG)
    state = tempfile.TemporaryDirectory(prefix="tcs-bench-")
    new = dataclasses.replace(
        config, server=dataclasses.replace(config.server, port=0, opentsi_port=-1),
        alpaca=dataclasses.replace(config.alpaca, port=0, discovery_port=-1),
        web=dataclasses.replace(config.web, port=-1), indi=dataclasses.replace(config.indi, port=-1),
        can=dataclasses.replace(config.can, channel=f"tcs-bench-{uuid.uuid4().hex[:12]}"),
        state=StateSection(path=state.name))
    object.__setattr__(new, "source", config.source)
    service = Service(new)
    port = await service.start()
    freeze_heap()
    runner = None
    try:
        c = await Client.connect(port)
        print("powering and referencing AZ and ZD …", flush=True)
        await power_and_reference(c, "AZ", "ZD")
        await c.close()
        alpaca = f"http://127.0.0.1:{service.alpaca_port}"
        import aiohttp
        async with aiohttp.ClientSession() as s:
            for member, form in (("connect", {}), ("tracking", {"Tracking": "True"})):
                async with s.put(f"{alpaca}/api/v1/telescope/0/{member}", data=form) as r:
                    body = await r.json()
                    if body["ErrorNumber"]:
                        raise SystemExit(f"{member}: {body['ErrorMessage']}")
            async with s.get(f"{alpaca}/api/v1/telescope/0/siderealtime") as r:
                lst = (await r.json())["Value"]
            ra = (lst + 1.0) % 24.0
            async with s.put(f"{alpaca}/api/v1/telescope/0/slewtocoordinatesasync",
                             data={"RightAscension": str(ra), "Declination": "30"}) as r:
                body = await r.json()
                if body["ErrorNumber"]:
                    raise SystemExit(f"slew: {body['ErrorMessage']}")
            deadline = time.monotonic() + 180
            while True:
                async with s.get(f"{alpaca}/api/v1/telescope/0/slewing") as r:
                    if not (await r.json())["Value"]:
                        break
                if time.monotonic() > deadline:
                    raise SystemExit("the slew did not end")
                await asyncio.sleep(0.5)
        print("tracking a star", flush=True)
        runner, base_port = await start_baseline()
        source = service.telescope.control_loop

        print(f"idle: {seconds:g} s …", flush=True)
        a = snapshot(source)
        await asyncio.sleep(seconds)
        idle = window(source, a, snapshot(source))
        baseline = await run_window("baseline", source, f"http://127.0.0.1:{base_port}", ["/value"],
                                    clients, seconds)
        alpaca_w = await run_window("alpaca", source, alpaca, [f"/api/v1/telescope/0/{m}" for m in MEMBERS],
                                    clients, seconds)
        still_tracking = bool(service.telescope.pointing.track)
    finally:
        if runner is not None:
            await runner.cleanup()
        await service.stop()
        thaw_heap()
        state.cleanup()
    print(f"{'window':9s} {'req/s':>8s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s} {'errors':>6s} | "
          f"{'cycles':>6s} {'late':>5s} {'missed':>6s} {'lat p99':>8s} {'lat max':>8s} {'loop p99':>8s}")
    for name, w in (("idle", {"clients": None, "loop": idle}), ("baseline", baseline), ("alpaca", alpaca_w)):
        cl, lp = w["clients"], w["loop"]
        head = (f"{cl['requests_per_s']:8.0f} {cl['latency_ms']['p50']:8.2f} {cl['latency_ms']['p99']:8.2f} "
                f"{cl['latency_ms']['max']:8.2f} {cl['errors']:6d}") if cl else f"{'-':>8s} " * 4 + f"{'-':>6s}"
        print(f"{name:9s} {head} | {lp['cycles']:6d} {lp['late']:5d} {lp['missed']:6d} "
              f"{lp['lateness_ms']['p99']:8.3f} {lp['lateness_ms']['max']:8.3f} {lp['loop_ms']['p99']:8.3f}")
    print(f"still tracking at the end: {still_tracking}")
    return {"n_clients": clients, "seconds": seconds, "members": MEMBERS, "idle": idle,
            "baseline": baseline, "alpaca": alpaca_w, "still_tracking": still_tracking}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--serve-load", metavar="BASE_URL", help=argparse.SUPPRESS)
    ap.add_argument("--paths", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve_load:
        asyncio.run(load(args.serve_load, args.paths.split(","), args.clients, args.seconds))
    else:
        print(json.dumps(asyncio.run(main(args.clients, args.seconds))))
