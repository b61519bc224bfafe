"""TPL2 values: the four types, their wire form, string escapes and weak typing.

How this works
--------------
A TPL2 value on the wire is one of (protocol doc §6):

=========  =======  ======================================================================
type       ``!TYPE``  wire form
=========  =======  ======================================================================
NULL       0        ``NULL``, unquoted
INT        1        plain decimal, never a point: ``42``, ``-7``
FLOAT      2        decimal with a point, never an exponent: ``1.0``, ``-0.0000001``
STRING     3        always double-quoted, 7-bit ASCII, C-like escapes: ``"a\\"b\\n"``
=========  =======  ======================================================================

The parser (``protocol.py``) turns each value of a ``SET`` into a :class:`Value` that keeps
*how the client wrote it* (kind and whether it was quoted); :func:`convert` then applies the
weak typing the clients in the field need (pyobs quotes every value: ``SET X="1"``) once the
variable tree knows the target type. :func:`format_value` produces the wire form of a value
read from the tree; :class:`ErrorValue` stands in place of a value in ``DATA INLINE`` when a
read failed (``UNKNOWN``, ``FAILED 15``).

Strings are escaped byte by byte after UTF-8 encoding, so any Unicode text survives the 7-bit
channel: bytes 32..126 other than ``"`` and ``\\`` stand as they are, ``\\a \\b \\t \\n \\v
\\f \\r \\" \\\\`` are named, every other byte is a three-digit octal escape ``\\ooo`` (three
digits always, so a following digit can never be read as part of it). The unescaper accepts
every escape of §6: the named ones, ``\\0``, ``\\o``/``\\oo``/``\\ooo`` octal and ``\\xh``/
``\\xhh`` hex; an unknown escape ``\\q`` stands for ``q``. The bytes are decoded as UTF-8, or
as Latin-1 when they are not valid UTF-8 (Python 2 clients send Latin-1).

Everything here is pure and thread-safe; the tree and the protocol layer both use it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from decimal import Decimal
from enum import IntEnum

from tcs.errors import TypeRefused

__all__ = [
    "ValueType",
    "Value",
    "ErrorValue",
    "ValueTypeError",
    "convert",
    "format_value",
    "format_float",
    "quote_string",
    "escape_text",
    "ascii_text",
    "unescape",
    "classify_bare",
    "NULL_VALUE",
]


class ValueType(IntEnum):
    """The TPL2 value types; the numbers are what ``!TYPE`` reads (§6)."""

    NULL = 0
    INT = 1
    FLOAT = 2
    STRING = 3


@dataclass(frozen=True, slots=True)
class Value:
    """One value as the client sent it in a ``SET``.

    Attributes
    ----------
    kind:
        ``INT`` / ``FLOAT`` for unquoted numbers, ``NULL`` for the bare word ``NULL`` (any
        case), ``STRING`` for quoted text and for any other bare token (lenient: ``SET X=abc``).
    value:
        ``int``, ``float`` (an overflowing literal such as ``1e999`` gives ``inf``, refused by
        :func:`convert`), ``str`` or ``None``.
    quoted:
        True when the client wrote the value in double quotes (then ``kind`` is ``STRING``).
    """

    kind: ValueType
    value: int | float | str | None
    quoted: bool = False


NULL_VALUE = Value(ValueType.NULL, None, False)


@dataclass(frozen=True, slots=True)
class ErrorValue:
    """An error keyword in place of a value in ``DATA INLINE`` (§4), formatted unquoted.

    ``keyword`` is the whole text: ``"UNKNOWN"``, ``"INVALID"``, ``"FAILED 15"``.
    """

    keyword: str

    @classmethod
    def failed(cls, number: int) -> ErrorValue:
        """``FAILED <number>`` for an action that failed with an Appendix-B number."""
        return cls(f"FAILED {int(number)}")

    def __str__(self) -> str:
        return self.keyword


class ValueTypeError(TypeRefused):
    """A value cannot be given to a variable of the requested type; replies ``TYPE``."""


# --------------------------------------------------------------------------- numbers

# Python's int() refuses more than 4300 digits (sys.int_info.str_digits_check_threshold);
# anything longer is no integer a client means, and must never raise outside this module.
_MAX_INT_DIGITS = 4000

# Decimal literals only (no underscores, nan, inf or hex, all of which float() would take).
_INT_TEXT = re.compile(r"[+-]?[0-9]+\Z", re.ASCII)
_FLOAT_TEXT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z", re.ASCII)


def classify_bare(token: str) -> Value:
    """Classify an unquoted ``SET`` token: ``NULL``, an INT, a FLOAT, or a bare STRING.

    Parameters
    ----------
    token:
        A non-empty token without quotes, commas, semicolons or whitespace.

    Returns
    -------
    Value
        With ``quoted=False``. Integers longer than 4000 digits are kept as bare strings
        (they are no value any variable accepts; :func:`convert` refuses them with ``TYPE``).
    """
    if _INT_TEXT.match(token):
        if len(token) <= _MAX_INT_DIGITS:
            return Value(ValueType.INT, int(token), False)
        return Value(ValueType.STRING, token, False)
    if _FLOAT_TEXT.match(token):
        return Value(ValueType.FLOAT, float(token), False)
    if len(token) == 4 and token.upper() == "NULL":
        return NULL_VALUE
    return Value(ValueType.STRING, token, False)


def _number_from_text(text: str) -> int | float | None:
    """Parse the text of a quoted number (weak typing); None when it is no number."""
    text = text.strip()
    if _INT_TEXT.match(text):
        return int(text) if len(text) <= _MAX_INT_DIGITS else None
    if _FLOAT_TEXT.match(text):
        return float(text)
    return None


def convert(value: Value, target: ValueType) -> int | float | str | None:
    """Give a client's value to a variable of type ``target`` (TPL2 weak typing, §3).

    Rules
    -----
    * ``NULL`` gives ``None`` whatever the target (the tree decides whether that is allowed).
    * Target ``INT``: an INT as is; a finite FLOAT only when integral (``1.0`` -> 1); a STRING
      (quoted or bare) whose text, stripped of surrounding whitespace, is a decimal integer
      (``"1"``, ``" 007 "``, ``"-3"``) or an integral decimal float (``"2.0"``, ``"1e3"``).
    * Target ``FLOAT``: an INT or FLOAT as a float; a STRING whose stripped text is a decimal
      number (``"2.5"``, ``" -1e-5 "``). ``nan``/``inf``, hexadecimal and underscores are no
      numbers; an infinite result (``1e999``) is refused.
    * Target ``STRING``: a STRING as is; an INT as its decimal text; a FLOAT as its wire text
      (:func:`format_float`, ``1.0``).
    * Target ``NULL`` accepts only ``NULL``.

    Raises
    ------
    ValueTypeError
        (a :class:`tcs.errors.TypeRefused`, reply ``TYPE``) for anything else.
    """
    kind, v = value.kind, value.value
    if kind is ValueType.NULL:
        return None
    if target is ValueType.INT:
        if kind is ValueType.STRING:
            v = _number_from_text(v)  # type: ignore[arg-type]
        if type(v) is int:
            return v
        if isinstance(v, float) and math.isfinite(v) and v.is_integer():
            return int(v)
    elif target is ValueType.FLOAT:
        if kind is ValueType.STRING:
            v = _number_from_text(v)  # type: ignore[arg-type]
        if isinstance(v, (int, float)):
            try:
                f = float(v)
            except OverflowError:
                f = math.inf
            if math.isfinite(f):
                return f
    elif target is ValueType.STRING:
        if kind is ValueType.STRING:
            return v
        if kind is ValueType.INT:
            return str(v)
        if kind is ValueType.FLOAT and math.isfinite(v):  # type: ignore[arg-type]
            return format_float(v)  # type: ignore[arg-type]
    shown = repr(value.value)
    if len(shown) > 40:
        shown = shown[:37] + "..."
    raise ValueTypeError(f"cannot give {shown} to a variable of type {target.name}")


# --------------------------------------------------------------------------- formatting


_ASCII = str.maketrans({
    "°": "deg", "²": "^2", "³": "^3", "…": "...", "−": "-", "–": "-", "—": "-", "·": "*",
    "×": "x", "±": "+/-", "µ": "u", "μ": "u", "≤": "<=", "≥": ">=", "≠": "!=", "≈": "~",
    "→": "->", "←": "<-", "↔": "<->", "″": '"', "′": "'", "‘": "'", "’": "'", "“": '"', "”": '"',
    "§": "S", "Δ": "d", "δ": "d", "σ": "sigma", "φ": "phi", "Σ": "sum", "↑": "^", "↓": "v",
})


def ascii_text(text: str) -> str:
    """Text the server itself writes (descriptions, event texts, units, status comments) in
    7-bit ASCII: ``°`` becomes ``deg``, ``²`` ``^2``, ``…`` ``...``, ``−`` ``-`` (protocol doc §1:
    clients compare and parse these texts; escapes like ``\\302\\260`` are unreadable). Other
    non-ASCII characters are left to the string escapes."""
    return text if text.isascii() else text.translate(_ASCII)


def format_float(x: float) -> str:
    """Wire form of a FLOAT: always a decimal point, never an exponent; NaN/inf -> ``NULL``.

    The digits are the shortest that round-trip (``repr``), written out positionally
    (``1e-07`` -> ``0.0000001``, ``1e+20`` -> ``100000000000000000000.0``). Negative zero is
    written ``0.0`` (clients compare the text).
    """
    r = repr(float(x))
    if "e" not in r:
        if r[0] == "-" and r == "-0.0":
            return "0.0"
        if r[-1] == "n" or r[-1] == "f":  # nan, inf, -inf
            return "NULL"
        return r
    text = format(Decimal(r), "f")
    return text if "." in text else text + ".0"


def format_value(value: object, vtype: ValueType | None = None) -> str:
    """Wire form of one value read from the tree (§6).

    Parameters
    ----------
    value:
        ``None``, ``bool``, ``int``, ``float``, ``str`` or an :class:`ErrorValue` (formatted
        as its keyword, whatever ``vtype``). Objects with ``__index__`` (numpy integers) count
        as ints.
    vtype:
        The variable's type. ``None`` infers it from the Python type (``bool`` -> INT).
        ``INT`` with a float value rounds to the nearest integer; ``FLOAT`` with an int writes
        the exact integer plus ``.0``; ``STRING`` writes ``str(value)`` quoted; ``NULL``
        always gives ``NULL``.

    Returns
    -------
    str
        7-bit ASCII text: ``NULL``, ``42``, ``1.0``, ``"text"``.
    """
    if value is None:
        return "NULL"
    if vtype is None:
        t = type(value)
        if t is float:
            return format_float(value)  # type: ignore[arg-type]
        if t is int:
            return str(value)
        if t is str:
            return quote_string(value)  # type: ignore[arg-type]
        if t is bool:
            return "1" if value else "0"
        if isinstance(value, ErrorValue):
            return value.keyword
        if isinstance(value, float):
            return format_float(value)
        if isinstance(value, str):
            return quote_string(value)
        if hasattr(value, "__index__"):
            return str(value.__index__())  # type: ignore[attr-defined]
        if hasattr(value, "__float__"):
            return format_float(float(value))  # type: ignore[arg-type]
        raise TypeError(f"no TPL2 wire form for {type(value).__name__} {value!r}")
    if isinstance(value, ErrorValue):
        return value.keyword
    if vtype is ValueType.FLOAT:
        if isinstance(value, float):
            return format_float(value)
        if hasattr(value, "__index__"):
            return f"{value.__index__()}.0"  # type: ignore[attr-defined]
        return format_float(float(value))  # type: ignore[arg-type]
    if vtype is ValueType.INT:
        if hasattr(value, "__index__"):
            return str(value.__index__())  # type: ignore[attr-defined]
        f = float(value)  # type: ignore[arg-type]
        return str(round(f)) if math.isfinite(f) else "NULL"
    if vtype is ValueType.STRING:
        return quote_string(value if isinstance(value, str) else str(value))
    return "NULL"


# --------------------------------------------------------------------------- escapes

_NAMED = {7: "\\a", 8: "\\b", 9: "\\t", 10: "\\n", 11: "\\v", 12: "\\f", 13: "\\r"}


def _make_table(escape_quote: bool) -> dict[int, str]:
    # Maps the code points 0..255 of the latin-1 view of UTF-8 bytes to their escapes.
    table: dict[int, str] = {}
    for b in range(256):
        if 32 <= b <= 126 and b != 0x5C and not (escape_quote and b == 0x22):
            continue
        table[b] = _NAMED.get(b) or f"\\{b:03o}"
    table[0x5C] = "\\\\"
    if escape_quote:
        table[0x22] = '\\"'
    return table


_STRING_TABLE = _make_table(escape_quote=True)
_TEXT_TABLE = _make_table(escape_quote=False)


def quote_string(s: str) -> str:
    """The wire form of a STRING: double quotes around the escaped text (7-bit ASCII)."""
    if s.isascii() and s.isprintable() and '"' not in s and "\\" not in s:
        return f'"{s}"'
    return '"' + s.encode("utf-8", "surrogatepass").decode("latin-1").translate(_STRING_TABLE) + '"'


def escape_text(s: str) -> str:
    """Free text (event text, greeting message, error detail) as printable 7-bit ASCII.

    Same escapes as strings, except that ``"`` stays as it is. ``unescape`` reverses it.
    """
    if s.isascii() and s.isprintable() and "\\" not in s:
        return s
    return s.encode("utf-8", "surrogatepass").decode("latin-1").translate(_TEXT_TABLE)


_ESCAPE = re.compile(r"\\(?:([0-3][0-7]{0,2}|[4-7][0-7]?)|x([0-9A-Fa-f]{1,2})|(.))", re.DOTALL)
_NAMED_BYTES = {
    "a": 7, "b": 8, "t": 9, "n": 10, "v": 11, "f": 12, "r": 13, "e": 27,
    "\\": 0x5C, '"': 0x22, "'": 0x27, "?": 0x3F,
}  # fmt: skip


def unescape(s: str) -> str:
    """Undo the escapes of a quoted string's inside (or of escaped free text).

    Every escape of §6 is understood (see the module docstring). A lone trailing backslash
    stands for itself. Never raises.
    """
    if "\\" not in s:
        return s
    out = bytearray()
    pos = 0
    for m in _ESCAPE.finditer(s):
        if m.start() > pos:
            out += s[pos : m.start()].encode("utf-8", "surrogatepass")
        octal, hexa, other = m.groups()
        if octal is not None:
            out.append(int(octal, 8))
        elif hexa is not None:
            out.append(int(hexa, 16))
        else:
            b = _NAMED_BYTES.get(other)  # type: ignore[arg-type]
            if b is not None:
                out.append(b)
            else:
                out += other.encode("utf-8", "surrogatepass")  # type: ignore[union-attr]
        pos = m.end()
    out += s[pos:].encode("utf-8", "surrogatepass")
    try:
        return out.decode("utf-8", "surrogatepass")
    except UnicodeDecodeError:
        return out.decode("latin-1")
