"""The typed TPL2 variable tree: declaration helpers, the built tree, lookup, reads and writes.

How it works
------------
The OpenTCI tree is *declared* once (``tcs/opentci_server/opentci/``) with the helpers
:func:`var`, :func:`sysvar`, :func:`var_array`, :func:`module` and :func:`module_array`. A
declaration names, for every variable, its type, access levels, range and how it reads and
writes the **domain object** the module is bound to (an attribute/method name, or a callable).
:meth:`Tree.build` walks the declaration against the telescope model: each module's ``bind``
picks its domain object from the parent's; a module whose object is ``None`` (an array whose
list is empty) is not configured and simply does not exist. Member numbers (``!INDEX`` and
numeric access ``<n>``) are the positions among the members that exist, in declaration order.
An element of a module array whose object is ``None`` (a port with no hardware) still gets every
declared member (TPL2 §8.3: all elements have the same substructure); its variables answer
their declared ``absent`` value (``VERSION`` 0) or ``FAILED 4``, reads and writes alike.
The elements of a module array whose members are all variables (``SERVER.CLIENT[]``: one per
connection slot, hundreds) are built on first use (:class:`_LazyElements`): building a variable
node reads nothing from its object, so an element built late is the one an eager build makes,
and a service starts without thousands of nodes no client may ever ask for.

Lookup validates every index against its array *before* expanding a range, and takes a limit
on the number of objects one reference may select (the server's per-command budget). In a
multi-element selection an element that lacks the member asked for becomes an error in its
own slot (``Target.error``) instead of failing the whole object; :meth:`Tree.check_write_each`
does the same for writes. A variable's ``WLEVEL`` may be a callable of its object (writable on
some parts only); ``RLEVEL`` −1 makes it write-only. String values and descriptions are sent
as 7-bit ASCII (``°`` -> ``deg``, see :func:`~tcs.opentci_server.values.ascii_text`).

Reads are synchronous and fast (the spec asks ~5 ms); a write calls the domain setter, which
validates at once (raising :class:`~tcs.errors.TcsError` subclasses) and either finishes or
returns an awaitable for a long-running action. The server awaits that in the command's task.

Access levels: lower number = more privilege. A client may read a variable when its read
level ≤ the variable's ``RLEVEL`` and write it when its write level ≤ ``WLEVEL``; ``WLEVEL``
−1 means nobody writes it (read-only).

Only the TPL2 server (``server.py``) and the declaration use this module.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

from tcs.errors import (AccessDenied, ErrorNumber, RangeRefused, RequestRefused, TcsError, TypeRefused,
                        UnknownObject)
from tcs.opentci_server.paths import ObjectRef
from tcs.opentci_server.values import Value, ValueType, ascii_text, convert, format_float
from tcs.opentci_server.values import format_value as _format_any

log = logging.getLogger(__name__)

# Object classes (!CLASS), protocol doc §7.
ROOT, MODULE, MODULEARR, VARIABLE, VARIABLEARR, SYSVAR, SYSVARARR = 1001, 1002, 1003, 1006, 1007, 2006, 2007

#: Default levels: everybody reads; observers (level ≤ 3) operate; configuration needs level ≤ 1.
READ_ALL, OPERATE, CONFIGURE = 9, 3, 1
NOBODY = -1


def allowed(conn_level: int, level: int) -> bool:
    """May a connection at ``conn_level`` read (write) an object of ``level``? ``READ_ALL`` is
    "no restriction" (TPL2 §9): any login, also one that asked for levels above 9."""
    return level != NOBODY and (level >= READ_ALL or conn_level <= level)

INT, FLOAT, STRING = ValueType.INT, ValueType.FLOAT, ValueType.STRING

Getter = str | Callable[[Any], Any] | None


# ----------------------------------------------------------------------------- declaration


@dataclass(frozen=True)
class VarSpec:
    name: str
    type: ValueType
    get: Getter
    set: Getter
    min: float | Callable[[Any], float | None] | None
    max: float | Callable[[Any], float | None] | None
    init: Any
    rlevel: int
    wlevel: int | Callable[[Any], int]  # a callable of the domain object: writable on some objects only
    info: str
    per_connection: bool = False
    long: bool = False
    count: int | Callable[[Any], int] | None = None  # variable arrays only
    absent: Any = None  # value on an element of a module array with no hardware (None: FAILED 4)


@dataclass(frozen=True)
class ModuleSpec:
    name: str
    members: tuple
    info: str
    bind: Getter
    array: bool = False


def var(name: str, type: ValueType, *, get: Getter = None, set: Getter = None, min=None, max=None,
        init=None, info: str = "", rlevel: int = READ_ALL, wlevel: int | None = None,
        long: bool = False, absent: Any = None) -> VarSpec:
    """Declare a variable.

    ``get``: attribute or zero-argument method name on the domain object, or ``f(obj)``.
    ``set``: method name called ``obj.method(value)``, or ``f(obj, value)``; it may return an
    awaitable for a long-running action (``long=True`` documents that). Without ``set`` the
    variable is read-only (``WLEVEL`` −1); with ``rlevel=NOBODY`` it is write-only (a GET is
    ``DENIED``). ``min``/``max`` may be callables of the object. ``absent``: what the variable
    reads on an element of a module array that has no hardware (default ``FAILED 4``, nocon).
    """
    if wlevel is None:
        wlevel = OPERATE if set is not None else NOBODY
    return VarSpec(name, type, get, set, min, max, init, rlevel, wlevel, info, long=long, absent=absent)


def sysvar(name: str, type: ValueType, *, get: Getter = None, set: Getter = None, min=None, max=None,
           init=None, info: str = "", rlevel: int = READ_ALL, wlevel: int | None = None) -> VarSpec:
    """Declare a per-connection variable: ``get(conn)`` / ``set(conn, value)`` see the caller's connection."""
    if wlevel is None:
        wlevel = READ_ALL if set is not None else NOBODY
    return VarSpec(name, type, get, set, min, max, init, rlevel, wlevel, info, per_connection=True)


