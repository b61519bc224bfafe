"""TPL2 load benchmark: N concurrent clients send 20-variable GETs back to back for T seconds.

Prints requests/s, variables/s and latency p50/p99/max for the TCS (``tcs-server`` on the
simulated telescope, in its own process), and the same figures for a minimal asyncio line-echo
server measured in the same run with the same client as the baseline, with the ratios. The
last line is one JSON object with the figures.

    python3 tools/bench/tpl2_load.py [--clients 50] [--seconds 5]

Goal (issue: TPL2 server): p99 latency of a 20-variable GET under 5 ms with 50 clients.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time

EXTRA: list[str] = []
VARIABLES = [  # what a status display polls
    "CABINET.POWER_STATE", "CABINET.ERROR_STATE", "CABINET.REFERENCED", "LOCAL.UT1",
    "AZ.REALPOS", "AZ.TARGETPOS", "AZ.MOTION_STATE", "AZ.LIMIT_STATE", "AZ.CURRSPEED",
    "ZD.REALPOS", "ZD.TARGETPOS", "ZD.MOTION_STATE", "ZD.LIMIT_STATE", "ZD.CURRSPEED",
    "DEROTATOR[2].REALPOS", "FOCUS.REALPOS", "FILTER[2].REALPOS", "MIRROR.REALPOS",
    "AZ.REALPOS!MIN", "ZD.REALPOS!MAX",
]

ECHO_SERVER = r"""
import asyncio, sys
class Echo(asyncio.Protocol):
    def connection_made(self, t): self.t = t; self.buf = b""
    def data_received(self, data):
        self.buf += data
        *lines, self.buf = self.buf.split(b"\n")
        for line in lines: self.t.write(line + b"\n")
async def main():
    srv = await asyncio.get_running_loop().create_server(Echo, "127.0.0.1", int(sys.argv[1]))
    print("ready", flush=True)
    await srv.serve_forever()
asyncio.run(main())
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port: int, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.05)
    raise SystemExit(f"server on port {port} did not start")


async def client(port: int, tpl2: bool, seconds: float, latencies: list[float], start: asyncio.Event):
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    if tpl2:
        await reader.readline()
        writer.write(b'AUTH PLAIN "admin" "admin"\n')
        assert (await reader.readline()).startswith(b"AUTH OK")
    request = ("1 GET " + ";".join(VARIABLES) + "\n").encode()
    # one read call per reply for both servers, so the client's own cost is the same
    terminator = b"1 COMMAND COMPLETE\n" if tpl2 else b"\n"
    await start.wait()
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        t0 = time.perf_counter()
        writer.write(request)
        reply = await reader.readuntil(terminator)
        if tpl2 and b"FAILED" in reply:
            raise RuntimeError(f"a variable failed: {reply[:200]!r}")
        latencies.append(time.perf_counter() - t0)
    writer.close()


async def load(port: int, tpl2: bool, clients: int, seconds: float) -> dict:
    latencies: list[float] = []
    start = asyncio.Event()
    tasks = [asyncio.create_task(client(port, tpl2, seconds, latencies, start)) for _ in range(clients)]
    await asyncio.sleep(0.5)  # all connected and logged in
    t0 = time.perf_counter()
    start.set()
    await asyncio.gather(*tasks)
    wall = time.perf_counter() - t0
    latencies.sort()
    q = lambda p: latencies[min(len(latencies) - 1, int(p * len(latencies)))] * 1e3  # noqa: E731
    return {"requests_per_s": len(latencies) / wall, "variables_per_s": len(latencies) * len(VARIABLES) / wall,
            "p50_ms": q(0.50), "p99_ms": q(0.99), "max_ms": latencies[-1] * 1e3,
            "mean_ms": statistics.fmean(latencies) * 1e3, "requests": len(latencies)}


def run_server(args: list[str], env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clients", type=int, default=50)
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--config", help="hardware file for tcs-server (default: the simulated telescope)")
    p.add_argument("--vars", help="comma-separated variables to GET (default: a status display's 20)")
    args = p.parse_args()
    if args.config:
        EXTRA.extend(["--config", args.config])
    if args.vars:
        VARIABLES[:] = args.vars.split(",")
    results = {}
    with tempfile.TemporaryDirectory() as state:
        for name, cmd, tpl2 in (
            ("echo", [sys.executable, "-c", ECHO_SERVER], False),
            ("tcs", [sys.executable, "-m", "tcs.cli.server", "--log-level", "WARNING"] + EXTRA, True),
        ):
            port = free_port()
            env = dict(os.environ, XDG_STATE_HOME=state)
            proc = run_server(cmd + ([str(port)] if not tpl2 else ["--port", str(port)]), env)
            try:
                wait_port(port)
                results[name] = asyncio.run(load(port, tpl2, args.clients, args.seconds))
            finally:
                proc.terminate()
                proc.wait(30)
    tcs, echo = results["tcs"], results["echo"]
    for name, r in results.items():
        print(f"{name:5s}: {r['requests_per_s']:9.0f} req/s {r['variables_per_s']:10.0f} var/s  "
              f"latency p50 {r['p50_ms']:.2f} ms  p99 {r['p99_ms']:.2f} ms  max {r['max_ms']:.2f} ms")
    ratio = {"requests_ratio_tcs_to_echo": tcs["requests_per_s"] / echo["requests_per_s"],
             "p99_ratio_tcs_to_echo": tcs["p99_ms"] / echo["p99_ms"]}
    print(f"ratio tcs/echo: throughput {ratio['requests_ratio_tcs_to_echo']:.2f}, "
          f"p99 latency {ratio['p99_ratio_tcs_to_echo']:.2f}  (goal: tcs p99 < 5 ms)")
    print(json.dumps({"benchmark": "tpl2_load", "clients": args.clients, "seconds": args.seconds,
                      "variables_per_get": len(VARIABLES), "tcs": tcs, "echo": echo, **ratio,
                      "goal_p99_ms": 5.0, "goal_met": tcs["p99_ms"] < 5.0}))


if __name__ == "__main__":
    main()
