"""One TPL2 connection: the command lifecycle over a pure protocol core and the variable tree.

How it works
------------
:class:`Session` is an ``asyncio.Protocol``. Bytes go into the pure
:class:`~tcs.opentci_server.protocol.Tpl2Connection`, which yields parsed messages; each is
handled **in order**. ``GET`` is answered synchronously (reads never wait). ``SET`` applies its
assignments in order; a setter that returns an awaitable (a long-running action) turns the rest
of the command into a task, so the connection goes on reading and answering other commands.
``ABORT`` cancels such tasks. ``AUTH`` verifies the password off the event loop; lines that
arrive meanwhile wait in a queue so that ``AUTH`` + ``GET`` sent back to back (UNAM) work.

The command lifecycle (protocol doc §4), one final line per command:

=========================  =============================================================
situation                  lines
=========================  =============================================================
not logged in              ``<id> COMMAND ERROR UNAUTHENTICATED``, ``<id> COMMAND FAILED``
id still running           ``0 COMMAND ERROR IDBUSY <id>``, ``0 COMMAND FAILED`` (the running command is untouched)
id out of range            ``0 COMMAND ERROR IDRANGE <id>``, ``0 COMMAND FAILED``
unparseable line           ``<id> COMMAND ERROR SYNTAX``, ``<id> COMMAND FAILED`` (id 0 when none could be read)
unknown verb               ``<id> COMMAND ERROR UNKNOWN [unknown command X]``, ``<id> COMMAND FAILED``
too many in flight         ``<id> COMMAND ERROR TOOMANY``, ``<id> COMMAND FAILED``
GET / SET                  ``COMMAND OK``, one ``DATA`` line per object, ``COMMAND COMPLETE``
aborted long SET           ``<id> COMMAND ABORTEDBY <abort id>`` (the motion it started stops)
server shutting down       ``<id> COMMAND FAILED``
=========================  =============================================================

Errors raised by the domain (:class:`~tcs.errors.TcsError`) become reply text here and only
here (``DATA ERROR <obj> FAILED n`` / keyword).

Fairness and back-pressure (``[server]`` limits, docs/security.md)
-------------------------------------------------------------------
Received bytes wait in an inbox and are parsed a little at a time (:data:`PARSE_CHUNK`) as
work of their own; parsed lines wait in one queue per connection; the server's
:class:`~tcs.opentci_server.scheduler.FairScheduler` handles them one at a time, least-served
connection first, in short slices (``work_slice``; after a full one it rests ``work_rest``
times as long when the control loop shares this interpreter), so pipelined commands of one
client take turns with every other client instead of running in one long burst. Reading from the
socket pauses while more than :data:`QUEUE_HIGH` lines or :data:`INBOX_HIGH` bytes wait.
Output: past ``max_output`` unsent bytes the transport calls ``pause_writing`` — the
connection then neither handles commands nor reads until the client has read its replies;
a client that stays paused ``output_stall_timeout`` seconds, or whose unsent output passes
``max_output_hard``, is dropped. Nothing a client does can grow the server's memory or its
share of the loop without bound.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from collections import deque
from functools import partial
from time import perf_counter
from typing import TYPE_CHECKING, Any, Protocol

from tcs.errors import TcsError
from tcs.model.events import ERROR, LEVEL_BITS, Event, current_cause
from tcs.opentci_server import messages as m
from tcs.opentci_server.guard import host_of
from tcs.opentci_server.protocol import Tpl2Connection, wire_object
from tcs.opentci_server.server_module import BLOCKED_HASH
from tcs.opentci_server.tree import allowed, module_of
from tcs.opentci_server.values import ascii_text
from tcs.state_epoch import EPOCH
from tcs.state_epoch import bump as bump_epoch

if TYPE_CHECKING:  # pragma: no cover
    from tcs.opentci_server.guard import ConnectionGuard
    from tcs.opentci_server.reply_cache import ReplyCache
    from tcs.opentci_server.scheduler import FairScheduler


class SessionHost(Protocol):
    """What a session may use of the server that made it (the TPL2 server gives itself;
    nothing else of the server is the session's business): the settings, accounts and events,
    the tree, the connection guard and fair scheduler, the other sessions (for ``ABORT`` of
    another connection's command), and the calls below."""

    settings: Any
    users: dict
    events: Any
    tree: Any
    guard: "ConnectionGuard"
    scheduler: "FairScheduler"
    replies: "ReplyCache"
    sessions: dict

    def admit(self, session: "Session") -> str | None:
        """Take ``session`` in (None) or say why not."""

    def forget(self, session: "Session") -> None:
        """The session ended."""

    def spawn(self, coro) -> asyncio.Task:
        """Run a command's coroutine as a task the server keeps track of."""

    async def authenticate(self, name: str, password: str) -> Any:
        """The user when ``password`` is right, else None."""

log = logging.getLogger(__name__)

QUEUE_HIGH, QUEUE_LOW = 512, 128  # parsed lines waiting: stop reading above, read again below
INBOX_HIGH = 64 * 1024  # received bytes not parsed yet: stop reading above
PARSE_CHUNK = 4096  # bytes parsed in one step of scheduled work
NO_ACCESS = 99
_SERIALS = itertools.count(1)  # tells a command from a later one that reuses its id


#: The verb label of a message in the command metrics (:mod:`tcs.model.command_stats`).
_VERBS = {m.Get: "GET", m.Set: "SET", m.Abort: "ABORT", m.Auth: "AUTH", m.Disconnect: "DISCONNECT"}


class _Command:
    """A running long command: its task and how it was ended from outside."""

    __slots__ = ("cmd_id", "task", "aborted_by", "cause", "moves", "started")

    def __init__(self, cmd_id: int, cause=None, started: float = 0.0):
        self.cmd_id = cmd_id
        self.started = started  # perf_counter() when it was handled (the latency metric)
        self.task: asyncio.Task | None = None
        self.aborted_by: int | None = None
        self.cause = cause  # (connection, id, serial): what the domain records as the cause
        self.moves: list = []  # (tree, target, awaitable) of its long-running writes

    def stop_moves(self) -> None:
        """ABORT: each long-running write stops what it started (the tree's abort hook)."""
        for tree, target, awaitable in self.moves:
            try:
                tree.abort(target, self.cause, awaitable)
            except Exception:
                log.exception("aborting the write of %s failed", getattr(target.node, "path", target))


#: Most plans kept per tree (distinct GET texts); past it a GET is planned each time.
PLAN_CACHE_SIZE = 4096


def _get_plan(tree, objects: tuple) -> tuple:
    """How to read each object of a GET: ``(ref, object as echoed, reader, rlevel, shared)``,
    with ``reader`` the variable's fast reader (:meth:`Tree.plain_reader`) or None for the
    general path, ``shared`` true when its answer is the same for every connection of the same
    read level (:meth:`Tree.same_for_every_connection`: a reply may then be kept). Kept per
    tree and per parsed-objects tuple (the parser hands out the same tuple for the same GET
    text); only lookups are kept, never a value."""
    plans = tree.get_plans
    entry = plans.get(id(objects))
    if entry is not None and entry[0] is objects:  # (the tuple is held here: its id stays its own)
        return entry[1]
    plan = []
    for ref in objects:
        found = tree.plain_reader(ref)
        reader, level = found if found is not None else (None, 0)
        shared = found is not None or tree.same_for_every_connection(ref)
        plan.append((ref, wire_object(ref.text), reader, level, shared))
    plan = tuple(plan)
    if len(plans) < PLAN_CACHE_SIZE:
        plans[id(objects)] = (objects, plan)
    return plan


class Session(asyncio.Protocol):
    """The server side of one TPL2 connection (also the object behind SERVER.CONNECTION.*)."""

    def __init__(self, server: SessionHost, conn_id: int):
        self.server = server
        self.id = conn_id
        cfg = server.settings
        self.proto = Tpl2Connection(line_ending=b"\r\n" if cfg.line_ending == "CRLF" else b"\n",
                                    max_line_length=cfg.max_line_length)
        self.transport: asyncio.Transport | None = None
        self.address = ""
        self.host = ""
        self.reserved = False  # admitted into the level-0 reserve (see guard.py)
        self._timer: asyncio.TimerHandle | None = None  # login, then idle time-out
        self._last_input = time.monotonic()
        self.username = ""
        self.rlevel = self.wlevel = NO_ACCESS
        self.authenticated = False
        self.eventmask = 15
        self.abort_on_disconnect = 0
        self.starttime = time.time()
        self._start_mono = time.monotonic()
        self.commands: dict[int, _Command] = {}
        self.command_times: deque = deque(maxlen=4096)  # admitted commands (SERVER.*.COMMAND_RATE)
        self._running: dict[int, int] = {}  # command id -> serial of the SET running under it
        self._announced: dict[int, set] = {}  # command id -> (source, number) of its events so far
        self._queue: deque = deque()
        self._auth_task: asyncio.Task | None = None
        self._auth_failures = 0
        self._closed = False
        self._paused = False              # the transport asked us to stop writing
        self._reading_paused = False
        self._inbox = bytearray()  # received, not parsed yet
        self._eof = False          # the client ended its input (parsed after the inbox)
        self._stall_timer: asyncio.TimerHandle | None = None
        self._cacheable: tuple | None = None  # (message, its whole line) of a one-line chunk

    # -- SERVER.CONNECTION.* ---------------------------------------------------------------------
    @property
    def uptime(self) -> float:
        return time.monotonic() - self._start_mono

    def set_eventmask(self, value: int) -> None:
        self.eventmask = int(value)

    def set_abort_on_disconnect(self, value: int) -> None:
        self.abort_on_disconnect = int(value)

    # -- asyncio.Protocol --------------------------------------------------------------------------
    def connection_made(self, transport) -> None:
        self.transport = transport
        peer = transport.get_extra_info("peername")
        self.address = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer or "")
        self.host = peer[0] if isinstance(peer, tuple) else host_of(self.address)
        cfg = self.server.settings
        refusal = self.server.admit(self)
        if refusal is not None:
            self.send(m.Greeting("2.1", self.id, (), (), refusal))
            transport.close()
            self._closed = True
            return
        self._arm_timer(cfg.login_timeout)
        transport.set_write_buffer_limits(high=cfg.max_output)
        implicit = cfg.implicit_auth
        self.send(m.Greeting("2.1", self.id, () if implicit else ("PLAIN",), (), cfg.greeting))
        if implicit:
            user = self.server.users[cfg.implicit_user]
            if user.password == BLOCKED_HASH:  # blocked over TPL2: refused as its AUTH would be
                log.warning("connection %d (%s): implicit login as blocked user %r refused",
                            self.id, self.address, user.name)
                self.send(m.AuthFailed())
                return
            self._login(user.name, max(user.rlevel, getattr(user, "default_rlevel", 0)),
                        max(user.wlevel, getattr(user, "default_wlevel", 0)))

    def data_received(self, data: bytes) -> None:
        self._last_input = time.monotonic()
        if self._closed:
            return
        if (not self._inbox and self.authenticated and not self._queue and self._auth_task is None
                and not self._paused and not self._eof and data.find(b"\n") == len(data) - 1
                and not self.proto.buffered):
            # one whole line and nothing else waiting: answered by a kept GET reply when one
            # is still good (reply_cache.py)
            kept = self.server.replies.get(data, self.rlevel)
            if kept is not None and self._answer_kept(*kept):
                return
        self._inbox += data
        self._pump()

    def _answer_kept(self, cmd_id: int, reply: bytes) -> bool:
        """Send a kept GET reply as this connection's answer to the same line (False: the id is
        busy or too many commands are in flight; the line then goes the normal way)."""
        if cmd_id in self.commands or len(self.commands) >= self.server.settings.max_in_flight:
            return False
        self.command_times.append(time.monotonic())
        self._send_kept(reply, perf_counter())
        return True

    def _send_kept(self, reply: bytes, started: float) -> None:
        self.write(reply)
        self.server.replies.hits += 1
        self.server.command_stats.record("GET", "complete", perf_counter() - started)

    def eof_received(self) -> bool:
        self._eof = True
        self._pump()
        return True  # the transport stays open until the queued lines are answered

    def connection_lost(self, exc) -> None:
        self._closed = True
        self._arm_timer(0.0)
        self._queue.clear()
        if self._stall_timer is not None:
            self._stall_timer.cancel()
        self.server.scheduler.forget(self)
        if self._auth_task is not None:
            self._auth_task.cancel()
        if self.abort_on_disconnect:
            for cmd in list(self.commands.values()):
                cmd.stop_moves()  # as an ABORT: the motion it started stops
                if cmd.task is not None:
                    cmd.task.cancel()
        self.server.forget(self)

    def pause_writing(self) -> None:
        """More than ``max_output`` unsent: stop handling and reading until the client reads."""
        self._paused = True
        self._flow_input()
        if self._stall_timer is None and not self._closed:
            self._stall_timer = asyncio.get_running_loop().call_later(
                self.server.settings.output_stall_timeout, self._stalled)

    def resume_writing(self) -> None:
        self._paused = False
        if self._stall_timer is not None:
            self._stall_timer.cancel()
            self._stall_timer = None
        if not self._closed:
            self._pump()

    def _stalled(self) -> None:
        self._stall_timer = None
        if self._paused and not self._closed:
            self._drop(f"has not read its replies for {self.server.settings.output_stall_timeout:g} s")

    def _drop(self, why: str) -> None:
        log.warning("connection %d (%s) %s; dropping it", self.id, self.address, why)
        self._closed = True
        self._queue.clear()
        if self.transport is not None:
            self.transport.abort()

    def _flow_input(self) -> None:
        """Read from the client only while its backlog (waiting lines, unsent output) is small."""
        t = self.transport
        if t is None or self._closed or t.is_closing():
            return
        if self._paused or len(self._queue) > QUEUE_HIGH or len(self._inbox) > INBOX_HIGH:
            if not self._reading_paused:
                self._reading_paused = True
                t.pause_reading()
        elif self._reading_paused and len(self._queue) <= QUEUE_LOW and len(self._inbox) <= INBOX_HIGH:
            self._reading_paused = False
            t.resume_reading()

    # -- output ----------------------------------------------------------------------------------
    def send(self, msg) -> None:
        bump_epoch()  # what a client is told may be a change: kept GET replies are not used again
        self.write(self.proto.send(msg))

    def write(self, data: bytes) -> None:
        t = self.transport
        if t is None or self._closed or t.is_closing():
            return
        t.write(data)
        if t.get_write_buffer_size() > self.server.settings.max_output_hard:
            self._drop(f"has more than {self.server.settings.max_output_hard} bytes of replies unread")

    def deliver_event(self, event: Event) -> None:
        """Send ``event`` if this connection is logged in and its mask lets it through."""
        cause = event.cause
        if not self.authenticated or not (self.eventmask & LEVEL_BITS.get(event.level, 0)):
            return
        cid = 0  # TPL2 §5: only an event of a command still executing carries its id
        if cause is not None:
            owner = self if cause[0] == self.id else self.server.sessions.get(cause[0])
            if owner is not None and owner.executing(cause):
                cid = cause[1] if owner is self else (cause[0] << 32) | cause[1]
        if cid and self._running:  # what the client was told under an id (_announce_failure)
            for cmd_id in self._running:
                self._announced.setdefault(cmd_id, set()).add((event.source, event.number))
        self.send(m.Event(cid, event.level, event.source, event.number, ascii_text(event.text)))

    def executing(self, cause: tuple) -> bool:
        """True while the command ``cause`` names (``(conn, id[, serial])``) has not sent its
        final line; a later command reusing the id is another command."""
        serial = self._running.get(cause[1])
        return serial is not None and (len(cause) < 3 or cause[2] == serial)

    def close(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()

    # -- dispatch --------------------------------------------------------------------------------
    def _drain_queue(self) -> None:
        self._pump()

    def _pump(self) -> None:
        """Hand waiting lines to the scheduler (they wait while AUTH is being checked and while
        output is paused)."""
        if self._closed:
            self._queue.clear()
            return
        if self.runnable():
            self.server.scheduler.ready(self)
        self._flow_input()

    def runnable(self) -> bool:
        """Input waits and may be handled now (for the scheduler)."""
        return ((bool(self._queue) or bool(self._inbox) or self._eof) and self._auth_task is None
                and not self._paused and not self._closed)

    def run_one(self) -> None:
        """Handle the next waiting line, parsing a little more input first when none is parsed
        (called by the scheduler)."""
        if not self._queue:
            if self._inbox:
                chunk = bytes(self._inbox[:PARSE_CHUNK])
                del self._inbox[:PARSE_CHUNK]
                whole = not self.proto.buffered and chunk.find(b"\n") == len(chunk) - 1
                msgs = self.proto.receive(chunk)
                if whole and len(msgs) == 1:  # one line, these bytes: its GET reply may be kept
                    self._cacheable = (msgs[0], chunk)
                self._queue.extend(msgs)
            elif self._eof:
                self._eof = False
                self._queue.extend(self.proto.eof())
        if self._queue:
            self._handle_safely(self._queue.popleft())
        if self._closed:
            self._queue.clear()
            self._inbox.clear()
        self._flow_input()

    def _handle_safely(self, msg) -> None:
        """A bug in handling one command must not cost the client its connection."""
        try:
            self._handle(msg)
        except Exception:
            log.exception("connection %d: handling %r failed", self.id, msg)
            cmd_id = getattr(msg, "cmd_id", 0)
            if cmd_id and cmd_id not in self.commands:
                self.send(m.CommandFailed(cmd_id))
                self.server.command_stats.record(_VERBS.get(type(msg), "OTHER"), "failed")

    def _handle(self, msg) -> None:
        kind = type(msg)
        if kind is m.Get:
            if self._admit_command(msg.cmd_id, "GET"):
                self._get(msg)
        elif kind is m.Set:
            if self._admit_command(msg.cmd_id, "SET"):
                self._set(msg)
        elif kind is m.Abort:
            if self._admit_command(msg.cmd_id, "ABORT"):
                self._abort(msg)
        elif kind is m.Auth:
            self._auth(msg)
        elif kind is m.Disconnect:
            self.send(m.DisconnectOk())
            self.server.command_stats.record("DISCONNECT", "complete")
            self._closed = True
            if self.abort_on_disconnect:
                for cmd in list(self.commands.values()):
                    if cmd.task is not None:
                        cmd.task.cancel()
            if self.transport is not None:
                self.transport.close()
        elif kind is m.Enc:
            self.send(m.EncUnsupported())
            self.server.command_stats.record("OTHER", "refused")
        elif kind is m.AuthSyntaxError:
            self.send(m.AuthError())
            self.server.command_stats.record("AUTH", "refused")
        elif kind is m.BadId:
            self.send(m.CommandError.idrange(msg.text))
            self.send(m.CommandFailed(0))  # every refused command ends with a final line
            self.server.command_stats.record("OTHER", "refused")
        elif kind is m.BadSyntax or kind is m.LineTooLong:
            self._refuse(msg.cmd_id, "SYNTAX")
        elif kind is m.UnknownCommand:
            self._refuse(msg.cmd_id, "UNKNOWN", f"unknown command {msg.verb}")
        else:  # pragma: no cover - every parser message is handled above
            log.error("unhandled message %r", msg)

    def _refuse(self, cmd_id: int, code: str, detail: str | None = None, verb: str = "OTHER") -> None:
        self.send(m.CommandError(cmd_id, code, detail))
        self.send(m.CommandFailed(cmd_id))  # id 0 too: the final line of the refused command
        self.server.command_stats.record(verb, "refused")

    def _admit_command(self, cmd_id: int, verb: str) -> bool:
        if not self.authenticated:
            self._refuse(cmd_id, "UNAUTHENTICATED", verb=verb)
            return False
        if cmd_id in self.commands:
            self.send(m.CommandError.idbusy(cmd_id))
            self.send(m.CommandFailed(0))  # ends the refused line; the running command goes on
            self.server.command_stats.record(verb, "refused")
            return False
        if len(self.commands) >= self.server.settings.max_in_flight:
            self._refuse(cmd_id, "TOOMANY", verb=verb)
            return False
        self.command_times.append(time.monotonic())
        return True

    # -- AUTH --------------------------------------------------------------------------------
    def _auth(self, msg: m.Auth) -> None:
        if msg.method != "PLAIN":
            self.send(m.AuthUnsupported())
            self.server.command_stats.record("AUTH", "refused")
            return
        if msg.user is None or msg.password is None:
            self.send(m.AuthError())
            self.server.command_stats.record("AUTH", "refused")
            return
        self._auth_task = asyncio.get_running_loop().create_task(self._verify(msg))

    async def _verify(self, msg: m.Auth) -> None:
        """Check a login; failures slow the attacker, never the user with the password
        (``guard.py``: per-connection delay, per-name back-off before the check)."""
        logins = self.server.guard.logins
        started = perf_counter()
        try:
            backoff = logins.wait_before_check(msg.user)
            if backoff > 0:  # right and wrong passwords alike: no early answer to read
                await asyncio.sleep(backoff)
            user = await self.server.authenticate(msg.user, msg.password)
            if user is None:
                self._auth_failures += 1
                count = logins.failed(msg.user)
                log.warning("connection %d (%s): failed login as %r (%d of that name within %.0f s)",
                            self.id, self.address, msg.user, count,
                            self.server.settings.auth_backoff_window)
                await asyncio.sleep(logins.fail_delay(self._auth_failures))
                self.send(m.AuthFailed())
                self.server.command_stats.record("AUTH", "failed", perf_counter() - started)
                if self._auth_failures >= self.server.settings.auth_max_failures:
                    log.warning("connection %d (%s): %d failed logins, dropping it",
                                self.id, self.address, self._auth_failures)
                    self._closed = True
                    self.close()
                return
            # levels asked for, else the account's defaults (SERVER.ACCOUNTS.MODIFY.DEFAULT_*);
            # never more privileged than the account's own (MIN_*)
            rlevel = max(user.rlevel, msg.rlevel if msg.rlevel is not None else getattr(user, "default_rlevel", 0))
            wlevel = max(user.wlevel, msg.wlevel if msg.wlevel is not None else getattr(user, "default_wlevel", 0))
            self._login(user.name, rlevel, wlevel)
            self.server.command_stats.record("AUTH", "complete" if self.authenticated else "failed",
                                             perf_counter() - started)
        finally:
            self._auth_task = None
            self._drain_queue()

    def _login(self, name: str, rlevel: int, wlevel: int) -> None:
        if self.reserved and wlevel != 0:
            log.warning("connection %d (%s) in the level-0 reserve logged in as %s (level %d): dropped",
                        self.id, self.address, name, wlevel)
            self.send(m.AuthFailed())
            self._closed = True
            self.close()
            return
        self.username, self.rlevel, self.wlevel = name, rlevel, wlevel
        self._arm_timer(self.server.settings.idle_timeout)
        self.authenticated = True
        self.send(m.AuthOk(rlevel, wlevel))
        # DEBUG: tcs-client opens a connection per call (failed logins stay WARNING)
        log.debug("connection %d (%s) logged in as %s (%d %d)", self.id, self.address, name, rlevel, wlevel)

    # -- time-outs -----------------------------------------------------------------------------
    def _arm_timer(self, seconds: float) -> None:
        """(Re)start the one time-out of this connection: login before, idle after login."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if seconds > 0 and not self._closed:
            self._timer = asyncio.get_running_loop().call_later(seconds, self._time_out)

    def _time_out(self) -> None:
        self._timer = None
        if self._closed:
            return
        cfg = self.server.settings
        if not self.authenticated and self._auth_task is not None:
            # a login being checked (back-off, hash queue): its answer comes in bounded time
            # (auth_backoff_max + the check + auth_fail_delay), and a right password must not
            # be cut off by the server's own slowness
            self._arm_timer(1.0)
            return
        if not self.authenticated:
            log.info("connection %d (%s): no login within %.1f s, closing it", self.id, self.address,
                     cfg.login_timeout)
        else:
            quiet = time.monotonic() - self._last_input
            if self.commands or quiet < cfg.idle_timeout:  # busy, or spoke since the timer began
                self._arm_timer(max(0.05, cfg.idle_timeout - quiet))
                return
            log.info("connection %d (%s): idle for %.0f s, closing it", self.id, self.address, quiet)
        self._closed = True
        self.close()

    # -- GET -----------------------------------------------------------------------------------
    def _get(self, msg: m.Get) -> None:
        """Read every object; the command's work is bounded by ``[server] max_objects`` (elements
        addressed) and ``max_reply_bytes`` (an object past either answers ``DIMENSION``).

        Plain variables are read through the GET's plan (:func:`_get_plan`: the objects' fast
        readers, looked up once per distinct GET text), everything else through
        :meth:`Tree.resolve` and :meth:`Tree.read`; both read the live value at this moment."""
        started = perf_counter()
        epoch, since = EPOCH.value, self.server.replies.now()
        cacheable, self._cacheable = self._cacheable, None
        keep = cacheable is not None and cacheable[0] is msg
        if keep:  # another connection's same line may have been answered meanwhile
            kept = self.server.replies.get(cacheable[1], self.rlevel)
            if kept is not None:
                self._send_kept(kept[1], started)
                return
        reply, shared = self._read_get(msg)
        if keep and shared:
            self.server.replies.keep(cacheable[1], self.rlevel, epoch, since, msg.cmd_id, reply,
                                     partial(self._read_again, msg, self.rlevel))
        self.write(reply)
        self.server.command_stats.record("GET", "complete", perf_counter() - started)

    def _read_get(self, msg: m.Get) -> tuple[bytes, bool]:
        """The reply to ``msg`` read now, and whether it is the same for every connection of
        this read level (no per-connection variable: it may then be kept)."""
        tree = self.server.tree
        settings = self.server.settings
        budget, room = settings.max_objects, settings.max_reply_bytes
        rlevel = self.rlevel
        shared = True
        items = []
        for ref, wire, reader, level, same in _get_plan(tree, msg.objects):
            if reader is not None and budget >= 1 and allowed(rlevel, level):
                budget -= 1
                try:
                    value = reader()
                except TcsError as exc:
                    value = exc.reply
                except Exception:
                    log.exception("reading %s failed", ref.text)
                    value = "FAILED 13"
            else:
                shared = shared and same
                value, budget = self._get_one(tree, ref, budget)
            room -= len(value) + len(ref.text)
            if room < 0:
                value = "DIMENSION"
            items.append((wire, value))
        return self.proto.get_reply(msg.cmd_id, items), shared

    def _read_again(self, msg: m.Get, rlevel: int) -> bytes | None:
        """The kept reply to ``msg`` read anew ahead of the next request (:mod:`.reply_cache`);
        None once this connection has closed or logged in again at another read level."""
        return None if self._closed or self.rlevel != rlevel else self._read_get(msg)[0]

    def _get_one(self, tree, ref, budget: int) -> tuple[str, int]:
        """The wire value of one object of a GET by the general path, and the budget left."""
        try:
            targets = tree.resolve(ref, budget)
            budget -= len(targets)
            if ref.slice is not None or ref.slice_error is not None:  # X{a:b}
                return ",".join([tree.read_slice(t, ref, self) for t in targets]), budget
            if len(targets) == 1:
                return tree.read(targets[0], ref.prop, self), budget
            return ",".join([tree.read(t, ref.prop, self) for t in targets]), budget
        except TcsError as exc:
            return exc.reply, budget

    # -- SET -----------------------------------------------------------------------------------
    def _set(self, msg: m.Set) -> None:
        cmd_id = msg.cmd_id
        started = perf_counter()
        self.send(m.CommandOk(cmd_id))
        serial = self._running[cmd_id] = next(_SERIALS)
        token = current_cause.set((self.id, cmd_id, serial))
        try:
            for i, assignment in enumerate(msg.assignments):
                pending = self._assign(cmd_id, assignment)
                if pending is not None:
                    cmd = _Command(cmd_id, (self.id, cmd_id, serial), started)
                    cmd.moves = [(self.server.tree, w[3], w[1]) for w in pending[1]]
                    self.commands[cmd_id] = cmd
                    cmd.task = self.server.spawn(
                        self._finish_set(cmd, assignment, pending, msg.assignments[i + 1:]))
                    return
        except BaseException:
            self._running.pop(cmd_id, None)
            raise
        finally:
            current_cause.reset(token)
        self.send(m.CommandComplete(cmd_id))
        self.server.command_stats.record("SET", "complete", perf_counter() - started)
        self._running.pop(cmd_id, None)
        self._announced.pop(cmd_id, None)

    def _assign(self, cmd_id: int, assignment: m.Assignment):
        """Start one assignment. Returns None when it finished (line sent), else the
        awaitables still to wait for and the number of targets."""
        ref = assignment.obj
        tree = self.server.tree
        if ref.slice is not None or ref.slice_error is not None:  # a string slice is read-only
            self.send(m.DataError(cmd_id, ref.text, ("TYPE",)))
            return None
        try:
            targets = tree.resolve(ref, self.server.settings.max_objects)
            checked = tree.check_write_each(targets, ref.prop, assignment.values, self)
        except TcsError as exc:
            self.send(m.DataError(cmd_id, ref.text, (exc.reply,)))
            return None
        errors: list[str] = []
        waits = []
        for target, (value, refused) in zip(targets, checked):
            if refused is not None:  # this element only; the others are written
                errors.append(refused)
                continue
            try:
                pending = tree.write(target, value, self)
            except TcsError as exc:
                errors.append(exc.reply)
                self._announce_failure(cmd_id, module_of(target), exc)
                continue
            except Exception:
                log.exception("setting %s failed", ref.text)
                errors.append("FAILED 13")
                continue
            errors.append("")
            if pending is not None:
                waits.append((len(errors) - 1, pending, module_of(target), target))
        if waits:
            return errors, waits
        self._data_result(cmd_id, ref.text, errors)
        return None

    def _announce_failure(self, cmd_id: int, source: str, exc: TcsError) -> None:
        """OpenTCI §4: a request the domain refused or failed (``FAILED n``) also sends its
        event ``ERROR <module>:<n>``, under the command's id, unless this connection already
        got an event of that number for that module under a command id while the command
        ran. (An unsolicited event, id 0, of the same number — a drive fault seen by the
        control loop — does not count: a client waiting for its command shows the events of
        commands, and a slew's ``FAILED 2`` came without a reason.)"""
        if exc.keyword is not None or (source, exc.number) in self._announced.get(cmd_id, ()):
            return
        self.server.events.emit(ERROR, source, exc.number, exc.message)

    def _data_result(self, cmd_id: int, obj: str, errors: list[str]) -> None:
        if any(errors):
            # one slot per element; an element that was written has an empty slot (",RANGE")
            self.send(m.DataError(cmd_id, obj, tuple(e or "" for e in errors)))
        else:
            self.send(m.DataOk(cmd_id, obj))

    async def _finish_set(self, cmd: _Command, assignment, pending, rest) -> None:
        cmd_id = cmd.cmd_id
        result = "failed"
        try:
            await self._await_assignment(cmd_id, assignment.obj.text, pending)
            for a in rest:
                more = self._assign(cmd_id, a)
                if more is not None:
                    cmd.moves += [(self.server.tree, w[3], w[1]) for w in more[1]]
                    await self._await_assignment(cmd_id, a.obj.text, more)
            self.send(m.CommandComplete(cmd_id))
            result = "complete"
        except asyncio.CancelledError:
            if cmd.aborted_by is not None:
                self.send(m.CommandAbortedBy(cmd_id, cmd.aborted_by))
                result = "aborted"
            else:
                self.send(m.CommandFailed(cmd_id))
                result = "failed"
        finally:
            self.server.command_stats.record("SET", result, perf_counter() - cmd.started)
            self.commands.pop(cmd_id, None)
            self._running.pop(cmd_id, None)
            self._announced.pop(cmd_id, None)

    async def _await_assignment(self, cmd_id: int, obj: str, pending) -> None:
        errors, waits = pending
        for slot, awaitable, source, _ in waits:
            try:
                await awaitable
            except TcsError as exc:
                errors[slot] = exc.reply
                self._announce_failure(cmd_id, source, exc)
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("long-running set of %s failed", obj)
                errors[slot] = "FAILED 13"
        self._data_result(cmd_id, obj, errors)

    # -- ABORT ---------------------------------------------------------------------------------
    def _abort(self, msg: m.Abort) -> None:
        cmd_id, target = msg.cmd_id, msg.target
        by = cmd_id
        started = perf_counter()
        if target >> 32:  # an extended id (conn << 32) | id
            conn, target = target >> 32, target & 0xFFFFFFFF
            if conn != self.id:
                self._abort_other(cmd_id, conn, target)
                return
        if target == 0:
            victims = [c for c in self.commands.values()]
        elif target in self.commands:
            victims = [self.commands[target]]
        else:
            self._refuse(cmd_id, "NOTRUNNING", verb="ABORT")
            return
        self._abort_victims(cmd_id, victims, by, started)

    def _abort_other(self, cmd_id: int, conn: int, target: int) -> None:
        """ABORT of another connection's command: allowed to a connection whose write level is
        at least as privileged as the owner's (else DENIED); the victim ends with
        ``ABORTEDBY <extended id of this ABORT>`` on its own connection."""
        other = self.server.sessions.get(conn)
        victim = other.commands.get(target) if other is not None else None
        if victim is None or victim.task is None:
            self._refuse(cmd_id, "NOTRUNNING", verb="ABORT")
        elif self.wlevel > other.wlevel:
            self._refuse(cmd_id, "DENIED", verb="ABORT")
        else:
            self._abort_victims(cmd_id, [victim], (self.id << 32) | cmd_id, perf_counter())

    def _abort_victims(self, cmd_id: int, victims: list, by: int, started: float) -> None:
        self.send(m.CommandOk(cmd_id))
        for victim in victims:
            victim.aborted_by = by
            victim.stop_moves()  # the motion it started stops (before its task is cancelled)
            if victim.task is not None:
                victim.task.cancel()
        tasks = [v.task for v in victims if v.task is not None]
        if not tasks:
            self.send(m.CommandComplete(cmd_id))
            self.server.command_stats.record("ABORT", "complete", perf_counter() - started)
            return
        cmd = _Command(cmd_id, started=started)
        self.commands[cmd_id] = cmd
        cmd.task = self.server.spawn(self._finish_abort(cmd, tasks))

    async def _finish_abort(self, cmd: _Command, tasks) -> None:
        result = "failed"
        try:
            _, still = await asyncio.wait(tasks, timeout=self.server.settings.abort_timeout)
            self.send(m.CommandTimeout(cmd.cmd_id) if still else m.CommandComplete(cmd.cmd_id))
            result = "timeout" if still else "complete"
        except asyncio.CancelledError:
            self.send(m.CommandFailed(cmd.cmd_id))
            result = "failed"
        finally:
            self.server.command_stats.record("ABORT", result, perf_counter() - cmd.started)
            self.commands.pop(cmd.cmd_id, None)

    def fail_all(self) -> None:
        """Server shutdown: end every running command with COMMAND FAILED."""
        for cmd in list(self.commands.values()):
            if cmd.task is not None:
                cmd.task.cancel()


__all__ = ["Session"]
