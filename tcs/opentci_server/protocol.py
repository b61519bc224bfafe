"""The TPL2 wire grammar: line framing, parsing into messages, formatting messages into lines.

How this works
--------------
No sockets, no asyncio, no variable tree (the h11 shape). A :class:`Tpl2Connection` is the
server's half of one connection: ``receive(bytes)`` returns the client's messages, parsed in
order; ``send(message)`` returns the bytes to write; ``eof()`` ends the input. Unparseable
input becomes a message too (:class:`BadSyntax`, :class:`BadId`, ...), so this module never
raises on anything a client sends. :class:`Tpl2ClientConnection` is the mirror image for test
clients and tools. :func:`parse_line`, :func:`format_message` and :func:`parse_reply` work on
single lines without a connection.

Framing (protocol doc §1): lines end in ``\\n``, a ``\\r`` before it is dropped; lines that
are empty or blank are ignored (INDI sends one first); bytes are UTF-8, or Latin-1 where they
are not valid UTF-8; a line longer than ``max_line_length`` bytes (not counting the ``\\n``)
becomes one :class:`LineTooLong` and the rest of it is dropped up to the next ``\\n``, so the
buffer never holds more than one maximal line. The result never depends on how the input was
split into chunks.

Client lines (§2, §3)::

    AUTH <method> ["<user>" "<password>" [<rlevel> <wlevel>]]    quoted or bare tokens
    ENC <algorithm>
    DISCONNECT
    <id> GET <obj>[;<obj>...]                                    a trailing ';' is allowed
    <id> SET <obj>=<value>[,<value>...][;<obj>=<value>...]       spaces around = , ; allowed
    <id> ABORT <id>

Words are case-insensitive; ids are decimal with optional leading zeros, 1..4294967295 (0 or
larger -> :class:`BadId`). A value is a quoted string (escapes in ``values.py``), ``NULL``, a
decimal number, or any other bare token (kept as an unquoted STRING; the tree refuses it with
``TYPE`` where a number is needed).

Server lines are formatted by :func:`format_message`, always 7-bit printable ASCII: free text
(greeting message, error detail, event text) and echoed objects are escaped where needed.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterable

from tcs.opentci_server.messages import (
    MAX_COMMAND_ID,
    Abort,
    Assignment,
    Auth,
    AuthDisabled,
    AuthError,
    AuthFailed,
    AuthOk,
    AuthSyntaxError,
    AuthUnsupported,
    BadId,
    BadSyntax,
    ClientMessage,
    CommandAbortedBy,
    CommandComplete,
    CommandError,
    CommandFailed,
    CommandOk,
    CommandTimeout,
    DataError,
    DataInline,
    DataOk,
    Disconnect,
    DisconnectOk,
    Enc,
    EncUnsupported,
    Event,
    Get,
    Greeting,
    LineTooLong,
    ServerMessage,
    Set,
    UnknownCommand,
)
from tcs.opentci_server.paths import PathSyntaxError, parse_object
from tcs.opentci_server.values import (
    Value,
    ValueType,
    classify_bare,
    escape_text,
    format_float,
    quote_string,
    unescape,
)

__all__ = [
    "Tpl2Connection",
    "Tpl2ClientConnection",
    "parse_line",
    "parse_reply",
    "format_message",
    "ReplySyntaxError",
    "DEFAULT_MAX_LINE_LENGTH",
]

log = logging.getLogger(__name__)

DEFAULT_MAX_LINE_LENGTH = 65536

_WS = " \t\r\n\f\v"
_FLAGS = re.ASCII | re.DOTALL

# ============================================================== parsing client lines

_WORD = re.compile(r"(\S+)\s*(.*)\Z", _FLAGS)
_COMMAND = re.compile(r"([0-9]+)(?:\s+(\S+))?(?:\s+(.*))?\Z", _FLAGS)
_SIGNED_ID = re.compile(r"[+-][0-9]+\Z", _FLAGS)
_NUMBER = re.compile(r"[0-9]+\Z", _FLAGS)
_AUTH_TOKEN = re.compile(r'\s*(?:"([^"\\]*(?:\\.[^"\\]*)*)"|([^\s"]+))(?=\s|\Z)', _FLAGS)
_ASSIGN_OBJ = re.compile(r'\s*([^=;"\s]+)\s*=\s*', _FLAGS)
_SET_VALUE = re.compile(r'"([^"\\]*(?:\\.[^"\\]*)*)"|([^,;"\s]+)', _FLAGS)
_AFTER_VALUE = re.compile(r"\s*(?:([,;])\s*|\Z)", _FLAGS)


def _number(text: str) -> int | None:
    """A decimal 1..4294967295 written with any leading zeros, else None (never raises)."""
    t = text.lstrip("0")
    if not t or len(t) > 10:
        return None
    n = int(t)
    return n if n <= MAX_COMMAND_ID else None


def _clip(text: str, n: int = 40) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."


def parse_line(line: str) -> ClientMessage:
    """Parse one client line (without its line end) into a message.

    Parameters
    ----------
    line:
        The decoded line; surrounding whitespace is ignored.

    Returns
    -------
    ClientMessage
        A command or connection message, or a parse-failure message; never raises.
    """
    line = line.strip(_WS)
    if not line:
        return BadSyntax(0, "empty line")
    if "0" <= line[0] <= "9":
        return _parse_command(line)
    m = _WORD.match(line)
    word, rest = m.groups()  # type: ignore[union-attr]
    verb = word.upper() if word.isascii() else word
    if verb == "AUTH":
        return _parse_auth(rest)
    if verb == "DISCONNECT":
        return Disconnect()
    if verb == "ENC":
        return Enc(rest.upper())
    if _SIGNED_ID.match(word):
        return BadId(word)
    return BadSyntax(0, f"expected a command id, AUTH, ENC or DISCONNECT, not {_clip(word)!r}")


def _parse_command(line: str) -> ClientMessage:
    m = _COMMAND.match(line)
    if m is None:
        return BadSyntax(0, f"bad command id in {_clip(line)!r}")
    id_text, verb, args = m.groups()
    cmd_id = _number(id_text)
    if cmd_id is None:
        return BadId(id_text)
    if verb is None:
        return BadSyntax(cmd_id, "command without a verb")
    parser = _VERBS.get(verb.upper() if verb.isascii() else verb)
    if parser is None:
        return UnknownCommand(cmd_id, verb)
    return parser(cmd_id, args)


#: Parsed objects of GET argument texts seen before (a poller sends the same GET over and
#: over). The parse is a pure function of the text and its result immutable, so a hit is
#: exactly what parsing again would give; bounded: past the size nothing more is added.
_GET_OBJECTS: dict[str, tuple] = {}
#: The same for whole received GET lines (bytes as framed): the Get message itself.
_GET_LINES: dict[bytes, "Get"] = {}
_GET_CACHE_SIZE = 4096
_GET_CACHE_TEXT = 8192  # longest argument text kept


def _parse_get(cmd_id: int, args: str | None) -> ClientMessage:
    if not args:
        return BadSyntax(cmd_id, "GET without an object")
    objects = _GET_OBJECTS.get(args)
    if objects is not None:
        return Get(cmd_id, objects)
    items = args.split(";")
    if len(items) > 1 and not items[-1].strip(_WS):
        items.pop()  # a trailing ';'
    try:
        objects = tuple(parse_object(item.strip(_WS)) for item in items)
    except PathSyntaxError as e:
        return BadSyntax(cmd_id, str(e))
    if len(_GET_OBJECTS) < _GET_CACHE_SIZE and len(args) <= _GET_CACHE_TEXT:
        _GET_OBJECTS[args] = objects
    return Get(cmd_id, objects)


def _parse_set(cmd_id: int, args: str | None) -> ClientMessage:
    if not args:
        return BadSyntax(cmd_id, "SET without an assignment")
    assignments = []
    pos, end = 0, len(args)
    while True:
        m = _ASSIGN_OBJ.match(args, pos)
        if m is None:
            return BadSyntax(cmd_id, f"expected <object>=<value> at {_clip(args[pos:])!r}")
        obj_text = m.group(1)
        try:
            obj = parse_object(obj_text)
        except PathSyntaxError as e:
            return BadSyntax(cmd_id, str(e))
        pos = m.end()
        values = []
        while True:
            m = _SET_VALUE.match(args, pos)
            if m is None:
                return BadSyntax(cmd_id, f"expected a value for {_clip(obj_text)}")
            quoted, bare = m.groups()
            if bare is None:
                values.append(Value(ValueType.STRING, unescape(quoted), True))
            else:
                values.append(classify_bare(bare))
            m = _AFTER_VALUE.match(args, m.end())
            if m is None:
                return BadSyntax(cmd_id, f"expected ',' or ';' after a value of {_clip(obj_text)}")
            pos = m.end()
            sep = m.group(1)
            if sep != ",":
                break
        assignments.append(Assignment(obj, tuple(values)))
        if sep is None or pos == end:  # end of line, or a trailing ';'
            return Set(cmd_id, tuple(assignments))


def _parse_abort(cmd_id: int, args: str | None) -> ClientMessage:
    """``ABORT <id>``: 0 (all of this connection), an id of this connection, or another
    connection's extended id ``(conn << 32) | id`` as its events show it (TPL2 §5)."""
    if not args or not _NUMBER.match(args):
        return BadSyntax(cmd_id, "ABORT needs one command id")
    target = 0 if not args.strip("0") else _number(args)
    if target is None:
        target = _extended_id(args)
    if target is None:
        return BadSyntax(cmd_id, f"ABORT of an id out of range: {_clip(args)}")
    return Abort(cmd_id, target)


