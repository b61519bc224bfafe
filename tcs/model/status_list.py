"""CABINET.STATUS.LIST: the operator's persistent record of unusual conditions (spec §6.2).

Every :class:`~tcs.model.health.ModuleHealth` reports its conditions to one
:class:`StatusList` (it is the modules' ``status_sink``: ``sink(device, name, bits, active,
text)``). Each (device, condition, comment) is one entry — a condition that comes back
with another cause (text) gets an entry of its own, the older cause stays — that keeps

* ``last`` — wall-clock time (UTC seconds) of the latest occurrence; the served ``Age`` is
  *now − last* in whole seconds, so ages stay right across restarts;
* ``bits`` — the ``ERROR_STATE`` bit field of the condition (0 PANIC … 4 DEBUG);
* ``total`` — occurrences since the entry was created (the last ``CLEAR``), persisted: the
  "since starting the telescope" of the spec read as "since the record began";
* ``count`` — occurrences since the last acknowledge (``ERROR_STATE=0``, see :meth:`acknowledged`);
* ``active`` — whether the condition is still present; ``comment`` — its cause (the text).

Causes are compared by kind (:func:`cause_kind`): texts that differ only in a number
(``within 1 s (reading 35 input at 0)``, ``no valid sentence for 6.6 s``) are one entry whose
comment is the newest text; so are entries saved by older versions, merged when loaded.

A report that the condition went away ends every active entry of that (device, condition).

An occurrence is a report with ``active=True`` (ModuleHealth reports a condition only when it
becomes active, so a condition that stays active is counted once). Entries stay when the
condition goes away; only ``CLEAR=-1`` (:meth:`clear`) deletes them. At most ``max_entries``
are kept: past that the oldest inactive entry (else the oldest) is dropped.

Served text (:meth:`text`), newest occurrence first, entries separated by ``,``::

    Age:Error:Status:TotalCount:Count:Active:Device[:comment]

``Error`` is the condition's symbolic name, ``Device`` the OpenTCI module name. Commas and
colons inside names and comments are replaced by ``;`` so a client can split the text safely.

Persistence: the entries live in the :class:`~tcs.model.state_store.StateStore` under
``cabinet_status``. After a restart they come back inactive (the conditions belonged to the
previous run; a module that still has the problem reports it again, which counts as a new
occurrence). Reports may come from any thread (the control loop raises conditions): the
entry is updated under a lock at once; the file is written at once on the event loop's thread
(or when no loop is bound), otherwise the write is handed to the loop so the control loop
never waits for a disk.
"""

from __future__ import annotations

import asyncio
import logging
import re
import threading
import time
from dataclasses import asdict, dataclass
from typing import Callable

from tcs.errors import RangeRefused
from tcs.model.state_store import StateStore

log = logging.getLogger(__name__)

