"""Counts of the commands a front end handled, by verb and result, and how long they took.

Each front end owns one :class:`CommandStats` (the TPL2 servers of OpenTCI and OpenTSI, the
Alpaca server) and calls :meth:`CommandStats.record` once per command when its final answer is
written, on the service's event loop; the status page's snapshot (:mod:`tcs.web.snapshot`)
reads :meth:`CommandStats.figures` on the same loop, so nothing is locked.

Labels stay a small fixed set, never per client or per object: the verb (TPL2: ``GET``,
``SET``, ``ABORT``, ``AUTH``, ``DISCONNECT``, ``OTHER`` for a line that names no command;
Alpaca: the HTTP method) and the result (TPL2: ``complete``, ``failed``, ``timeout`` (an ABORT
whose victims did not stop in time), ``refused`` (``COMMAND ERROR`` before it ran: syntax,
unknown, not logged in, busy id, too many); Alpaca: ``ok``, ``error`` (an ASCOM error number),
``bad_request`` (HTTP 400)). The latency is from the moment the command is handled to its final
line — for a GET the work of reading, for a SET that moves an axis until the move ended — in the
buckets of :data:`LATENCY_BOUNDS` (seconds); refused commands are counted, not timed.
"""

from __future__ import annotations

from tcs.axes.control_loop import Histogram

#: Upper bounds (s) of the latency histogram's buckets; a last bucket holds the rest (+Inf).
LATENCY_BOUNDS = (0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25,
                  0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 300.0)


class CommandStats:
    """The commands of one front end: ``counts[(verb, result)]`` and a latency
    :class:`~tcs.axes.control_loop.Histogram` per verb (buckets :data:`LATENCY_BOUNDS`)."""

    __slots__ = ("counts", "latency")

    def __init__(self) -> None:
        self.counts: dict[tuple[str, str], int] = {}
        self.latency: dict[str, Histogram] = {}

    def record(self, verb: str, result: str, seconds: float | None = None) -> None:
        """One command ended with ``result``; ``seconds`` from handling to the final line (None:
        not timed, e.g. refused)."""
        key = (verb, result)
        counts = self.counts
        counts[key] = counts.get(key, 0) + 1
        if seconds is not None:
            hist = self.latency.get(verb)
            if hist is None:
                hist = self.latency[verb] = Histogram(LATENCY_BOUNDS)
            hist.observe(seconds)

    def figures(self) -> dict:
        """Plain data for the snapshot: ``{"counts": [[verb, result, n], ...], "latency":
        {verb: ([bucket counts...], sum)}}``."""
        return {"counts": [[v, r, n] for (v, r), n in sorted(self.counts.items())],
                "latency": {v: h.export() for v, h in sorted(self.latency.items())}}
