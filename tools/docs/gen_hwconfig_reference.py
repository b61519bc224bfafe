"""Generate the hardware-file reference (Markdown) from the configuration schema.

    python3 tools/docs/gen_hwconfig_reference.py > hwconfig.md

How it works: :class:`tcs.config.hwconfig.HwConfig` and the section dataclasses it names
(``tcs/config/*.py``) *are* the schema — every key is a dataclass field whose annotation is its
type and whose ``setting(...)`` metadata holds the default, the range and the one-line
description. This script walks that tree (nested tables, ``[name.<key>]`` tables of tables,
``[[arrays]]`` of tables) and prints one Markdown table per TOML table. Nothing is written by
hand: a key added to a section appears in the next documentation build
(``mkdocs build``, whose hook ``tools/docs/mkdocs_hooks.py`` calls :func:`render`).

Only the documentation build and its test use this module.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import sys
import types
import typing
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tcs.config.hwconfig import HwConfig  # noqa: E402

MISSING = dataclasses.MISSING
_SCALARS = {int: "integer", float: "number", bool: "boolean", str: "string"}


def md_text(text: str) -> str:
    """Plain text safe inside a Markdown table cell (no HTML, emphasis, links or cell breaks).
    ``double backticks`` of the docstrings become code spans."""
    parts = re.split(r"(``[^`]+``|`[^`]+`)", text)
    out = []
    for i, part in enumerate(parts):
        if i % 2:
            code = part.strip("`")
            out.append(f"`{code}`" if "|" not in code else md_escape(code))
        else:
            out.append(md_escape(part))
    return "".join(out)


def md_escape(text: str) -> str:
    text = re.sub(r"([\\`*_\[\]|])", r"\\\1", text)
    return text.replace("<", "&lt;").replace(">", "&gt;").replace("\n", " ")


def _optional(tp: Any) -> tuple[Any, bool]:
    """(inner type, whether ``None`` is allowed)."""
    if get_origin(tp) in (typing.Union, types.UnionType):
        args = get_args(tp)
        inner = [a for a in args if a is not type(None)]
        return (inner[0] if len(inner) == 1 else typing.Union[tuple(inner)]), type(None) in args
    return tp, False


def type_text(tp: Any) -> str:
    """A reader's name of a field type: ``integer``, ``one of "LF", "CRLF"``, ``array of strings``."""
    tp, _ = _optional(tp)
    origin = get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(toml_value(a) for a in get_args(tp))
    if origin is list:
        (item,) = get_args(tp)
        return f"array of {_plural(item)}"
    if origin is dict:
        _, item = get_args(tp)
        return f"table: name → {type_text(item)}"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(type_text(a) for a in get_args(tp))
    if dataclasses.is_dataclass(tp):
        return "table"
    return _SCALARS.get(tp, getattr(tp, "__name__", str(tp)))


def _plural(tp: Any) -> str:
    tp, _ = _optional(tp)
    if get_origin(tp) is Literal:
        return "values " + type_text(tp)
    if dataclasses.is_dataclass(tp):
        return "tables"
    return {int: "integers", float: "numbers", bool: "booleans", str: "strings"}.get(tp, type_text(tp))