def var_array(name: str, type: ValueType, *, count: int | Callable[[Any], int], get: Getter,
              info: str = "", rlevel: int = READ_ALL, min=None, max=None) -> VarSpec:
    """Declare a read-only variable array; ``get`` returns a sequence of ``count`` values."""
    return VarSpec(name, type, get, None, min, max, None, rlevel, NOBODY, info, count=count)


def module(name: str, *members, info: str = "", bind: Getter = None) -> ModuleSpec:
    """Declare a module; ``bind`` picks its domain object from the parent's (None = absent)."""
    return ModuleSpec(name, tuple(members), info, bind)


def module_array(name: str, *members, info: str = "", bind: Getter = None) -> ModuleSpec:
    """Declare a module array; ``bind`` returns the list of element objects (empty = absent)."""
    return ModuleSpec(name, tuple(members), info, bind, array=True)


def _call(how: Getter, obj: Any, *args):
    if callable(how):
        return how(obj, *args)
    attr = getattr(obj, how)
    if args or callable(attr):
        return attr(*args)
    return attr


# ----------------------------------------------------------------------------- built tree


@dataclass(eq=False)
class Node:
    name: str
    index: int
    info: str
    parent: "Node | None"

    cls_code = 0

    @property
    def path(self) -> str:
        parts = []
        node: Node | None = self
        while node is not None and node.parent is not None:
            parts.append(node.name)
            node = node.parent
        return ".".join(reversed(parts))

    def object_count(self) -> int:
        return 1


@dataclass(eq=False)
class ModuleNode(Node):
    obj: Any = None
    members: list[Node] = field(default_factory=list)
    by_name: dict[str, Node] = field(default_factory=dict)

    @property
    def cls_code(self):  # type: ignore[override]
        return ROOT if self.parent is None else MODULE

    def add(self, node: Node) -> None:
        self.members.append(node)
        self.by_name[node.name] = node

    def object_count(self) -> int:
        return 1 + sum(m.object_count() for m in self.members)


