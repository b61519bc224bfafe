"""Reading an EDS/DCF file as real ones come: any encoding, duplicate entries, a BOM.

``canopen.import_od`` opens the file with the locale's encoding and a strict ini parser: an EDS
written in Windows-1252 (a "°" or "µ" in a ParameterName), with a byte-order mark, or with a
section or key written twice — all found in vendors' files — does not load. :func:`eds_source`
gives canopen the same file as text it can read: decoded as UTF-8 (with or without BOM), else
as Windows-1252/Latin-1 (which always decodes), a repeated section merged into its first
occurrence and a repeated key within a section dropped (the first one counts, as most tools
read it).

:func:`compact_entries` tells what canopen drops of ``CompactSubObj`` arrays.

Shared by the TCS's drivers (:func:`tcs.drivers.eds.read_od`) and the simulated drives
(:mod:`tcs.sim.cia402_drive`), which must read a file the same way; imports nothing of either.
"""

from __future__ import annotations

import io
import os
import re
from pathlib import Path

_SECTION = re.compile(r"^\s*\[(.+?)\]\s*$")


def decode(data: bytes) -> str:
    """The text of an EDS file: UTF-8 (BOM removed), else Windows-1252, else Latin-1."""
    for encoding in ("utf-8-sig", "cp1252"):
        try:
            return data.decode(encoding)
        except UnicodeDecodeError:
            continue
    return data.decode("latin-1")


def clean(text: str) -> str:
    """``text`` with each section once (repeats merged into the first) and each key once per
    section (the first kept); comments and everything else unchanged."""
    order: list[str] = [""]
    names: dict[str, str] = {"": ""}          # upper-case name -> the first spelling
    bodies: dict[str, list[str]] = {"": []}
    keys: dict[str, set[str]] = {"": set()}
    current = ""
    for line in text.splitlines():
        m = _SECTION.match(line)
        if m:
            current = m.group(1).strip().upper()
            if current not in bodies:
                order.append(current)
                names[current], bodies[current], keys[current] = m.group(1).strip(), [], set()
            continue
        stripped = line.strip()
        if current and stripped and not stripped.startswith(";") and "=" in stripped:
            key = stripped.split("=", 1)[0].strip().lower()
            if key in keys[current]:
                continue
            keys[current].add(key)
        bodies[current].append(line)
    out: list[str] = []
    for name in order:
        if name:
            out.append(f"[{names[name]}]")
        out.extend(bodies[name])
    return "\n".join(out) + "\n"


def eds_source(path: str | os.PathLike) -> io.StringIO:
    """A file-like object of the cleaned text of ``path`` for ``canopen.import_od`` (its
    ``name`` keeps the file's suffix, which tells canopen the format)."""
    p = Path(path)
    source = io.StringIO(clean(decode(p.read_bytes())))
    source.name = str(p)
    return source


def compact_entries(path: str | os.PathLike) -> dict[int, int]:
    """{index: n} of the objects written with ``CompactSubObj=n`` (canopen keeps only their
    sub-index 1: a PDO mapping written so would seem to take one object)."""
    compact: dict[int, int] = {}
    section = None
    try:
        text = decode(Path(path).read_bytes())
    except OSError:
        return compact
    for line in text.splitlines():
        m = _SECTION.match(line)
        if m:
            name = m.group(1).strip()
            section = int(name, 16) if re.fullmatch(r"[0-9A-Fa-f]{4}", name) else None
        elif section is not None and "=" in line:
            key, _, value = line.partition("=")
            if key.strip().lower() == "compactsubobj":
                try:
                    n = int(value.split(";")[0].strip(), 0)
                except ValueError:
                    continue
                if n > 0:
                    compact[section] = n
    return compact


def expand_compact(od, compact: dict[int, int]) -> None:
    """Give each array of ``compact`` (index -> n) its sub-indices 2..n in ``od`` (a canopen
    object dictionary), made from sub-index 1 as canopen's own array access makes them, so a
    ``CompactSubObj`` mapping has its n entries for every reader; ``od.tcs_compact`` keeps the
    table."""
    for index, n in compact.items():
        obj = od.get(index) if hasattr(od, "get") else None
        subs = getattr(obj, "subindices", None)
        if subs is None or 1 not in subs or not hasattr(obj, "add_member"):
            continue
        for sub in range(2, min(n, 254) + 1):
            if sub not in subs:
                obj.add_member(obj[sub])
    od.tcs_compact = dict(compact)