def _extended_id(text: str) -> int | None:
    """``(conn << 32) | id`` with conn and id ≥ 1, below 2**64, else None."""
    t = text.lstrip("0")
    if len(t) > 20:
        return None
    n = int(t)
    return n if n < 1 << 64 and n & MAX_COMMAND_ID else None


_VERBS: dict[str, Callable[[int, str | None], ClientMessage]] = {
    "GET": _parse_get,
    "SET": _parse_set,
    "ABORT": _parse_abort,
}


def _parse_auth(rest: str) -> ClientMessage:
    m = _WORD.match(rest)
    if m is None:
        return AuthSyntaxError()
    word, rest = m.groups()
    method = word.upper()
    tokens: list[str] = []
    pos, end = 0, len(rest)
    while pos < end and len(tokens) <= 4:
        m = _AUTH_TOKEN.match(rest, pos)
        if m is None:
            break
        quoted, bare = m.groups()
        tokens.append(unescape(quoted) if bare is None else bare)
        pos = m.end()
    complete = pos >= end and len(tokens) <= 4
    if method != "PLAIN":
        # Unsupported method: parse what we can, the reply is AUTH UNSUPPORTED anyway.
        return Auth(method, *tokens[:2])
    if not complete or len(tokens) not in (2, 4):
        return AuthSyntaxError()
    if len(tokens) == 2:
        return Auth(method, tokens[0], tokens[1])
    r, w = tokens[2], tokens[3]
    if not (_NUMBER.match(r) and _NUMBER.match(w) and len(r) < 10 and len(w) < 10):
        return AuthSyntaxError()
    return Auth(method, tokens[0], tokens[1], int(r), int(w))