@dataclass(eq=False)
class ArrayNode(Node):
    elements: Sequence[ModuleNode] = field(default_factory=list)
    cls_code = MODULEARR

    def object_count(self) -> int:
        if isinstance(self.elements, _LazyElements):  # without building them: 1 + one per member
            return 1 + len(self.elements) * (1 + len(self.elements.spec.members))
        return 1 + sum(e.object_count() for e in self.elements)


class _LazyElements(SequenceABC):
    """The elements of a module array whose members are all variables, each built (and kept)
    the first time it is asked for; ``len`` needs none of them."""

    __slots__ = ("_array", "spec", "_objs", "_built")

    def __init__(self, array: ArrayNode, spec: ModuleSpec, objs: list):
        self._array, self.spec, self._objs = array, spec, objs
        self._built: list[ModuleNode | None] = [None] * len(objs)

    def __len__(self) -> int:
        return len(self._objs)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self._objs)))]
        element = self._built[i]  # IndexError past the end, like a list
        if element is None:
            element = self._built[i] = _element(self._array, self.spec, i % len(self._objs), self._objs[i])
        return element


#: The reply of a variable of a module-array element that has no hardware (nocon, App. B 4).
ABSENT_REPLY = "FAILED 4"


@dataclass(eq=False)
class VarNode(Node):
    spec: VarSpec = None  # type: ignore[assignment]
    obj: Any = None
    fast: Callable[[], str] | None = None  # plain variable: reads and formats its value
    absent: bool = False  # on a module-array element with no hardware

    def __post_init__(self) -> None:
        if self.absent:
            reply = ABSENT_REPLY if self.spec.absent is None else format_value(self.spec.absent, self.spec.type)
            self.fast = lambda: reply
        else:
            self.fast = _fast_reader(self.spec, self.obj)

    @property
    def cls_code(self):  # type: ignore[override]
        array = self.spec.count is not None
        if self.spec.per_connection:
            return SYSVARARR if array else SYSVAR
        return VARIABLEARR if array else VARIABLE

    @property
    def count(self) -> int | None:
        c = self.spec.count
        if c is not None and self.absent:
            return 0
        return c(self.obj) if callable(c) else c

    @property
    def wlevel(self) -> int:
        """The write level on this node's object (a declared callable is asked; −1 nobody)."""
        w = self.spec.wlevel
        if callable(w):  # (no hardware to ask: the operation level; a write answers FAILED 4)
            return OPERATE if self.absent else int(w(self.obj))
        return w

    def limit(self, which: str) -> float | None:
        value = getattr(self.spec, which)
        if callable(value):
            return None if self.absent else value(self.obj)
        return value


@dataclass(frozen=True, slots=True)
class Target:
    """One resolved object: a node, and for arrays the selected element (None = the whole).

    ``error``: in a multi-element selection, the error keyword of this one slot (an element
    that lacks the member asked for); the other slots are answered normally.
    """

    node: Node
    element: int | None = None
    error: str | None = None


class _WholeRefused(RequestRefused):
    """Refuses the whole object even inside a multi-element selection."""


