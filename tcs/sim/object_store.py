"""The object dictionary of a simulated CANopen node: typed values plus read/write hooks.

The store is filled from an EDS (parsed with ``canopen.import_od``): every (index, sub-index)
holds a Python value (int or str). SDO and PDO access go through :meth:`read_bytes` /
:meth:`write_bytes`, which check existence, access type, length and value range and raise
:class:`SdoAbort` with the CiA-301 abort code a real device would answer.

Owners hook behaviour onto objects:

* ``on_read(index, provider)`` — ``provider(sub) -> value`` computes a live value (position
  actual, statusword …) whenever it is read, by SDO or to fill a TPDO;
* ``on_write(index, hook)`` — ``hook(sub, value)`` runs *before* the value is stored; it may
  raise :class:`SdoAbort` to refuse the write (e.g. PDO mapping in the wrong NMT state).

Internal code (the node's own model) uses ``get`` / ``set`` which bypass access checks and
hooks. Nothing here knows CiA-402; the store is not thread-safe (the port's lock covers it).

Any valid EDS works, however few objects it has: ``get`` of an object the EDS lacks answers
the ``builtins(index, sub)`` value (or 0) — the model keeps working — while SDO and PDO access
to it abort 0x06020000 / 0x06090011 as a real device would. Two options make the wire differ
from the model:

* ``scale`` ``{index: factor}``: the wire value is the model value × factor (a drive whose
  velocity objects are in rpm while the model counts increments/s); limits apply to the wire
  value;
* ``allowed`` ``{(index, sub): set}``: writes of other values abort 0x06090030 before any hook
  runs (the modes 0x6502 says the drive has).

Limits are the EDS ``LowLimit``/``HighLimit``; for 0x1016:n (consumer heartbeat time, ``node
id << 16 | ms``) a HighLimit below 0x10000 bounds the time part only, as on real drives; for a
PDO COB-ID (0x1400+n:1, 0x1800+n:1) a HighLimit below 0x80000000 does not bound bit 31 (the
PDO switched off), which every device takes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from canopen import objectdictionary as odmod
from canopen.objectdictionary import datatypes

# CiA-301 SDO abort codes the simulator uses.
ABORT_TOGGLE = 0x05030000
ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_LENGTH = 0x06070010
ABORT_TOO_LONG = 0x06070012
ABORT_TOO_SHORT = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_STORE = 0x08000020
ABORT_STATE = 0x08000022


class SdoAbort(Exception):
    """Refusal of an object access, carrying its CiA-301 abort code."""

    def __init__(self, code: int, text: str = ""):
        super().__init__(f"SDO abort 0x{code:08X}{': ' + text if text else ''}")
        self.code = code


Provider = Callable[[int], Any]
WriteHook = Callable[[int, Any], None]


class ObjectStore:
    """Values of every object of an object dictionary, with access checks and hooks."""

    def __init__(self, od: odmod.ObjectDictionary, builtins: Callable[[int, int], Any] | None = None,
                 scale: dict[int, float] | None = None,
                 allowed: dict[tuple[int, int], set] | None = None):
        self.od = od
        self._builtins = builtins
        self.scale = dict(scale or {})
        self.allowed = dict(allowed or {})
        self._values: dict[tuple[int, int], Any] = {}
        self._readers: dict[int, Provider] = {}
        self._writers: dict[int, list[WriteHook]] = {}
        self.reset_all()

    # -- defaults ----------------------------------------------------------------------------
    def variables(self):
        """Every ``ODVariable`` of the dictionary (sub-indices of arrays and records included)."""
        for obj in self.od.values():
            if isinstance(obj, odmod.ODVariable):
                yield obj
            else:
                yield from obj.values()

    def reset_range(self, first: int, last: int) -> None:
        """Restore the EDS defaults of the objects ``first..last`` (inclusive)."""
        for key in [k for k in self._values if first <= k[0] <= last]:
            del self._values[key]  # objects the EDS lacks fall back to the built-ins again
        for var in self.variables():
            if first <= var.index <= last:
                default = var.value if var.value is not None else var.default
                if default is None:
                    builtin = self._builtins(var.index, var.subindex) if self._builtins else None
                    default = builtin if builtin is not None else (
                        "" if var.data_type in (datatypes.VISIBLE_STRING, datatypes.UNICODE_STRING) else 0)
                self._values[(var.index, var.subindex)] = default

    def reset_all(self) -> None:
        self.reset_range(0x0000, 0xFFFF)

    # -- hooks -------------------------------------------------------------------------------
    def on_read(self, index: int, provider: Provider) -> None:
        self._readers[index] = provider

    def on_write(self, index: int, hook: WriteHook) -> None:
        self._writers.setdefault(index, []).append(hook)

    # -- internal access (no checks, no hooks) -----------------------------------------------
    def get(self, index: int, sub: int = 0) -> Any:
        try:
            return self._values[(index, sub)]
        except KeyError:  # not in this EDS: the model still needs a value
            builtin = self._builtins(index, sub) if self._builtins else None
            return 0 if builtin is None else builtin

    def set(self, index: int, sub: int, value: Any) -> None:
        self._values[(index, sub)] = value

    def value(self, index: int, sub: int = 0) -> Any:
        """The value as a reader sees it (live providers applied), without access checks."""
        provider = self._readers.get(index)
        if provider is not None:
            live = provider(sub)
            if live is not None:
                return live
        return self.get(index, sub)

    def wire_value(self, index: int, sub: int = 0) -> Any:
        """:meth:`value` in the units of the wire (``scale`` applied)."""
        value = self.value(index, sub)
        factor = self.scale.get(index)
        return value if factor is None else round(value * factor)

    # -- checked access (SDO, PDO) -----------------------------------------------------------
    def variable(self, index: int, sub: int) -> odmod.ODVariable:
        """The dictionary entry of (index, sub), or the abort a device answers."""
        if index not in self.od:
            raise SdoAbort(ABORT_NO_OBJECT)
        obj = self.od[index]
        if isinstance(obj, odmod.ODVariable):
            if sub != 0:
                raise SdoAbort(ABORT_NO_SUBINDEX)
            return obj
        if sub not in obj.subindices:
            raise SdoAbort(ABORT_NO_SUBINDEX)
        return obj[sub]

    def read_bytes(self, index: int, sub: int) -> bytes:
        var = self.variable(index, sub)
        if not var.readable:
            raise SdoAbort(ABORT_WRITE_ONLY)
        return self.encode(var, self.wire_value(index, sub))

    def write_bytes(self, index: int, sub: int, data: bytes) -> None:
        var = self.variable(index, sub)
        if not var.writable:
            raise SdoAbort(ABORT_READ_ONLY)
        self.write_value(var, self.decode(var, data))

    def write_value(self, var: odmod.ODVariable, value: Any) -> None:
        """Range-check the wire ``value``, convert it (``scale``), run the write hooks, store it."""
        if isinstance(value, int):
            checked = value
            if var.index == 0x1016 and var.subindex >= 1 and var.max is not None and var.max <= 0xFFFF:
                checked = value & 0xFFFF  # node id << 16 | ms: a 16-bit limit bounds the time
            elif (0x1400 <= var.index < 0x1600 or 0x1800 <= var.index < 0x1A00) and var.subindex == 1 \
                    and var.max is not None and var.max < 0x80000000:
                checked = value & 0x7FFFFFFF  # a PDO COB-ID: bit 31 (invalid) is no number
            if var.min is not None and checked < var.min:
                raise SdoAbort(ABORT_VALUE_LOW)
            if var.max is not None and checked > var.max:
                raise SdoAbort(ABORT_VALUE_HIGH)
        allowed = self.allowed.get((var.index, var.subindex))
        if allowed is not None and value not in allowed:
            raise SdoAbort(ABORT_VALUE_RANGE, f"{value} not supported")
        factor = self.scale.get(var.index)
        if factor is not None and isinstance(value, (int, float)):
            value = value / factor
        for hook in self._writers.get(var.index, ()):
            hook(var.subindex, value)
        self._values[(var.index, var.subindex)] = value

    @staticmethod
    def encode(var: odmod.ODVariable, value: Any) -> bytes:
        if var.data_type == datatypes.VISIBLE_STRING:
            return str(value).encode("ascii", "replace")
        if var.data_type in datatypes.INTEGER_TYPES:
            bits = len(var)
            if var.data_type in datatypes.SIGNED_TYPES:
                lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
            else:
                lo, hi = 0, (1 << bits) - 1
            value = max(lo, min(hi, int(value)))
        return var.encode_raw(value)

    @staticmethod
    def decode(var: odmod.ODVariable, data: bytes) -> Any:
        if var.data_type in datatypes.NUMBER_TYPES:
            size = len(var) // 8
            if len(data) > size:
                raise SdoAbort(ABORT_TOO_LONG)
            if len(data) < size:
                raise SdoAbort(ABORT_TOO_SHORT)
        if var.data_type == datatypes.VISIBLE_STRING:
            return bytes(data).decode("ascii", "replace")
        return var.decode_raw(bytes(data))
