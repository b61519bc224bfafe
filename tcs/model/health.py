"""What every OpenTCI module has in common: ``VERSION``, ``TYPE`` and ``ERROR_STATE``.

:class:`ModuleHealth` is the base of every domain object bound to an OpenTCI module. It keeps
the module's error conditions as a set of named, active-or-latched entries; ``error_state`` is
the OR of their bits (0 PANIC, 1 ERROR, 2 WARNING, 3 INFO, 4 DEBUG). A condition raised by the
hardware stays latched until a client writes 0 to ``ERROR_STATE`` (acknowledge) *and* the
condition is gone; writing 0 while it is still active keeps it. Every change emits
ERRORCHANGE (15) and is reported to the optional ``status_sink`` (CABINET.STATUS.LIST).
"""

from __future__ import annotations

import threading
from typing import Callable

from tcs.errors import ErrorNumber, RangeRefused

#: Packed interface version: (24 << 16) | (age << 8) | revision (opentci-notes "Common variables").
INTERFACE_VERSION, INTERFACE_AGE, REVISION = 24, 0, 1
VERSION = (INTERFACE_VERSION << 16) | (INTERFACE_AGE << 8) | REVISION

PANIC, ERROR, WARNING, INFO, DEBUG = 1, 2, 4, 8, 16


class ModuleHealth:
    """Error conditions of one module. Thread-safe: the control loop may raise conditions."""

    module_name: str = ""
    hw_type: int = 1
    version: int = VERSION

    def __init__(self, module_name: str, events=None, hw_type: int = 1,
                 status_sink: Callable[[str, str, int, bool, str], None] | None = None):
        self.module_name = module_name
        self.hw_type = hw_type
        self._events = events
        self._status_sink = status_sink
        self._conditions: dict[str, list] = {}  # name -> [bits, active, latched]
        self._health_lock = threading.Lock()
        self._error_state = 0  # OR of the conditions' bits, kept current under the lock
        #: Called after ``_error_state`` changed (the cabinet keeps its aggregate with it).
        self.on_error_state: Callable[[], None] | None = None

    @property
    def error_state(self) -> int:
        # Read on every GET of an ERROR_STATE (and CABINET's reads all of them): a plain
        # attribute, recomputed only when a condition changes.
        return self._error_state

    def _recompute(self) -> None:
        """Refresh ``_error_state``; the caller holds ``_health_lock``."""
        state = 0
        for bits, active, latched in self._conditions.values():
            if active or latched:
                state |= bits
        changed, self._error_state = state != self._error_state, state
        if changed and self.on_error_state is not None:
            self.on_error_state()

    def raise_condition(self, name: str, bits: int = ERROR, text: str = "") -> None:
        """Mark condition ``name`` active (and latched until acknowledged)."""
        before = self.error_state
        with self._health_lock:
            entry = self._conditions.get(name)
            fresh = entry is None or not entry[1]
            self._conditions[name] = [bits, True, True]
            self._recompute()
        if fresh and self._status_sink is not None:
            self._status_sink(self.module_name, name, bits, True, text)
        self._changed(before, text or name)

    def clear_condition(self, name: str) -> None:
        """The cause of ``name`` went away; it stays visible until acknowledged."""
        before = self.error_state
        with self._health_lock:
            entry = self._conditions.get(name)
            if entry is None or not entry[1]:
                return
            entry[1] = False
            self._recompute()
        if self._status_sink is not None:
            self._status_sink(self.module_name, name, entry[0], False, "")
        self._changed(before, f"{name} cleared")

    def acknowledge_errors(self, value: int) -> None:
        """``SET <module>.ERROR_STATE=0``: forget latched conditions whose cause is gone."""
        if value != 0:
            raise RangeRefused("only 0 (acknowledge) may be written to ERROR_STATE")
        before = self.error_state
        with self._health_lock:
            for name in [n for n, e in self._conditions.items() if not e[1]]:
                del self._conditions[name]
            for entry in self._conditions.values():
                entry[2] = False
            self._recompute()
        self.on_acknowledge()
        acknowledged = getattr(self._status_sink, "acknowledged", None)
        if acknowledged is not None:  # STATUS.LIST: the Count column restarts
            acknowledged(self.module_name)
        self._changed(before, "acknowledged")

    def on_acknowledge(self) -> None:
        """Hook for modules that must do something on acknowledge (never re-enable hardware)."""

    def conditions(self) -> dict[str, tuple[int, bool]]:
        with self._health_lock:
            return {n: (e[0], e[1]) for n, e in self._conditions.items()}

    def standing(self) -> dict[str, int]:
        """The conditions that count in ``error_state`` now (active, or latched until an
        acknowledge): name -> bits."""
        with self._health_lock:
            return {n: e[0] for n, e in self._conditions.items() if e[1] or e[2]}

    def _changed(self, before: int, text: str) -> None:
        after = self.error_state
        if after != before and self._events is not None:
            level = "ERROR" if after & (PANIC | ERROR) > before & (PANIC | ERROR) else "INFO"
            self._events.emit(level, self.module_name, ErrorNumber.ERRORCHANGE, text)