class Tree:
    """The built variable tree of one telescope. Immutable after :meth:`build`."""

    def __init__(self, root: ModuleNode):
        self.root = root
        self._cache: dict[tuple, list[Target]] = {}
        #: The TPL2 sessions' GET plans (tcs.opentci_server.session._get_plan): lookups only.
        self.get_plans: dict[int, tuple] = {}

    @classmethod
    def build(cls, members: Sequence[ModuleSpec | VarSpec], obj: Any, info: str = "") -> "Tree":
        root = ModuleNode("", 0, info, None, obj)
        _build_members(root, members, obj)
        return cls(root)

    # -- lookup ------------------------------------------------------------------------------

    def resolve(self, ref: ObjectRef, limit: int | None = None) -> list[Target]:
        """The objects ``ref`` names (several when one index selects several elements).

        Every index is checked against the array it selects from *before* the selection is
        expanded, so a range such as ``[0-999999999]`` costs nothing.

        Parameters
        ----------
        ref:
            The parsed object.
        limit:
            The most objects the reference may select (the caller's remaining budget, see
            ``[server] max_objects``); None: no limit.

        Raises ``UnknownObject`` (no such member), ``RequestRefused`` with keyword ``INVALID``
        (two multi-selections, an index on a scalar, an array used without index inside a
        path) or ``DIMENSION`` (an index out of range, or more objects than ``limit``).
        """
        key = ref.text  # the exact text: cheaper to hash than the parsed parts
        cached = self._cache.get(key)
        if cached is None:
            cached = self._resolve(ref, limit)
            if len(self._cache) < 8192 and len(cached) <= 64:  # small selections only
                self._cache[key] = cached
        if limit is not None and len(cached) > limit:
            raise _too_many(ref, len(cached), limit)
        return cached

    def _resolve(self, ref: ObjectRef, limit: int | None = None) -> list[Target]:
        current: list[Target] = [Target(self.root)]
        multi = False
        last = len(ref.parts) - 1
        for i, part in enumerate(ref.parts):
            nxt: list[Target] = []
            for t in current:
                if t.error is not None:
                    nxt.append(t)
                    continue
                try:
                    _step(ref, part, i == last, t, nxt, limit, multi)
                except _WholeRefused:
                    raise
                except RequestRefused as exc:
                    if not multi:  # a single object: the error is the object's
                        raise
                    nxt.append(Target(t.node, t.element, exc.reply))  # this element's slot only
            multi = multi or part.multi
            current = nxt
        return current

    def plain_reader(self, ref: ObjectRef) -> tuple[Callable[[], str], int] | None:
        """``(reader, rlevel)`` when ``ref`` names one plain variable that :meth:`read` answers
        by its fast reader (no property, no slice, no element, no error), else None. The
        reader is the very closure :meth:`read` calls, so a GET that uses it reads the same
        live value (nothing is cached but the lookup); the caller checks ``rlevel`` with
        :func:`allowed` and counts the object against its budget."""
        if ref.prop is not None or ref.slice is not None or ref.slice_error is not None:
            return None
        try:
            targets = self.resolve(ref)
        except TcsError:
            return None
        if len(targets) != 1:
            return None
        target = targets[0]
        if target.error is not None or target.element is not None:
            return None
        fast = getattr(target.node, "fast", None)
        if fast is None or not isinstance(target.node, VarNode):
            return None
        return fast, target.node.spec.rlevel

    def same_for_every_connection(self, ref: ObjectRef) -> bool:
        """True when what :meth:`read` answers for ``ref`` depends on the reading connection
        only through its read level: every object it names is a variable (or a property of
        one) that is not per connection. False when it cannot be told (an error, a module)."""
        try:
            targets = self.resolve(ref)
        except TcsError:
            return False
        for target in targets:
            node = target.node
            if target.error is not None or not isinstance(node, VarNode) or node.spec.per_connection:
                return False
        return bool(targets)

    # -- walking (documentation, tests) ------------------------------------------------------

    def walk(self) -> Iterator[tuple[str, Node]]:
        """Every object with its path, depth first; array elements as ``NAME[i]``."""
        yield from _walk(self.root, "")

    # -- reads ---------------------------------------------------------------------------------

    def read(self, target: Target, prop: str | None, conn: Any) -> str:
        """The wire text of one object (value or property), or an error keyword."""
        if target.error is not None:
            return target.error
        node = target.node
        fast = getattr(node, "fast", None) if prop is None and target.element is None else None
        if fast is not None and allowed(conn.rlevel, node.spec.rlevel):  # the common case: a plain variable
            try:
                return fast()
            except TcsError as exc:
                return exc.reply
            except Exception:
                log.exception("reading %s failed", node.path)
                return "FAILED 13"
        try:
            if prop is not None:
                return _format_property(target, prop)
            node = target.node
            if not isinstance(node, VarNode):
                return "INVALID"
            spec = node.spec
            if not allowed(conn.rlevel, spec.rlevel):
                return "DENIED"
            if node.absent:
                return node.fast()  # type: ignore[misc]
            if spec.get is None:  # write-only
                return "DENIED"
            if spec.count is not None and target.element is None:
                values = _call(spec.get, node.obj)
                return ",".join(format_value(v, spec.type) for v in values)
            value = _call(spec.get, conn if spec.per_connection else node.obj)
            if target.element is not None:
                value = value[target.element]
            return format_value(value, spec.type)
        except TcsError as exc:
            return exc.reply
        except Exception:
            log.exception("reading %s failed", target.node.path)
            return "FAILED 13"

    def read_slice(self, target: Target, ref: ObjectRef, conn: Any) -> str:
        """The wire text of the string slice ``X{a:b}`` (characters a to b inclusive, clipped
        to the string) of one object: ``TYPE`` on anything but a STRING variable's value,
        ``ref.slice_error`` for a slice that cannot be applied."""
        if ref.slice_error is not None:
            return ref.slice_error
        if target.error is not None:
            return target.error
        node = target.node
        if (ref.prop is not None or not isinstance(node, VarNode) or node.spec.type is not STRING
                or (node.spec.count is not None and target.element is None)):
            return "TYPE"
        spec = node.spec
        if not allowed(conn.rlevel, spec.rlevel) or spec.get is None:
            return "DENIED"
        if node.absent:
            return node.fast()  # type: ignore[misc]
        try:
            value = _call(spec.get, conn if spec.per_connection else node.obj)
            if target.element is not None:
                value = value[target.element]
        except TcsError as exc:
            return exc.reply
        except Exception:
            log.exception("reading %s failed", node.path)
            return "FAILED 13"
        if value is None:
            return "NULL"
        a, b = ref.slice  # type: ignore[misc]
        return format_value(ascii_text(str(value))[a:None if b is None else b + 1], STRING)

    # -- writes ------------------------------------------------------------------------------

    def check_write(self, targets: list[Target], prop: str | None, values: tuple[Value, ...],
                    conn: Any) -> list[Any]:
        """Validate a SET before anything happens; return the converted values, one per target.

        Raises a ``RequestRefused`` whose keyword is the reply: INVALID (module, property,
        read-only array), DENIED (levels), DIMENSION (value count), TYPE, RANGE.
        """
        self._check_shape(targets, prop, values)
        return [self._check_one(t, v, conn) for t, v in zip(targets, values)]

    def check_write_each(self, targets: list[Target], prop: str | None, values: tuple[Value, ...],
                         conn: Any) -> list[tuple[Any, str | None]]:
        """Like :meth:`check_write`, but element by element (TPL2: a multi-element SET answers
        one OK/error per element and writes the good ones): ``(value, None)`` for an element
        that may be written, ``(None, error keyword)`` for one that may not. A property, a
        value count that does not match, or any error of a single object still raises."""
        self._check_shape(targets, prop, values)
        if len(targets) == 1:
            return [(self._check_one(targets[0], values[0], conn), None)]
        out: list[tuple[Any, str | None]] = []
        for t, v in zip(targets, values):
            try:
                out.append((self._check_one(t, v, conn), None))
            except TcsError as exc:
                out.append((None, exc.reply))
        return out

    @staticmethod
    def _check_shape(targets: list[Target], prop: str | None, values: tuple[Value, ...]) -> None:
        if prop is not None:
            raise RequestRefused("properties cannot be set")
        if len(values) != len(targets):
            raise RequestRefused(f"{len(values)} values for {len(targets)} elements", keyword="DIMENSION")

    @staticmethod
    def _check_one(t: Target, v: Value, conn: Any) -> Any:
        if t.error is not None:
            raise RequestRefused(f"{t.node.path}: {t.error}", keyword=t.error)
        node = t.node
        if not isinstance(node, VarNode) or (node.spec.count is not None):
            raise RequestRefused(f"{node.path} is not a settable variable")
        spec = node.spec
        wlevel = node.wlevel
        if spec.set is None or not allowed(conn.wlevel, wlevel):
            raise AccessDenied(f"{node.path} is not writable at level {conn.wlevel}")
        if node.absent:
            raise TcsError(f"{node.path}: no hardware at this index", ErrorNumber.NOCON)
        value = convert(v, spec.type)
        if value is None:
            raise TypeRefused(f"{node.path} cannot be NULL")
        if spec.type in (INT, FLOAT) and value is not None:
            lo, hi = node.limit("min"), node.limit("max")
            if (lo is not None and value < lo) or (hi is not None and value > hi):
                raise RangeRefused(f"{node.path}={value} outside [{lo}, {hi}]")
        return value

    def write(self, target: Target, value: Any, conn: Any) -> Any:
        """Apply one checked value; returns None or an awaitable for a long-running action."""
        spec: VarSpec = target.node.spec  # type: ignore[attr-defined]
        obj = conn if spec.per_connection else target.node.obj  # type: ignore[attr-defined]
        result = _call(spec.set, obj, value)
        return result if inspect.isawaitable(result) else None


    def abort(self, target: Target, cause, awaitable) -> None:
        """TPL2 ABORT of a long-running write of ``target`` that returned ``awaitable`` in the
        command ``cause``: the object's ``abort_request(cause, awaitable)`` stops what that
        write started (an axis, tracking, a dome part); objects without one just stop waiting."""
        spec: VarSpec = target.node.spec  # type: ignore[attr-defined]
        if spec.per_connection:
            return
        hook = getattr(target.node.obj, "abort_request", None)  # type: ignore[attr-defined]
        if hook is not None:
            hook(cause, awaitable)


