"""The INDI XML protocol (version 1.7), pure: no sockets, no model — what the TPL2 core is to TPL2.

How it works
------------
INDI is a stream of XML elements with no document around them. :class:`StreamParser` feeds the
bytes of one connection, as they come, to an expat pull parser inside a synthetic root element
and hands out each complete top-level element (``getProperties``, ``newNumberVector`` …) as an
:class:`xml.etree.ElementTree.Element`. A DOCTYPE or an entity declaration (the only ways to
make expat expand text without bound) ends the connection with :class:`ProtocolError`, and so
does one element larger than ``MAX_ELEMENT`` bytes or malformed XML.

:class:`Vector` is one property: its device, name, type (Number, Switch, Text, Light), label,
group, permission, state (Idle, Ok, Busy, Alert), switch rule, and elements (name, label,
value; numbers also format, min, max, step; values are written in full precision, the format
is the client's display). It renders itself as ``def<Type>Vector`` (the
definition a client gets for ``getProperties``) and ``set<Type>Vector`` (an update), escaping
attribute and text values. :func:`parse_new` reads a client's ``new<Type>Vector`` into
``(device, name, {element: value})`` with numbers as floats (decimal or sexagesimal, as INDI
allows) and switches as booleans.

What may touch it
-----------------
Anything: pure functions and small objects, no I/O; :mod:`tcs.indi.server` uses them.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field
from xml.etree import ElementTree as ET
from xml.sax.saxutils import escape, quoteattr

VERSION = "1.7"
#: bytes one top-level element may take (a BLOB-less client never comes near it)
MAX_ELEMENT = 1 << 20
TYPES = ("Number", "Switch", "Text", "Light")
STATES = ("Idle", "Ok", "Busy", "Alert")
PERMS = ("ro", "wo", "rw")
RULES = ("OneOfMany", "AtMostOne", "AnyOfMany")


class ProtocolError(Exception):
    """The client's stream cannot be read on: the connection is closed with this reason."""


class StreamParser:
    """Top-level elements out of an INDI byte stream, fed in pieces of any size."""

    def __init__(self, max_element: int = MAX_ELEMENT):
        self._parser = ET.XMLPullParser(events=("start", "end"))
        self._parser.feed(b"<indi>")
        self._root: ET.Element | None = None
        self._depth = 0        # 1 inside the synthetic root, 2 inside a top-level element
        self._pending = 0      # bytes fed since the last complete top-level element
        self._max = max_element

    def feed(self, data: bytes) -> list[ET.Element]:
        upper = data.upper()
        if b"<!DOCTYPE" in upper or b"<!ENTITY" in upper:
            raise ProtocolError("DOCTYPE and ENTITY declarations are not INDI")
        self._pending += len(data)
        out = []
        try:
            self._parser.feed(data)
            for event, element in self._parser.read_events():
                if event == "start":
                    self._depth += 1
                    if self._root is None:
                        self._root = element
                    continue
                self._depth -= 1
                if self._depth == 1:          # a top-level element is complete
                    out.append(element)
                    self._root.remove(element)  # the root keeps nothing
                    self._pending = 0
        except ET.ParseError as exc:
            raise ProtocolError(f"malformed XML: {exc}") from None
        if self._depth > 1 and self._pending > self._max:
            raise ProtocolError(f"an element of more than {self._max} bytes")
        return out


def timestamp(t: float | None = None) -> str:
    """INDI's timestamp: UTC, ISO 8601 without a zone, to the second's tenths."""
    t = time.time() if t is None else t
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 10)}"


def parse_number(text: str) -> float:
    """A number as INDI sends it: decimal, or sexagesimal ``d:m:s`` / ``d m s`` / ``d;m;s``."""
    s = text.strip()
    if not s:
        raise ValueError("an empty number")
    parts = re.split(r"[:; ]+", s)
    if len(parts) == 1:
        value = float(s)
    else:
        if len(parts) > 3:
            raise ValueError(f"{text!r} is not a number")
        sign = -1.0 if parts[0].lstrip().startswith("-") else 1.0
        nums = [abs(float(parts[0]))] + [float(p) for p in parts[1:]]
        if any(n < 0 for n in nums[1:]):
            raise ValueError(f"{text!r} is not a number")
        value = sign * sum(n / 60.0 ** i for i, n in enumerate(nums))
    if not math.isfinite(value):
        raise ValueError(f"{text!r} is not a finite number")
    return value


