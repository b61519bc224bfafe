"""Modbus PLC driver: polls a register map into snapshots of named points, writes named points.

How it works
------------
One :class:`PlcDriver` per ``[plcs.<name>]`` section runs one asyncio task on the server's
event loop. The task owns the link (:class:`~tcs.drivers.modbus_client.ModbusLink`, the only
code touching pymodbus) and does, in order:

1. connect; poll once — the PLC counts as **connected** only after a complete poll cycle —
   then write *stop* to the command point of every axis of the map (``X_command`` = 2, see
   :mod:`tcs.drivers.plc_axis`) before anything else: a move the TCS aborted while the PLC was
   unreachable never resumes when the link returns (issue 14.3), and no queued write precedes it;
2. loop: send queued writes first (each as soon as it is queued), then the poll cycle when it
   is due (every ``poll_interval``; a late cycle skips the slots it missed, counted in
   ``stats.missed``). With ``idle_poll_interval`` set, a resting PLC is polled that much less
   often: resting means no poll for :data:`IDLE_AFTER` (2 s) has seen an axis of the map
   moving (``X_status.moving``) or commanded (``X_command`` not yet reset to 0 by the PLC),
   nothing was written meanwhile, and nobody holds the full rate (:meth:`hold_full_rate`: a
   dome trajectory, sampled at every poll). A write brings the full rate back at once: the
   next poll comes at most ``poll_interval`` after it (``stats.interval`` is the one in effect);
3. on any communication failure: close the link, mark the snapshot invalid, report **lost**
   with the OpenTCI number — 4 (nocon) when the connection cannot be opened or was closed,
   3 (confail) when the PLC did not answer in time or refused a poll — fail every pending write
   with :class:`~tcs.errors.CommunicationError` carrying that number, wait (backoff from
   ``reconnect_min`` doubling to ``reconnect_max``) and start again at 1. Recovery needs no
   one's help.

Every poll cycle first increments the ``watchdog`` point of the map (``tcs_watchdog``, a
16-bit counter) when the map has it: a PLC program stops its axes when it stops changing.

The poll reads the map in few requests: points of one kind are grouped into blocks that span
at most ``max_gap`` unused addresses and ``max_read_registers`` / ``max_read_bits``.

What others use
---------------
* ``driver.snapshot`` (:class:`PlcSnapshot`): every readable point by name, plus
  ``"<point>.<bit>"`` for named bits; ``valid`` is False while the PLC is lost.
* ``driver.value(name)`` — the latest value, or ``CommunicationError`` while lost.
* ``await driver.write(name, value)`` / ``write_many({...})`` — scaled and range-checked,
  adjacent points merged into one request; returns the poll cycle number after which
  snapshots reflect the write (``wait_for(..., after=n)``).
* ``driver.add_connection_listener(cb)`` (:class:`PlcConnectionEvent`) and
  ``add_poll_listener(cb)`` (:class:`PlcSnapshot`); both return a function that removes the
  listener. Listeners run on the event loop and must not block.

Nothing here knows OpenTCI; :mod:`tcs.drivers.plc_axis` builds the axis convention on top.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from tcs.config.plc import AXIS_STOP, BIT_KINDS, PlcSection, RegisterPoint, Value
from tcs.drivers.modbus_client import ModbusExceptionResponse, ModbusLink
from tcs.errors import (AccessDenied, CommunicationError, ErrorNumber, HardwareError, RangeRefused,
                        TcsError, UnknownObject)
from tcs.state_epoch import bump as bump_epoch

__all__ = ["PlcDriver", "PlcSnapshot", "PlcConnectionEvent", "PollStats", "ReadBlock",
           "ModbusExceptionResponse", "plan_reads"]

log = logging.getLogger(__name__)

#: Seconds after the last write, the last poll that saw an axis moving or commanded, or the end
#: of a full-rate hold, before the idle poll rate (``idle_poll_interval``) may begin.
IDLE_AFTER = 2.0


async def _within(fut: asyncio.Future, timeout: float | None):
    """Await ``fut``, failing it with TimeoutError after ``timeout`` s (unlike 3.11's
    ``wait_for``, a cancel of the caller is never swallowed)."""
    if timeout is None:
        return await fut
    handle = asyncio.get_running_loop().call_later(
        timeout, lambda: fut.done() or fut.set_exception(asyncio.TimeoutError()))
    try:
        return await fut
    finally:
        handle.cancel()


@dataclass(frozen=True)
class ReadBlock:
    """One read request of the poll cycle: ``count`` addresses of ``kind`` from ``address``."""

    kind: str
    address: int
    count: int
    points: tuple[RegisterPoint, ...]


def plan_reads(points: Mapping[str, RegisterPoint], *, max_gap: int = 8, max_registers: int = 125,
               max_bits: int = 2000) -> list[ReadBlock]:
    """Group the readable points into as few read requests as the limits allow."""
    blocks: list[ReadBlock] = []
    for kind in ("coil", "discrete", "holding", "input"):
        limit = max_bits if kind in BIT_KINDS else max_registers
        pts = sorted((p for p in points.values() if p.kind == kind and p.readable),
                     key=lambda p: p.address)
        group: list[RegisterPoint] = []
        for p in pts:
            if group and (p.address - group_end > max_gap or p.end - group[0].address > limit):
                blocks.append(ReadBlock(kind, group[0].address, group_end - group[0].address, tuple(group)))
                group = []
            if not group:
                group_end = p.end
            group.append(p)
            group_end = max(group_end, p.end)
        if group:
            blocks.append(ReadBlock(kind, group[0].address, group_end - group[0].address, tuple(group)))
    return blocks


@dataclass(frozen=True)
class PlcSnapshot:
    """The PLC's points as read by one complete poll cycle.

    ``cycle`` counts completed cycles since start (0: none yet); ``time`` is the event loop's
    clock at the end of the cycle; ``valid`` is False while the PLC is lost (the values are
    then the last ones read).
    """

    plc: str
    cycle: int
    time: float
    valid: bool
    values: Mapping[str, Value] = field(default_factory=lambda: MappingProxyType({}))

    def __getitem__(self, name: str) -> Value:
        return self.values[name]

    def get(self, name: str, default=None):
        return self.values.get(name, default)

    def changed(self, other: PlcSnapshot | None) -> set[str]:
        """Names whose value differs from ``other`` (all names when ``other`` is None)."""
        if other is None:
            return set(self.values)
        return {k for k, v in self.values.items() if other.values.get(k) != v}


@dataclass(frozen=True)
class PlcConnectionEvent:
    """The PLC became reachable (``connected``) or not; ``number`` is 4 nocon / 3 confail."""

    plc: str
    connected: bool
    number: int | None
    message: str


@dataclass
class PollStats:
    """Counters and recent timings (seconds) of one driver, for diagnostics and benchmarks;
    ``interval`` is the poll interval in effect (the idle one while the PLC rests)."""

    interval: float = 0.0
    cycles: int = 0
    missed: int = 0
    failures: int = 0
    connects: int = 0
    writes: int = 0
    cycle_times: deque = field(default_factory=lambda: deque(maxlen=4096))
    latencies: deque = field(default_factory=lambda: deque(maxlen=4096))
    lateness: deque = field(default_factory=lambda: deque(maxlen=4096))


@dataclass
class _WriteJob:
    kind: str
    address: int
    values: list
    what: str
    future: asyncio.Future


class PlcDriver:
    """One Modbus PLC, polled on the running event loop.

    Parameters
    ----------
    name:
        The PLC's name (the key of ``[plcs.<name>]``); used in messages and events.
    section:
        Its configuration: transport, address, timing and register map.
    """

    def __init__(self, name: str, section: PlcSection):
        self.name = name
        self.section = section
        self.points: Mapping[str, RegisterPoint] = MappingProxyType(dict(section.map))
        self.blocks = plan_reads(self.points, max_gap=section.max_gap,
                                 max_registers=section.max_read_registers,
                                 max_bits=section.max_read_bits)
        self.stats = PollStats(interval=section.poll_interval)
        self._link = ModbusLink(name, section)
        self._snapshot = PlcSnapshot(name, 0, 0.0, False)
        self._connected = False
        self._error: int | None = None
        self._message = "not started"
        self._writes: deque[_WriteJob] = deque()
        self._wake: asyncio.Future | None = None
        self._task: asyncio.Task | None = None
        self._stopping = False
        self._conn_listeners: list[Callable[[PlcConnectionEvent], None]] = []
        self._poll_listeners: list[Callable[[PlcSnapshot], None]] = []
        wd = self.points.get(section.watchdog)
        self._watchdog = wd if wd is not None and wd.writable and wd.kind == "holding" else None
        self._watchdog_count = 0
        self._holds = [self.points[f"{axis}_command"] for axis in section.axis_names()]
        # the idle rate (idle_poll_interval): the points that say an axis is busy, the loop time
        # until which the PLC counts as busy anyway, and who holds the full rate
        self._busy_points = [name for axis in section.axis_names()
                             for name in (f"{axis}_status.moving", f"{axis}_command")]
        self._busy_until = 0.0
        self._full_rate_holders: set = set()

    # ---------------------------------------------------------------- lifecycle

    async def start(self) -> None:
        """Start polling (returns at once; watch ``connected`` or ``wait_connected``)."""
        if self._task is None:
            self._stopping = False
            self._message = "connecting"
            self._task = asyncio.get_running_loop().create_task(self._run(), name=f"plc {self.name}")

    async def stop(self) -> None:
        """Stop polling, close the link, fail pending writes (nocon)."""
        task, self._task = self._task, None
        self._stopping = True
        if task is not None:
            # Python 3.11's wait_for (inside pymodbus) can swallow a cancel that coincides with
            # an answer: cancel until the task has really ended.
            while not task.done():
                task.cancel()
                await asyncio.wait([task], timeout=0.05)
            if not task.cancelled() and task.exception() is not None:  # pragma: no cover
                log.error("PLC %s: I/O task ended with %r", self.name, task.exception())
        self._link.close()
        self._fail_writes(CommunicationError(self.name, "driver stopped", ErrorNumber.NOCON))
        self._connected = False
        self._error = ErrorNumber.NOCON
        self._message = "stopped"
        self._snapshot = PlcSnapshot(self.name, self._snapshot.cycle, self._snapshot.time, False,
                                     self._snapshot.values)

    async def __aenter__(self) -> PlcDriver:
        await self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()

    # ---------------------------------------------------------------- state

    @property
    def connected(self) -> bool:
        """True after a complete poll cycle, until the next communication failure."""
        return self._connected

    @property
    def error(self) -> int | None:
        """None while connected, else the OpenTCI number of the failure (4 nocon, 3 confail)."""
        return None if self._connected else (self._error or ErrorNumber.NOCON)

    @property
    def message(self) -> str:
        """Why the PLC is not connected (or ``"connected"``)."""
        return self._message

    @property
    def snapshot(self) -> PlcSnapshot:
        return self._snapshot

    def value(self, name: str) -> Value:
        """Latest value of a point (or ``"<point>.<bit>"``).

        Raises
        ------
        UnknownObject
            No such readable point.
        CommunicationError
            The PLC is not connected (number 4 or 3).
        """
        if name not in self._snapshot.values and not self._known_readable(name):
            raise UnknownObject(f"PLC {self.name!r} has no readable point {name!r}")
        if not self._connected:
            raise self._not_connected()
        return self._snapshot.values[name]

    def add_connection_listener(self, callback: Callable[[PlcConnectionEvent], None]) -> Callable[[], None]:
        """Call ``callback(event)`` whenever ``connected`` or ``error`` changes."""
        self._conn_listeners.append(callback)
        return lambda: self._conn_listeners.remove(callback) if callback in self._conn_listeners else None

    def add_poll_listener(self, callback: Callable[[PlcSnapshot], None]) -> Callable[[], None]:
        """Call ``callback(snapshot)`` after every complete poll cycle."""
        self._poll_listeners.append(callback)
        return lambda: self._poll_listeners.remove(callback) if callback in self._poll_listeners else None

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Return once connected; ``CommunicationError`` with the current number on timeout."""
        if self._connected:
            return
        fut = asyncio.get_running_loop().create_future()
        remove = self.add_connection_listener(
            lambda ev: ev.connected and not fut.done() and fut.set_result(None))
        try:
            await _within(fut, timeout)
        except asyncio.TimeoutError:
            raise CommunicationError(self.name, f"not connected after {timeout:g} s: {self._message}",
                                     self.error) from None
        finally:
            remove()

    async def wait_for(self, predicate: Callable[[PlcSnapshot], bool], *, after: int = 0,
                       timeout: float | None = None) -> PlcSnapshot:
        """The first snapshot newer than cycle ``after`` for which ``predicate`` is true.

        Raises
        ------
        CommunicationError
            The PLC is or gets lost while waiting (number 4 or 3).
        HardwareError
            Number 7 (timeout) when ``timeout`` seconds pass first.
        """
        snap = self._snapshot
        if not self._connected:
            raise self._not_connected()
        if snap.valid and snap.cycle > after and predicate(snap):
            return snap
        fut: asyncio.Future = asyncio.get_running_loop().create_future()

        def on_poll(s: PlcSnapshot) -> None:
            if not fut.done() and s.cycle > after:
                try:
                    if predicate(s):
                        fut.set_result(s)
                except Exception as exc:  # a broken predicate is the caller's error
                    fut.set_exception(exc)

        def on_conn(ev: PlcConnectionEvent) -> None:
            if not ev.connected and not fut.done():
                fut.set_exception(CommunicationError(self.name, ev.message, ev.number))

        removers = [self.add_poll_listener(on_poll), self.add_connection_listener(on_conn)]
        try:
            return await _within(fut, timeout)
        except asyncio.TimeoutError:
            raise HardwareError(self.name, f"condition not met within {timeout:g} s",
                                ErrorNumber.TIMEOUT) from None
        finally:
            for remove in removers:
                remove()

    # ---------------------------------------------------------------- writes

    async def write(self, name: str, value: Value) -> int:
        """Write one point; see :meth:`write_many`."""
        return await self.write_many({name: value})

    async def write_many(self, values: Mapping[str, Value]) -> int:
        """Write points in the given order; adjacent points of one kind go in one request.

        Returns
        -------
        int
            The number of the last poll cycle completed before the write: snapshots with a
            higher ``cycle`` were read after the PLC acknowledged it.

        Raises
        ------
        UnknownObject, AccessDenied, RangeRefused
            Unknown point, read-only point, value outside the point's type (nothing written).
        CommunicationError
            Not connected, or the link failed before the PLC acknowledged (4 nocon / 3 confail).
        ModbusExceptionResponse
            The PLC refused the request (exception response; the link stays up).
        """
        jobs = self._make_jobs(values)
        if not self._connected or self._task is None:
            raise self._not_connected()
        loop = asyncio.get_running_loop()
        for job in jobs:
            job.future = loop.create_future()
            self._writes.append(job)
        self._wakeup()
        result = 0
        try:
            for job in jobs:
                result = await job.future
        finally:
            for job in jobs:  # a cancelled caller does not leave writes behind
                if not job.future.done():
                    job.future.cancel()
        return result

    def _make_jobs(self, values: Mapping[str, Value]) -> list[_WriteJob]:
        jobs: list[_WriteJob] = []
        for name, value in values.items():
            p = self.points.get(name)
            if p is None:
                raise UnknownObject(f"PLC {self.name!r} has no point {name!r}")
            if not p.writable:
                raise AccessDenied(f"PLC {self.name!r} point {name!r} is read-only")
            try:
                raw = p.encode(value)
            except ValueError as exc:
                raise RangeRefused(f"PLC {self.name!r}: {exc}") from None
            last = jobs[-1] if jobs else None
            if last is not None and last.kind == p.kind and last.address + len(last.values) == p.address:
                last.values.extend(raw)
                last.what += f", {name}"
            else:
                jobs.append(_WriteJob(p.kind, p.address, list(raw), name, None))  # type: ignore[arg-type]
        return jobs

    def _fail_writes(self, exc: TcsError) -> None:
        while self._writes:
            job = self._writes.popleft()
            if not job.future.done():
                job.future.set_exception(CommunicationError(self.name, f"write of {job.what} failed: "
                                                            f"{self._bare(exc)}", exc.number))

    def _bare(self, exc: TcsError) -> str:
        return exc.message.removeprefix(f"{self.name}: ")

    def _not_connected(self) -> CommunicationError:
        return CommunicationError(self.name, f"not connected ({self._message})", self.error)

    def _known_readable(self, name: str) -> bool:
        base = name.split(".", 1)[0]
        p = self.points.get(base)
        return p is not None and p.readable and (base == name or name.split(".", 1)[1] in dict(p.bits))

    # ---------------------------------------------------------------- the I/O task

    async def _run(self) -> None:
        s = self.section
        delay = s.reconnect_min
        while not self._stopping:
            try:
                await self._link.connect()
                await self._poll()
                await self._hold_axes()
                self.stats.connects += 1
                self._set_state(True, None, "connected")
                delay = s.reconnect_min
                await self._serve()
            except (HardwareError, Exception) as caught:
                exc = caught if isinstance(caught, HardwareError) else HardwareError(
                    self.name, f"internal error: {caught!r}", ErrorNumber.INTERNAL)
                if exc is not caught:
                    log.exception("PLC %s: unexpected error in the I/O task", self.name)
                self.stats.failures += 1
                self._link.close()
                self._snapshot = PlcSnapshot(self.name, self._snapshot.cycle, self._snapshot.time,
                                             False, self._snapshot.values)
                self._set_state(False, exc.number, self._bare(exc))
                self._fail_writes(exc)
            await asyncio.sleep(delay)
            delay = min(s.reconnect_max, max(2 * delay, 0.05))

    async def _serve(self) -> None:
        loop = asyncio.get_running_loop()
        interval = self.stats.interval = self.section.poll_interval
        self._busy_until = loop.time() + IDLE_AFTER  # (connected: the full rate first)
        due = loop.time() + interval  # the slot of the next poll
        while not self._stopping:
            while self._writes:
                job = self._writes[0]
                if job.future.done():  # caller gave up before it was sent
                    self._writes.popleft()
                    continue
                self._busy_until = loop.time() + IDLE_AFTER
                try:
                    await self._link.write(job.kind, job.address, job.values)
                except ModbusExceptionResponse as exc:
                    self._writes.popleft()
                    if not job.future.done():
                        job.future.set_exception(exc)
                    continue
                self._writes.popleft()
                self.stats.writes += 1
                if not job.future.done():
                    job.future.set_result(self._snapshot.cycle)
            now = loop.time()
            wanted = self._interval_at(now)
            if wanted != interval:  # the idle rate begins or ends: the next slot follows
                last = due - interval  # (the previous poll's slot)
                due = last + wanted if wanted > interval else max(now, last + wanted)
                interval = self.stats.interval = wanted
            if now >= due:
                late = now - due
                self.stats.lateness.append(late)
                if late >= interval:
                    skipped = int(late // interval)
                    self.stats.missed += skipped
                    due += skipped * interval
                due += interval
                await self._poll()
                continue
            await self._sleep_until(due)

    def _interval_at(self, now: float) -> float:
        """The poll interval in effect: ``idle_poll_interval`` while the PLC rests."""
        idle = self.section.idle_poll_interval
        if not idle or now < self._busy_until or self._full_rate_holders:
            return self.section.poll_interval
        return idle

    def hold_full_rate(self, holder: object, hold: bool = True) -> None:
        """Keep (``hold``) or release the full poll rate for ``holder`` whatever the PLC's axes
        do — e.g. a dome trajectory sampled at every poll. Releasing starts the 2 s before the
        idle rate (``idle_poll_interval``) may begin."""
        if hold:
            if holder not in self._full_rate_holders:
                self._full_rate_holders.add(holder)
                self._wakeup()
        elif holder in self._full_rate_holders:
            self._full_rate_holders.discard(holder)
            self._busy_until = max(self._busy_until, asyncio.get_running_loop().time() + IDLE_AFTER)

    async def _sleep_until(self, when: float) -> None:
        loop = asyncio.get_running_loop()
        fut = self._wake = loop.create_future()
        handle = loop.call_at(when, self._wakeup)
        try:
            await fut
        finally:
            handle.cancel()
            self._wake = None

    def _wakeup(self) -> None:
        if self._wake is not None and not self._wake.done():
            self._wake.set_result(None)

    async def _hold_axes(self) -> None:
        """Write stop to every axis of the map (each connect, before the PLC counts as connected)."""
        for p in self._holds:
            try:
                await self._link.write(p.kind, p.address, list(p.encode(AXIS_STOP)))
            except ModbusExceptionResponse as exc:
                log.warning("PLC %s: stop of %s at connect refused: %s", self.name, p.name, exc)
        if self._holds:
            log.info("PLC %s: stop written to %s at connect", self.name, ", ".join(p.name for p in self._holds))

    async def _poll(self) -> None:
        loop = asyncio.get_running_loop()
        t0 = time.perf_counter()
        wd = self._watchdog
        if wd is not None:
            self._watchdog_count = (self._watchdog_count + 1) % 0x8000
            try:
                await self._link.write(wd.kind, wd.address, list(wd.encode(self._watchdog_count)))
            except ModbusExceptionResponse as exc:  # the PLC refuses it: poll on without
                log.warning("PLC %s: watchdog %s refused (%s); not written any more", self.name, wd.name, exc)
                self._watchdog = None
        values: dict[str, Value] = {}
        for block in self.blocks:
            t = time.perf_counter()
            data = await self._link.read(block.kind, block.address, block.count)
            self.stats.latencies.append(time.perf_counter() - t)
            for p in block.points:
                raw = data[p.address - block.address: p.end - block.address]
                values[p.name] = p.decode(raw)
                if p.bits:
                    values.update(p.decode_bits(raw))
        self.stats.cycle_times.append(time.perf_counter() - t0)
        self.stats.cycles += 1
        now = loop.time()
        if any(values.get(name) for name in self._busy_points):  # an axis moves or is commanded
            self._busy_until = now + IDLE_AFTER
        self._snapshot = PlcSnapshot(self.name, self._snapshot.cycle + 1, now, True,
                                     MappingProxyType(values))
        bump_epoch()  # readable state may have changed (tcs.state_epoch)
        for cb in list(self._poll_listeners):
            try:
                cb(self._snapshot)
            except Exception:
                log.exception("PLC %s: poll listener %r failed", self.name, cb)

    def _set_state(self, connected: bool, number: int | None, message: str) -> None:
        changed = connected != self._connected or (not connected and number != self._error)
        self._connected, self._error, self._message = connected, number, message
        if not changed:
            return
        bump_epoch()  # its modules read unknown (or again) from now on (tcs.state_epoch)
        if connected:
            log.info("PLC %s: connected (%s)", self.name, self._link.where)
        else:
            log.warning("PLC %s: lost (%s): %s", self.name, number, message)
        event = PlcConnectionEvent(self.name, connected, number, message)
        for cb in list(self._conn_listeners):
            try:
                cb(event)
            except Exception:
                log.exception("PLC %s: connection listener %r failed", self.name, cb)