def _step(ref: ObjectRef, part, is_last: bool, t: Target, nxt: list[Target], limit: int | None,
          multi: bool) -> None:
    """Resolve ``part`` below ``t``, appending what it selects to ``nxt``.

    Every index is validated against its array before it is expanded."""
    parent = t.node
    if t.element is not None:  # element of a module array
        parent = parent.elements[t.element]  # type: ignore[attr-defined]
    if not isinstance(parent, ModuleNode):
        raise UnknownObject(f"{ref.text}: {parent.path} has no members")
    if part.number is not None:
        if not 0 <= part.number < len(parent.members):
            raise UnknownObject(f"{ref.text}: no member <{part.number}>")
        child = parent.members[part.number]
    else:
        child = parent.by_name.get(part.name)
        if child is None:
            raise UnknownObject(f"{ref.text}: unknown object {part.name}")
    if part.index is None:
        if isinstance(child, ArrayNode) and not is_last:
            raise RequestRefused(f"{ref.text}: {child.name} is an array, give an index")
        nxt.append(Target(child))
        return
    size = len(child.elements) if isinstance(child, ArrayNode) else (
        child.count if isinstance(child, VarNode) else None)
    if size is None:
        raise RequestRefused(f"{ref.text}: {child.name} is not an array")
    if part.multi and multi:
        raise _WholeRefused(f"{ref.text}: only one index may select several elements")
    if max(hi for _, hi in part.index) >= size:
        raise RequestRefused(f"{ref.text}: index beyond {size} elements", keyword="DIMENSION")
    selected = part.count
    if limit is not None and len(nxt) + selected > limit:
        raise _too_many(ref, len(nxt) + selected, limit)
    nxt.extend(Target(child, j) for j in part.elements())


