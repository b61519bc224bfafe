"""``tcs-client``: talk to the telescope over TPL2 from a shell or a script.

    tcs-client get VAR... [--json] [--meta P]  values (strings decoded; a module: its variables;
                                              VAR:PROP = VAR!PROP; times also in ISO UTC),
                                              exit 1 if one failed (the error and its meaning)
    tcs-client set VAR=VALUE... [--no-wait]   one SET per module, all started together; waits
                                              for their completion with a progress line
    tcs-client watch [VAR...] [--count N]     events and a compact status line, live
    tcs-client tree [PREFIX] [--json]         the variable tree with its properties

Operator verbs (OpenTCI only; each waits until really done, with progress lines; Ctrl-C sends
CABINET.STOP=1, then exits 130):

    tcs-client ready                          power on, reference what is not referenced
    tcs-client goto TARGET | --altaz ALT AZ   a star (IAU name), a body, "RA DEC": slew, track,
                                              return on target (POINTING.TARGETDISTANCE)
    tcs-client wait EXPR... [--timeout S]     until VAR==/!=/</<=/>/>=VALUE or VAR&BITS hold
    tcs-client stop                           CABINET.STOP=1
    tcs-client park                           TRACK=0, every axis to its PARKPOS, power off

Connection options come before or after the subcommand: ``--host`` (``$TCS_HOST``, default
127.0.0.1), ``--port`` (``$TCS_PORT``, 65432), ``--user`` (``$TCS_USER``, default your login
name), ``--password-file`` (``$TCS_PASSWORD_FILE``; ``-`` reads standard input); without a
file the password is asked for on the terminal. A server with implicit login needs none.

Exit codes: 0 done, 1 a value or command failed (or not done within --timeout), 2 usage
error, 3 no connection or login refused, 130 interrupted (a running SET is aborted first; a
verb's commands are aborted and CABINET.STOP=1 sent).

How it works: one blocking socket, lines parsed with the server's own reply parser
(:func:`tcs.opentci_server.protocol.parse_reply`), replies routed by command id so that a SET
and the GETs of its progress line run at the same time on one connection; events are shown
as they come; a SET's progress variables are read once per progress line, not in a loop.
Error keywords are printed with their meaning (:func:`explain`: the object's MIN/MAX, levels,
the OpenTCI meaning of ``FAILED n`` from :data:`tcs.errors.EVENT_MEANINGS`). The verbs are
sequences of plain SETs and GETs run by :func:`run` (commands started together, a progress
GET per refresh, an ``until`` condition for what a SET does not wait for: REINIT, TRACK);
their TARGETs are resolved by :mod:`tcs.cli.targets` (the shipped bright-star list, DE421 for
bodies). Nothing here imports the service: it is a plain client.
"""

from __future__ import annotations

import argparse
import datetime
import getpass
import json
import math
import os
import re
import select
import shutil
import socket
import sys
import time
from dataclasses import dataclass, field

from tcs import __version__
from tcs.errors import EVENT_MEANINGS
from tcs.opentci_server import messages as m
from tcs.opentci_server.protocol import ReplySyntaxError, parse_reply
from tcs.opentci_server.values import unescape

OK, FAILED, USAGE, CONNECTION, INTERRUPTED = 0, 1, 2, 3, 130
CLASSES = {1001: "root", 1002: "module", 1003: "module array", 1006: "variable",
           1007: "variable array", 2006: "system variable", 2007: "system variable array"}
TYPES = {0: "NULL", 1: "INT", 2: "FLOAT", 3: "STRING"}
MAIN_AXES = ("AZ", "ZD", "HA", "DEC")
VARIABLE_CLASSES = (1006, 1007, 2006, 2007)
#: What the bare TPL2 error keywords mean (RANGE, DENIED and FAILED n get more, see explain()).
KEYWORDS = {"UNKNOWN": "no such object", "TYPE": "not a value this variable takes (type)",
            "INVALID": "cannot be addressed this way (a module needs a member or a property)",
            "DIMENSION": "index out of range, or too many objects in one command",
            "LOCKED": "locked by another connection"}
#: Operator verbs people look for as variables (``set CABINET.PARK=1``): the UNKNOWN says where
#: they are. Keys: the last name of the object.
VERB_HINTS = {
    "PARK": "to park and power off: tcs-client park", "UNPARK": "tcs-client ready",
    "READY": "power on and reference: tcs-client ready (OpenTSI: TELESCOPE.READY on its own port)",
    "INIT": "tcs-client ready", "HOME": "tcs-client ready", "GOTO": "tcs-client goto TARGET",
    "SLEW": "tcs-client goto TARGET", "TRACKING": "POINTING.TRACK, or tcs-client goto TARGET",
    "ABORT": "tcs-client stop, or STOP=1 of a module",
}
#: Root members of the OpenTSI tree: they have no ERROR_STATE (TELESCOPE.STATUS has the errors).
OPENTSI_MODULES = ("TELESCOPE", "OBJECT", "POSITION", "CURRENT", "AUXILIARY")
TERMINAL_REFRESH = 0.5  # s between progress GETs of `set` on a terminal (elsewhere: --progress-interval)


class ClientError(Exception):
    """Ends the program with ``code`` and a one-line message."""

    def __init__(self, message: str, code: int = FAILED):
        super().__init__(message)
        self.code = code


def decode(wire: str):
    """A wire value as Python: int, float, str (unescaped), None for NULL. Error keywords
    (``UNKNOWN``, ``FAILED 4`` …) come back as :class:`WireError`."""
    if wire.startswith('"') and wire.endswith('"') and len(wire) >= 2:
        return unescape(wire[1:-1])
    if wire == "NULL":
        return None
    try:
        return int(wire)
    except ValueError:
        pass
    try:
        return float(wire)
    except ValueError:
        return WireError(wire)


class WireError(str):
    """An error keyword in place of a value (``UNKNOWN``, ``FAILED 4``, ``DIMENSION``)."""


@dataclass
class Reply:
    """Everything one command got: its DATA lines in order and its final line."""

    cmd_id: int
    data: list = field(default_factory=list)
    error: m.CommandError | None = None
    final: object | None = None

    @property
    def ok(self) -> bool:
        return (isinstance(self.final, m.CommandComplete) and self.error is None
                and not any(isinstance(d, m.DataError) for d in self.data)
                and not any(isinstance(v, WireError) for d in self.data
                            if isinstance(d, m.DataInline) for v in map(decode, d.values)))

    def values(self) -> dict:
        """``{object: python value}`` of the DATA INLINE lines (one value, or a list)."""
        out = {}
        for d in self.data:
            if isinstance(d, m.DataInline):
                vals = [decode(v) for v in d.values]
                out[d.obj] = vals[0] if len(vals) == 1 else vals
        return out

    def problems(self) -> list[str]:
        """What failed, one text per object (or the command)."""
        out = []
        if self.error is not None:
            out.append(f"command refused: {self.error.code}"
                       + (f" {self.error.arg}" if self.error.arg else "")
                       + (f" [{self.error.detail}]" if self.error.detail else ""))
        for d in self.data:
            if isinstance(d, m.DataError):
                out.append(f"{d.obj}: {' '.join(d.errors)}")
            elif isinstance(d, m.DataInline):
                out.extend(f"{d.obj}: {v}" for v in map(decode, d.values) if isinstance(v, WireError))
        if isinstance(self.final, m.CommandFailed) and not out:
            out.append("command failed")
        elif isinstance(self.final, m.CommandAbortedBy):
            out.append(f"aborted by command {self.final.by}")
        elif isinstance(self.final, m.CommandTimeout):
            out.append("command timed out")
        return out