# ============================================================== formatting


def _text(s: str) -> str:
    """A protocol word or echoed object: kept when printable ASCII, else escaped."""
    if s.isascii() and s.isprintable() and "\\" not in s:
        return s
    return escape_text(s)


def wire_object(text: str) -> str:
    """An object as a reply echoes it (escaped where not printable ASCII)."""
    return _text(text)


def _list(words: tuple[str, ...]) -> str:
    return " " + ",".join(map(_text, words)) if words else ""


def _sent_value(v: Value) -> str:
    if v.quoted:
        return quote_string(str(v.value))
    kind = v.kind
    if kind is ValueType.INT:
        return str(v.value)
    if kind is ValueType.FLOAT:
        return format_float(v.value)  # type: ignore[arg-type]
    if kind is ValueType.NULL:
        return "NULL"
    return str(v.value)


def _format_auth(m: Auth) -> str:
    s = "AUTH " + _text(m.method)
    if m.user is not None:
        s += " " + quote_string(m.user)
        if m.password is not None:
            s += " " + quote_string(m.password)
            if m.rlevel is not None and m.wlevel is not None:
                s += f" {m.rlevel} {m.wlevel}"
    return s


def _format_set(m: Set) -> str:
    return f"{m.cmd_id} SET " + ";".join(
        a.obj.text + "=" + ",".join(map(_sent_value, a.values)) for a in m.assignments
    )


