"""Typed, declarative validation of TOML tables into frozen dataclasses.

A configuration section is a frozen dataclass whose field annotations are the schema:
``int``, ``float``, ``bool``, ``str``, ``Literal[...]``, ``list[T]``, ``dict[str, T]``, another
section dataclass, and ``T | None`` (the key may be absent). Ranges and documentation go in
the field metadata through :func:`setting`::

    @dataclass(frozen=True)
    class ServerSection:
        port: int = setting(65432, min=1, max=65535, doc="TCP port of the TPL2 server")

:func:`build` walks a parsed TOML table against such a class and collects **every** problem as
a :class:`~tcs.errors.ConfigError` with the file, the dotted key path and what is wrong
(unknown key, wrong type, out of range, missing), instead of stopping at the first. A section
may define ``check(self) -> list[tuple[str, str]]`` for rules across fields (duplicate node ids,
min < max); each returned pair is (sub-key, problem).

Only the configuration package uses this module; sections live in ``tcs/config/sections*.py``.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Literal, get_args, get_origin

from tcs.errors import ConfigError

MISSING = dataclasses.MISSING


def setting(default: Any = MISSING, *, min: float | None = None, max: float | None = None,
            doc: str = "", factory: Any = MISSING) -> Any:
    """Declare a configuration field with an optional range and a one-line description."""
    meta = {"min": min, "max": max, "doc": doc}
    if factory is not MISSING:
        return dataclasses.field(default_factory=factory, metadata=meta)
    if isinstance(default, (list, dict)):
        value = default
        return dataclasses.field(default_factory=lambda: type(value)(value), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _type_name(tp: Any) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in get_args(tp))
    if origin in (list, dict):
        return "an array" if origin is list else "a table"
    if dataclasses.is_dataclass(tp):
        return "a table"
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(
        tp, getattr(tp, "__name__", str(tp)))


def _join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


class _Builder:
    def __init__(self, file: str):
        self.file = file
        self.errors: list[ConfigError] = []

    def fail(self, path: str, problem: str) -> None:
        self.errors.append(ConfigError(self.file, path, problem))

    def value(self, tp: Any, data: Any, path: str, meta: dict | None = None) -> Any:
        origin = get_origin(tp)
        if origin in (typing.Union, types.UnionType):
            inner = [a for a in get_args(tp) if a is not type(None)]
            return self.value(inner[0] if len(inner) == 1 else inner, data, path, meta)
        if origin is Literal:
            if data not in get_args(tp):
                self.fail(path, f"must be {_type_name(tp)}, not {data!r}")
                return None
            return data
        if origin is list:
            if not isinstance(data, list):
                self.fail(path, f"must be an array, not {type(data).__name__}")
                return None
            (item_tp,) = get_args(tp)
            return tuple(self.value(item_tp, item, _join(path, i)) for i, item in enumerate(data))
        if origin is dict:
            if not isinstance(data, dict):
                self.fail(path, f"must be a table, not {type(data).__name__}")
                return None
            _, item_tp = get_args(tp)
            return {k: self.value(item_tp, v, _join(path, k)) for k, v in data.items()}
        if dataclasses.is_dataclass(tp):
            return self.section(tp, data, path)
        return self.scalar(tp, data, path, meta or {})

    def scalar(self, tp: Any, data: Any, path: str, meta: dict) -> Any:
        ok = {
            bool: isinstance(data, bool),
            int: isinstance(data, int) and not isinstance(data, bool),
            float: isinstance(data, (int, float)) and not isinstance(data, bool),
            str: isinstance(data, str),
        }.get(tp)
        if ok is None:  # pragma: no cover - schema bug, not a user error
            raise TypeError(f"unsupported configuration type {tp!r} at {path}")
        if not ok:
            self.fail(path, f"must be {_type_name(tp)}, not {type(data).__name__} {data!r}")
            return None
        if tp is float:
            data = float(data)
        lo, hi = meta.get("min"), meta.get("max")
        if lo is not None and data < lo or hi is not None and data > hi:
            rng = f"{'' if lo is None else lo} … {'' if hi is None else hi}"
            self.fail(path, f"{data!r} is out of range ({rng})")
            return None
        return data

    def section(self, cls: Any, data: Any, path: str) -> Any:
        if not isinstance(data, dict):
            self.fail(path, f"must be a table, not {type(data).__name__}")
            return None
        hints = typing.get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
        kwargs: dict[str, Any] = {}
        before = len(self.errors)
        for key in data:
            if key not in fields:
                known = ", ".join(sorted(fields)) or "none"
                self.fail(_join(path, key), f"unknown key (known keys here: {known})")
        for name, f in fields.items():
            sub = _join(path, name)
            if name in data:
                kwargs[name] = self.value(hints[name], data[name], sub, dict(f.metadata))
            elif f.default is MISSING and f.default_factory is MISSING:
                self.fail(sub, "missing")
        if len(self.errors) > before:
            return None
        obj = cls(**kwargs)
        check = getattr(obj, "check", None)
        if check is not None:
            for key, problem in check():
                self.fail(_join(path, key) if key else path, problem)
        return obj


def build(cls: Any, data: dict, file: str, path: str = "") -> tuple[Any, list[ConfigError]]:
    """Validate ``data`` against section class ``cls``; return (instance or None, errors)."""
    builder = _Builder(file)
    obj = builder.section(cls, data, path)
    return (obj if not builder.errors else None), builder.errors


def describe(cls: Any, prefix: str = "") -> list[tuple[str, str, Any, str]]:
    """List (key path, type, default, doc) of every setting of ``cls``, for the documentation."""
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        path = _join(prefix, f.name)
        default = f.default if f.default is not MISSING else (
            f.default_factory() if f.default_factory is not MISSING else "(required)")
        if dataclasses.is_dataclass(tp):
            rows.extend(describe(tp, path))
        else:
            rows.append((path, _type_name(tp), default, f.metadata.get("doc", "")))
    return rows