def module_of(target: Target) -> str:
    """The top-level module a target belongs to, as events name it (``AZ`` for
    ``AZ.TRAJECTORY.RUN``, ``DOME[0]`` for ``DOME[0].TARGETPOS``)."""
    node, below = target.node, None
    while node.parent is not None and node.parent.parent is not None:
        node, below = node.parent, node
    if isinstance(node, ArrayNode) and below is not None:
        return below.name
    return node.name


def _too_many(ref: ObjectRef, count: int, limit: int) -> RequestRefused:
    return _WholeRefused(f"{ref.text}: selects {count} objects, more than the {limit} one command may",
                          keyword="DIMENSION")


def _fast_reader(spec: VarSpec, obj: Any) -> Callable[[], str] | None:
    """A closure reading and formatting a plain variable of ``obj`` with no per-read lookups
    (the hot path of GET); None where the general path is needed (per-connection variables,
    arrays, attributes whose kind cannot be told from the class)."""
    if spec.per_connection or spec.count is not None or obj is None or spec.get is None:
        return None
    get, vtype = spec.get, spec.type
    if vtype is FLOAT:
        fmt = _format_float_or_null
    elif vtype is INT:
        def fmt(v):  # a plain int is its decimal text (format_value's answer, without the checks)
            return str(v) if type(v) is int else format_value(v, INT)
    else:
        def fmt(v):
            return format_value(v, vtype)
    if callable(get):
        return lambda: fmt(get(obj))
    member = getattr(type(obj), get, None)
    if isinstance(member, property) and member.fget is not None:
        fget = member.fget
        return lambda: fmt(fget(obj))
    if inspect.isfunction(member):
        return lambda: fmt(member(obj))
    return None  # instance attribute (plain value or a stored callable): the general path