def _format_command_error(m: CommandError) -> str:
    s = f"{m.cmd_id} COMMAND ERROR {_text(m.code)}"
    if m.arg is not None:
        s += " " + _text(m.arg)
    if m.detail is not None:
        s += " [" + escape_text(m.detail) + "]"
    return s


def _format_event(m: Event) -> str:
    s = f"{m.cmd_id} EVENT {_text(m.level)} {_text(m.obj)}:{m.number}"
    return s + " " + escape_text(m.text) if m.text else s


_FORMATTERS: dict[type, Callable[..., str]] = {
    # client -> server
    Auth: _format_auth,
    Enc: lambda m: f"ENC {_text(m.algorithm)}" if m.algorithm else "ENC",
    Disconnect: lambda m: "DISCONNECT",
    Get: lambda m: f"{m.cmd_id} GET " + ";".join(o.text for o in m.objects),
    Set: _format_set,
    Abort: lambda m: f"{m.cmd_id} ABORT {m.target}",
    # server -> client
    Greeting: lambda m: (
        f"TPL2 {_text(m.version)} CONN {m.conn} AUTH{_list(m.auth_methods)}"
        f" ENC{_list(m.encryptions)} MESSAGE {escape_text(m.message)}"
    ),
    AuthOk: lambda m: f"AUTH OK {m.rlevel} {m.wlevel}",
    AuthFailed: lambda m: "AUTH FAILED",
    AuthError: lambda m: "AUTH ERROR",
    AuthUnsupported: lambda m: "AUTH UNSUPPORTED",
    AuthDisabled: lambda m: "AUTH DISABLED",
    DisconnectOk: lambda m: "DISCONNECT OK",
    EncUnsupported: lambda m: "ENC UNSUPPORTED",
    CommandOk: lambda m: f"{m.cmd_id} COMMAND OK",
    CommandError: _format_command_error,
    CommandComplete: lambda m: f"{m.cmd_id} COMMAND COMPLETE",
    CommandFailed: lambda m: f"{m.cmd_id} COMMAND FAILED",
    CommandAbortedBy: lambda m: f"{m.cmd_id} COMMAND ABORTEDBY {m.by}",
    CommandTimeout: lambda m: f"{m.cmd_id} COMMAND TIMEOUT",
    DataInline: lambda m: f"{m.cmd_id} DATA INLINE {_text(m.obj)}={','.join(m.values)}",
    DataOk: lambda m: f"{m.cmd_id} DATA OK {_text(m.obj)}",
    DataError: lambda m: f"{m.cmd_id} DATA ERROR {_text(m.obj)} {','.join(m.errors)}",
    Event: _format_event,
}


def format_message(msg: ServerMessage | ClientMessage) -> str:
    """The wire line of a message, without the line end.

    Server messages give 7-bit printable ASCII (``DataInline.values`` are trusted to be wire
    text already). Client commands format too (for test clients); parse-failure messages
    have no wire form.

    Raises
    ------
    TypeError
        For an object that is no formattable message.
    """
    try:
        formatter = _FORMATTERS[type(msg)]
    except KeyError:
        raise TypeError(f"{type(msg).__name__} has no TPL2 wire form") from None
    return formatter(msg)


