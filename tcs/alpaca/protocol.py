"""The Alpaca wire rules, without I/O: parameters in, a JSON-able reply out.

How it works
------------
The HTTP adapter (:mod:`tcs.alpaca.server`) turns a request into an :class:`AlpacaRequest`
(method, the parameters of the query string for GET or of the form body for PUT) and gets back
either a reply dictionary or a :class:`BadRequest`, which it sends as HTTP 400 with a plain-text
message. Rules of the ASCOM Alpaca API reference (v1):

* ``ClientID`` and ``ClientTransactionID`` are unsigned 32-bit integers; the reply echoes the
  transaction id (0 when absent or not a valid number) and carries a ``ServerTransactionID``
  that increases with every reply of the server.
* GET parameter *names* are case-insensitive; PUT form field names must be spelled as the
  interface spells them (``RightAscension``), and a field spelled otherwise counts as missing.
* A missing parameter, or one that does not parse as its type, is a malformed request (HTTP
  400). A value that parses but is refused (out of range, not now) is a device error: HTTP 200
  with ``ErrorNumber`` and ``ErrorMessage`` (:class:`AscomError`; numbers in :class:`Code`).
* Booleans are ``true``/``false`` in any case; numbers are invariant-culture decimals.

What may touch it: anything (pure functions and small value classes).
"""

from __future__ import annotations

import enum
import itertools
import math
import threading
from dataclasses import dataclass, field
from typing import Any

from tcs.errors import ErrorNumber, RangeRefused, TcsError

UINT32 = 0xFFFFFFFF


class Code(enum.IntEnum):
    """ASCOM error numbers (Alpaca API reference, "Error handling")."""

    OK = 0
    NOT_IMPLEMENTED = 0x400
    INVALID_VALUE = 0x401
    VALUE_NOT_SET = 0x402
    NOT_CONNECTED = 0x407
    INVALID_WHILE_PARKED = 0x408
    INVALID_WHILE_SLAVED = 0x409
    INVALID_OPERATION = 0x40B
    ACTION_NOT_IMPLEMENTED = 0x40C
    OPERATION_CANCELLED = 0x40E
    DRIVER_ERROR = 0x500


class AscomError(Exception):
    """A device error: the reply is HTTP 200 with ``ErrorNumber``/``ErrorMessage``."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = int(code)
        self.message = message


class BadRequest(Exception):
    """A malformed request: HTTP 400 with this plain-text message."""


def not_implemented(what: str) -> AscomError:
    return AscomError(Code.NOT_IMPLEMENTED, f"{what} is not implemented by this device")


def from_tcs_error(exc: TcsError) -> AscomError:
    """The ASCOM error for a refusal of the telescope model: a value outside a limit (software
    limit, horizon, range) is InvalidValue; a state that forbids it now (not powered, not
    referenced, interlock, local mode) is InvalidOperation; hardware trouble is a driver error."""
    number = exc.number
    if isinstance(exc, RangeRefused) or number in (ErrorNumber.SOFTLIMIT, ErrorNumber.LIMIT):
        code = Code.INVALID_VALUE
    elif number in (ErrorNumber.LIBFAIL, ErrorNumber.CONFAIL, ErrorNumber.NOCON, ErrorNumber.TIMEOUT,
                    ErrorNumber.INTERNAL) and exc.keyword is None:
        code = Code.DRIVER_ERROR
    else:   # not now: power, referencing, local mode, weather interlock (1020), a fault
        code = Code.INVALID_OPERATION
    return AscomError(code, exc.message or exc.reply)


class TransactionCounter:
    """``ServerTransactionID``: 1, 2, 3 … for every reply of one server (any thread)."""

    def __init__(self) -> None:
        self._next = itertools.count(1)
        self._lock = threading.Lock()

    def __call__(self) -> int:
        with self._lock:
            return next(self._next) & UINT32 or 1


def _uint32(text: str | None) -> int:
    """A ClientID / ClientTransactionID: 0 when absent or not an unsigned 32-bit number."""
    if text is None:
        return 0
    try:
        value = int(text.strip())
    except ValueError:
        return 0
    return value if 0 <= value <= UINT32 else 0


@dataclass
class AlpacaRequest:
    """One device request: ``method`` is ``GET`` or ``PUT``; ``params`` as received."""

    method: str
    params: dict[str, str]
    _folded: dict[str, str] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._folded = {k.lower(): v for k, v in self.params.items()}

    def raw(self, name: str) -> str | None:
        """The value of parameter ``name``: any case for GET, the exact name for PUT."""
        if self.method == "GET":
            return self._folded.get(name.lower())
        return self.params.get(name)

    @property
    def client_id(self) -> int:
        return _uint32(self.raw("ClientID"))

    @property
    def client_transaction_id(self) -> int:
        return _uint32(self.raw("ClientTransactionID"))

    def text(self, name: str) -> str:
        value = self.raw(name)
        if value is None:
            raise BadRequest(f"missing parameter {name}")
        return value

    def float(self, name: str) -> float:
        text = self.text(name)
        try:
            value = float(text.strip())
        except ValueError:
            raise BadRequest(f"parameter {name}={text!r} is not a number") from None
        if not math.isfinite(value):
            raise BadRequest(f"parameter {name}={text!r} is not a finite number")
        return value

    def int(self, name: str) -> int:
        text = self.text(name)
        try:
            return int(text.strip())
        except ValueError:
            raise BadRequest(f"parameter {name}={text!r} is not an integer") from None

    def bool(self, name: str) -> bool:
        text = self.text(name).strip().lower()
        if text == "true":
            return True
        if text == "false":
            return False
        raise BadRequest(f"parameter {name}={self.text(name)!r} is not true or false")


def reply(request: AlpacaRequest, server_id: int, value: Any = None, *,
          has_value: bool = True, error: AscomError | None = None) -> dict[str, Any]:
    """The JSON body of a device reply (``Value`` only for GET and only without an error)."""
    body: dict[str, Any] = {}
    if error is None and has_value:
        body["Value"] = value
    body["ClientTransactionID"] = request.client_transaction_id
    body["ServerTransactionID"] = server_id
    body["ErrorNumber"] = 0 if error is None else error.code
    body["ErrorMessage"] = "" if error is None else error.message
    return body


__all__ = ["AlpacaRequest", "AscomError", "BadRequest", "Code", "TransactionCounter",
           "from_tcs_error", "not_implemented", "reply"]
