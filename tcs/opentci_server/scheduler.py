"""Fair scheduling of the TPL2 command work of all connections of one server.

How it works
------------
A :class:`~tcs.opentci_server.session.Session` with parsed lines waiting calls
:meth:`FairScheduler.ready`. The scheduler runs on the event loop and handles **one line at a
time**, always of the connection that has had the least work done so far (its *virtual time*:
the seconds its commands took, plus a small charge per command, like Linux's CFS). A
connection that was quiet starts at the smallest virtual time of those running, so it cannot
bank credit. A light client (an operator's status GET) is therefore served next, however many
heavy clients are pipelining, and a heavy one gets its share and no more.

Work runs in *slices* of at most ``slice`` seconds; after a slice that ran out of time the
scheduler rests ``rest`` times as long before the next (``call_later``), so under a flood the
event-loop thread spends at most ``1 / (1 + rest)`` of its time on command work, and a
control-loop thread in the same interpreter — which needs its lock for every cycle — never
waits longer than about one slice. Without a flood the queue empties within the slice and
nothing rests. With the control loop in its own process the server passes ``rest = 0``
(:func:`tcs.opentci_server.server.work_rest`): resting then only leaves clients waiting.

Only :class:`~tcs.opentci_server.server.Tpl2Server` makes one (one per server instance, so a
second listener has its own); sessions talk to it through :meth:`ready` and :meth:`forget`,
and it calls back ``session.runnable()`` and ``session.run_one()``.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import time

#: Virtual seconds charged per command on top of its measured time (many tiny commands count).
COMMAND_CHARGE = 20e-6


class FairScheduler:
    """Least-served-first scheduler of sessions' queued lines (see the module docstring).

    Parameters
    ----------
    slice:
        Longest stretch of command work before the scheduler yields, seconds.
    rest:
        After a full slice, rest ``rest × slice`` before the next one.
    """

    def __init__(self, slice: float = 0.002, rest: float = 1.0):
        self.slice = slice
        self.rest = rest
        self._heap: list[tuple[float, int, object]] = []
        self._queued: set[int] = set()
        self._vtime: dict[int, float] = {}
        self._floor = 0.0
        self._seq = itertools.count()
        self._handle: asyncio.Handle | None = None
        self._running = False
        self.slices = 0
        self.rests = 0

    def ready(self, session) -> None:
        """``session`` has lines waiting and may run: queue it (no-op when queued)."""
        key = id(session)
        if key in self._queued:
            return
        self._queued.add(key)
        v = max(self._vtime.get(key, 0.0), self._floor)
        heapq.heappush(self._heap, (v, next(self._seq), session))
        if self._running:
            return  # the running slice takes it, or schedules the next one
        if self._handle is None:
            if len(self._heap) == 1:
                # Nobody else waits for a turn: start at once (one event-loop pass less per
                # request; a lone client's latency). The slice bounds it as ever; the rest of a
                # flood waits for the next pass like everyone else's work.
                self._run()
            else:
                self._handle = asyncio.get_running_loop().call_soon(self._run)

    def forget(self, session) -> None:
        """The session is gone: drop its bookkeeping (it leaves the heap when reached)."""
        self._vtime.pop(id(session), None)

    def close(self) -> None:
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None
        self._heap.clear()
        self._queued.clear()

    def _run(self) -> None:
        self._handle = None
        self._running = True
        try:
            self._slice()
        finally:
            self._running = False

    def _slice(self) -> None:
        self.slices += 1
        start = time.perf_counter()
        now = start
        while self._heap and now - start < self.slice:
            v, _, session = heapq.heappop(self._heap)
            key = id(session)
            self._queued.discard(key)
            if not session.runnable():
                continue
            self._floor = max(self._floor, v)
            session.run_one()
            after = time.perf_counter()
            v += after - now + COMMAND_CHARGE
            now = after
            if session.runnable():
                self._queued.add(key)
                heapq.heappush(self._heap, (v, next(self._seq), session))
            else:
                self._vtime[key] = v
        if not self._heap:
            return
        loop = asyncio.get_running_loop()
        used = now - start
        if used >= self.slice and self.rest > 0:
            self.rests += 1
            self._handle = loop.call_later(used * self.rest, self._run)
        else:
            self._handle = loop.call_soon(self._run)


__all__ = ["FairScheduler", "COMMAND_CHARGE"]
