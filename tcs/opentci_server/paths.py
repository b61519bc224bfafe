"""TPL2 object paths: ``MODULE[.SUB...].VARIABLE[!PROPERTY]`` parsed into immutable parts.

Grammar (protocol doc §3)::

    object   := [ part ( "." part )* ] [ "!" name ]      -- not empty; "!NAME" is the root's
    part     := ( name | "<" digits ">" ) [ "[" ranges "]" ] [ "{" slice "}" ]
    slice    := digits ":" digits                         -- characters a..b of a STRING (§4.1.2)
    ranges   := range ( "," range )*                      -- spaces allowed around items
    range    := digits [ "-" digits ]                     -- inclusive, never decreasing
    name     := ( letter | digit | "_" | "-" )+           -- case-insensitive

``<n>`` is numeric access to the member with fixed index n (``GET <5>.<3>!NAME``). Names are
upper-cased in the parts, while :attr:`ObjectRef.text` keeps the object exactly as the client
wrote it: replies echo it. Numbers have at most 9 digits. Semantic checks (does it exist,
is the index inside the array, at most one multi-element index per path) belong to the tree.
A string slice ``X{a:b}`` never makes the line a syntax error: a slice that is malformed,
decreasing or not on the last part is recorded in :attr:`ObjectRef.slice_error` and fails
that object only.

:func:`parse_object` is pure and memoised in a bounded LRU cache (4096 texts of at most 200
characters): status polls repeat the same objects, so the common case costs one lookup.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache

__all__ = ["PathPart", "ObjectRef", "PathSyntaxError", "parse_object"]


class PathSyntaxError(ValueError):
    """A malformed object path; the command gets ``COMMAND ERROR SYNTAX``."""


@dataclass(frozen=True, slots=True)
class PathPart:
    """One component of an object path.

    Attributes
    ----------
    name:
        The upper-cased name, or ``None`` for numeric access.
    number:
        The member index for numeric access ``<n>``, else ``None``.
    index:
        ``None`` without brackets; else the selected element ranges, inclusive, in the
        client's order: ``[3]`` -> ``((3, 3),)``, ``[0,2-4]`` -> ``((0, 0), (2, 4))``.
    """

    name: str | None
    number: int | None = None
    index: tuple[tuple[int, int], ...] | None = None

    @property
    def count(self) -> int:
        """How many elements the index selects (1 without an index)."""
        if self.index is None:
            return 1
        return sum(hi - lo + 1 for lo, hi in self.index)

    @property
    def multi(self) -> bool:
        """True when the index may select several elements (a range or a list)."""
        idx = self.index
        return idx is not None and (len(idx) > 1 or idx[0][0] != idx[0][1])

    def elements(self) -> Iterator[int]:
        """The selected element numbers in order (check :attr:`count` before iterating)."""
        if self.index is None:
            return
        for lo, hi in self.index:
            yield from range(lo, hi + 1)


@dataclass(frozen=True, slots=True)
class ObjectRef:
    """An object as named in a GET or SET.

    Attributes
    ----------
    text:
        Exactly as the client wrote it (replies echo it).
    parts:
        The path components; empty for a root property (``!MEMBERS``).
    prop:
        The upper-cased property name after ``!``, or ``None``.
    slice:
        ``(a, b)`` of a string slice ``X{a:b}``: characters a to b inclusive, 0-based; b is
        ``None`` for "to the end" (``X{a:}``).
    slice_error:
        The error keyword of a slice that cannot be applied (malformed, decreasing or not on
        the last part: ``DIMENSION``), else ``None``.
    """

    text: str
    parts: tuple[PathPart, ...]
    prop: str | None = None
    slice: tuple[int, int | None] | None = None
    slice_error: str | None = None

    @property
    def multi_count(self) -> int:
        """How many parts carry a multi-element index (more than one is ``INVALID``)."""
        return sum(1 for p in self.parts if p.multi)

    def __str__(self) -> str:
        return self.text


_SIMPLE = re.compile(r"[A-Za-z0-9_-]+(?:\.[A-Za-z0-9_-]+)*(?:![A-Za-z0-9_-]+)?\Z", re.ASCII)
_PART = re.compile(r"(?:([A-Za-z0-9_-]+)|<([0-9]{1,9})>)(?:\[([^\]]*)\])?(?:\{([^}]*)\})?", re.ASCII)
# TPL2 §4.1.2: X{a:b}, characters a to b inclusive; an omitted a is the string's start, an
# omitted b its end ({:2}, {4:}, {:}); a start past the end reads "".
_SLICE = re.compile(r"\s*([0-9]{1,9})?\s*:\s*([0-9]{1,9})?\s*\Z", re.ASCII)
_PROP = re.compile(r"!([A-Za-z0-9_-]+)\Z", re.ASCII)
_RANGE = re.compile(r"\s*([0-9]{1,9})\s*(?:-\s*([0-9]{1,9})\s*)?\Z", re.ASCII)


def _parse_index(text: str, where: str) -> tuple[tuple[int, int], ...]:
    ranges = []
    for item in text.split(","):
        m = _RANGE.match(item)
        if m is None:
            raise PathSyntaxError(f"bad index [{text}] in {where}")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        if hi < lo:
            raise PathSyntaxError(f"decreasing range {lo}-{hi} in {where}")
        ranges.append((lo, hi))
    return tuple(ranges)


def _parse_object(text: str) -> ObjectRef:
    if _SIMPLE.match(text):
        path, bang, prop = text.partition("!")
        parts = tuple(PathPart(n) for n in path.upper().split(".")) if path else ()
        return ObjectRef(text, parts, prop.upper() if bang else None)
    if not text:
        raise PathSyntaxError("empty object name")
    parts: list[PathPart] = []
    pos, end = 0, len(text)
    slice_text: str | None = None
    slice_error: str | None = None
    if text[0] != "!":
        while True:
            m = _PART.match(text, pos)
            if m is None:
                raise PathSyntaxError(f"bad object name {text!r} at position {pos + 1}")
            name, number, index, sliced = m.groups()
            if slice_text is not None:  # a slice before the last part
                slice_error = "DIMENSION"
            slice_text = sliced
            parts.append(
                PathPart(
                    name.upper() if name is not None else None,
                    int(number) if number is not None else None,
                    _parse_index(index, text) if index is not None else None,
                )
            )
            pos = m.end()
            if pos == end or text[pos] == "!":
                break
            if text[pos] != ".":
                raise PathSyntaxError(f"bad object name {text!r} at position {pos + 1}")
            pos += 1
    prop = None
    if pos < end:
        m = _PROP.match(text, pos)
        if m is None:
            raise PathSyntaxError(f"bad property in {text!r}")
        prop = m.group(1).upper()
    slice = None
    if slice_text is not None and slice_error is None:
        s = _SLICE.match(slice_text)
        first = int(s.group(1)) if s is not None and s.group(1) is not None else 0
        last = int(s.group(2)) if s is not None and s.group(2) is not None else None
        if s is None or (last is not None and first > last):
            slice_error = "DIMENSION"
        else:
            slice = (first, last)
    return ObjectRef(text, tuple(parts), prop, slice, slice_error)


_parse_cached = lru_cache(maxsize=4096)(_parse_object)
_CACHE_TEXT_LIMIT = 200  # longer texts are parsed each time, so the cache stays small


def parse_object(text: str) -> ObjectRef:
    """Parse one object path (see the module docstring for the grammar).

    Parameters
    ----------
    text:
        The object without surrounding whitespace.

    Returns
    -------
    ObjectRef

    Raises
    ------
    PathSyntaxError
        For an empty or malformed path, a bad index or a decreasing range (``[5-2]``).
    """
    if len(text) <= _CACHE_TEXT_LIMIT:
        return _parse_cached(text)
    return _parse_object(text)


parse_object.cache_clear = _parse_cached.cache_clear  # type: ignore[attr-defined]