# ============================================================== parsing server lines


class ReplySyntaxError(ValueError):
    """A server line that is no TPL2 reply (client side only)."""


_GREETING = re.compile(
    r"TPL2 (\S+) CONN ([0-9]+) AUTH(?: (\S+))? ENC(?: (\S+))? MESSAGE ?(.*)\Z", _FLAGS
)
_AUTH_OK = re.compile(r"AUTH OK (-?[0-9]+) (-?[0-9]+)\Z", _FLAGS)
_REPLY = re.compile(r"([0-9]+) (COMMAND|DATA|EVENT) (.*)\Z", _FLAGS)
_COMMAND_ERROR = re.compile(r"ERROR (\S+)(?: ([^\s\[]\S*))?(?: \[(.*)\])?\Z", _FLAGS)
_ABORTEDBY = re.compile(r"ABORTEDBY ([0-9]+)\Z", _FLAGS)
_EVENT = re.compile(r"(\S+) ([^:\s]*):([0-9]+)(?: (.*))?\Z", _FLAGS)
_WIRE_ITEM = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"|[^,"]*', _FLAGS)

_SIMPLE_REPLIES: dict[str, ServerMessage] = {
    "AUTH FAILED": AuthFailed(),
    "AUTH ERROR": AuthError(),
    "AUTH UNSUPPORTED": AuthUnsupported(),
    "AUTH DISABLED": AuthDisabled(),
    "DISCONNECT OK": DisconnectOk(),
    "ENC UNSUPPORTED": EncUnsupported(),
}
_COMMAND_FINALS: dict[str, type] = {
    "OK": CommandOk,
    "COMPLETE": CommandComplete,
    "FAILED": CommandFailed,
    "TIMEOUT": CommandTimeout,
}


def _split_wire_values(text: str) -> tuple[str, ...]:
    if not text:
        return ()
    items, pos, end = [], 0, len(text)
    while True:
        m = _WIRE_ITEM.match(text, pos)
        items.append(m.group())  # type: ignore[union-attr]
        pos = m.end()  # type: ignore[union-attr]
        if pos == end:
            return tuple(items)
        if text[pos] != ",":
            raise ReplySyntaxError(f"bad value list {text!r}")
        pos += 1


def parse_reply(line: str) -> ServerMessage:
    """Parse one server line (without its line end): the client side of :func:`format_message`.

    Raises
    ------
    ReplySyntaxError
        For a line that is no TPL2 reply.
    """
    simple = _SIMPLE_REPLIES.get(line)
    if simple is not None:
        return simple
    m = _REPLY.match(line)
    if m is not None:
        cmd_id, kind, rest = int(m.group(1)), m.group(2), m.group(3)
        if kind == "COMMAND":
            final = _COMMAND_FINALS.get(rest)
            if final is not None:
                return final(cmd_id)
            if (e := _COMMAND_ERROR.match(rest)) is not None:
                code, arg, detail = e.groups()
                return CommandError(cmd_id, code, unescape(detail) if detail is not None else None, arg)
            if (a := _ABORTEDBY.match(rest)) is not None:
                return CommandAbortedBy(cmd_id, int(a.group(1)))
        elif kind == "DATA":
            word, _, rest = rest.partition(" ")
            if word == "INLINE" and "=" in rest:
                obj, _, values = rest.partition("=")
                return DataInline(cmd_id, obj, _split_wire_values(values))
            if word == "OK" and rest and " " not in rest:
                return DataOk(cmd_id, rest)
            if word == "ERROR":
                obj, _, errors = rest.partition(" ")
                if obj and errors:
                    return DataError(cmd_id, obj, tuple(errors.split(",")))
        else:
            if (ev := _EVENT.match(rest)) is not None:
                level, obj, number, text = ev.groups()
                return Event(cmd_id, level, obj, int(number), unescape(text) if text else "")
        raise ReplySyntaxError(f"bad {kind} line {_clip(line, 80)!r}")
    if (a := _AUTH_OK.match(line)) is not None:
        return AuthOk(int(a.group(1)), int(a.group(2)))
    if (g := _GREETING.match(line)) is not None:
        version, conn, methods, encs, message = g.groups()
        return Greeting(
            version,
            int(conn),
            tuple(methods.split(",")) if methods else (),
            tuple(encs.split(",")) if encs else (),
            unescape(message),
        )
    raise ReplySyntaxError(f"not a TPL2 reply: {_clip(line, 80)!r}")


