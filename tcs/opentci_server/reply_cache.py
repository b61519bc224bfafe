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

Only :class:`~tcs.opentci_server.server.Tpl2Server` makes one (per server, i.e. per tree);
its sessions call :meth:`ReplyCache.get` and :meth:`ReplyCache.keep`.
"""

from __future__ import annotations

import time

from tcs.state_epoch import EPOCH

#: Most replies kept (distinct GET lines × read levels); past it all are dropped and kept anew.
LIMIT = 256


class ReplyCache:
    """GET replies kept for ``max_age`` seconds while nothing changed (the module docstring)."""

    def __init__(self, max_age: float = 0.005, clock=time.monotonic) -> None:
        self.max_age = max_age
        self._clock = clock
        self._replies: dict[tuple[bytes, int], tuple[int, float, int, bytes]] = {}
        self.hits = 0   # lines answered from here (for tests and benchmarks)
        self.kept = 0

    def get(self, line: bytes, rlevel: int) -> tuple[int, bytes] | None:
        """``(command id, reply)`` kept for ``line`` at this read level and still good, or None."""
        if not self._replies:
            return None
        entry = self._replies.get((line, rlevel))
        if entry is None or entry[0] != EPOCH.value or self._clock() - entry[1] > self.max_age:
            return None
        return entry[2], entry[3]

    def keep(self, line: bytes, rlevel: int, epoch: int, started: float, cmd_id: int,
             reply: bytes) -> None:
        """Keep ``reply`` to ``line``, whose values were read from ``epoch`` and ``started``
        (this cache's clock) on."""
        if self.max_age <= 0 or epoch != EPOCH.value:  # off, or changed while reading: not kept
            return
        if len(self._replies) >= LIMIT:
            self._replies.clear()
        self._replies[(line, rlevel)] = (epoch, started, cmd_id, reply)
        self.kept += 1

    def clear(self) -> None:
        """Forget every reply."""
        self._replies.clear()


__all__ = ["ReplyCache", "LIMIT"]
