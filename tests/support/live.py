"""A service shared by the tests of one module: the real TCS on its own event-loop thread.

``LiveService(path, state_dir).start()`` runs :func:`support.service.start_service` on a new
thread with its own loop; tests talk to it over TPL2 on ``port`` and reach the simulated
hardware in it with :meth:`LiveService.call` (a function or coroutine run on the service's
loop, awaited from the test's loop) — the simulators are not thread-safe, so fault injection
must happen on their loop. :meth:`stop` ends the service and checks that no thread is left.

:func:`live_service` makes the module-scoped ``live`` fixture of a test file out of a hardware
file: one service for all the tests of the module (they must not depend on each other's state).
Such a module also overrides the autouse ``_no_leaked_threads`` check with a no-op: the
service's threads are expected while it runs, and :meth:`LiveService.stop` checks them at the end.
"""

from __future__ import annotations

import asyncio
import inspect
import threading
import time
from pathlib import Path
from typing import Callable

import pytest

from support.service import start_service


class LiveService:
    def __init__(self, path: Path, state_dir: Path, envelope: dict | None = None):
        self.path = path
        self.state_dir = state_dir
        self.envelope = envelope   # [envelope] keys (default: the Sun cone off, see make_config)
        self.loop = asyncio.new_event_loop()
        self.service = None
        self.port = 0
        self._thread: threading.Thread | None = None
        self._stop: asyncio.Event | None = None
        self._before: set[int] = set()

    @property
    def telescope(self):
        return self.service.telescope

    def start(self, timeout: float = 60.0) -> "LiveService":
        self._before = {t.ident for t in threading.enumerate()}
        ready = threading.Event()
        box: dict = {}

        def run():
            asyncio.set_event_loop(self.loop)

            async def main():
                try:
                    self.service, self.port = await start_service(self.state_dir, self.path,
                                                                     envelope=self.envelope)
                except BaseException as exc:  # handed to the starting thread
                    box["error"] = exc
                    ready.set()
                    return
                self._stop = asyncio.Event()
                ready.set()
                await self._stop.wait()
                await self.service.stop()

            self.loop.run_until_complete(main())
            self.loop.close()

        self._thread = threading.Thread(target=run, name=f"live-{self.path.stem}")
        self._thread.start()
        assert ready.wait(timeout), "service did not start"
        if "error" in box:
            self._thread.join(10)
            raise box["error"]
        return self

    async def call(self, fn, *args):
        """Run ``fn(*args)`` (plain or async) on the service's loop; return its result."""
        async def wrapper():
            result = fn(*args)
            return await result if inspect.isawaitable(result) else result

        return await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(wrapper(), self.loop))

    def stop(self, timeout: float = 60.0) -> None:
        self.loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout)
        assert not self._thread.is_alive(), "service thread did not end"
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and self._left():
            time.sleep(0.02)
        assert not self._left(), f"the service left threads behind: {self._left()}"

    def _left(self) -> list[str]:
        return [t.name for t in threading.enumerate() if t.ident not in self._before]


def live_service(hwfile: Path | Callable[[Path], Path]):
    """A module-scoped pytest fixture yielding a started :class:`LiveService`.

    Parameters
    ----------
    hwfile:
        The hardware file, or a function of a fresh directory that writes one there and
        returns its path. The service's state lives in that directory too.

    Usage: ``live = live_service(HW)`` at module level.
    """
    @pytest.fixture(scope="module")
    def live(tmp_path_factory):
        base = tmp_path_factory.mktemp("live")
        path = hwfile(base) if callable(hwfile) else hwfile
        service = LiveService(path, base / "state").start()
        try:
            yield service
        finally:
            service.stop()

    return live