# ============================================================== framing


class _LineFramer:
    """Splits a byte stream into lines of at most ``max_len`` bytes (see module docstring).

    ``feed`` returns ``(raw, too_long)`` pairs; for an over-long line ``raw`` is its first
    ``max_len`` bytes and the rest of the line is dropped as it arrives.
    """

    __slots__ = ("_buf", "_discarding", "_max")

    def __init__(self, max_len: int):
        if max_len < 1:
            raise ValueError(f"max_line_length must be at least 1, not {max_len}")
        self._buf = bytearray()
        self._discarding = False
        self._max = max_len

    def feed(self, data: bytes) -> list[tuple[bytes, bool]]:
        out: list[tuple[bytes, bool]] = []
        if not isinstance(data, (bytes, bytearray)):
            data = bytes(data)
        start = 0
        if self._discarding:
            i = data.find(b"\n")
            if i < 0:
                return out
            self._discarding = False
            start = i + 1
        elif self._buf:
            i = data.find(b"\n")
            if i < 0:
                self._buf += data
                self._check_overflow(out)
                return out
            self._buf += data[:i]
            self._emit(bytes(self._buf), out)
            self._buf.clear()
            start = i + 1
        find = data.find
        while True:
            i = find(b"\n", start)
            if i < 0:
                break
            self._emit(data[start:i], out)
            start = i + 1
        if start < len(data):
            self._buf += data[start:]
            self._check_overflow(out)
        return out

    def end(self) -> bytes | None:
        """The unterminated last line (never too long), or None."""
        rest = bytes(self._buf) if self._buf and not self._discarding else None
        self._buf.clear()
        self._discarding = False
        return rest

    def _emit(self, line: bytes, out: list[tuple[bytes, bool]]) -> None:
        if len(line) > self._max:
            out.append((line[: self._max], True))
        else:
            out.append((line, False))

    def _check_overflow(self, out: list[tuple[bytes, bool]]) -> None:
        if len(self._buf) > self._max:
            out.append((bytes(self._buf[: self._max]), True))
            self._buf.clear()
            self._discarding = True


