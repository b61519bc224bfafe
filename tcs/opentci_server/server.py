"""The asyncio TPL2 server: listening socket, sessions, logins, events, shutdown.

A thin adapter over the pure protocol core (``protocol.py``) and the tree (``tree.py``): each
accepted connection is a :class:`~tcs.opentci_server.session.Session`. The server owns what
sessions share — the tree, the user table, the connection numbering and limit, the event
fan-out from the telescope's :class:`~tcs.model.events.EventHub`, and every task a command
started (so :meth:`stop` can end them with ``COMMAND FAILED``). It is also the domain object
of the ``SERVER`` module (``UPTIME``, ``STARTTIME``, ``VERSION``, ``INFO.*``).

Exposure limits live with each server instance (a second listener serving another tree gets
the same protections from its own ``[server]`` settings): the
:class:`~tcs.opentci_server.guard.ConnectionGuard` (connection slots, the level-0 reserve,
per-address limits, the per-name login back-off), TLS when ``tls_cert``/``tls_key`` are set (the port itself
TLS-only, or a second TLS-only listener on ``tls_port``), and a loud warning at start when the
server is reachable beyond loopback with a well-known password, implicit logins or no TLS.
Unknown user names are checked against a dummy hash of the same cost, so the time a failed
login takes does not tell which names exist.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import hmac
import logging
import base64
import ipaddress
import os
import ssl
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import tcs
from tcs.config.passwords import DEFAULT_ITERATIONS, SCHEME, verify_password
from tcs.config.sections import ServerSection, UserSection
from tcs.errors import ConfigError
from tcs.model.command_stats import CommandStats
from tcs.model.events import Event, EventHub
from tcs.opentci_server.guard import ConnectionGuard
from tcs.opentci_server.reply_cache import ReplyCache
from tcs.opentci_server.scheduler import FairScheduler
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
    shares_interpreter:
        The control loop runs as a thread of this interpreter (``[can] control_process =
        false``): with ``work_rest = -1`` (the default) the scheduler then rests after each
        full work slice (see :func:`work_rest`).
    """

    vendor = "tcs project"
    device = "OpenTCI telescope control system"

    def __init__(self, settings: ServerSection, users: tuple[UserSection, ...], events: EventHub,
                 manufacturer: str = "", event_source=None, shares_interpreter: bool = False):
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
        #: the commands handled, by verb and result, and their latency (``/metrics``)
        self.command_stats = CommandStats()
        self._next_conn = 1
        self._server: asyncio.base_events.Server | None = None
        self._tls_server: asyncio.base_events.Server | None = None
        self.guard = ConnectionGuard(settings)
        self.scheduler = FairScheduler(settings.work_slice, work_rest(settings, shares_interpreter))
        self.replies = ReplyCache(settings.reuse_reply)  # GET replies kept while nothing changed
        self._dummy_hash = _dummy_hash(users)
        self._tasks: set[asyncio.Task] = set()
        self._pepper = os.urandom(16)
        self._verified: dict[str, bytes] = {}
        self._inflight: dict[tuple[str, bytes], asyncio.Future] = {}
        self._hasher: ThreadPoolExecutor | None = None  # password hashing, off the loop
        self._unsubscribe = events.subscribe(self._on_event)

    # -- SERVER module ------------------------------------------------------------------------
    @property
    def uptime(self) -> float:
        return time.monotonic() - self._start_mono

    # -- lifecycle ---------------------------------------------------------------------------
    async def start(self, host: str | None = None, port: int | None = None, *,
                    serve: bool = True) -> int:
        """Listen; returns the port actually bound (useful with port 0).

        ``serve=False`` only binds (the port is taken, connections wait in the backlog); a
        later ``start()`` starts accepting them. With ``tls_cert``/``tls_key`` and ``tls_port``
        0 that port speaks TLS only; with a ``tls_port`` a second, TLS-only listener is opened
        there as well (:attr:`tls_port`) once serving.
        """
        loop = asyncio.get_running_loop()
        cfg = self.settings
        host = host or cfg.host
        tls = tls_context(cfg)
        handshake = min(60.0, cfg.login_timeout)
        only_tls = tls is not None and not cfg.tls_port
        if self._server is None:
            self._server = await loop.create_server(
                self._new_session, host, cfg.port if port is None else port, reuse_address=True,
                ssl=tls if only_tls else None, ssl_handshake_timeout=handshake if only_tls else None,
                start_serving=False)
        bound = self._server.sockets[0].getsockname()[1]
        if not serve:
            return bound
        await self._server.start_serving()
        log.info("TPL2 server listening on %s:%d%s", host, bound, " (TLS only)" if only_tls else "")
        if tls is not None and cfg.tls_port and self._tls_server is None:
            self._tls_server = await loop.create_server(
                self._new_session, host, cfg.tls_port, reuse_address=True, ssl=tls,
                ssl_handshake_timeout=handshake)
            log.info("TPL2 server listening on %s:%d (TLS only)", host, self.tls_port)
        await self._warn_exposure(host, tls is not None)
        return bound

    @property
    def tls_port(self) -> int:
        """Port of the second, TLS-only listener (0 when there is none)."""
        return self._tls_server.sockets[0].getsockname()[1] if self._tls_server else 0

    async def _warn_exposure(self, host: str, tls: bool) -> None:
        if is_loopback(host):
            return
        weak = await asyncio.get_running_loop().run_in_executor(None, weak_users, tuple(self.users.values()))
        for problem in exposure_problems(self.settings, host, tls, weak):
            log.warning("!!! SECURITY: %s !!!", problem)

    @property
    def port(self) -> int:
        return self._server.sockets[0].getsockname()[1] if self._server else 0

    async def stop(self) -> None:
        """Stop listening, end running commands with COMMAND FAILED, close every connection."""
        if self._server is not None:
            self._server.close()
        if self._tls_server is not None:
            self._tls_server.close()
            self._tls_server = None
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
        self.scheduler.close()
        if self._hasher is not None:
            self._hasher.shutdown(wait=True)
            self._hasher = None
        await asyncio.sleep(0)  # let transports deliver connection_lost

    def _new_session(self) -> Session:
        conn_id = self._next_conn
        self._next_conn += 1
        return Session(self, conn_id)

    def admit(self, session: Session) -> str | None:
        """Take ``session`` in (None) or say why not (the text for its greeting)."""
        ok, reserved, reason = self.guard.admit(session.host, self.sessions.values())
        if not ok:
            log.warning("refusing connection %d from %s: %s (%d open)",
                        session.id, session.address, reason, len(self.sessions))
            return reason
        session.reserved = reserved
        self.sessions[session.id] = session
        return None

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
        if user is None:  # as long as a wrong password of a real user: names stay secret
            if self._hasher is None:
                self._hasher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tcs-auth")
            await asyncio.get_running_loop().run_in_executor(self._hasher, verify_password, password,
                                                             self._dummy_hash)
            return None
        key = hmac.new(self._pepper, password.encode("utf-8", "surrogateescape"), hashlib.sha256).digest()
        known = self._verified.get(name)
        if known is not None and hmac.compare_digest(known, key):
            return user
        if self._hasher is None:
            self._hasher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tcs-auth")
        job = self._inflight.get((name, key))  # many clients logging in at once share one check
        if job is None:
            job = asyncio.get_running_loop().run_in_executor(self._hasher, verify_password, password,
                                                             user.password)
            self._inflight[(name, key)] = job
            job.add_done_callback(lambda _f, k=(name, key): self._inflight.pop(k, None))
        ok = await asyncio.shield(job)
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