def toml_value(value: Any) -> str:
    """A default as it would be written in the file."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, int) and value == 0xFFFFFFFF:
        return "0xFFFFFFFF"
    return repr(value)


def default_text(field: dataclasses.Field, optional: bool) -> str:
    if field.default is not MISSING:
        value = field.default
    elif field.default_factory is not MISSING:
        value = field.default_factory()
    else:
        return "**required**"
    if value is None:
        return "absent" if optional else "—"
    if dataclasses.is_dataclass(value):
        return "(its keys' defaults)"
    return "`" + toml_value(value) + "`"


def range_text(meta: dict) -> str:
    lo, hi = meta.get("min"), meta.get("max")
    if lo is None and hi is None:
        return ""
    if lo is None:
        return f"≤ {toml_value(hi)}"
    if hi is None:
        return f"≥ {toml_value(lo)}"
    return f"{toml_value(lo)} … {toml_value(hi)}"


@dataclasses.dataclass
class Table:
    """One TOML table of the reference: its header, where it is defined, its rows."""

    header: str               # e.g. "[drives.<name>]"
    path: str                 # key prefix, e.g. "drives.<name>"
    cls: Any
    doc: str = ""
    rows: list[tuple[str, str, str, str, str]] = dataclasses.field(default_factory=list)


def _class_doc(cls: Any) -> str:
    doc = inspect.getdoc(cls) or ""
    # dataclasses invent a signature docstring when there is none
    return "" if doc.startswith(cls.__name__ + "(") else doc


def walk(cls: Any, path: str, header: str, doc: str, out: list[Table]) -> None:
    """Append the table of ``cls`` and, after it, the tables nested in it."""
    table = Table(header, path, cls, doc or _class_doc(cls))
    out.append(table)
    nested: list[tuple[Any, str, str, str]] = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp, optional = _optional(hints[f.name])
        key = f"{path}.{f.name}" if path else f.name
        meta = dict(f.metadata)
        text = meta.get("doc", "")
        origin = get_origin(tp)
        if dataclasses.is_dataclass(tp):
            nested.append((tp, key, f"[{key}]", _join(text, "optional table: absent = none" if optional else "")))
            required = f.default is MISSING and f.default_factory is MISSING
            table.rows.append((key, "table", "**required**" if required else
                               "absent" if optional else "(its keys' defaults)", "",
                               _join(md_text(text), _link(f"[{key}]", key))))
            continue
        if origin is dict and dataclasses.is_dataclass(get_args(tp)[1]):
            item = get_args(tp)[1]
            name = _placeholder(f.name)
            nested.append((item, f"{key}.<{name}>", f"[{key}.<{name}>]", text))
            table.rows.append((key, "tables", "none", "",
                               _join(md_text(text), _link(f"[{key}.<{name}>]", f"{key}.<{name}>"))))
            continue
        if origin is list and dataclasses.is_dataclass(get_args(tp)[0]):
            item = get_args(tp)[0]
            nested.append((item, f"{key}[<n>]", f"[[{key}]]", text))
            table.rows.append((key, "array of tables", "none", "",
                               _join(md_text(text), _link(f"[[{key}]]", f"{key}[<n>]"))))
            continue
        table.rows.append((key, md_escape(type_text(hints[f.name])), default_text(f, optional),
                           range_text(meta), md_text(text)))
    for item, key, head, text in nested:
        walk(item, key, head, text, out)


def anchor(path: str) -> str:
    """The id of a table's heading: ``drives.<name>.homing`` -> ``drives-name-homing``."""
    return re.sub(r"[^a-z0-9]+", "-", path.lower()).strip("-") or "top-level"


def _link(header: str, path: str) -> str:
    return f"see [`{header}`](#{anchor(path)})"


def _join(*parts: str) -> str:
    return "; ".join(p for p in parts if p)


def _placeholder(field_name: str) -> str:
    """The name placeholder of a table of tables: ``drives`` -> ``name``, ``points`` -> ``point``."""
    return {"points": "point", "axes": "axis", "sensors": "point", "switches": "point"}.get(field_name, "name")


def tables() -> list[Table]:
    """Every table of the hardware file, top-level keys first, in the schema's order."""
    out: list[Table] = []
    walk(HwConfig, "", "top level", "", out)
    return out


def _source(cls: Any) -> str:
    try:
        return Path(inspect.getsourcefile(cls)).resolve().relative_to(ROOT).as_posix()
    except (TypeError, ValueError):
        return cls.__module__


def render() -> str:
    lines = [
        "# Hardware-file reference",
        "",
        "<!-- Generated by tools/docs/gen_hwconfig_reference.py from tcs/config/: do not edit. -->",
        "",
        "Every key of the hardware file (TOML), generated from the configuration schema "
        "(`tcs/config/`) at each documentation build: the type, the default (**required**: "
        "the file must give it; *absent*: leaving it out means \"none\"), the allowed range "
        "and what it does. `<name>` stands for a name you choose (`[drives.az]`), `<n>` for the "
        "position in an array of tables (`[[users]]`: `users[0]`, `users[1]` …).",
        "",
        "The loader checks every key against this schema and reports each problem as "
        "`file: key.path: problem` (also unknown keys); rules across keys (min below max, "
        "unique node ids, a drive named by an axis exists, each drive against its EDS) are "
        "checked at the same time. Validate a file with "
        "`tcs-server --check-config FILE` (status 0 valid, 2 not). The guide to the file "
        "is in [Configuration](../configuration.md).",
        "",
    ]
    for table in tables():
        title = f"`{table.header}`" if table.path else "Top-level tables"
        lines += [f"## {title} {{#{anchor(table.path)}}}", ""]
        lines += [f"Defined in `{_source(table.cls)}` (`{table.cls.__name__}`).", ""]
        if table.doc:
            lines += [md_text(" ".join(table.doc.split())), ""]
        lines += ["| key | type | default | range | meaning |", "|---|---|---|---|---|"]
        for key, tp, default, rng, text in table.rows:
            lines.append(f"| `{key}` | {tp} | {default} | {rng} | {text} |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    sys.stdout.write(render())


if __name__ == "__main__":
    main()