@dataclass
class Element:
    name: str
    label: str = ""
    value: object = None
    # numbers
    format: str = "%g"
    min: float = 0.0
    max: float = 0.0
    step: float = 0.0


@dataclass
class Vector:
    """One INDI property (see the module docstring)."""

    device: str
    name: str
    type: str
    elements: list[Element]
    label: str = ""
    group: str = "Main Control"
    perm: str = "rw"
    state: str = "Idle"
    rule: str = "OneOfMany"
    timeout: float = 60.0
    message: str | None = None
    _by_name: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        assert self.type in TYPES and self.state in STATES and self.perm in PERMS
        self._by_name = {e.name: e for e in self.elements}

    def element(self, name: str) -> Element | None:
        return self._by_name.get(name)

    def values(self) -> dict:
        return {e.name: e.value for e in self.elements}

    def _value_text(self, e: Element) -> str:
        if self.type == "Number":  # full precision, as libindi writes (the format is for display)
            v = float(e.value) if e.value is not None else math.nan
            return repr(v) if math.isfinite(v) else "nan"
        if self.type == "Switch":
            return "On" if e.value else "Off"
        if self.type == "Light":
            return e.value if e.value in STATES else "Idle"
        return "" if e.value is None else str(e.value)

    def _head(self, verb: str, *, define: bool) -> list[str]:
        attrs = [f"device={quoteattr(self.device)}", f"name={quoteattr(self.name)}",
                 f"state={quoteattr(self.state)}", f"timestamp={quoteattr(timestamp())}"]
        if define:
            attrs[2:2] = [f"label={quoteattr(self.label or self.name)}", f"group={quoteattr(self.group)}"]
            if self.type != "Light":
                attrs.append(f"perm={quoteattr(self.perm)}")
            if self.type == "Switch":
                attrs.append(f"rule={quoteattr(self.rule)}")
            if self.type != "Light":
                attrs.append(f"timeout={quoteattr(format(self.timeout, 'g'))}")
        if self.message:
            attrs.append(f"message={quoteattr(self.message)}")
        return [f"<{verb}{self.type}Vector " + " ".join(attrs) + ">"]

    def define_xml(self) -> str:
        out = self._head("def", define=True)
        kind = self.type
        for e in self.elements:
            attrs = f"name={quoteattr(e.name)} label={quoteattr(e.label or e.name)}"
            if kind == "Number":
                attrs += (f" format={quoteattr(e.format)} min={quoteattr(format(e.min, 'g'))}"
                          f" max={quoteattr(format(e.max, 'g'))} step={quoteattr(format(e.step, 'g'))}")
            out.append(f"  <def{kind} {attrs}>{escape(self._value_text(e))}</def{kind}>")
        out.append(f"</def{kind}Vector>")
        return "\n".join(out) + "\n"

    def set_xml(self) -> str:
        out = self._head("set", define=False)
        kind = self.type
        one = "one" + kind
        for e in self.elements:
            out.append(f"  <{one} name={quoteattr(e.name)}>{escape(self._value_text(e))}</{one}>")
        out.append(f"</set{kind}Vector>")
        return "\n".join(out) + "\n"


def message_xml(device: str | None, text: str) -> str:
    dev = f" device={quoteattr(device)}" if device else ""
    return f"<message{dev} timestamp={quoteattr(timestamp())} message={quoteattr(text)}/>\n"


def parse_new(element: ET.Element) -> tuple[str, str, str, dict]:
    """``(type, device, name, {element: value})`` of a client's ``new<Type>Vector``.

    Raises
    ------
    ValueError
        not a new…Vector, a missing device or name, an unreadable number or switch.
    """
    tag = element.tag
    m = re.fullmatch(r"new(Number|Switch|Text|BLOB)Vector", tag)
    if not m:
        raise ValueError(f"<{tag}> is not a new…Vector")
    kind = m.group(1)
    device, name = element.get("device"), element.get("name")
    if not device or not name:
        raise ValueError(f"<{tag}> without device or name")
    values: dict = {}
    for child in element:
        key = child.get("name")
        if not key or child.tag != "one" + kind:
            continue
        text = (child.text or "").strip()
        if kind == "Number":
            values[key] = parse_number(text)
        elif kind == "Switch":
            if text not in ("On", "Off"):
                raise ValueError(f"{device}.{name}.{key}: a switch is On or Off, not {text!r}")
            values[key] = text == "On"
        else:
            values[key] = child.text or ""
    return kind, device, name, values