# -- exposure ------------------------------------------------------------------------------------
WELL_KNOWN_PASSWORDS = ("admin", "password", "")


def work_rest(settings: ServerSection, shares_interpreter: bool) -> float:
    """The scheduler's rest factor: ``[server] work_rest`` when set (>= 0); by default (-1) none
    when the control loop has a process of its own, and 1.0 when it shares this interpreter.

    Measured (issue 27, ``tools/bench/tpl2_load.py``, 50 clients): resting as long as it worked
    left the server idle half the time while clients waited (0.15 of an echo server's requests/s,
    p99 89 ms); without the rest 0.42, p99 8.5 ms. The rest only protects a control loop that
    needs this interpreter's lock.
    """
    if settings.work_rest >= 0:
        return settings.work_rest
    return 1.0 if shares_interpreter else 0.0


def loop_shares_interpreter(config) -> bool:
    """Whether the control loop of hardware file ``config`` runs in the service's interpreter
    (anything but ``[can] control_process = true``)."""
    can = getattr(config, "can", None)
    return not (can is not None and can.control_process)


def _dummy_hash(users) -> str:
    """A hash no password matches, as costly as the users' own (most iterations among them)."""
    counts = [int(p[1]) for p in (u.password.split("$") for u in users) if len(p) == 4 and p[1].isdigit()]
    iterations = max(counts, default=DEFAULT_ITERATIONS)
    b64 = lambda b: base64.b64encode(b).decode("ascii")  # noqa: E731
    return f"{SCHEME}${iterations}${b64(os.urandom(16))}${b64(os.urandom(32))}"


def is_loopback(host: str) -> bool:
    """True when binding ``host`` only reaches this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def weak_users(users) -> list[str]:
    """Names of users whose password is well known: their own name, or one of
    :data:`WELL_KNOWN_PASSWORDS` (the shipped ``hwconfig/sim.toml`` has admin/admin)."""
    return [u.name for u in users
            if any(verify_password(p, u.password) for p in (u.name, *WELL_KNOWN_PASSWORDS))]


def exposure_problems(settings: ServerSection, host: str, tls: bool, weak: list[str]) -> list[str]:
    """What is dangerous about serving on ``host`` (empty on loopback)."""
    if is_loopback(host):
        return []
    problems = [f"user {name!r} has a well-known password (the shipped development login?) and the "
                f"server listens on {host}: make a new hash with tcs-passwd" for name in weak]
    if settings.implicit_auth:
        problems.append(f"implicit_auth logs every connection to {host} in as {settings.implicit_user!r} "
                        "without a password")
    if not tls:
        problems.append(f"passwords and commands travel in clear text on {host}: set tls_cert/tls_key "
                        "or bind 127.0.0.1 and let remote clients come through an SSH tunnel")
    return problems


def tls_context(settings: ServerSection) -> ssl.SSLContext | None:
    """The server-side TLS context of ``tls_cert``/``tls_key`` (None without them)."""
    if not settings.tls_cert:
        return None
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_cert_chain(settings.tls_cert, settings.tls_key)
    except (OSError, ssl.SSLError) as exc:
        raise ConfigError(settings.tls_cert, "server.tls_cert", f"cannot load certificate/key: {exc}") from exc
    return ctx