def _format_float_or_null(value) -> str:
    return "NULL" if value is None else format_float(value)


def _build_members(parent: ModuleNode, members, obj, absent: bool = False,
                   shape: "ModuleNode | None" = None) -> None:
    """Add the declared ``members`` bound to ``obj``; ``absent``: the parent is a module-array
    element with no hardware, which still gets the members (TPL2 §8.3: all elements of a
    module array have the same substructure) whose variables answer their ``absent``. Its
    submodules are those of ``shape``, a configured sibling (a filter wheel without
    TRAJECTORY has placeholders without one), or every declared one when none is configured."""
    for spec in members:
        index = len(parent.members)
        if isinstance(spec, VarSpec):
            parent.add(VarNode(spec.name, index, spec.info, parent, spec, obj, absent=absent))
            continue
        if absent:
            model = None
            if shape is not None:
                model = next((m for m in shape.members if m.name == spec.name), None)
                if model is None:
                    continue  # the configured elements have no such submodule
            if spec.array:
                array = ArrayNode(spec.name, index, spec.info, parent)
                count = len(model.elements) if isinstance(model, ArrayNode) else 0
                if count and all(isinstance(m, VarSpec) for m in spec.members):
                    # as many elements as the configured sibling's (a trajectory BUFFER[120]),
                    # each answering its members' absent value
                    array.elements = _LazyElements(array, spec, [None] * count)
                parent.add(array)  # else COUNT 0
            else:
                child = ModuleNode(spec.name, index, spec.info, parent, None)
                _build_members(child, spec.members, None, absent=True,
                               shape=model if isinstance(model, ModuleNode) else None)
                parent.add(child)
            continue
        bound = obj if spec.bind is None else _call(spec.bind, obj)
        if spec.array:
            objs = list(bound or [])
            if not objs:
                continue
            array = ArrayNode(spec.name, index, spec.info, parent)
            if all(isinstance(m, VarSpec) for m in spec.members):
                array.elements = _LazyElements(array, spec, objs)
            else:  # submodules bind to their objects now, as every other module does
                array.elements = _elements(array, spec, objs)
            parent.add(array)
        else:
            if bound is None:
                continue
            child = ModuleNode(spec.name, index, spec.info, parent, bound)
            _build_members(child, spec.members, bound)
            parent.add(child)