def _decode(raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


_LEADING_ID = re.compile(rb"[ \t\r\f\v]*([0-9]+)[ \t]")


class Tpl2Connection:
    """The server's half of one TPL2 connection: bytes in, client messages out, and back.

    Parameters
    ----------
    line_ending:
        What ends each line the server sends: ``b"\\n"`` (default; chimera and pyobs break
        on ``\\r``) or ``b"\\r\\n"`` (RTS2).
    max_line_length:
        The longest client line accepted, in bytes without the ``\\n``.
    """

    def __init__(self, line_ending: bytes = b"\n", max_line_length: int = DEFAULT_MAX_LINE_LENGTH):
        if line_ending not in (b"\n", b"\r\n"):
            raise ValueError(f"line_ending must be b'\\n' or b'\\r\\n', not {line_ending!r}")
        self.line_ending = line_ending
        self.max_line_length = max_line_length
        self._le = line_ending.decode("ascii")
        self._framer = _LineFramer(max_line_length)
        self._last_was_disconnect = False
        self._ended = False

    @property
    def buffered(self) -> int:
        """Bytes of an unfinished line held (never more than ``max_line_length``)."""
        return len(self._framer._buf)

    def receive(self, data: bytes) -> list[ClientMessage]:
        """Feed received bytes; returns the messages of every line completed by them.

        Never raises on any input. Raises RuntimeError after :meth:`eof`.
        """
        if self._ended:
            raise RuntimeError("receive() after eof()")
        out: list[ClientMessage] = []
        for raw, too_long in self._framer.feed(data):
            self._line(raw, too_long, out)
        if out:
            self._last_was_disconnect = type(out[-1]) is Disconnect
        return out

    def eof(self) -> list[ClientMessage]:
        """The input ended: the unterminated last line's message, then :class:`Disconnect`.

        The Disconnect is left out when the last message already was one (pyobs sends a bare
        ``disconnect`` without a line end and closes).
        """
        if self._ended:
            return []
        self._ended = True
        out: list[ClientMessage] = []
        rest = self._framer.end()
        if rest is not None:
            self._line(rest, False, out)
        last = type(out[-1]) is Disconnect if out else self._last_was_disconnect
        if not last:
            out.append(Disconnect())
        return out

    def send(self, msg: ServerMessage) -> bytes:
        """The bytes of one message's line, with the line end (7-bit ASCII)."""
        return (format_message(msg) + self._le).encode("ascii", "backslashreplace")

    def send_all(self, msgs: Iterable[ServerMessage]) -> bytes:
        """The bytes of several lines at once (one write for a whole GET reply)."""
        le = self._le
        return "".join([format_message(m) + le for m in msgs]).encode("ascii", "backslashreplace")

    def get_reply(self, cmd_id: int, items: Iterable[tuple[str, str]]) -> bytes:
        """A whole GET reply in one go: ``COMMAND OK``, one ``DATA INLINE`` per (object as
        echoed — :func:`wire_object` of the object as sent —, wire value), ``COMMAND COMPLETE``:
        the same bytes as :meth:`send_all` of those messages, without building them (the
        server's hot path; the session escapes each object of a GET once, in its plan)."""
        le = self._le
        head = f"{cmd_id} DATA INLINE "
        parts = [f"{cmd_id} COMMAND OK{le}"]
        parts += [f"{head}{wire}={value}{le}" for wire, value in items]
        parts.append(f"{cmd_id} COMMAND COMPLETE{le}")
        return "".join(parts).encode("ascii", "backslashreplace")

    def _line(self, raw: bytes, too_long: bool, out: list[ClientMessage]) -> None:
        if too_long:
            m = _LEADING_ID.match(raw)
            cmd_id = _number(m.group(1).decode("ascii")) if m else None
            out.append(LineTooLong(cmd_id or 0))
            return
        known = _GET_LINES.get(raw)
        if known is not None:  # a poller's GET seen before: the message parsing gives (immutable)
            out.append(known)
            return
        text = _decode(raw).strip(_WS)
        if not text:
            return
        try:
            msg = parse_line(text)
            out.append(msg)
            if type(msg) is Get and len(_GET_LINES) < _GET_CACHE_SIZE and len(raw) <= _GET_CACHE_TEXT:
                _GET_LINES[raw] = msg
        except Exception:  # pragma: no cover - a parser bug must not kill the connection
            log.exception("TPL2 parser failed on %r", text[:200])
            out.append(BadSyntax(0, "internal parser error"))


class Tpl2ClientConnection:
    """The client's half (for tests and tools): server bytes in, replies out; commands back.

    Lines may end in ``\\n`` or ``\\r\\n``. :meth:`receive` raises :class:`ReplySyntaxError`
    for a line that is no TPL2 reply.
    """

    def __init__(self, max_line_length: int = 1 << 20):
        self._framer = _LineFramer(max_line_length)

    def receive(self, data: bytes) -> list[ServerMessage]:
        """Feed received bytes; returns the replies of every line completed by them."""
        out = []
        for raw, too_long in self._framer.feed(data):
            if too_long:
                raise ReplySyntaxError(f"server line longer than {self._framer._max} bytes")
            line = raw[:-1] if raw.endswith(b"\r") else raw
            out.append(parse_reply(_decode(line)))
        return out

    def send(self, msg: ClientMessage) -> bytes:
        """The bytes of one client line (``\\n``-terminated)."""
        return (format_message(msg) + "\n").encode("utf-8", "surrogatepass")
