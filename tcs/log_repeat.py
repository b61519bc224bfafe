"""Rate limit for repeated log lines: the first occurrence, then a count every ``interval`` s.

A dead bus or a lost peer makes the same warning come from every cycle (a failed send of
SYNC, of each RPDO …): thousands of lines a second that bury everything else in the journal.
:class:`RepeatFilter` is a :class:`logging.Filter` for the service's handlers: a warning or
error line (INFO and DEBUG always pass: the journal of events stays complete) is passed the
first time; the same line again (same logger and level, numbers ignored, so "no
heartbeat for 0.52 s" and "… 0.61 s" are one kind) within ``interval`` seconds is counted and
dropped; the first one after the interval is passed with "(N more like it in the last T s)".

Installed by ``tcs-server`` on its root handlers (:func:`install`); thread-safe (the filter
runs in whichever thread logs).
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable

_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


class RepeatFilter(logging.Filter):
    """Pass a kind of line once per ``interval`` s, with the count of those dropped."""

    def __init__(self, interval: float = 10.0, clock: Callable[[], float] = time.monotonic,
                 max_kinds: int = 2000, level: int = logging.WARNING):
        super().__init__()
        self.level = level
        self.interval = float(interval)
        self._clock = clock
        self._max = max_kinds
        self._seen: dict[tuple, list] = {}  # kind -> [window start, dropped]
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < self.level:
            return True
        try:
            text = record.getMessage()
        except Exception:  # a bad format string: let the handler report it
            return True
        key = (record.name, record.levelno, _NUMBER.sub("#", text))
        now = self._clock()
        with self._lock:
            entry = self._seen.get(key)
            if entry is not None and now - entry[0] < self.interval:
                entry[1] += 1
                return False
            if len(self._seen) >= self._max:
                self._seen = {k: e for k, e in self._seen.items() if now - e[0] < self.interval}
            self._seen[key] = [now, 0]
        if entry is not None and entry[1]:
            record.msg = f"{text} ({entry[1]} more like it in the last {now - entry[0]:.0f} s)"
            record.args = None
        return True


def install(interval: float = 10.0) -> RepeatFilter:
    """Put one :class:`RepeatFilter` on every handler of the root logger; returns it."""
    flt = RepeatFilter(interval)
    for handler in logging.getLogger().handlers:
        handler.addFilter(flt)
    return flt