def _element(array: ArrayNode, spec: ModuleSpec, i: int, obj: Any,
             shape: ModuleNode | None = None) -> ModuleNode:
    """Element ``i`` of ``array``, bound to ``obj``; None: an index with nothing configured,
    which has the members all the same (those of ``shape``, a configured sibling), answering
    their ``absent`` value or FAILED 4."""
    element = ModuleNode(f"{spec.name}[{i}]", i, spec.info, array, obj)
    _build_members(element, spec.members, obj, absent=obj is None, shape=shape)
    return element


def _elements(array: ArrayNode, spec: ModuleSpec, objs: list) -> list[ModuleNode]:
    """Every element of ``array``: the configured ones first, so the placeholders can take the
    substructure of the first of them (TPL2 §8.3)."""
    built = {i: _element(array, spec, i, o) for i, o in enumerate(objs) if o is not None}
    shape = next(iter(built.values()), None)
    return [built[i] if i in built else _element(array, spec, i, None, shape) for i in range(len(objs))]


def _walk(node: Node, prefix: str) -> Iterator[tuple[str, Node]]:
    if isinstance(node, ModuleNode):
        for m in node.members:
            path = f"{prefix}.{m.name}" if prefix else m.name
            yield path, m
            yield from _walk(m, path)
    elif isinstance(node, ArrayNode):
        for e in node.elements:
            path = f"{prefix}[{e.index}]"
            yield path, e
            yield from _walk(e, path)


def format_value(value: Any, vtype: ValueType | None = None) -> str:
    """The wire form of a value read from the tree; text the server writes is 7-bit ASCII
    (``°C`` reads ``degC``, see :func:`~tcs.opentci_server.values.ascii_text`)."""
    if vtype is STRING and isinstance(value, str):
        value = ascii_text(value)
    return _format_any(value, vtype)


def _q(text: str) -> str:
    return format_value(text, STRING)


def _format_property(target: Target, prop: str) -> str:
    node = target.node
    if target.element is not None and isinstance(node, ArrayNode):
        node = node.elements[target.element]
    if prop == "INDEX":
        return str(node.index)
    if prop == "CLASS":
        return str(node.cls_code)
    if prop == "NAME":
        return _q(node.name)
    if prop == "INFO":
        return _q(node.info)
    if isinstance(node, ModuleNode):
        if prop == "MEMBERS":  # the number of direct members: walk <0>!NAME … <n-1>!NAME
            return str(len(node.members))
        if prop == "OBJECTCOUNT":
            return str(node.object_count() - 1)
        if prop == "ATTACHED" and node.parent is not None:
            return "0"  # 1 only for a module that lives on a sub-server
    elif isinstance(node, ArrayNode):
        if prop == "ATTACHED":
            return "0"
        if prop == "COUNT":
            return str(len(node.elements))
        if prop == "OBJECTCOUNT":
            return str(node.object_count() - 1)
    elif isinstance(node, VarNode):
        spec = node.spec
        if spec.count is not None and prop == "COUNT":
            return str(node.count)
        if prop == "TYPE":
            return str(int(spec.type))
        if prop in ("MIN", "MAX"):
            if spec.type not in (INT, FLOAT):
                return "UNKNOWN"
            return format_value(node.limit(prop.lower()), spec.type)
        if prop == "INIT":
            return format_value(spec.init, spec.type)
        if prop == "RLEVEL":
            return str(spec.rlevel)
        if prop == "WLEVEL":
            return str(node.wlevel)
        if prop in ("RLOCK", "WLOCK", "CALLBACKTYPE"):
            return "0"
        if prop == "CALLBACK":
            return '""'  # STRING: no callback
    return "UNKNOWN"


__all__ = ["Tree", "Target", "module_of", "VarSpec", "ModuleSpec", "var", "sysvar", "var_array", "module",
           "module_array", "READ_ALL", "OPERATE", "CONFIGURE", "NOBODY", "INT", "FLOAT", "STRING"]
