"""The same status GET from many clients, read once while nothing changed.

How it works
------------
A status display polls with one GET line, the same bytes every time, and fifty displays send
it within the same few milliseconds. A :class:`~tcs.opentci_server.session.Session` that receives
exactly one whole line while nothing else of it waits (logged in, no queued or partial line,
output not paused) looks the line up here before parsing it. A reply is kept when such a line
was a GET whose every object reads the same for every connection of its read level (no
per-connection variable), keyed by the line's bytes and the read level, and it answers the
same line again only

* for ``[server] reuse_reply`` seconds (default 5 ms; 0 keeps nothing); and
* while :mod:`tcs.state_epoch` has the value it had before the reply's values were read:
  readbacks of the control loop (100 a second), a lost control process, PLC polls and PLC
  connection changes, GPS input, every line other than a GET reply that a TPL2 server writes
  (so a client told of a change — a completion, an event, a SET's answer — never reads the
  state from before it) and Alpaca PUTs change it.

So a reply reused here is what a GET at most 5 ms earlier read, with nothing the service knows
of changed since; only values derived from the clock (``LOCAL.UT1``, the sky place of a
telescope at rest) and changes the model makes without telling anyone may be that much older
than a fresh read would give — less than the control cycle the readbacks come at (10 ms).
With 1 ms the 50-client benchmark gave 0.75 of the echo server, with 5 ms 0.83
(``tools/bench/README.md``). A reused reply still counts as a command
(``COMMAND_RATE``, ``/metrics``), obeys the connection's command ids and in-flight limit (a busy
id goes the normal way and is refused there) and is written like any other. At most one line
per received chunk is answered here: a client pipelining many lines goes through the fair
scheduler as before.

Read again ahead of the next request: a reply that answers a request when it is older than
half its life (``reuse_reply / 2``) is read anew right after that answer is written — on the
event loop, once, by the reader the session handed to :meth:`ReplyCache.keep` — and replaces the
kept one. A client polling the same line faster than every ``reuse_reply`` then finds a kept
reply nearly always instead of paying a whole read every 5 ms in its own round trip (the
1-client p99 of ``tools/bench/tpl2_load.py``); the guarantee is unchanged (a reply answers only
while younger than ``reuse_reply`` and while nothing changed since its values were read), and a
line nobody asks for again is never read ahead: only a request that used a kept reply starts it.
It costs at most one read per line every ``reuse_reply / 2`` while the line is polled that fast.

Only :class:`~tcs.opentci_server.server.Tpl2Server` makes one (per server, i.e. per tree);
its sessions call :meth:`ReplyCache.get` and :meth:`ReplyCache.keep` (on the event loop).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from tcs.state_epoch import EPOCH

log = logging.getLogger(__name__)

#: Most replies kept (distinct GET lines × read levels); past it all are dropped and kept anew.
LIMIT = 256

#: A kept reply used when older than this share of ``max_age`` is read again ahead of time.
REFRESH_AT = 0.5

# an entry: [epoch, read since (this cache's clock), command id, reply, reader, refresh handle]
_EPOCH, _SINCE, _ID, _REPLY, _READER, _REFRESH = range(6)


class ReplyCache:
    """GET replies kept for ``max_age`` seconds while nothing changed (the module docstring)."""

    def __init__(self, max_age: float = 0.005, clock=time.monotonic) -> None:
        self.max_age = max_age
        self._clock = clock
        self._replies: dict[tuple[bytes, int], list] = {}
        self.hits = 0       # lines answered from here (for tests and benchmarks)
        self.kept = 0       # replies kept after a request read them
        self.refreshed = 0  # replies read again ahead of the next request

    def now(self) -> float:
        """This cache's clock (what :meth:`keep` takes as ``started``)."""
        return self._clock()

    def get(self, line: bytes, rlevel: int) -> tuple[int, bytes] | None:
        """``(command id, reply)`` kept for ``line`` at this read level and still good, or None.
        A reply past half its life is read again once this callback has ended (event loop)."""
        if not self._replies:
            return None
        key = (line, rlevel)
        entry = self._replies.get(key)
        if entry is None or entry[_EPOCH] != EPOCH.value:
            return None
        age = self._clock() - entry[_SINCE]
        if age > self.max_age:
            return None
        if age > self.max_age * REFRESH_AT and entry[_REFRESH] is None and entry[_READER] is not None:
            entry[_REFRESH] = asyncio.get_running_loop().call_soon(self._refresh, key, entry)
        return entry[_ID], entry[_REPLY]

    def keep(self, line: bytes, rlevel: int, epoch: int, started: float, cmd_id: int,
             reply: bytes, reader: Callable[[], bytes | None] | None = None) -> None:
        """Keep ``reply`` to ``line``, whose values were read from ``epoch`` and ``started``
        (this cache's clock) on; ``reader()`` reads the same reply anew (None: it cannot now)."""
        if self.max_age <= 0 or epoch != EPOCH.value:  # off, or changed while reading: not kept
            return
        if len(self._replies) >= LIMIT:
            self.clear()
        old = self._replies.get((line, rlevel))
        if old is not None and old[_REFRESH] is not None:
            old[_REFRESH].cancel()
        self._replies[(line, rlevel)] = [epoch, started, cmd_id, reply, reader, None]
        self.kept += 1

    def _refresh(self, key: tuple[bytes, int], entry: list) -> None:
        if self._replies.get(key) is not entry:  # kept anew or dropped meanwhile
            return
        entry[_REFRESH] = None  # (running now: nothing to cancel)
        epoch, started = EPOCH.value, self._clock()
        try:
            reply = entry[_READER]()
        except Exception:
            log.exception("reading a kept GET reply again failed")
            reply = None
        if reply is None:  # (its connection has gone, or the read failed: the next request reads)
            del self._replies[key]
            return
        self.refreshed += 1
        self.keep(key[0], key[1], epoch, started, entry[_ID], reply, entry[_READER])

    def clear(self) -> None:
        """Forget every reply."""
        for entry in self._replies.values():
            if entry[_REFRESH] is not None:
                entry[_REFRESH].cancel()
        self._replies.clear()


__all__ = ["ReplyCache", "LIMIT", "REFRESH_AT"]
