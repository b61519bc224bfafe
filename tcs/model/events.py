"""Events of the telescope model and who caused them.

Domain code (axes, cabinet, LOCAL, …) announces state changes and errors with
``events.emit(level, source, number, text)``; it never knows about connections. The TPL2
server subscribes and turns each event into ``<id> EVENT <LEVEL> <source>:<number> <text>``
lines for every authenticated connection whose event mask lets it through.

Which command caused an event is carried implicitly: the server runs each command with the
context variable :data:`current_cause` set to ``(connection id, command id, serial)``; tasks
started from it inherit the value, so an event emitted while a long SET runs names that SET.
The serial tells the command from a later one that reuses its id: the server sends an event
with the command's id only while that very command executes, and id 0 once its final line
was sent (TPL2 §5). Events from the control-loop thread or timers without a stored cause
have none (id 0). Domain code treats a cause as opaque: it stores and passes it on.

``emit`` may be called from any thread: events from other threads are handed to the event
loop with ``call_soon_threadsafe`` so subscribers always run on the loop.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
import threading
from dataclasses import dataclass
from typing import Callable

from tcs.errors import event_text

log = logging.getLogger(__name__)

ERROR, WARN, INFO, DEBUG = "ERROR", "WARN", "INFO", "DEBUG"
LEVEL_BITS = {ERROR: 1, WARN: 2, INFO: 4, DEBUG: 8}
ERRORCHANGE = 15  # tcs.errors.ErrorNumber.ERRORCHANGE

#: (connection id, command id, serial) of the command being executed, or None.
current_cause: contextvars.ContextVar[tuple[int, ...] | None] = contextvars.ContextVar(
    "current_cause", default=None)


@dataclass(frozen=True, slots=True)
class Event:
    level: str
    source: str
    number: int
    text: str
    cause: tuple[int, ...] | None


class EventHub:
    """Fan-out of :class:`Event` to subscribers on one asyncio loop."""

    def __init__(self) -> None:
        self._subscribers: list[Callable[[Event], None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None

    def bind_loop(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        """Deliver events on ``loop`` (the running loop by default)."""
        self._loop = loop or asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()

    def subscribe(self, callback: Callable[[Event], None]) -> Callable[[], None]:
        """Call ``callback(event)`` for every event; returns the unsubscribe function."""
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback) if callback in self._subscribers else None

    def emit(self, level: str, source: str, number: int, text: str = "",
             cause: tuple[int, ...] | None = None, *, quiet: bool = False) -> None:
        """Announce an event; ``cause`` defaults to the command being executed.

        ERROR and WARN events are logged as warnings, except ERRORCHANGE (15: it follows an
        event or a log line of its cause) and ``quiet`` ones (their cause was logged once
        already, e.g. a lost PLC by its driver, however many modules it serves).
        """
        event = Event(level, source, int(number), event_text(number, text),
                      cause if cause is not None else current_cause.get())
        loud = level in (ERROR, WARN) and not quiet and event.number != ERRORCHANGE
        log.log(logging.WARNING if loud else logging.INFO,
                "event %s %s:%d %s", level, source, event.number, event.text)
        loop = self._loop
        if loop is not None and threading.get_ident() != self._loop_thread:
            try:
                loop.call_soon_threadsafe(self._deliver, event)
            except RuntimeError:  # loop closed during shutdown
                pass
        else:
            self._deliver(event)

    def _deliver(self, event: Event) -> None:
        for callback in list(self._subscribers):
            try:
                callback(event)
            except Exception:  # a broken subscriber must not silence the others
                log.exception("event subscriber failed")
