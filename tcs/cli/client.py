"""``tcs-client``: talk to the telescope over TPL2 from a shell or a script.

    tcs-client get VAR... [--json]            values (strings decoded; a module: its variables),
                                              exit 1 if one failed (the error and its meaning)
    tcs-client set VAR=VALUE... [--no-wait]   one SET; waits for its completion with a
                                              progress line; exit 0 done, 1 failed
    tcs-client watch [VAR...] [--count N]     events and a compact status line, live
    tcs-client tree [PREFIX] [--json]         the variable tree with its properties

Connection options come before or after the subcommand: ``--host`` (``$TCS_HOST``, default
127.0.0.1), ``--port`` (``$TCS_PORT``, 65432), ``--user`` (``$TCS_USER``, default your login
name), ``--password-file`` (``$TCS_PASSWORD_FILE``; ``-`` reads standard input); without a
file the password is asked for on the terminal. A server with implicit login needs none.

Exit codes: 0 done, 1 a value or command failed, 2 usage error, 3 no connection or login
refused, 130 interrupted (a running SET is aborted first).

How it works: one blocking socket, lines parsed with the server's own reply parser
(:func:`tcs.opentci_server.protocol.parse_reply`), replies routed by command id so that a SET
and the GETs of its progress line run at the same time on one connection; events are shown
as they come; a SET's progress variables are read once per progress line, not in a loop.
Error keywords are printed with their meaning (:func:`explain`: the object's MIN/MAX, levels,
the OpenTCI meaning of ``FAILED n`` from :data:`tcs.errors.EVENT_MEANINGS`). Nothing here
imports the service: it is a plain client.
"""

from __future__ import annotations

import argparse
import getpass
import json
import os
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
    """Print ``NAME=value`` lines; a module (INVALID to a bare GET) prints its members."""
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
                print(text(value) if args.value_only else f"{name}={text(value)}")
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


def cmd_set(conn: Connection, args) -> int:
    for a in args.assignments:
        if "=" not in a or not a.split("=", 1)[0].strip():
            raise ClientError(f"not an assignment: {a!r} (VAR=VALUE)", USAGE)
    line = Line(sys.stderr, args.progress_interval)
    what = ";".join(args.assignments)
    cmd_id = conn.start("SET " + what)
    conn.on_event = lambda ev: line.message(event_text(ev)) if ev.cmd_id == cmd_id else None
    watch = progress_vars(args.assignments)
    started = time.monotonic()
    deadline = started + args.timeout if args.timeout else None
    poll = None
    # one progress GET per refresh of the line, not one per round trip (~400/s before)
    every = min(TERMINAL_REFRESH, args.progress_interval) if line.tty else args.progress_interval
    next_poll = started + min(0.5, every)
    try:
        while not conn.done(cmd_id):
            now = time.monotonic()
            if args.no_wait and now - started >= args.grace:
                line.end()
                print(f"{what}: started (command {cmd_id} runs on)", file=sys.stderr)
                return OK
            if deadline is not None and now >= deadline:
                conn.command(f"ABORT {cmd_id}", 30.0)
                conn.wait(cmd_id, 30.0)
                line.end()
                print(f"tcs-client: {what}: not done within {args.timeout:g} s, aborted", file=sys.stderr)
                return FAILED
            if not args.no_wait:
                if poll is not None and conn.done(poll):
                    values = conn.replies.pop(poll).values()
                    shown = " ".join(f"{k}={text(v)}" for k, v in values.items() if not isinstance(v, WireError))
                    line.show(f"{what}: {now - started:.1f} s {shown}".rstrip(), force=True)
                    poll = None
                if poll is None and now >= next_poll:
                    next_poll = now + every
                    if watch:
                        poll = conn.start("GET " + ";".join(watch))
                    else:
                        line.show(f"{what}: {now - started:.1f} s", force=True)
            wake = [0.2] if poll is not None else [0.2, next_poll - now]
            if deadline is not None:
                wake.append(deadline - now)
            conn.pump(max(0.01, min(wake)))
    except KeyboardInterrupt:
        conn.command(f"ABORT {cmd_id}", 30.0)
        line.end()
        print(f"tcs-client: {what}: interrupted, aborted", file=sys.stderr)
        return INTERRUPTED
    line.end()
    reply = conn.replies.pop(cmd_id)
    for problem in problems_of(conn, reply, writing=True):
        print(f"tcs-client: {problem}", file=sys.stderr)
    if reply.ok and not args.quiet:
        print(f"{what}: done in {time.monotonic() - started:.1f} s", file=sys.stderr)
    return OK if reply.ok else FAILED


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

    parts = [time.strftime("%H:%M:%S")]
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
    conn.on_event = lambda ev: line.message(time.strftime("%H:%M:%S ") + event_text(ev))
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
                                description="Talk to the telescope over TPL2: get, set, watch, tree.",
                                epilog="exit codes: 0 done, 1 failed, 2 usage, 3 no connection or "
                                       "login refused, 130 interrupted")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    s = sub.add_parser("get", parents=[common], help="read variables")
    s.add_argument("vars", nargs="+", metavar="VAR", help="object, e.g. AZ.REALPOS or AZ.REALPOS!MAX")
    s.add_argument("--json", action="store_true", help="one JSON object {name: value}")
    s.add_argument("--value-only", "-v", action="store_true", help="print only the values, one a line")
    s = sub.add_parser("set", parents=[common], help="write variables and wait for the result")
    s.add_argument("assignments", nargs="+", metavar="VAR=VALUE",
                   help='e.g. AZ.TARGETPOS=120 or POINTING.TARGET.NAME="M 42"; all in one SET, set '
                        'one after another (a long one completes before the next starts)')
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
        args.timeout = getattr(args, "timeout", None) or (None if args.command == "set" else 60.0)
        args.connect_timeout = 10.0
        conn = open_connection(args)
        try:
            return {"get": cmd_get, "set": cmd_set, "watch": cmd_watch, "tree": cmd_tree}[args.command](conn, args)
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
