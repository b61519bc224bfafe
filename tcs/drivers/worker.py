"""A background thread for the few SDO transfers a running drive needs (mode switch, speed).

SDO is request/response and blocks for a round trip; the per-cycle ``step()`` must not. A
drive hands such work to the bus's one :class:`SdoWorker` as a :class:`Job` and looks at
``job.done`` in later cycles. Jobs run one at a time, in order, so two SDO transfers never
overlap on the bus (they are rare: a mode switch, a new profile velocity — SDO stays out of
the steady cyclic phase).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)


class Job:
    """One unit of blocking work; ``done``, then ``result`` or ``error`` (any exception)."""

    __slots__ = ("fn", "done", "result", "error", "name")

    def __init__(self, fn: Callable[[], Any], name: str = ""):
        self.fn = fn
        self.name = name
        self.done = False
        self.result: Any = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.result = self.fn()
        except Exception as exc:  # delivered to the requester, which reports it
            self.error = exc
        finally:
            self.done = True


class SdoWorker:
    """One thread running :class:`Job`\\ s in order; ``start()``/``stop()`` around its use."""

    def __init__(self, name: str = "tcs-sdo"):
        self._name = name
        self._queue: queue.Queue[Job | None] = queue.Queue()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Finish the job in progress, drop the rest (they end with an error), join."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        self._queue.put(None)
        thread.join(timeout=10.0)
        while True:
            try:
                job = self._queue.get_nowait()
            except queue.Empty:
                break
            if job is not None:
                job.error, job.done = RuntimeError("SDO worker stopped"), True

    def submit(self, fn: Callable[[], Any], name: str = "") -> Job:
        """Queue ``fn`` (non-blocking); poll the returned job's ``done``."""
        job = Job(fn, name)
        if self._thread is None:
            job.error, job.done = RuntimeError("SDO worker is not running"), True
        else:
            self._queue.put(job)
        return job

    def _run(self) -> None:
        while True:
            job = self._queue.get()
            if job is None:
                return
            job.run()