class Connection:
    """One logged-in TPL2 connection; replies are collected per command id."""

    def __init__(self, host: str, port: int, timeout: float = 10.0):
        try:
            self.sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as exc:
            raise ClientError(f"cannot connect to {host}:{port}: {exc.strerror or exc}", CONNECTION) from None
        self.address = f"{host}:{port}"
        self._buf = b""
        self._next_id = 1
        self.replies: dict[int, Reply] = {}
        self.on_event = lambda event: None
        greeting = self._read_message(timeout)
        if not isinstance(greeting, m.Greeting):
            raise ClientError(f"{self.address} is no TPL2 server (greeting {greeting!r})", CONNECTION)
        self.greeting = greeting

    # ------------------------------------------------------------------------------- wire
    def _readline(self, timeout: float | None) -> str | None:
        """One line without its end, or None when ``timeout`` passed first."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while b"\n" not in self._buf:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([self.sock], [], [], wait)
            if not ready:
                return None
            try:
                chunk = self.sock.recv(65536)
            except OSError as exc:
                raise ClientError(f"connection to {self.address} lost: {exc}", CONNECTION) from None
            if not chunk:
                raise ClientError(f"{self.address} closed the connection", CONNECTION)
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        return line.rstrip(b"\r").decode("utf-8", "replace")

    def _read_message(self, timeout: float | None):
        line = self._readline(timeout)
        if line is None:
            return None
        try:
            return parse_reply(line)
        except ReplySyntaxError as exc:
            raise ClientError(f"{self.address}: {exc}", CONNECTION) from None

    def send(self, line: str) -> None:
        try:
            self.sock.sendall(line.encode("utf-8") + b"\n")
        except OSError as exc:
            raise ClientError(f"connection to {self.address} lost: {exc}", CONNECTION) from None

    def close(self) -> None:
        try:
            self.send("DISCONNECT")
        except ClientError:
            pass
        self.sock.close()

    # ------------------------------------------------------------------------------ login
    @property
    def needs_login(self) -> bool:
        return bool(self.greeting.auth_methods)

    def login(self, user: str, password: str | None) -> m.AuthOk:
        if not self.needs_login:  # implicit login: AUTH OK follows the greeting at once
            reply = self._read_message(10.0)
        else:
            quoted = [x.replace("\\", "\\\\").replace('"', '\\"') for x in (user, password or "")]
            self.send(f'AUTH PLAIN "{quoted[0]}" "{quoted[1]}"')
            reply = self._read_message(30.0)
        if not isinstance(reply, m.AuthOk):
            raise ClientError(f"{self.address}: login as {user!r} refused", CONNECTION)
        return reply

    # --------------------------------------------------------------------------- commands
    def start(self, command: str) -> int:
        """Send ``<id> command``; returns the id (see :meth:`pump`, :meth:`wait`)."""
        cmd_id = self._next_id
        self._next_id += 1
        self.replies[cmd_id] = Reply(cmd_id)
        self.send(f"{cmd_id} {command}")
        return cmd_id

    def pump(self, timeout: float | None) -> bool:
        """Handle the lines that arrive within ``timeout``; True if one did."""
        msg = self._read_message(timeout)
        if msg is None:
            return False
        while msg is not None:
            self._dispatch(msg)
            msg = self._read_message(0.0) if b"\n" in self._buf else None
        return True

    def _dispatch(self, msg) -> None:
        if isinstance(msg, m.Event):
            self.on_event(msg)
            return
        reply = self.replies.get(getattr(msg, "cmd_id", -1))
        if reply is None:
            return  # e.g. 0 COMMAND ERROR IDBUSY: nothing of ours
        if isinstance(msg, (m.DataInline, m.DataOk, m.DataError)):
            reply.data.append(msg)
        elif isinstance(msg, m.CommandError):
            reply.error = msg
        elif isinstance(msg, (m.CommandComplete, m.CommandFailed, m.CommandAbortedBy, m.CommandTimeout)):
            reply.final = msg

    def done(self, cmd_id: int) -> bool:
        return self.replies[cmd_id].final is not None

    def wait(self, cmd_id: int, timeout: float = 60.0) -> Reply:
        deadline = time.monotonic() + timeout
        while not self.done(cmd_id):
            left = deadline - time.monotonic()
            if left <= 0:
                raise ClientError(f"no answer to command {cmd_id} within {timeout:g} s")
            self.pump(left)
        return self.replies.pop(cmd_id)

    def command(self, command: str, timeout: float = 60.0) -> Reply:
        return self.wait(self.start(command), timeout)

    def get(self, *objs: str, timeout: float = 60.0) -> dict:
        """``{object: value}`` of one GET; failed objects map to :class:`WireError`."""
        reply = self.command("GET " + ";".join(objs), timeout)
        if reply.error is not None:
            raise ClientError("; ".join(reply.problems()))
        return reply.values()


# ------------------------------------------------------------------------------ helpers
def _base(obj: str) -> str:
    """``AZ.TARGETPOS`` of ``AZ.TARGETPOS``, ``X[0-3]`` → ``X[0]`` (properties of one element)."""
    if obj.endswith("]") and "[" in obj:
        head, _, index = obj.rpartition("[")
        first = index[:-1].split("-")[0].split(",")[0]
        return f"{head}[{first}]" if first.isdigit() else obj
    return obj


def explain(conn: Connection, obj: str, error: str, writing: bool) -> str:
    """``error`` of ``obj`` with its meaning: RANGE with the object's !MIN/!MAX, DENIED with
    why (read-only, write-only, the levels), ``FAILED n`` with the OpenTCI meaning of n."""
    word, _, arg = error.partition(" ")
    try:
        if word == "FAILED" and arg.strip().isdigit():
            meaning = EVENT_MEANINGS.get(int(arg))
            return f"{error} ({meaning})" if meaning else error
        if word == "RANGE" and "!" not in obj:
            base = _base(obj)
            v = conn.get(f"{base}!MIN", f"{base}!MAX", timeout=10.0)
            lo, hi = v.get(f"{base}!MIN"), v.get(f"{base}!MAX")
            if isinstance(lo, (int, float)) and isinstance(hi, (int, float)):
                return f"RANGE (allowed {text(lo)} .. {text(hi)})"
            return "RANGE (a value this variable does not take)"
        if word == "DENIED" and "!" not in obj:
            base = _base(obj)
            prop = "WLEVEL" if writing else "RLEVEL"
            v = conn.get(f"{base}!{prop}", f"SERVER.CONNECTION.{prop}", timeout=10.0)
            need, have = v.get(f"{base}!{prop}"), v.get(f"SERVER.CONNECTION.{prop}")
            if isinstance(need, int) and need < 0:
                return f"DENIED ({'read-only' if writing else 'write-only'})"
            if isinstance(need, int) and isinstance(have, int):
                return (f"DENIED (needs {'write' if writing else 'read'} level {need} or lower; "
                        f"this login has {have})")
            return "DENIED (not allowed to this login)"
    except ClientError:
        return error
    meaning = KEYWORDS.get(word)
    hint = VERB_HINTS.get(obj.split("!", 1)[0].rsplit(".", 1)[-1].upper()) if word == "UNKNOWN" else None
    if meaning and hint:
        return f"{error} ({meaning}; {hint})"
    return f"{error} ({meaning})" if meaning else error


def problems_of(conn: Connection, reply: Reply, writing: bool) -> list[str]:
    """:meth:`Reply.problems` with the meaning of each error keyword (see :func:`explain`)."""
    out = []
    if reply.error is not None:
        out.append(f"command refused: {reply.error.code}"
                   + (f" {reply.error.arg}" if reply.error.arg else "")
                   + (f" [{reply.error.detail}]" if reply.error.detail else ""))
    for d in reply.data:
        if isinstance(d, m.DataError):
            errors = list(d.errors)
            if len(errors) == 1:
                out.append(f"{d.obj}: {explain(conn, d.obj, errors[0], writing)}")
            else:  # one per element: OK,TYPE,OK
                meanings = [explain(conn, d.obj, e, writing) for e in dict.fromkeys(errors) if e != "OK"]
                out.append(f"{d.obj}: {','.join(errors)}"
                           + (f" ({'; '.join(meanings)})" if meanings else ""))
        elif isinstance(d, m.DataInline):
            out.extend(f"{d.obj}: {explain(conn, d.obj, v, writing)}"
                       for v in map(decode, d.values) if isinstance(v, WireError))
    rest = [p for p in reply.problems() if p == "command failed" or p.startswith(("aborted", "command timed"))]
    return out + rest


def _env_int(name: str, default: int) -> int:
    try:
        return int(os.environ.get(name, default))
    except ValueError:
        raise ClientError(f"${name} must be a port number", USAGE) from None


def read_password(path: str | None) -> str:
    if path == "-":
        return sys.stdin.readline().rstrip("\r\n")
    if path:
        try:
            with open(path, encoding="utf-8") as f:
                return f.readline().rstrip("\r\n")
        except OSError as exc:
            raise ClientError(f"cannot read the password file {path}: {exc.strerror}", USAGE) from None
    if sys.stdin.isatty():
        return getpass.getpass("password: ")
    raise ClientError("no password: give --password-file FILE (or -) or run on a terminal", USAGE)


def open_connection(args) -> Connection:
    conn = Connection(args.host, args.port, timeout=args.connect_timeout)
    password = read_password(args.password_file) if conn.needs_login else None
    conn.login(args.user, password)
    return conn


def text(value) -> str:
    """A decoded value for people: strings as they are, floats without noise."""
    if value is None:
        return "NULL"
    if isinstance(value, float):
        return f"{value:.6f}".rstrip("0").rstrip(".") if abs(value) < 1e9 else repr(value)
    if isinstance(value, list):
        return ",".join(map(text, value))
    return str(value)


#: Variables holding a Unix time (seconds since 1970, UTC or UT1): by their last name
TIME_NAMES = {"UTC", "UT1", "TAI", "TIME", "STARTTIME", "LAST_CHANGE", "MODIFIED"}


def iso_utc(seconds: float) -> str:
    """``2026-11-29T07:31:02.123Z`` of Unix seconds."""
    when = datetime.datetime.fromtimestamp(round(seconds, 3), datetime.timezone.utc)
    return when.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def human(name: str, value) -> str:
    """A value for people: a Unix time as ISO UTC with the number after it."""
    last = name.split("!", 1)[0].rsplit(".", 1)[-1].split("[", 1)[0].upper()
    if "!" not in name and last in TIME_NAMES and isinstance(value, (int, float)) and value > 1e8:
        return f"{iso_utc(float(value))} ({text(value)})"
    return text(value)


class Line:
    """A status/progress line: rewritten in place on a terminal, plain lines otherwise
    (at most one per ``every`` seconds)."""

    def __init__(self, stream, every: float):
        self.stream = stream
        self.tty = stream.isatty()
        self.every = every
        self._last = -1e9
        self._shown = False

    def show(self, line: str, force: bool = False) -> None:
        if self.tty:
            width = shutil.get_terminal_size((80, 24)).columns
            self.stream.write("\r\x1b[K" + line[:max(10, width - 1)])
            self._shown = True
        elif force or time.monotonic() - self._last >= self.every:
            self.stream.write(line + "\n")
            self._last = time.monotonic()
        self.stream.flush()

    def message(self, line: str) -> None:
        """A line that stays (an event) above the status line."""
        if self.tty and self._shown:
            self.stream.write("\r\x1b[K")
            self._shown = False
        self.stream.write(line + "\n")
        self.stream.flush()

    def end(self) -> None:
        if self.tty and self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False


def event_text(ev: m.Event) -> str:
    return f"EVENT {ev.level} {ev.obj}:{ev.number} {ev.text}".rstrip()


# ---------------------------------------------------------------------------- commands
def _is_module(conn: Connection, name: str) -> bool:
    return "!" not in name and conn.get(f"{name}!CLASS").get(f"{name}!CLASS") in (1001, 1002)


def cmd_get(conn: Connection, args) -> int:
    """Print ``NAME=value`` lines; a module (INVALID to a bare GET) prints its members. Times
    (LOCAL.UTC, LOCAL.UT1, …) are shown in ISO UTC beside the number (not with --json,
    --value-only or --raw)."""
    args.vars = [meta_name(v) for v in args.vars]
    if args.meta:
        args.vars = [f"{v.split('!', 1)[0]}!{p.upper()}" for v in args.vars for p in args.meta]
    reply = conn.command("GET " + ";".join(args.vars), args.timeout)
    values: dict = {}      # printed, in order (None: failed, JSON null)
    notes: list[str] = []
    problems: list[str] = []

    bad: set[str] = set()

    def failed(obj: str, error: str) -> None:
        values[obj] = None
        bad.add(obj)
        problems.append(f"{obj}: {explain(conn, obj, error, writing=False)}")

    def module(obj: str) -> None:
        below: dict = {}
        module_values(conn, obj, below, notes)
        for k, v in below.items():
            if isinstance(v, WireError):
                failed(k, v)
            else:
                values[k] = v

    if reply.error is not None:
        problems.extend(reply.problems())
    for d in reply.data:
        if isinstance(d, m.DataInline):
            vals = [decode(v) for v in d.values]
            if len(vals) == 1 and isinstance(vals[0], WireError):
                if vals[0] == "INVALID" and _is_module(conn, d.obj):
                    module(d.obj)
                else:
                    failed(d.obj, vals[0])
                continue
            for v in vals:
                if isinstance(v, WireError):
                    problems.append(f"{d.obj}: {explain(conn, d.obj, v, writing=False)}")
            values[d.obj] = vals[0] if len(vals) == 1 else vals
        elif isinstance(d, m.DataError):
            if tuple(d.errors) == ("INVALID",) and _is_module(conn, d.obj):
                module(d.obj)
            else:
                for e in dict.fromkeys(d.errors):
                    if e != "OK":
                        failed(d.obj, e)
    if not isinstance(reply.final, m.CommandComplete) and not problems:
        problems.extend(reply.problems() or ["command failed"])
    if args.json:
        print(json.dumps({k: (None if isinstance(v, WireError) else v) for k, v in values.items()},
                         indent=None))
    else:
        for name, value in values.items():
            if value is not None and not isinstance(value, WireError):
                shown = text(value) if args.raw or args.value_only else human(name, value)
                print(shown if args.value_only else f"{name}={shown}")
            elif value is None and name not in bad:
                print("NULL" if args.value_only else f"{name}=NULL")
    for note in notes:
        print(f"tcs-client: {note}", file=sys.stderr)
    for problem in problems:
        print(f"tcs-client: {problem}", file=sys.stderr)
    return FAILED if problems else OK


def progress_vars(assignments: list[str]) -> list[str]:
    """What to show while a SET runs: the position of a moving axis, referencing, power."""
    out = []
    for a in assignments:
        name = a.split("=", 1)[0].strip()
        module, _, var = name.rpartition(".")
        upper = var.upper()
        if module and upper in ("TARGETPOS", "OFFSET"):
            out.append(f"{module}.REALPOS")
        elif module and upper == "REINIT":
            out.append(f"{module}.REFERENCED")
        elif module and upper == "POWER":
            out.append(f"{module}.POWER_STATE")
        elif module and upper == "TRACK":
            out.append(f"{module}.TARGETDISTANCE")
    return list(dict.fromkeys(out))


def split_assignments(assignments: list[str], in_order: bool) -> list[list[str]]:
    """The SETs a ``set`` sends, started together: one per module (``AZ``, ``ZD``, ``DOME[1]``
    …: the server assigns the objects of one SET in order, each long one complete before the
    next starts), the assignments of one module in one SET in their order (``POINTING.TARGET.RA``
    before ``POINTING.TRACK``). ``in_order``: all in one SET, one after another."""
    if in_order:
        return [list(assignments)]
    groups: dict[str, list[str]] = {}
    for a in assignments:
        head = a.split("=", 1)[0].strip().split(".", 1)[0].split("!", 1)[0].upper()
        groups.setdefault(head, []).append(a)
    return list(groups.values())


@dataclass
class Run:
    """Commands started together and watched until they end (see :func:`run`)."""

    label: str
    commands: list[str]
    watch: list[str] = field(default_factory=list)
    #: values of ``watch`` → True when the run is done (the commands may still run: TRACK),
    #: None: done when every command ended
    until: object = None
    #: values of ``watch`` → a failure text, or None
    failed: object = None
    #: value text for the progress line (default: NAME=value of every watched variable)
    show: object = None
    #: an event (any command's) → a failure text that ends the run, or None
    event_fails: object = None


def run(conn: Connection, job: Run, args, *, on_interrupt: str = "abort") -> int:
    """Start ``job.commands`` together (each its own command id), show a progress line (the
    ``watch`` variables, one GET per refresh), show the events of these commands and every
    ERROR event, and wait until they all ended (or ``until`` holds). ``args``: timeout,
    progress_interval, no_wait, grace, quiet. Ctrl-C or the time-out: ``on_interrupt`` "abort"
    ABORTs the commands; "stop" also sends CABINET.STOP=1 (the operator verbs)."""
    line = Line(sys.stderr, args.progress_interval)
    ids = [conn.start(c) for c in job.commands]
    what = job.label
    errors: list[str] = []

    def on_event(ev) -> None:
        if ev.cmd_id in ids or ev.level == "ERROR":
            line.message(event_text(ev))
        why = job.event_fails(ev) if job.event_fails is not None else None
        if why:
            errors.append(why)
    conn.on_event = on_event
    started = time.monotonic()
    deadline = started + args.timeout if args.timeout else None
    poll = None
    values: dict = {}
    every = min(TERMINAL_REFRESH, args.progress_interval) if line.tty else args.progress_interval
    next_poll = started + min(0.5, every) if job.until is None else started

    def problems() -> list[str]:
        out = []
        for cmd_id in ids:
            reply = conn.replies.get(cmd_id)
            if reply is not None and reply.final is not None:
                out += problems_of(conn, reply, writing=True)
        return out

    def halt(why: str) -> int:
        for cmd_id in ids:
            if not conn.done(cmd_id):
                conn.command(f"ABORT {cmd_id}", 30.0)
        if on_interrupt == "stop":
            conn.command("SET CABINET.STOP=1", 30.0)
        line.end()
        print(f"tcs-client: {what}: {why}", file=sys.stderr)
        return INTERRUPTED if why.startswith("interrupted") else FAILED

    done_word = {"abort": "aborted", "stop": "stopped"}.get(on_interrupt, "")
    try:
        while True:
            now = time.monotonic()
            ended = all(conn.done(i) for i in ids)
            bad = [i for i in ids if conn.done(i) and not conn.replies[i].ok]
            if bad:
                line.end()
                found = problems()
                for problem in found:
                    print(f"tcs-client: {problem}", file=sys.stderr)
                if any("FAILED 5 " in p for p in found):
                    print("tcs-client: (power on and reference first: tcs-client ready)", file=sys.stderr)
                for cmd_id in ids:
                    if not conn.done(cmd_id):
                        conn.command(f"ABORT {cmd_id}", 30.0)
                return FAILED
            if job.until is None and ended:
                break
            if job.until is not None and poll is None and values and job.until(values):
                break
            if job.failed is not None and values and (why := job.failed(values)):
                return halt(why)
            if errors:
                return halt(errors[0])
            if args.no_wait and now - started >= args.grace:
                line.end()
                running = [str(i) for i in ids if not conn.done(i)]
                print(f"{what}: started (command {', '.join(running) or '-'} runs on)", file=sys.stderr)
                return OK
            if deadline is not None and now >= deadline:
                return halt(f"not done within {args.timeout:g} s" + (f", {done_word}" if done_word else ""))
            if poll is not None and conn.done(poll):
                values = conn.replies.pop(poll).values()
                if not args.no_wait:
                    shown = (job.show(values) if job.show is not None else
                             " ".join(f"{k}={text(v)}" for k, v in values.items() if not isinstance(v, WireError)))
                    # (an until-run polls twice a second: its line at most once per interval)
                    line.show(f"{what}: {now - started:.1f} s {shown}".rstrip(), force=job.until is None)
                poll = None
            if poll is None and now >= next_poll:
                next_poll = now + (min(every, 0.5) if job.until is not None else every)
                if job.watch:
                    poll = conn.start("GET " + ";".join(job.watch))
                elif not args.no_wait:
                    line.show(f"{what}: {now - started:.1f} s", force=True)
            wake = [0.2] if poll is not None else [0.2, next_poll - now]
            if deadline is not None:
                wake.append(deadline - now)
            conn.pump(max(0.01, min(wake)))
    except KeyboardInterrupt:
        return halt("interrupted" + (f", {done_word}" if done_word else ""))
    line.end()
    for problem in problems():
        print(f"tcs-client: {problem}", file=sys.stderr)
    for cmd_id in ids:
        if conn.done(cmd_id):
            conn.replies.pop(cmd_id, None)
    if not args.quiet:
        print(f"{what}: done in {time.monotonic() - started:.1f} s", file=sys.stderr)
    return OK


def cmd_set(conn: Connection, args) -> int:
    for a in args.assignments:
        if "=" not in a or not a.split("=", 1)[0].strip():
            raise ClientError(f"not an assignment: {a!r} (VAR=VALUE)", USAGE)
    groups = split_assignments(args.assignments, args.in_order)
    job = Run(";".join(args.assignments), ["SET " + ";".join(g) for g in groups],
              watch=progress_vars(args.assignments))
    code = run(conn, job, args)
    reinit = [a.split("=", 1)[0].strip() for a in args.assignments
              if a.split("=", 1)[0].strip().upper().endswith(".REINIT")]
    if code == OK and reinit and not args.quiet and not args.no_wait:
        module = reinit[0].rsplit(".", 1)[0]
        print(f"{module}: referencing runs on in the background; `tcs-client wait "
              f"'{module}.REFERENCED>=1'` (or `tcs-client ready`) waits until it is done", file=sys.stderr)
    return code


# ------------------------------------------------------------------------ operator verbs
#: what ``wait`` compares with; ``&`` is a bit test (nonzero)
WAIT_OPERATORS = ("==", "!=", "<=", ">=", "=", "<", ">", "&")


def meta_name(obj: str) -> str:
    """``X:MIN`` (or ``X::MIN``) → ``X!MIN``: the property separator without bash's ``!``
    history expansion (a ``:`` is never part of an object path)."""
    head, sep, prop = obj.rpartition(":")
    return f"{head.rstrip(':')}!{prop}" if sep and head and prop else obj


def parse_condition(expr: str) -> tuple[str, str, object]:
    """``VAR OP VALUE`` of ``wait``: (object, operator, value) — value an int, float or str."""
    for op in sorted(WAIT_OPERATORS, key=len, reverse=True):
        name, found, value = expr.partition(op)
        if found and name.strip():
            name, value = meta_name(name.strip()), value.strip()
            if op == "=":
                op = "=="
            wire = decode(value) if value else value
            if isinstance(wire, WireError):  # a bare word: a string
                wire = str(value)
            return name, op, wire
    raise ClientError(f"not a condition: {expr!r} (VAR==VALUE, VAR>=VALUE, VAR&BITS …)", USAGE)


_CONDITION = re.compile(r"""\s*(?P<name>[A-Za-z_<][A-Za-z0-9_.\-\[\],:<>]*?(?:![A-Za-z]+)?)\s*
                          (?P<op>==|!=|<=|>=|=|<|>|&)\s*
                          (?P<value>"(?:[^"\\]|\\.)*"|[^\s;,&]+)\s*
                          (?:(?:&&|\band\b|[;,])\s*)?""", re.X)


def parse_conditions(words: list[str]) -> list[tuple[str, str, object]]:
    """The conditions of ``wait``, however the shell split them: ``'A>=1' 'B==2'``,
    ``A >= 1 and B == 2``, ``"A>=1 && B&8"``."""
    text = " ".join(words).strip()
    out, pos = [], 0
    while pos < len(text):
        found = _CONDITION.match(text, pos)
        if found is None or found.end() == pos:
            raise ClientError(f"not a condition: {text[pos:]!r} (VAR==VALUE, VAR>=VALUE, VAR&BITS …; "
                              "several: separate with spaces, 'and' or '&&')", USAGE)
        out.append(parse_condition(found.group("name") + found.group("op") + found.group("value")))
        pos = found.end()
    if not out:
        raise ClientError("wait: no condition", USAGE)
    return out


def holds(value, op: str, want) -> bool:
    if value is None or isinstance(value, WireError):
        return False
    try:
        if op == "&":
            return bool(int(value) & int(want))
        if op in ("==", "!="):
            same = (abs(float(value) - float(want)) <= 1e-9 * max(1.0, abs(float(want)))
                    if isinstance(value, (int, float)) and isinstance(want, (int, float)) else value == want)
            return same if op == "==" else not same
        return {"<": value < want, "<=": value <= want, ">": value > want, ">=": value >= want}[op]
    except (TypeError, ValueError):
        return False


def cmd_wait(conn: Connection, args) -> int:
    """Until every condition holds (exit 0), or the time-out (exit 1); Ctrl-C: exit 130."""
    conditions = parse_conditions(args.conditions)
    names = list(dict.fromkeys(c[0] for c in conditions))
    first = conn.get(*names)
    unknown = [f"{n}: {explain(conn, n, v, writing=False)}" for n, v in first.items() if isinstance(v, WireError)
               and not v.startswith("FAILED")]
    if unknown:
        raise ClientError("; ".join(unknown))
    job = Run("wait " + " ".join(args.conditions), [], watch=names,
              until=lambda v: all(holds(v.get(n), op, want) for n, op, want in conditions))
    return run(conn, job, args, on_interrupt="none")


def _number(values: dict, name: str, default=None):
    v = values.get(name)
    return v if isinstance(v, (int, float)) and not isinstance(v, bool) else default


def _members(conn: Connection) -> list[str]:
    return member_names(conn, "")


def _main_axes(conn: Connection) -> tuple[str, str]:
    mount = conn.get("CONFIG.MOUNT").get("CONFIG.MOUNT")
    return ("HA", "DEC") if mount == "RA-DEC" else ("AZ", "ZD")


def power_on(conn: Connection, args) -> int:
    state = _number(conn.get("CABINET.POWER_STATE"), "CABINET.POWER_STATE")
    if state == 1.0:
        return OK
    return run(conn, Run("power on", ["SET CABINET.POWER=1"], watch=["CABINET.POWER_STATE"]),
               args, on_interrupt="stop")


def cmd_ready(conn: Connection, args) -> int:
    """Power on, reference what is not referenced (main axes first), wait until every axis is
    referenced: exit 0 once the telescope can move."""
    started = time.monotonic()
    quiet = args.quiet
    args.quiet = True
    code = power_on(conn, args)
    if code != OK:
        return code
    values = conn.get("CABINET.REFERENCED", "CABINET.POWER_STATE")
    if _number(values, "CABINET.REFERENCED", 0.0) < 1.0:
        def failed_event(ev):
            if ev.obj == "CABINET" and ev.number == 20:     # REFERENCE_BAD: which axis and why
                return f"referencing failed: {ev.text}"
            if ev.level == "ERROR" and ev.obj == "CABINET" and ev.number == 10:
                return f"referencing ended: {ev.text}"     # STOP from elsewhere
            return None
        axes = [a for a in _main_axes(conn) if a in _members(conn)]
        job = Run("referencing", ["SET CABINET.REINIT=0"],
                  watch=["CABINET.REFERENCED", *(f"{a}.REFERENCED" for a in axes), "CABINET.POWER_STATE"],
                  until=lambda v: _number(v, "CABINET.REFERENCED", 0.0) >= 1.0,
                  failed=lambda v: ("the power went off" if _number(v, "CABINET.POWER_STATE", 1.0) < 1.0
                                    else None),
                  event_fails=failed_event)
        code = run(conn, job, args, on_interrupt="stop")
        if code != OK:
            return code
    if not quiet:
        print(f"ready: powered and referenced in {time.monotonic() - started:.1f} s", file=sys.stderr)
    return OK


def cmd_stop(conn: Connection, args) -> int:
    """CABINET.STOP=1: every axis stops with its normal deceleration, tracking and POWER/REINIT
    sequences end."""
    reply = conn.command("SET CABINET.STOP=1", 30.0)
    for problem in problems_of(conn, reply, writing=True):
        print(f"tcs-client: {problem}", file=sys.stderr)
    if reply.ok and not args.quiet:
        print("stop: sent (every axis stops, tracking ends)", file=sys.stderr)
    return OK if reply.ok else FAILED


def park_positions(conn: Connection) -> dict[str, float]:
    """``{axis module: park position}`` of every axis with a PARKPOS (the TCS's extension)."""
    members = _members(conn)
    axes = [a for a in members if a in ("AZ", "ZD", "HA", "DEC", "FOCUS", "MIRROR")]
    arrays = []
    for name in ("DEROTATOR", "FILTER", "ZD"):
        count = conn.get(f"{name}!COUNT").get(f"{name}!COUNT") if name in members else None
        if isinstance(count, int):
            arrays += [f"{name}[{i}]" for i in range(count)]
    names = axes + arrays
    values = conn.get(*(f"{n}.PARKPOS" for n in names)) if names else {}
    return {n: float(values[f"{n}.PARKPOS"]) for n in names
            if isinstance(values.get(f"{n}.PARKPOS"), (int, float))}


def cmd_park(conn: Connection, args) -> int:
    """Stop tracking, move every axis with a park position there (all together), power off:
    what OpenTSI's TELESCOPE.READY=0 does, on OpenTCI."""
    started = time.monotonic()
    quiet = args.quiet
    args.quiet = True
    parks = park_positions(conn)
    if not parks:
        raise ClientError("no park position: the hardware file's [axes.*] park (or Alpaca "
                          "SetPark) gives one; nothing moved")
    state = conn.get("CABINET.POWER_STATE", "CABINET.REFERENCED", "POINTING.TRACK")
    if _number(state, "POINTING.TRACK", 0):
        code = run(conn, Run("tracking off", ["SET POINTING.TRACK=0"]), args, on_interrupt="stop")
        if code != OK:
            return code
    if _number(state, "CABINET.POWER_STATE") == 1.0 and _number(state, "CABINET.REFERENCED", 0.0) >= 1.0:
        offsets = conn.get(*(f"{a}.OFFSET" for a in parks))
        commands = [f"SET {a}.TARGETPOS={text(p - _number(offsets, f'{a}.OFFSET', 0.0))}"
                    for a, p in parks.items()]
        names = list(parks)
        code = run(conn, Run("to the park position", commands, watch=[f"{a}.REALPOS" for a in names],
                             show=lambda v: " ".join(f"{a} {text(round(_number(v, f'{a}.REALPOS', 0.0), 3))}"
                                                     for a in names)),
                   args, on_interrupt="stop")
        if code != OK:
            return code
    elif _number(state, "CABINET.POWER_STATE") != 0.0 or _number(state, "CABINET.REFERENCED", 0.0) < 1.0:
        values = conn.get(*(f"{a}.REALPOS" for a in parks))
        away = [a for a, p in parks.items() if not isinstance(values.get(f"{a}.REALPOS"), (int, float))
                or abs(values[f"{a}.REALPOS"] - p) > 0.1]
        if away and _number(state, "CABINET.POWER_STATE") != 0.0:
            raise ClientError("the telescope is not powered and referenced: "
                              "it cannot move to the park position (tcs-client ready first); nothing moved")
    code = run(conn, Run("power off", ["SET CABINET.POWER=0"], watch=["CABINET.POWER_STATE"]),
               args, on_interrupt="abort")
    if code != OK:
        return code
    if not quiet:
        where = " ".join(f"{a}={text(p)}" for a, p in parks.items())
        print(f"park: parked ({where}) and powered off in {time.monotonic() - started:.1f} s",
              file=sys.stderr)
    return OK


def site_of(conn: Connection) -> tuple[float, float, float, float]:
    """(latitude, east longitude, height, UTC now) of the TCS. LOCAL.LONGITUDE may be served
    west-positive (a site setting): the sign that agrees with the TCS's sidereal time wins."""
    from tcs.cli.targets import gast_hours

    v = conn.get("LOCAL.LATITUDE", "LOCAL.LONGITUDE", "LOCAL.HEIGHT", "LOCAL.UTC", "LOCAL.UT1-UTC",
                 "POINTING.CURRENT.SIDEREAL_TIME")
    lat, lon, height, utc = (_number(v, k) for k in ("LOCAL.LATITUDE", "LOCAL.LONGITUDE",
                                                     "LOCAL.HEIGHT", "LOCAL.UTC"))
    if None in (lat, lon, height, utc):
        raise ClientError("the TCS gives no site or time (LOCAL.LATITUDE/LONGITUDE/HEIGHT/UTC)")
    last = _number(v, "POINTING.CURRENT.SIDEREAL_TIME")
    if last is not None:
        east = (last - gast_hours(utc)) * 15.0
        if abs(math.remainder(east + lon, 360.0)) < abs(math.remainder(east - lon, 360.0)):
            lon = -lon
    return lat, lon, height, utc


def cmd_goto(conn: Connection, args) -> int:
    """Slew to TARGET and track it; exit 0 once on target (tracking runs on)."""
    from tcs.cli import targets as tg

    if args.list:
        for star in sorted(tg.stars().values(), key=lambda s: s.vmag):
            print(f"{star.name:<18} RA {star.ra:9.5f} h  Dec {star.dec:+9.4f}°  V {star.vmag:5.2f}")
        print("bodies: " + ", ".join(tg.BODIES))
        return OK
    started = time.monotonic()
    quiet = args.quiet
    args.quiet = True
    if args.altaz is not None:
        return goto_altaz(conn, args, started, quiet)
    if not args.target:
        raise ClientError("goto TARGET: a star name, a body, 'RA DEC', or --altaz ALT AZ", USAGE)
    try:
        goal = tg.resolve(args.target)
    except tg.TargetError as exc:
        raise ClientError(str(exc), USAGE) from None
    if "POINTING" not in _members(conn):
        raise ClientError("this TCS has no POINTING module (no sky targets)")
    if goal.kind == "body":
        lat, lon, height, utc = site_of(conn)
        ra, dec, ra_v, dec_v = tg.body_place(goal.body, utc, lat, lon, height)
    elif goal.kind == "star":
        utc = _number(conn.get("LOCAL.UTC"), "LOCAL.UTC") or time.time()
        ra, dec = tg.star_place(tg.find_star(goal.label), utc)
        ra_v = dec_v = 0.0
    else:
        ra, dec, ra_v, dec_v = goal.ra, goal.dec, 0.0, 0.0
    label = f"goto {goal.label}"
    if not quiet:
        print(f"{label}: RA {ra:.6f} h, Dec {dec:+.5f}° (ICRS, now)"
              + (f", rates {ra_v:+.4f}\"/s of RA, {dec_v:+.4f}\"/s" if ra_v or dec_v else ""),
              file=sys.stderr)
    tolerance = args.tolerance / 3600.0
    settle: list[float] = []

    def on_target(v) -> bool:
        distance = _number(v, "POINTING.TARGETDISTANCE")
        if _number(v, "POINTING.TRACK", 0) and distance is not None and distance <= tolerance:
            settle.append(time.monotonic())
            return len(settle) >= 2      # twice in a row: settled, not passing through
        settle.clear()
        return False
    tracked: list[bool] = []

    def ended(v):
        if _number(v, "POINTING.TRACK", 0):
            tracked.append(True)
            return None
        return "tracking ended (stopped, or refused: see above)" if tracked else None
    job = Run(label, [f"SET POINTING.TARGET.RA={ra!r};POINTING.TARGET.DEC={dec!r};"
                      f"POINTING.TARGET.RA_V={ra_v!r};POINTING.TARGET.DEC_V={dec_v!r};POINTING.TRACK=1"],
              watch=["POINTING.TARGETDISTANCE", "POINTING.TRACK", "POINTING.SLEWINGTIME"],
              until=on_target, failed=ended,
              show=lambda v: (f"distance {_angle(_number(v, 'POINTING.TARGETDISTANCE'))}"
                              + (f", {text(round(_number(v, 'POINTING.SLEWINGTIME'), 1))} s to go"
                                 if (_number(v, 'POINTING.SLEWINGTIME') or 0) > 0 else "")))
    code = run(conn, job, args, on_interrupt="stop")
    if code == OK and not quiet:
        print(f"{label}: on target and tracking in {time.monotonic() - started:.1f} s", file=sys.stderr)
    return code


def _angle(degrees) -> str:
    if degrees is None:
        return "-"
    return f"{degrees:.3f}°" if degrees >= 1.0 else f"{degrees * 3600.0:.1f}\""


def goto_altaz(conn: Connection, args, started: float, quiet: bool) -> int:
    """A fixed AZ/ZD (axis positions: no pointing model, no tracking), both axes together."""
    alt, az = args.altaz
    if _main_axes(conn) != ("AZ", "ZD"):
        raise ClientError("--altaz needs an AZ-ZD mount (this one is equatorial)", USAGE)
    if not -90.0 <= alt <= 90.0:
        raise ClientError(f"altitude {alt:g} is outside -90..90", USAGE)
    if _number(conn.get("POINTING.TRACK"), "POINTING.TRACK", 0):
        code = run(conn, Run("tracking off", ["SET POINTING.TRACK=0"]), args, on_interrupt="stop")
        if code != OK:
            return code
    label = f"goto alt {alt:g} az {az:g}"
    job = Run(label, [f"SET AZ.TARGETPOS={az % 360.0!r}", f"SET ZD.TARGETPOS={90.0 - alt!r}"],
              watch=["AZ.REALPOS", "ZD.REALPOS"],
              show=lambda v: f"AZ {text(round(_number(v, 'AZ.REALPOS', 0.0), 3))} "
                             f"ZD {text(round(_number(v, 'ZD.REALPOS', 0.0), 3))}")
    code = run(conn, job, args, on_interrupt="stop")
    if code == OK and not quiet:
        print(f"{label}: arrived in {time.monotonic() - started:.1f} s", file=sys.stderr)
    return code


def member_names(conn: Connection, prefix: str) -> list[str]:
    """Names of the members of ``prefix`` ("" = the root), as TPL2 clients walk the tree:
    ``!MEMBERS`` is their number, ``<i>!NAME`` each name (an older server's comma-separated
    list is accepted too)."""
    members = conn.get(f"{prefix}!MEMBERS").get(f"{prefix}!MEMBERS")
    if isinstance(members, str):
        return [m for m in members.split(",") if m]
    if not isinstance(members, int) or members <= 0:
        return []
    sep = "." if prefix else ""
    objs = [f"{prefix}{sep}<{i}>!NAME" for i in range(members)]
    values = conn.get(*objs)
    return [v for v in (values.get(o) for o in objs) if isinstance(v, str) and v]


def module_values(conn: Connection, prefix: str, values: dict, notes: list) -> None:
    """The readable variables below the module ``prefix`` (depth first) into ``values``;
    module arrays and write-only variables are named in ``notes`` instead."""
    members = member_names(conn, prefix)
    if not members:
        return
    names = [f"{prefix}.{n}" for n in members]
    props = conn.get(*(f"{n}!{p}" for n in names for p in ("CLASS", "RLEVEL", "COUNT")))
    readable = []
    for name in names:
        kind = props.get(f"{name}!CLASS")
        if kind == 1002:
            if readable:  # keep the tree's order: read what came before this sub-module
                values.update(conn.get(*readable))
                readable = []
            module_values(conn, name, values, notes)
        elif kind == 1003:
            count = props.get(f"{name}!COUNT")
            notes.append(f"{name}[]: module array of {count if isinstance(count, int) else '?'} "
                         f"(get {name}[i] for one element)")
        elif kind in VARIABLE_CLASSES:
            level = props.get(f"{name}!RLEVEL")
            if isinstance(level, int) and level < 0:
                continue  # write-only (REINIT, STOP …): nothing to read
            readable.append(name)
    if readable:
        values.update(conn.get(*readable))


@dataclass
class StatusPlan:
    """Which variables the status line reads, from the tree's root members."""

    objs: list[str]
    members: list[str]

    @classmethod
    def of(cls, conn: Connection, extra: list[str]) -> "StatusPlan":
        members = member_names(conn, "")
        objs = []
        if "CABINET" in members:
            objs += ["CABINET.POWER_STATE", "CABINET.REFERENCED", "CABINET.ERROR_STATE"]
        elif "TELESCOPE" in members:  # the OpenTSI tree: errors are TELESCOPE.STATUS.*
            objs += ["TELESCOPE.READY_STATE", "TELESCOPE.MOTION_STATE", "TELESCOPE.STATUS.GLOBAL",
                     "TELESCOPE.STATUS.LIST"]
            if "POSITION" in members:
                objs += ["POSITION.HORIZONTAL.AZ", "POSITION.HORIZONTAL.ZD"]
        for axis in MAIN_AXES:
            if axis in members:
                objs += [f"{axis}.REALPOS", f"{axis}.MOTION_STATE", f"{axis}.ERROR_STATE"]
        if "POINTING" in members:
            objs += ["POINTING.TRACK", "POINTING.ERROR_STATE"]
        if "DOME" in members:
            count = conn.get("DOME!COUNT").get("DOME!COUNT")
            for i in range(count if isinstance(count, int) else 0):
                objs += [f"DOME[{i}].REALPOS", f"DOME[{i}].ERROR_STATE"]
        for name in members:
            if name not in ("SERVER", "LOCAL", "CONFIG", "CABINET", "POINTING", "DOME", *MAIN_AXES,
                            *OPENTSI_MODULES):
                objs.append(f"{name}.ERROR_STATE")
        return cls(objs + list(extra), members)


def tsi_errors(listing, level) -> list[str]:
    """``component=level`` of every component in an OpenTSI ``TELESCOPE.STATUS.LIST``
    (``<group>|<level>:<component>|<level>[;…]:<errors>``, groups separated by ``,``); the
    GLOBAL level alone when the list names none."""
    out = []
    if isinstance(listing, str) and listing:
        for group in listing.split(","):
            fields = group.split(":")
            if len(fields) >= 2:
                for comp in fields[1].split(";"):
                    name, _, bits = comp.partition("|")
                    if name:
                        out.append(f"{name}={bits or '?'}")
    if not out and isinstance(level, int) and level:
        out.append(f"TELESCOPE={level}")
    return list(dict.fromkeys(out))


def status_line(values: dict, extra: list[str]) -> str:
    def num(name, fmt="{:.3f}"):
        v = values.get(name)
        return "-" if v is None or isinstance(v, WireError) else fmt.format(v)

    parts = [time.strftime("%H:%M:%SZ", time.gmtime())]
    if "CABINET.POWER_STATE" in values:
        parts.append(f"power {num('CABINET.POWER_STATE', '{:.2f}')} ref {num('CABINET.REFERENCED', '{:.2f}')}")
    axes = []
    for axis in MAIN_AXES:
        if f"{axis}.REALPOS" in values:
            moving = values.get(f"{axis}.MOTION_STATE")
            mark = "*" if isinstance(moving, int) and moving & 1 else ""
            axes.append(f"{axis} {num(axis + '.REALPOS')}{mark}")
    if axes:
        parts.append(" ".join(axes))
    if "TELESCOPE.READY_STATE" in values:  # OpenTSI
        parts.append(f"ready {num('TELESCOPE.READY_STATE', '{:.2f}')}")
        if "POSITION.HORIZONTAL.AZ" in values:
            moving = values.get("TELESCOPE.MOTION_STATE")
            mark = "*" if isinstance(moving, int) and moving & 1 else ""
            parts.append(f"AZ {num('POSITION.HORIZONTAL.AZ')}{mark} ZD {num('POSITION.HORIZONTAL.ZD')}{mark}")
        parts.append(f"motion {num('TELESCOPE.MOTION_STATE', '{}')}")
    if "POINTING.TRACK" in values:
        parts.append(f"track {num('POINTING.TRACK', '{}')}")
    dome = [f"{i}:{num(f'DOME[{i}].REALPOS', '{:.1f}')}" for i in range(8)
            if isinstance(values.get(f"DOME[{i}].REALPOS"), (int, float))]
    if dome:
        parts.append("dome " + " ".join(dome))
    errors = [k.rsplit(".", 1)[0] + f"={v}" for k, v in values.items()
              if k.endswith(".ERROR_STATE") and isinstance(v, (int, float)) and v]
    errors += tsi_errors(values.get("TELESCOPE.STATUS.LIST"), values.get("TELESCOPE.STATUS.GLOBAL"))
    parts.append("errors " + (" ".join(errors) if errors else "none"))
    parts.extend(f"{name}={text(values.get(name))}" for name in extra)
    return " | ".join(parts)


def cmd_watch(conn: Connection, args) -> int:
    line = Line(sys.stdout, 0.0)
    conn.on_event = lambda ev: line.message(time.strftime("%H:%M:%SZ ", time.gmtime()) + event_text(ev))
    plan = StatusPlan.of(conn, args.vars)
    shown = 0
    try:
        while args.count is None or shown < args.count:
            started = time.monotonic()
            reply = conn.command("GET " + ";".join(plan.objs), args.timeout)
            line.show(status_line(reply.values(), args.vars), force=True)
            shown += 1
            if args.count is not None and shown >= args.count:
                break
            while (left := args.interval - (time.monotonic() - started)) > 0:
                conn.pump(left)
    except KeyboardInterrupt:
        pass
    line.end()
    return OK


def walk(conn: Connection, prefix: str, all_elements: bool, out: list) -> None:
    """Depth-first through the tree below ``prefix`` ("" = root), one GET per level."""
    sep = "." if prefix else ""
    members = member_names(conn, prefix)
    if not members:
        return
    names = [f"{prefix}{sep}{n}" for n in members]
    props = ("CLASS", "TYPE", "COUNT", "RLEVEL", "WLEVEL", "MIN", "MAX", "INFO")
    values = conn.get(*(f"{n}!{p}" for n in names for p in props))
    for name in names:
        entry = {"name": name}
        for p in props:
            v = values.get(f"{name}!{p}")
            if v is not None and not isinstance(v, WireError):
                entry[p.lower()] = v
        out.append(entry)
        kind = entry.get("class")
        if kind == 1002:
            walk(conn, name, all_elements, out)
        elif kind == 1003:
            count = entry.get("count", 0)
            for i in range(count if all_elements else min(count, 1)):
                element = conn.get(f"{name}[{i}]!CLASS").get(f"{name}[{i}]!CLASS")
                if element == 1002:
                    out.append({"name": f"{name}[{i}]", "class": 1002})
                    walk(conn, f"{name}[{i}]", all_elements, out)


def cmd_tree(conn: Connection, args) -> int:
    out: list = []
    prefix = args.prefix.strip(".") if args.prefix else ""
    if prefix:
        kind = conn.get(f"{prefix}!CLASS").get(f"{prefix}!CLASS")
        if isinstance(kind, WireError) or kind is None:
            raise ClientError(f"{prefix}: {kind or 'UNKNOWN'}")
        if kind not in (1001, 1002):
            walk_single = conn.get(*(f"{prefix}!{p}" for p in ("CLASS", "TYPE", "RLEVEL", "WLEVEL", "INFO")))
            out.append({"name": prefix, **{k.split("!")[1].lower(): v for k, v in walk_single.items()
                                           if not isinstance(v, WireError)}})
        else:
            walk(conn, prefix, args.all_elements, out)
    else:
        walk(conn, "", args.all_elements, out)
    if args.json:
        print(json.dumps(out, indent=1))
        return OK
    width = max((len(e["name"]) for e in out), default=0)
    for e in out:
        kind = e.get("class")
        desc = CLASSES.get(kind, str(kind))
        if kind in (1006, 1007, 2006, 2007):
            desc = TYPES.get(e.get("type"), "?") + (f"[{e['count']}]" if "count" in e else "")
            desc += f"  r{e.get('rlevel', '-')} w{e.get('wlevel', '-')}"
            if "min" in e or "max" in e:
                desc += f"  {text(e.get('min'))}..{text(e.get('max'))}"
        elif kind == 1003:
            desc += f"[{e.get('count', '?')}]"
        info = e.get("info")
        print(f"{e['name']:<{width}}  {desc}" + (f"  {info}" if info else ""))
    return OK


# -------------------------------------------------------------------------------- main
def parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    g = common.add_argument_group("connection")
    g.add_argument("--host", default=argparse.SUPPRESS, help="server address ($TCS_HOST, default 127.0.0.1)")
    g.add_argument("--port", type=int, default=argparse.SUPPRESS, help="TPL2 port ($TCS_PORT, default 65432)")
    g.add_argument("--user", default=argparse.SUPPRESS, help="user name ($TCS_USER, default your login name)")
    g.add_argument("--password-file", default=argparse.SUPPRESS,
                   help="file whose first line is the password, - for standard input "
                        "($TCS_PASSWORD_FILE; default: asked on the terminal)")
    g.add_argument("--timeout", type=float, default=argparse.SUPPRESS,
                   help="seconds to wait for an answer (set: for completion, then ABORT; "
                        "default 60 for get/tree, no limit for set)")
    p = argparse.ArgumentParser(prog="tcs-client", parents=[common],
                                description="Talk to the telescope over TPL2: get, set, watch, tree, and the operator "
                                            "verbs ready, goto, wait, stop, park.",
                                epilog="exit codes: 0 done, 1 failed, 2 usage, 3 no connection or "
                                       "login refused, 130 interrupted")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    s = sub.add_parser("get", parents=[common], help="read variables")
    s.add_argument("vars", nargs="+", metavar="VAR",
                   help="object, e.g. AZ.REALPOS, or a property: AZ.REALPOS:MAX (= AZ.REALPOS!MAX, "
                        "which bash's history expansion breaks unless quoted with '')")
    s.add_argument("--meta", action="append", metavar="PROP",
                   help="read this property of every VAR (MIN, MAX, INFO, TYPE …); may repeat")
    s.add_argument("--json", action="store_true", help="one JSON object {name: value}")
    s.add_argument("--value-only", "-v", action="store_true", help="print only the values, one a line")
    s.add_argument("--raw", action="store_true", help="times as plain Unix seconds (no ISO UTC)")
    s = sub.add_parser("set", parents=[common], help="write variables and wait for the result")
    s.add_argument("assignments", nargs="+", metavar="VAR=VALUE",
                   help='e.g. AZ.TARGETPOS=120 or POINTING.TARGET.RA=5.5; the modules start together '
                        '(one SET each: AZ.TARGETPOS=120 ZD.TARGETPOS=30 move both axes at once), '
                        'the assignments of one module in their order')
    s.add_argument("--in-order", action="store_true",
                   help="one SET of all assignments, each complete before the next starts")
    s.add_argument("--no-wait", action="store_true",
                   help="return once the command runs (after --grace seconds without a failure)")
    s.add_argument("--grace", type=float, default=1.0, help="see --no-wait (default %(default)s s)")
    s.add_argument("--progress-interval", type=float, default=5.0,
                   help="seconds between progress lines when not on a terminal (default %(default)s)")
    s.add_argument("--quiet", "-q", action="store_true", help="no 'done' line")
    s = sub.add_parser("watch", parents=[common], help="events and a status line, live")
    s.add_argument("vars", nargs="*", metavar="VAR", help="more variables for the status line")
    s.add_argument("--interval", type=float, default=1.0, help="seconds between status lines (default %(default)s)")
    s.add_argument("--count", type=int, help="stop after this many status lines")
    verb = argparse.ArgumentParser(add_help=False)
    verb.add_argument("--progress-interval", type=float, default=5.0,
                      help="seconds between progress lines when not on a terminal (default %(default)s)")
    verb.add_argument("--quiet", "-q", action="store_true", help="no summary line")
    s = sub.add_parser("ready", parents=[common, verb],
                       help="power on and reference every axis; waits until done (Ctrl-C: stop)")
    s = sub.add_parser("park", parents=[common, verb],
                       help="stop tracking, move to the park position, power off; waits (Ctrl-C: stop)")
    s = sub.add_parser("stop", parents=[common, verb], help="stop every axis and the tracking now")
    s = sub.add_parser("goto", parents=[common, verb],
                       help="slew to a star, a body or RA DEC, track, wait until on target (Ctrl-C: stop)")
    s.add_argument("target", nargs="*", metavar="TARGET",
                   help="a star's IAU name (Vega, 'Rigil Kentaurus'; --list), a body (moon, mars, "
                        "jupiter …), or 'RA DEC': RA hours (5.5, 5:35:17.3, 5h35m17s; 83.8d in "
                        "degrees), Dec degrees (-5.4, -5:23:28)")
    s.add_argument("--altaz", nargs=2, type=float, metavar=("ALT", "AZ"),
                   help="a fixed altitude and azimuth (degrees, azimuth from north through east): "
                        "axis positions, no tracking")
    s.add_argument("--tolerance", type=float, default=2.0,
                   help="on target: POINTING.TARGETDISTANCE below this many arcsec (default %(default)s)")
    s.add_argument("--list", action="store_true", help="list the named stars and bodies")
    s = sub.add_parser("wait", parents=[common, verb],
                       help="wait until every condition holds (exit 1 at --timeout, default 300 s)")
    s.add_argument("conditions", nargs="+", metavar="EXPR",
                   help="VAR OP VALUE, OP one of == != < <= > >= (= is ==) and & (bits set), e.g. "
                        "'CABINET.REFERENCED>=1' 'POINTING.TRACK==1' 'AZ.MOTION_STATE&8'")
    s.add_argument("--interval", type=float, default=0.5, help="seconds between reads (default %(default)s)")
    s = sub.add_parser("tree", parents=[common], help="the variable tree with its properties")
    s.add_argument("prefix", nargs="?", default="", help="start here, e.g. AZ or POINTING.TARGET")
    s.add_argument("--json", action="store_true", help="a JSON list of objects and properties")
    s.add_argument("--all-elements", action="store_true",
                   help="walk every element of module arrays (default: the first)")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    try:
        args.host = getattr(args, "host", None) or os.environ.get("TCS_HOST", "127.0.0.1")
        args.port = getattr(args, "port", None) or _env_int("TCS_PORT", 65432)
        args.user = getattr(args, "user", None) or os.environ.get("TCS_USER") or getpass.getuser()
        args.password_file = getattr(args, "password_file", None) or os.environ.get("TCS_PASSWORD_FILE")
        default = {"set": None, "ready": 900.0, "park": 900.0, "goto": 900.0, "wait": 300.0}
        args.timeout = getattr(args, "timeout", None) or default.get(args.command, 60.0)
        args.connect_timeout = 10.0
        for name, value in (("no_wait", False), ("grace", 1.0), ("quiet", False)):
            if not hasattr(args, name):
                setattr(args, name, value)
        if args.command == "wait":
            args.progress_interval = min(args.progress_interval, args.interval)
        if args.command == "goto" and args.list:
            return cmd_goto(None, args)
        conn = open_connection(args)
        try:
            return {"get": cmd_get, "set": cmd_set, "watch": cmd_watch, "tree": cmd_tree,
                    "ready": cmd_ready, "park": cmd_park, "stop": cmd_stop, "goto": cmd_goto,
                    "wait": cmd_wait}[args.command](conn, args)
        finally:
            conn.close()
    except ClientError as exc:
        print(f"tcs-client: {exc}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        return INTERRUPTED
    except BrokenPipeError:
        return OK


if __name__ == "__main__":
    sys.exit(main())
