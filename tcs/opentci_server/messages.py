"""One frozen dataclass per TPL2 message, named as the protocol names it.

How this works
--------------
Messages are plain immutable data: ``protocol.py`` parses text lines into them and formats
them back into lines; nothing here does I/O or knows the variable tree. Each class's
docstring shows its wire form (protocol doc §2-§5).

Client -> server: :class:`Auth`, :class:`Enc`, :class:`Disconnect`, :class:`Get`,
:class:`Set` (of :class:`Assignment`), :class:`Abort`, and the parse failures
:class:`BadSyntax`, :class:`UnknownCommand`, :class:`BadId`, :class:`AuthSyntaxError`,
:class:`LineTooLong` -- a line that cannot be understood is still a message, so the server
answers it in the one place where it answers everything.

Server -> client: :class:`Greeting`, the ``AUTH`` replies, :class:`DisconnectOk`,
:class:`EncUnsupported`, the ``COMMAND`` lines (acknowledgement and final line), the ``DATA``
lines and :class:`Event`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

from tcs.opentci_server.paths import ObjectRef
from tcs.opentci_server.values import Value

__all__ = [
    # client -> server
    "Auth", "Enc", "Disconnect", "Get", "Assignment", "Set", "Abort",
    "BadSyntax", "UnknownCommand", "BadId", "AuthSyntaxError", "LineTooLong",
    "ClientMessage", "CommandMessage",
    # server -> client
    "Greeting", "AuthOk", "AuthFailed", "AuthError", "AuthUnsupported", "AuthDisabled",
    "DisconnectOk", "EncUnsupported",
    "CommandOk", "CommandError", "CommandComplete", "CommandFailed", "CommandAbortedBy",
    "CommandTimeout", "DataInline", "DataOk", "DataError", "Event",
    "ServerMessage", "EVENT_LEVEL_BITS", "MAX_COMMAND_ID",
]  # fmt: skip

MAX_COMMAND_ID = 4294967295
"""Command ids are 1..2**32-1 (§3); 0 is the id of lines the server originates."""

EVENT_LEVEL_BITS = {"ERROR": 1, "WARN": 2, "INFO": 4, "DEBUG": 8}
"""Bit of each event level in ``SERVER.CONNECTION.EVENTMASK`` (§5)."""


# ============================================================== client -> server


@dataclass(frozen=True, slots=True)
class Auth:
    """``AUTH PLAIN "<user>" "<password>"[ <rlevel> <wlevel>]`` (no command id).

    ``method`` is upper-cased; an unknown method still parses (the server replies
    ``AUTH UNSUPPORTED``). ``rlevel``/``wlevel`` are the optional requested levels.
    """

    method: str
    user: str | None = None
    password: str | None = None
    rlevel: int | None = None
    wlevel: int | None = None


@dataclass(frozen=True, slots=True)
class Enc:
    """``ENC <algorithm>`` (TLS upgrade request; ``algorithm`` upper-cased, may be empty)."""

    algorithm: str


@dataclass(frozen=True, slots=True)
class Disconnect:
    """``DISCONNECT`` (any case, no id); also produced for end of input."""


@dataclass(frozen=True, slots=True)
class Get:
    """``<id> GET <obj>[;<obj>...]``."""

    cmd_id: int
    objects: tuple[ObjectRef, ...]


@dataclass(frozen=True, slots=True)
class Assignment:
    """``<obj>=<value>[,<value>...]``: one object and its values (one per element)."""

    obj: ObjectRef
    values: tuple[Value, ...]


@dataclass(frozen=True, slots=True)
class Set:
    """``<id> SET <obj>=<value>[,<value>...][;<obj>=<value>...]``."""

    cmd_id: int
    assignments: tuple[Assignment, ...]


@dataclass(frozen=True, slots=True)
class Abort:
    """``<id> ABORT <target>``; target 0 aborts all other commands of the connection."""

    cmd_id: int
    target: int


@dataclass(frozen=True, slots=True)
class BadSyntax:
    """A line that does not parse: reply ``<id> COMMAND ERROR SYNTAX`` + ``COMMAND FAILED``.

    ``cmd_id`` is 0 when no valid id could be read; ``detail`` says what is wrong (for logs
    and an optional ``[...]`` message).
    """

    cmd_id: int
    detail: str


@dataclass(frozen=True, slots=True)
class UnknownCommand:
    """A command line with a verb other than GET/SET/ABORT (``verb`` as sent)."""

    cmd_id: int
    verb: str


@dataclass(frozen=True, slots=True)
class BadId:
    """A command id of 0 or above 4294967295 (or signed): ``0 COMMAND ERROR IDRANGE <text>``."""

    text: str


@dataclass(frozen=True, slots=True)
class AuthSyntaxError:
    """A malformed ``AUTH`` line: reply ``AUTH ERROR``."""


@dataclass(frozen=True, slots=True)
class LineTooLong:
    """A line above the connection's maximum length (the rest of it was discarded).

    ``cmd_id`` is the line's id when it began with a valid one, else 0.
    """

    cmd_id: int


ClientMessage = Union[
    Auth, Enc, Disconnect, Get, Set, Abort,
    BadSyntax, UnknownCommand, BadId, AuthSyntaxError, LineTooLong,
]  # fmt: skip
CommandMessage = Union[Get, Set, Abort]


# ============================================================== server -> client


@dataclass(frozen=True, slots=True)
class Greeting:
    """``TPL2 <version> CONN <n> AUTH <methods> ENC <algs> MESSAGE <text>`` (§2).

    Methods and algorithms are comma-separated (chimera's regex), an empty list leaves
    ``AUTH ENC``; there is always a space after ``MESSAGE`` (chimera needs it).
    """

    version: str
    conn: int
    auth_methods: tuple[str, ...]
    encryptions: tuple[str, ...]
    message: str


@dataclass(frozen=True, slots=True)
class AuthOk:
    """``AUTH OK <rlevel> <wlevel>``."""

    rlevel: int
    wlevel: int


@dataclass(frozen=True, slots=True)
class AuthFailed:
    """``AUTH FAILED`` (bad credentials)."""


@dataclass(frozen=True, slots=True)
class AuthError:
    """``AUTH ERROR`` (malformed AUTH line)."""


@dataclass(frozen=True, slots=True)
class AuthUnsupported:
    """``AUTH UNSUPPORTED`` (unknown method)."""


@dataclass(frozen=True, slots=True)
class AuthDisabled:
    """``AUTH DISABLED``."""


@dataclass(frozen=True, slots=True)
class DisconnectOk:
    """``DISCONNECT OK``."""


@dataclass(frozen=True, slots=True)
class EncUnsupported:
    """``ENC UNSUPPORTED`` (no encryption offered)."""


@dataclass(frozen=True, slots=True)
class CommandOk:
    """``<id> COMMAND OK`` (bare: RTS2 compares the tail)."""

    cmd_id: int


@dataclass(frozen=True, slots=True)
class CommandError:
    """``<id> COMMAND ERROR <code>[ <arg>][ [<detail>]]``.

    ``code`` is ``UNAUTHENTICATED``, ``IDBUSY``, ``IDRANGE``, ``SYNTAX``, ``TOOMANY``,
    ``UNKNOWN``, ``DENIED``, ``NOTRUNNING``. ``arg`` is the bare argument of IDBUSY/IDRANGE
    (the offending id: ``0 COMMAND ERROR IDBUSY 5``); ``detail`` a message written in literal
    square brackets (``UNKNOWN [unknown command FOO]``). Use :meth:`idbusy`/:meth:`idrange`.
    """

    cmd_id: int
    code: str
    detail: str | None = None
    arg: str | None = None

    @classmethod
    def idbusy(cls, busy_id: int | str) -> CommandError:
        """``0 COMMAND ERROR IDBUSY <id>``."""
        return cls(0, "IDBUSY", arg=str(busy_id))

    @classmethod
    def idrange(cls, text: str) -> CommandError:
        """``0 COMMAND ERROR IDRANGE <id as sent>``."""
        return cls(0, "IDRANGE", arg=text)


@dataclass(frozen=True, slots=True)
class CommandComplete:
    """``<id> COMMAND COMPLETE``."""

    cmd_id: int


@dataclass(frozen=True, slots=True)
class CommandFailed:
    """``<id> COMMAND FAILED`` (after an ERROR acknowledgement)."""

    cmd_id: int


@dataclass(frozen=True, slots=True)
class CommandAbortedBy:
    """``<id> COMMAND ABORTEDBY <by>``."""

    cmd_id: int
    by: int


@dataclass(frozen=True, slots=True)
class CommandTimeout:
    """``<id> COMMAND TIMEOUT`` (ABORT only)."""

    cmd_id: int


@dataclass(frozen=True, slots=True)
class DataInline:
    """``<id> DATA INLINE <obj>=<value>[,<value>...]``.

    ``obj`` is the object exactly as the client sent it; ``values`` are already-formatted
    wire strings (:func:`tcs.opentci_server.values.format_value`, or an error keyword such as
    ``UNKNOWN`` / ``FAILED 15`` in place of a value).
    """

    cmd_id: int
    obj: str
    values: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class DataOk:
    """``<id> DATA OK <obj>`` (a SET of that object succeeded)."""

    cmd_id: int
    obj: str


@dataclass(frozen=True, slots=True)
class DataError:
    """``<id> DATA ERROR <obj> <error>[,<error>...]`` (one slot per element)."""

    cmd_id: int
    obj: str
    errors: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Event:
    """``<id> EVENT <level> <obj>:<number>[ <text>]`` (§5).

    ``cmd_id`` may be a 64-bit ``(connection << 32) | id``; ``level`` is ERROR, WARN, INFO or
    DEBUG; ``text`` is escaped to printable 7-bit ASCII on the wire.
    """

    cmd_id: int
    level: str
    obj: str
    number: int
    text: str = ""


ServerMessage = Union[
    Greeting, AuthOk, AuthFailed, AuthError, AuthUnsupported, AuthDisabled,
    DisconnectOk, EncUnsupported,
    CommandOk, CommandError, CommandComplete, CommandFailed, CommandAbortedBy, CommandTimeout,
    DataInline, DataOk, DataError, Event,
]  # fmt: skip
