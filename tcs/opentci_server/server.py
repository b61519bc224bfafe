"""The asyncio TPL2 server: listening socket, sessions, logins, events, shutdown.

A thin adapter over the pure protocol core (``protocol.py``) and the tree (``tree.py``): each
accepted connection is a :class:`~tcs.opentci_server.session.Session`. The server owns what
sessions share — the tree, the user table, the connection numbering and limit, the event
fan-out from the telescope's :class:`~tcs.model.events.EventHub`, and every task a command
started (so :meth:`stop` can end them with ``COMMAND FAILED``). It is also the domain object
of the ``SERVER`` module (``UPTIME``, ``STARTTIME``, ``VERSION``, ``INFO.*``).
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import hmac
import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import tcs
from tcs.config.passwords import verify_password
from tcs.config.sections import ServerSection, UserSection
from tcs.model.events import Event, EventHub
from tcs.opentci_server.session import Session

log = logging.getLogger(__name__)


class Tpl2Server:
    """TPL2 server for one tree.

    Parameters
    ----------
    settings:
        The ``[server]`` section (limits, line ending, implicit authentication).
    users:
        The ``[[users]]`` of the hardware file.
    events:
        The telescope's event hub; every event goes to every logged-in connection.
    cabinet:
        Text for ``SERVER.INFO.MANUFACTURER``.
    event_source:
        Optional ``f(module) -> name`` for the event lines (the OpenTSI server names its own
        modules); the same users and settings may serve several trees on several ports.
    """

    vendor = "tcs project"
    device = "OpenTCI telescope control system"

    def __init__(self, settings: ServerSection, users: tuple[UserSection, ...], events: EventHub,
                 manufacturer: str = "", event_source=None):
        #: Optional ``f(module name) -> name`` for the event lines of another tree (OpenTSI).
        self.event_source = event_source
        self.settings = settings
        self.users = {u.name: u for u in users}
        self.events = events
        self.manufacturer = manufacturer
        self.version = f"tcs {tcs.__version__}"
        self.tree: Any = None
        self.starttime = time.time()
        self._start_mono = time.monotonic()
        self.sessions: dict[int, Session] = {}
        self._next_conn = 1
        self._server: asyncio.base_events.Server | None = None
        self._tasks: set[asyncio.Task] = set()
        self._pepper = os.urandom(16)
        self._verified: dict[str, bytes] = {}
        self._hasher: ThreadPoolExecutor | None = None  # password hashing, off the loop
        self._unsubscribe = events.subscribe(self._on_event)

    # -- SERVER module ------------------------------------------------------------------------
    @property
    def uptime(self) -> float:
        return time.monotonic() - self._start_mono

    # -- lifecycle ---------------------------------------------------------------------------
    async def start(self, host: str | None = None, port: int | None = None) -> int:
        """Listen; returns the port actually bound (useful with port 0)."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            self._new_session, host or self.settings.host,
            self.settings.port if port is None else port, reuse_address=True)
        bound = self._server.sockets[0].getsockname()[1]
        log.info("TPL2 server listening on %s:%d", host or self.settings.host, bound)
        return bound

    @property
    def port(self) -> int:
        return self._server.sockets[0].getsockname()[1] if self._server else 0

    async def stop(self) -> None:
        """Stop listening, end running commands with COMMAND FAILED, close every connection."""
        if self._server is not None:
            self._server.close()
        for session in list(self.sessions.values()):
            session.fail_all()
        if self._tasks:
            await asyncio.wait(list(self._tasks), timeout=5.0)
        for session in list(self.sessions.values()):
            session.close()
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None
        self._unsubscribe()
        if self._hasher is not None:
            self._hasher.shutdown(wait=True)
            self._hasher = None
        await asyncio.sleep(0)  # let transports deliver connection_lost

    def _new_session(self) -> Session:
        conn_id = self._next_conn
        self._next_conn += 1
        return Session(self, conn_id)

    def admit(self, session: Session) -> bool:
        if len(self.sessions) >= self.settings.max_connections:
            log.warning("refusing connection %d from %s: %d connections open",
                        session.id, session.address, len(self.sessions))
            return False
        self.sessions[session.id] = session
        return True

    def forget(self, session: Session) -> None:
        self.sessions.pop(session.id, None)

    def spawn(self, coro) -> asyncio.Task:
        """Run a command's coroutine as a task the server keeps track of."""
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    # -- logins --------------------------------------------------------------------------------
    async def authenticate(self, name: str, password: str) -> UserSection | None:
        """The user when ``password`` is right, else None (hash checked off the loop)."""
        user = self.users.get(name)
        if user is None:
            return None
        key = hmac.new(self._pepper, password.encode("utf-8", "surrogateescape"), hashlib.sha256).digest()
        known = self._verified.get(name)
        if known is not None and hmac.compare_digest(known, key):
            return user
        if self._hasher is None:
            self._hasher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tcs-auth")
        ok = await asyncio.get_running_loop().run_in_executor(self._hasher, verify_password, password,
                                                              user.password)
        if ok:
            self._verified[name] = key
            return user
        return None

    # -- events --------------------------------------------------------------------------------
    def _on_event(self, event: Event) -> None:
        if self.event_source is not None:
            event = dataclasses.replace(event, source=self.event_source(event.source))
        for session in list(self.sessions.values()):
            session.deliver_event(event)
