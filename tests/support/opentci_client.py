"""A TPL2 test client for OpenTCI module tests: fresh command ids, numeric GETs, waiting for a
value or an event line. Built on the raw wire client (:class:`support.tpl2.RawClient`)."""

from __future__ import annotations

import asyncio
import itertools
import re
import time

from support.tpl2 import RawClient

WAIT = 30.0  # s: generous limit for anything simulated hardware does
_ids = itertools.count(1000)


class Client(RawClient):
    #: default time limit of set / wait / event; a module's tests may raise it in a subclass
    patience: float = WAIT

    async def set(self, text: str, timeout: float | None = None) -> list[str]:
        """``SET text``; all lines of the command up to its final line."""
        return await self.command(next(_ids), f"SET {text}", timeout or self.patience)

    async def start(self, text: str) -> int:
        """Send ``SET text`` and return its id without waiting."""
        cmd_id = next(_ids)
        await self.send(f"{cmd_id} SET {text}")
        return cmd_id

    async def value(self, obj: str) -> str:
        return await self.get(obj, next(_ids))

    async def num(self, obj: str) -> float:
        return float(await self.value(obj))

    async def nums(self, *objs: str) -> list[float]:
        cmd_id = next(_ids)
        lines = await self.command(cmd_id, "GET " + ";".join(objs))
        return [float(line.split("=", 1)[1]) for line in lines[1:-1]]

    async def wait(self, obj: str, pred, timeout: float | None = None):
        """Poll ``obj`` until ``pred(value)`` (value as float when it is a number)."""
        deadline = time.monotonic() + (timeout or self.patience)
        while True:
            text = await self.value(obj)
            try:
                value = float(text)
            except ValueError:
                value = text
            if pred(value):
                return value
            assert time.monotonic() < deadline, f"{obj} stayed at {text}"
            await asyncio.sleep(0.02)

    async def event(self, pattern: str, timeout: float | None = None) -> str:
        """The first line (already read or still to come) matching ``pattern``; consumed."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + (timeout or self.patience)
        while True:
            for line in self.lines:
                if rx.search(line):
                    self.lines.remove(line)
                    return line
            left = deadline - time.monotonic()
            assert left > 0, f"no line matching {pattern!r}; seen {self.lines}"
            try:
                self.lines.append(await self._read(left))
            except asyncio.TimeoutError:
                pass

    def seen(self, pattern: str) -> list[str]:
        rx = re.compile(pattern)
        return [line for line in self.lines if rx.search(line)]

    def forget(self) -> None:
        """Drop lines read ahead (events of earlier steps)."""
        self.lines.clear()


def done_ok(lines: list[str], obj: str) -> bool:
    return any(line.endswith(f"DATA OK {obj}") for line in lines) and lines[-1].endswith("COMMAND COMPLETE")


def failed(lines: list[str], obj: str) -> int | None:
    """The n of ``DATA ERROR <obj> FAILED n`` among ``lines`` (None when absent)."""
    for line in lines:
        m = re.search(rf"DATA ERROR {re.escape(obj)} FAILED (\d+)$", line)
        if m:
            return int(m.group(1))
    return None


async def upload(c: Client, ax: str, points: list[tuple[float, float]]) -> list[str]:
    """Stage ``points`` in ``ax``.TRAJECTORY.BUFFER[0..n-1] (one SET) and ADDPOINTS them;
    returns the ADDPOINTS reply."""
    parts = []
    for i, (t, p) in enumerate(points):
        parts += [f"{ax}.TRAJECTORY.BUFFER[{i}].TIME={t!r}", f"{ax}.TRAJECTORY.BUFFER[{i}].TARGETPOS={p!r}"]
    lines = await c.set(";".join(parts))
    assert all(" DATA OK " in x for x in lines[1:-1]), lines
    return await c.set(f"{ax}.TRAJECTORY.ADDPOINTS={len(points)}")
