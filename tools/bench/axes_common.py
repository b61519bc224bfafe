"""What the axis benchmarks (``slew.py``, ``loop_load.py``) share: the in-process service on a
free port, a small TPL2 client, and an observer of the control loop.

Not a benchmark itself. The service is the real one (``tcs.app.Service``) on the given
hardware file with its own virtual CAN channel and a throw-away state directory; the client
speaks TPL2 over a real socket; :class:`LoopRecorder` is a cycle callback added after the
control loop's own, reading only what the drives report (instrumentation, as a scope on the
real machine would be).
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import re
import sys
import tempfile
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tcs.app import Service  # noqa: E402
from tcs.config import DEFAULT_CONFIG, load_config  # noqa: E402
from tcs.config.sections import StateSection  # noqa: E402

ARCSEC = 3600.0


async def start_service(path: Path = DEFAULT_CONFIG, *, can: dict | None = None,
                        **server) -> tuple[Service, int, tempfile.TemporaryDirectory]:
    """The service of hardware file ``path`` on a free port (``server`` overrides other
    ``[server]`` settings, ``can`` ``[can]`` settings); returns (service, port, state dir)."""
    config = load_config(path)
    state = tempfile.TemporaryDirectory(prefix="tcs-bench-")
    changes = dict(web=dataclasses.replace(config.web, port=-1), indi=dataclasses.replace(config.indi, port=-1), server=dataclasses.replace(config.server, **{"port": 0, "opentsi_port": -1, **server}),
                   state=StateSection(path=state.name))
    if config.can is not None:
        bus = dict(can or {})
        if config.can.interface == "virtual":
            bus["channel"] = f"tcs-bench-{uuid.uuid4().hex[:12]}"
        changes["can"] = dataclasses.replace(config.can, **bus)
    new = dataclasses.replace(config, **changes)
    object.__setattr__(new, "source", config.source)
    service = Service(new, alpaca_port=0, alpaca_discovery_port=-1)  # a free port (11111 may be taken)
    port = await service.start()
    return service, port, state


class Client:
    """A TPL2 connection logged in as admin: ``get``, ``set`` (waits for the end), ``start``."""

    def __init__(self, reader, writer):
        self.reader, self.writer = reader, writer
        self.ids = iter(range(1, 1 << 31))
        self.pending: dict[int, list[str]] = {}

    @classmethod
    async def connect(cls, port: int, user: str = "admin", password: str = "admin") -> "Client":
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        await reader.readline()
        writer.write(f'AUTH PLAIN "{user}" "{password}"\n'.encode())
        line = await reader.readline()
        if not line.startswith(b"AUTH OK"):
            raise SystemExit(f"login failed: {line!r}")
        return cls(reader, writer)

    async def start(self, text: str) -> int:
        cmd = next(self.ids)
        self.pending[cmd] = []
        self.writer.write(f"{cmd} {text}\n".encode())
        await self.writer.drain()
        return cmd

    async def wait(self, cmd: int, timeout: float = 300.0) -> list[str]:
        """Lines of ``cmd`` up to its final line (other commands' lines are kept for later)."""
        final = re.compile(r"^\d+ COMMAND (COMPLETE|FAILED|ABORTEDBY \d+|TIMEOUT)$")
        deadline = time.monotonic() + timeout
        while not (self.pending[cmd] and final.match(self.pending[cmd][-1])):
            line = (await asyncio.wait_for(self.reader.readline(), deadline - time.monotonic())).decode()
            if not line:
                raise ConnectionError("server closed the connection")
            line = line.rstrip("\r\n")
            owner = int(line.split(" ", 1)[0])
            if owner in self.pending:
                self.pending[owner].append(line)
        return self.pending.pop(cmd)

    async def command(self, text: str, timeout: float = 300.0) -> list[str]:
        return await self.wait(await self.start(text), timeout)

    async def set(self, text: str, timeout: float = 300.0) -> list[str]:
        lines = await self.command(f"SET {text}", timeout)
        if not all(" DATA OK " in x for x in lines if " DATA " in x):
            raise SystemExit(f"SET {text} failed: {lines}")
        return lines

    async def get(self, *objs: str) -> list[str]:
        lines = await self.command("GET " + ";".join(objs))
        return [x.split("=", 1)[1] for x in lines if " DATA INLINE " in x]

    async def num(self, obj: str) -> float:
        return float((await self.get(obj))[0])

    async def until(self, obj: str, pred, timeout: float = 120.0) -> float:
        deadline = time.monotonic() + timeout
        while True:
            value = await self.num(obj)
            if pred(value):
                return value
            if time.monotonic() > deadline:
                raise SystemExit(f"{obj} stayed at {value}")
            await asyncio.sleep(0.05)

    async def close(self) -> None:
        self.writer.close()
        try:
            await self.writer.wait_closed()
        except OSError:
            pass


async def power_and_reference(c: Client, *axes: str) -> None:
    """Main power on (if the tree has CABINET), then every axis on and referenced."""
    if (await c.get("CABINET.POWER_STATE"))[0] not in ("UNKNOWN", "1.0"):
        await c.set("CABINET.POWER=1")
    for ax in axes:
        if await c.num(f"{ax}.POWER_STATE") != 1.0:
            await c.set(f"{ax}.POWER=1")
    for ax in axes:
        if await c.num(f"{ax}.REFERENCED") < 1.0:
            await c.set(f"{ax}.REINIT=0")
    for ax in axes:
        await c.until(f"{ax}.REFERENCED", lambda v: v == 1.0)
        await c.until(f"{ax}.MOTION_STATE", lambda v: not int(v) & 1)


class LoopRecorder:
    """Per control cycle and axis: (UT1 the setpoint is reached, setpoint sent), the same for
    the point-to-point planner's unrounded setpoint (``planned``), and (UT1 of the SYNC,
    position the drive measured then). A CSP drive reaches a setpoint one interpolation
    period (the SYNC period) after the SYNC that latches it."""

    def __init__(self, service: Service, modules: list[str]):
        self.telescope = service.telescope
        self.source = service.telescope.can.cycle
        self.axes = {a.module_name: a for a in service.telescope.axes if a.module_name in modules}
        self.setpoints: dict[str, list[tuple[float, float]]] = {m: [] for m in self.axes}
        self.planned: dict[str, list[tuple[float, float]]] = {m: [] for m in self.axes}
        self.actual: dict[str, list[tuple[float, float]]] = {m: [] for m in self.axes}

    def __call__(self, cycle) -> None:
        now = time.monotonic()
        ut1 = self.telescope.local.ut1()
        reached = ut1 + cycle.next_sync + self.source.period - now
        measured = ut1 - (now - cycle.sync_time)
        for name, axis in self.axes.items():
            st = axis.drive.status()
            if st.setpoint is not None:
                self.setpoints[name].append((reached, st.setpoint))
            self.planned[name].append((reached, axis.planner.setpoint.position))
            last = axis.last_status
            if last is not None:
                self.actual[name].append((measured, last.position))

    def __enter__(self) -> "LoopRecorder":
        self.source.add_callback(self)
        return self

    def __exit__(self, *exc) -> None:
        self.source.remove_callback(self)


def error_stats(samples, path, t0: float, t1: float) -> dict:
    """RMS and max |sample − path(t)| over [t0, t1], arcsec (samples in degrees)."""
    errs = [abs(p - path(t)) for t, p in samples if t0 <= t <= t1]
    if not errs:
        return {"rms_arcsec": None, "max_arcsec": None, "n": 0}
    return {"rms_arcsec": round(math.sqrt(sum(e * e for e in errs) / len(errs)) * ARCSEC, 4),
            "max_arcsec": round(max(errs) * ARCSEC, 4), "n": len(errs)}


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, max(0, math.ceil(q / 100 * len(s)) - 1))]
