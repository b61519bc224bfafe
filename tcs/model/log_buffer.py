"""CABINET.STATUS.LOG[]: the most recent log lines of the service, readable over OpenTCI.

:class:`LogBuffer` is a :class:`logging.Handler` keeping the last ``size`` records of the
``tcs`` logger (level INFO and above by default; a record the logger itself filters out —
``tcs-server --log-level WARNING`` — never reaches it) in a ring. It is installed on the logger
by :meth:`install` and taken off by :meth:`remove` (the cabinet does both in its start/close).

Layout served (one element per line, the array has exactly ``size`` elements, **newest
first**; elements beyond the lines logged so far read empty strings and 0):

``LOG[i].TEXT``   the whole line: ``2024-05-01T22:13:05.123Z WARNING tcs.axes.axis: text``
``LOG[i].TIME``   UTC seconds since 1970 of the record
``LOG[i].LEVEL``  ``INFO``, ``WARNING``, ``ERROR``, ``CRITICAL`` (or ``DEBUG``)
``LOG[i].SOURCE`` the logger's name

Multi-line messages and tracebacks are folded into one line (``|`` between lines; only the
exception's last line is kept). Any thread may log; reads take the handler's lock briefly.
"""

from __future__ import annotations

import collections
import logging
import time
from dataclasses import dataclass


@dataclass(frozen=True)
class LogRecordLine:
    time: float
    level: str
    source: str
    message: str

    @property
    def text(self) -> str:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(self.time))
        return f"{stamp}.{int(self.time % 1 * 1000):03d}Z {self.level} {self.source}: {self.message}"


class LogLine:
    """The view of one ``LOG[i]`` element: the i-th newest line (or nothing)."""

    def __init__(self, buffer: "LogBuffer", index: int):
        self._buffer = buffer
        self.index = index

    def _line(self) -> LogRecordLine | None:
        return self._buffer.line(self.index)

    @property
    def text(self) -> str:
        line = self._line()
        return line.text if line else ""

    @property
    def time(self) -> float:
        line = self._line()
        return line.time if line else 0.0

    @property
    def level(self) -> str:
        line = self._line()
        return line.level if line else ""

    @property
    def source(self) -> str:
        line = self._line()
        return line.source if line else ""


class LogBuffer(logging.Handler):
    """Ring buffer of the last ``size`` log records."""

    def __init__(self, size: int = 20, level: int = logging.INFO):
        super().__init__(level)
        self.size = int(size)
        self._lines: collections.deque[LogRecordLine] = collections.deque(maxlen=self.size)
        #: One view per ``LOG[i]`` element, index 0 = newest.
        self.entries = [LogLine(self, i) for i in range(self.size)]
        self._logger: logging.Logger | None = None

    def install(self, logger: str = "tcs") -> None:
        """Start capturing the records of ``logger`` (and its children)."""
        if self._logger is None:
            self._logger = logging.getLogger(logger)
            self._logger.addHandler(self)

    def remove(self) -> None:
        """Stop capturing; the lines kept so far stay readable."""
        if self._logger is not None:
            self._logger.removeHandler(self)
            self._logger = None

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
            if record.exc_info and record.exc_info[1] is not None:
                exc = record.exc_info[1]
                message = f"{message}: {type(exc).__name__}: {exc}"
            message = " | ".join(part.strip() for part in message.splitlines() if part.strip())
            self._lines.appendleft(LogRecordLine(record.created, record.levelname, record.name, message))
        except Exception:  # a log handler must never raise into the code that logs
            self.handleError(record)

    def line(self, index: int) -> LogRecordLine | None:
        """The ``index``-th newest line, or None."""
        with self.lock:  # type: ignore[union-attr]
            return self._lines[index] if 0 <= index < len(self._lines) else None

    def lines(self) -> list[LogRecordLine]:
        """All lines kept, newest first."""
        with self.lock:  # type: ignore[union-attr]
            return list(self._lines)


__all__ = ["LogBuffer", "LogLine", "LogRecordLine"]