STORE_KEY = "cabinet_status"
_UNSAFE = re.compile(r"[,:\r\n]+")
_NUMBER = re.compile(r"(0[xX][0-9a-fA-F]+)|[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def cause_kind(text: str) -> str:
    """A cause with its numbers left out (``no valid sentence for 6.6 s`` → ``no valid sentence
    for # s``); hexadecimal codes (``0x8130``) are kept: they name different causes."""
    return _NUMBER.sub(lambda m: m.group(1) or "#", str(text))


def _clean(text: str) -> str:
    return _UNSAFE.sub(";", str(text)).strip()


@dataclass
class StatusEntry:
    device: str
    error: str
    bits: int
    last: float
    total: int = 0
    count: int = 0
    active: bool = False
    comment: str = ""

    def line(self, now: float) -> str:
        age = max(0, int(now - self.last))
        text = (f"{age}:{_clean(self.error) or 'unknown'}:{self.bits}:{self.total}:{self.count}:"
                f"{int(self.active)}:{_clean(self.device)}")
        comment = _clean(self.comment)
        return f"{text}:{comment}" if comment else text


class StatusList:
    """The persistent list of conditions; call it as ``sink(device, name, bits, active, text)``.

    Parameters
    ----------
    store:
        Where the entries are kept across restarts.
    clock:
        Wall clock (UTC seconds since 1970), injectable for tests.
    max_entries:
        Most entries kept.
    """

    def __init__(self, store: StateStore, clock: Callable[[], float] = time.time,
                 max_entries: int = 200):
        self._store = store
        self._clock = clock
        self.max_entries = max_entries
        self._lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._entries: dict[tuple[str, str], StatusEntry] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        self._flush_pending = False
        self._dirty = False
        for raw in store.get(STORE_KEY, []) or []:
            try:
                entry = StatusEntry(**raw)
                entry.active = False
                self._load(entry)
            except (TypeError, ValueError) as exc:
                log.error("ignoring a saved status entry %r: %s", raw, exc)

    def _load(self, entry: StatusEntry) -> None:
        """A saved entry; one of the same cause kind already loaded absorbs it."""
        key = (entry.device, entry.error, cause_kind(entry.comment))
        old = self._entries.get(key)
        if old is None:
            self._entries[key] = entry
            return
        newer = entry if entry.last >= old.last else old
        self._entries[key] = StatusEntry(entry.device, entry.error, newer.bits, newer.last,
                                         old.total + entry.total, old.count + entry.count,
                                         False, newer.comment)

    # -- threads -------------------------------------------------------------------------------
    def bind_loop(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        """Write the file on ``loop`` (the running loop by default); reports from other
        threads are handed to it."""
        self._loop = loop or asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()

    def unbind_loop(self) -> None:
        """Back to writing at once (service shutdown); writes what is pending."""
        self._loop = None
        self._loop_thread = None
        self.flush()

    # -- reports (the status sink) --------------------------------------------------------------
    def __call__(self, device: str, name: str, bits: int, active: bool, text: str = "") -> None:
        self.record(device, name, bits, active, text)

    def record(self, device: str, name: str, bits: int, active: bool, text: str = "") -> None:
        """A condition became active (an occurrence) or went away (the entry stays)."""
        device, name = str(device), str(name)
        with self._lock:
            if not active:
                ended = [e for (d, n, _), e in self._entries.items() if d == device and n == name and e.active]
                if not ended:
                    return
                for entry in ended:
                    entry.active = False
            else:
                key = (device, name, cause_kind(text))
                entry = self._entries.get(key)
                if entry is None:
                    entry = StatusEntry(device, name, int(bits), self._clock(), comment=str(text))
                    self._entries[key] = entry
                    self._trim()
                entry.comment = str(text)  # the newest cause of this kind
                entry.bits = int(bits)
                entry.last = self._clock()
                entry.total += 1
                entry.count += 1
                entry.active = True
            self._dirty = True
        self._persist()

    def acknowledged(self, device: str | None = None) -> None:
        """``ERROR_STATE=0`` of ``device`` (None: every device): reset its ``Count``."""
        with self._lock:
            changed = False
            for entry in self._entries.values():
                if (device is None or entry.device == device) and entry.count:
                    entry.count = 0
                    changed = True
            self._dirty |= changed
        if changed:
            self._persist()

    def clear(self, value: int = -1) -> None:
        """``CABINET.STATUS.CLEAR=-1``: delete every entry."""
        if value != -1:
            raise RangeRefused("only -1 (delete all entries) may be written to CABINET.STATUS.CLEAR")
        with self._lock:
            self._entries.clear()
            self._dirty = True
        self._persist()

    # -- reading -------------------------------------------------------------------------------
    def entries(self) -> list[StatusEntry]:
        """Copies of the entries, newest occurrence first."""
        with self._lock:
            items = [StatusEntry(**asdict(e)) for e in self._entries.values()]
        return sorted(items, key=lambda e: e.last, reverse=True)

    def text(self) -> str:
        """The served ``LIST`` value."""
        now = self._clock()
        return ",".join(e.line(now) for e in self.entries())

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    # -- persistence -----------------------------------------------------------------------------
    def _trim(self) -> None:  # under the lock
        while len(self._entries) > self.max_entries:
            victims = [k for k, e in self._entries.items() if not e.active] or list(self._entries)
            del self._entries[min(victims, key=lambda k: self._entries[k].last)]

    def _persist(self) -> None:
        loop = self._loop
        if loop is None or threading.get_ident() == self._loop_thread:
            self.flush()
            return
        with self._lock:
            if self._flush_pending:
                return
            self._flush_pending = True
        try:
            loop.call_soon_threadsafe(self.flush)
        except RuntimeError:  # loop closed: write here rather than lose the entry
            self.flush()

    def flush(self) -> None:
        """Write the entries if they changed since the last write."""
        with self._write_lock:  # snapshot and write in one piece: never an older over a newer
            with self._lock:
                self._flush_pending = False
                if not self._dirty:
                    return
                self._dirty = False
                data = [asdict(e) for e in self._entries.values()]
            try:
                self._store.update(**{STORE_KEY: data})
            except OSError as exc:
                log.error("cannot save CABINET.STATUS.LIST: %s", exc)
                with self._lock:
                    self._dirty = True


__all__ = ["StatusList", "StatusEntry", "cause_kind"]
