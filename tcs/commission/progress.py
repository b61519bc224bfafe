"""A one-line text progress bar on stderr for long commissioning steps (homing, limit search).

:class:`ProgressBar` redraws one line (``\\r``) at most ten times a second with one segment
per drive: ``az [########------------]  40% 12.345``. It draws only when its stream is a
terminal (or when forced), so scripts and ``--json`` output never see it; :meth:`close`
ends the line. Called from the main thread only.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Progress of one or more named tasks on one terminal line.

    Parameters
    ----------
    stream : where to draw (default stderr).
    enabled : draw at all; default: when ``stream`` is a terminal.
    width : characters of each bar.
    """

    def __init__(self, stream: TextIO | None = None, enabled: bool | None = None, width: int = 20):
        self.stream = stream if stream is not None else sys.stderr
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.width = width
        self._items: dict[str, tuple[float, str]] = {}
        self._last_draw = 0.0
        self._drawn = 0

    def update(self, name: str, fraction: float, text: str = "", *, force: bool = False) -> None:
        """Set ``name`` to ``fraction`` (0..1) with a short ``text`` and redraw (rate-limited)."""
        self._items[name] = (min(max(fraction, 0.0), 1.0), text)
        now = time.monotonic()
        if self.enabled and (force or now - self._last_draw >= 0.1):
            self._last_draw = now
            self._draw()

    def line(self) -> str:
        """The text of the bar as it would be drawn now."""
        parts = []
        for name, (fraction, text) in self._items.items():
            filled = round(fraction * self.width)
            bar = "#" * filled + "-" * (self.width - filled)
            parts.append(f"{name} [{bar}] {fraction * 100:3.0f}% {text}".rstrip())
        return " | ".join(parts)

    def _draw(self) -> None:
        text = self.line()
        pad = max(0, self._drawn - len(text))
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()
        self._drawn = len(text)

    def close(self) -> None:
        """Draw the final state and end the line (nothing if never drawn)."""
        if self.enabled and self._items:
            self._draw()
            self.stream.write("\n")
            self.stream.flush()
        self._items.clear()
        self._drawn = 0
