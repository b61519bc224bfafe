"""A one-line text progress report on stderr for long commissioning steps (homing, limit search).

:class:`ProgressBar` has two modes, chosen by its stream:

* on a terminal it redraws one line (``\\r``) at most ten times a second with one segment per
  drive, ``az [########------------]  40% 12.345``, and keeps that line within the terminal's
  width: the bars shrink, then go, then the texts, then the line is cut;
* anywhere else (a log, a pipe, ``journalctl``) it writes a plain line with the elapsed time
  every ``plain_every`` seconds, ``[ 30 s] az  40% 12.345 | zd 100% 0.000``, so a seven-minute
  limit search is never silent; nothing before the first period has passed.

``enabled=False`` draws nothing at all. :meth:`close` ends the line (and writes the final
state in plain mode if anything was written). Called from the main thread only.
"""

from __future__ import annotations

import shutil
import sys
import time
from typing import TextIO


class ProgressBar:
    """Progress of one or more named tasks on one line.

    Parameters
    ----------
    stream : where to draw (default stderr).
    enabled : True: draw as on a terminal; False: nothing; None (default): terminal mode when
        ``stream`` is a terminal, plain periodic lines otherwise.
    width : characters of each bar (at most).
    plain_every : seconds between two plain lines.
    columns : the terminal's width (default: asked when drawing).
    """

    def __init__(self, stream: TextIO | None = None, enabled: bool | None = None, width: int = 20,
                 plain_every: float = 10.0, columns: int | None = None):
        self.stream = stream if stream is not None else sys.stderr
        isatty = getattr(self.stream, "isatty", None)
        tty = bool(isatty and isatty())
        self.plain = enabled is None and not tty
        self.enabled = enabled is not False
        self.width = width
        self.plain_every = plain_every
        self.columns = columns
        self._items: dict[str, tuple[float, str]] = {}
        self._last_draw = 0.0
        self._drawn = 0
        self._start = time.monotonic()
        self._last_plain = self._start
        self._plain_lines = 0

    def update(self, name: str, fraction: float, text: str = "", *, force: bool = False) -> None:
        """Set ``name`` to ``fraction`` (0..1) with a short ``text`` and redraw (rate-limited)."""
        self._items[name] = (min(max(fraction, 0.0), 1.0), text)
        if not self.enabled:
            return
        now = time.monotonic()
        if self.plain:
            if now - self._last_plain >= self.plain_every:
                self._last_plain = now
                self._write_plain(now)
        elif force or now - self._last_draw >= 0.1:
            self._last_draw = now
            self._draw()

    def line(self, width: int | None = None, texts: bool = True) -> str:
        """The text of the bar as it would be drawn now (``width=0``: no bars)."""
        width = self.width if width is None else width
        parts = []
        for name, (fraction, text) in self._items.items():
            text = text if texts else ""
            if width > 0:
                filled = round(fraction * width)
                bar = "#" * filled + "-" * (width - filled)
                parts.append(f"{name} [{bar}] {fraction * 100:3.0f}% {text}".rstrip())
            else:
                parts.append(f"{name} {fraction * 100:3.0f}% {text}".rstrip())
        return " | ".join(parts)

    def fitted(self, columns: int) -> str:
        """The fullest line that fits in ``columns - 1`` characters."""
        room = max(10, columns - 1)
        for width in sorted({self.width, min(self.width, 10), min(self.width, 5)}, reverse=True):
            text = self.line(width)
            if len(text) <= room:
                return text
        for texts in (True, False):
            text = self.line(0, texts)
            if len(text) <= room:
                return text
        return text[:room - 1] + "…"

    def _draw(self) -> None:
        columns = self.columns or shutil.get_terminal_size((80, 24)).columns
        text = self.fitted(columns)
        pad = max(0, self._drawn - len(text))
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()
        self._drawn = len(text)

    def _write_plain(self, now: float) -> None:
        self.stream.write(f"[{now - self._start:3.0f} s] {self.line(0)}\n")
        self.stream.flush()
        self._plain_lines += 1

    def close(self) -> None:
        """Draw the final state and end the line (nothing if never drawn)."""
        if self.enabled and self._items:
            if self.plain:
                if self._plain_lines:
                    self._write_plain(time.monotonic())
            else:
                self._draw()
                self.stream.write("\n")
                self.stream.flush()
        self._items.clear()
        self._drawn = 0
