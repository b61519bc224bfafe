"""Hardware-file sections of the Modbus PLCs: ``[plcs.<name>]`` and its register map.

A PLC section says how to reach the PLC (``transport = "tcp"`` with host/port, or ``"rtu"``
with a serial port or pyserial URL), how often to poll it, and its **register map**: one table
``[plcs.<name>.points.<point>]`` per named value::

    [plcs.dome.points.az_target]
    kind = "holding"          # coil | discrete | holding | input
    address = 0               # 0-based protocol address (no 4xxxx offsets)
    type = "float32"          # bool | int16 | uint16 | int32 | uint32 | float32
    word_order = "big"        # for 32-bit types; default: the PLC's word_order
    scale = 1.0               # engineering value = raw * scale + offset
    offset = 0.0
    access = "rw"             # r | rw | w; default r for discrete/input, rw for coil/holding
    bits = { moving = 0 }     # named bits of an integer register, read as "<point>.<bit>"
    unit = "deg"
    description = "dome azimuth target"

Coils and discrete inputs are single bits (``type = "bool"``); registers hold the integer and
float types (32-bit types take two registers; ``word_order = "big"`` puts the high word first).

:class:`RegisterPoint` is the resolved, immutable meaning of one point and does the value ↔
register conversion (``decode``/``encode``). Both the driver (:mod:`tcs.drivers.modbus`) and
the simulated PLC (:mod:`tcs.sim.plc`) use it, so they agree on the map by construction.

**Axis convention.** A PLC axis ``X`` (dome rotation, slit, roof, shell, mirror cover) is the
four points ``X_target`` (holding float, rw), ``X_command`` (holding integer, rw: 0 idle,
1 move to target, 2 stop, 3 reset fault; the PLC sets it back to 0 once accepted),
``X_position`` (readable) and ``X_status`` (readable integer with bits ``moving``,
``at_target``, ``closed``, ``open``, ``fault``, ``stalled``), optionally ``X_speed``.
:meth:`PlcSection.axis_names` lists them; ``hwconfig/plc-sim-map.toml`` documents a full map.

The optional ``[plcs.<name>.sim]`` table only matters to the simulator (physics of axes,
sensor models, switch feedback); the driver ignores it.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, Union

from tcs.config.schema import setting

Kind = Literal["coil", "discrete", "holding", "input"]
PointType = Literal["bool", "int16", "uint16", "int32", "uint32", "float32"]
Value = Union[bool, int, float]

KINDS: tuple[str, ...] = ("coil", "discrete", "holding", "input")
BIT_KINDS = frozenset({"coil", "discrete"})
READ_ONLY_KINDS = frozenset({"discrete", "input"})
KIND_NAMES = {"coil": "a coil", "discrete": "a discrete input", "holding": "a holding register",
              "input": "an input register"}
REGISTERS = {"bool": 1, "int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2}
_STRUCT = {"int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "float32": "f"}
_INT_RANGE = {"int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1),
              "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1)}
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _decimal_places(x: float) -> int:
    """Decimals of the shortest text of ``x`` (0.1 -> 1, 0.05 -> 2, 2.0 -> 0)."""
    text = repr(float(x))
    if "e" in text or "E" in text:
        mantissa, exp = text.lower().split("e")
        return max(0, len(mantissa.partition(".")[2].rstrip("0")) - int(exp))
    return len(text.partition(".")[2].rstrip("0"))


def _shortest_float32(x: float) -> float:
    """The value with the fewest significant digits that is the same float32 as ``x`` (a
    float32 register holding 9.6 reads 9.6, not 9.600000381469727)."""
    if not math.isfinite(x):
        return x
    target = struct.pack(">f", x)
    for digits in range(1, 10):
        candidate = float(f"{x:.{digits}g}")
        if struct.pack(">f", candidate) == target:
            return candidate
    return x

#: The status bits an axis must have (bit names in ``X_status.bits``).
AXIS_STATUS_BITS = ("moving", "at_target", "closed", "open", "fault", "stalled")
#: ``X_command`` values (the PLC resets the register to IDLE once it accepted a command).
AXIS_IDLE, AXIS_MOVE, AXIS_STOP, AXIS_RESET = 0, 1, 2, 3


@dataclass(frozen=True)
class PlcPoint:
    """One named value in the register map, as written in the file."""

    kind: Kind = setting(doc="coil | discrete | holding | input")
    address: int = setting(min=0, max=65535, doc="0-based protocol address")
    type: PointType | None = setting(None, doc="value type; default bool for bits, uint16 for registers")
    word_order: Literal["big", "little"] | None = setting(None, doc="32-bit word order; default: the PLC's")
    scale: float = setting(1.0, doc="engineering value = raw * scale + offset")
    offset: float = setting(0.0, doc="engineering value = raw * scale + offset")
    access: Literal["r", "rw", "w"] | None = setting(None, doc="default r for discrete/input, rw otherwise")
    bits: dict[str, int] = setting(factory=dict, doc="named bits of an integer register")
    unit: str = setting("", doc="unit of the engineering value (SENSOR/SWITCH UNIT)")
    description: str = setting("", doc="free text (SENSOR/SWITCH DESCRIPTION)")

    @property
    def value_type(self) -> str:
        return self.type or ("bool" if self.kind in BIT_KINDS else "uint16")

    def check(self):
        problems = []
        vtype = self.value_type
        if self.kind in BIT_KINDS and vtype != "bool":
            problems.append(("type", f"{KIND_NAMES[self.kind]} is one bit: type must be 'bool', "
                                     f"not {vtype!r}"))
        if self.kind not in BIT_KINDS and vtype == "bool":
            problems.append(("type", f"'bool' is for coils and discrete inputs; {KIND_NAMES[self.kind]} "
                                     "needs int16, uint16, int32, uint32 or float32"))
        if self.kind in READ_ONLY_KINDS and self.access not in (None, "r"):
            problems.append(("access", f"{KIND_NAMES[self.kind]} is read-only on Modbus: "
                                       f"access must be 'r', not {self.access!r}"))
        count = REGISTERS.get(vtype, 1)
        if self.address + count - 1 > 65535:
            problems.append(("address", f"{_article(vtype)} {vtype} needs {count} registers "
                                        f"({self.address}..{self.address + count - 1}), beyond 65535"))
        if not math.isfinite(self.scale) or self.scale == 0.0:
            problems.append(("scale", f"must be a finite non-zero number, not {self.scale!r}"))
        if not math.isfinite(self.offset):
            problems.append(("offset", f"must be finite, not {self.offset!r}"))
        if vtype == "bool" and (self.scale != 1.0 or self.offset != 0.0):
            problems.append(("scale", "a bool point cannot be scaled"))
        if self.bits:
            if vtype not in _INT_RANGE:
                problems.append(("bits", f"bit fields need an integer register type, not {vtype!r}"))
            else:
                width = 16 * REGISTERS[vtype]
                for name, index in self.bits.items():
                    if not _NAME.match(name):
                        problems.append((f"bits.{name}", "bit name must be an identifier"))
                    if not 0 <= index < width:
                        problems.append((f"bits.{name}", f"bit {index} is beyond a {vtype} "
                                                         f"(0..{width - 1})"))
                seen: dict[int, str] = {}
                for name, index in self.bits.items():
                    if index in seen:
                        problems.append((f"bits.{name}", f"bit {index} is already {seen[index]!r}"))
                    seen.setdefault(index, name)
        return problems


@dataclass(frozen=True)
class RegisterPoint:
    """A point with every default resolved, and the value ↔ raw conversion.

    ``decode(raw)`` takes the point's raw data (a list of 16-bit words, or ``[bool]`` for a
    bit) and returns the engineering value: ``bool`` for bits, ``int`` for unscaled integer
    types, ``float`` otherwise. ``encode(value)`` is the inverse and raises ``ValueError`` with
    a readable reason when the value does not fit the type.
    """

    name: str
    kind: str
    address: int
    type: str
    word_order: str
    scale: float
    offset: float
    access: str
    bits: tuple[tuple[str, int], ...]
    unit: str
    description: str

    @property
    def count(self) -> int:
        """Registers (or bits) the point occupies."""
        return REGISTERS[self.type]

    @property
    def end(self) -> int:
        """One past the last address."""
        return self.address + self.count

    @property
    def readable(self) -> bool:
        return "r" in self.access

    @property
    def writable(self) -> bool:
        return "w" in self.access

    @property
    def is_integer(self) -> bool:
        return self.type in _INT_RANGE and self.scale == 1.0 and self.offset == 0.0

    def decode(self, raw) -> Value:
        if self.type == "bool":
            return bool(raw[0])
        words = list(raw[:self.count])
        if self.word_order == "little":
            words.reverse()
        number = struct.unpack(">" + _STRUCT[self.type], struct.pack(f">{len(words)}H", *words))[0]
        if self.is_integer:
            return number
        if self.type == "float32":
            number = _shortest_float32(number)
            value = number * self.scale + self.offset
            return value if self.scale == 1.0 and self.offset == 0.0 else float(f"{value:.7g}")
        # raw * scale + offset has at most `_decimals` decimals: the nearest double to that
        # decimal prints as such (9.6, not 9.600000000000001); no resolution is lost
        return round(number * self.scale + self.offset, self._decimals)

    @cached_property
    def _decimals(self) -> int:
        return max(_decimal_places(self.scale), _decimal_places(self.offset))

    def encode(self, value: Value) -> list:
        if self.type == "bool":
            if not isinstance(value, (bool, int)) or value not in (0, 1):
                raise ValueError(f"{self.name} is a bool: {value!r} is not true/false/0/1")
            return [bool(value)]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{self.name} needs a number, not {value!r}")
        raw = (value - self.offset) / self.scale if not self.is_integer else value
        if not math.isfinite(raw):
            raise ValueError(f"{self.name}: {value!r} is not a finite number")
        if self.type in _INT_RANGE:
            raw = int(round(raw))
            lo, hi = _INT_RANGE[self.type]
            if not lo <= raw <= hi:
                lo_v, hi_v = sorted((lo * self.scale + self.offset, hi * self.scale + self.offset))
                raise ValueError(f"{self.name}: {value!r} is outside {lo_v:g} … {hi_v:g} ({self.type})")
        elif abs(raw) > 3.4028234e38:
            raise ValueError(f"{self.name}: {value!r} does not fit a float32")
        words = list(struct.unpack(f">{self.count}H", struct.pack(">" + _STRUCT[self.type], raw)))
        if self.word_order == "little":
            words.reverse()
        return words

    def decode_bits(self, raw) -> dict[str, bool]:
        """The named bits of the point's unscaled integer, as ``{"<point>.<bit>": bool}``."""
        if not self.bits:
            return {}
        words = list(raw[:self.count])
        if self.word_order == "little":
            words.reverse()
        number = 0
        for w in words:
            number = (number << 16) | (int(w) & 0xFFFF)
        return {f"{self.name}.{bit}": bool((number >> index) & 1) for bit, index in self.bits}


@dataclass(frozen=True)
class SimAxisSection:
    """Physics of one simulated PLC axis (``[plcs.<name>.sim.axes.<axis>]``).

    Every ``None`` comes from the preset (``tcs/sim/enclosure.py``, ``tcs/sim/covers.py``).
    """

    preset: Literal["azimuth", "slit", "flap", "seal", "roof", "shell", "fold", "cover",
                    "generic"] = setting("generic", doc="default physics for this kind of axis")
    speed: float | None = setting(None, min=1e-6, doc="top speed, units/s")
    acceleration: float | None = setting(None, min=1e-6, doc="acceleration, units/s²")
    min: float | None = setting(None, doc="lowest position (closed end switch)")
    max: float | None = setting(None, doc="highest position (open end switch)")
    circular: bool | None = setting(None, doc="positions wrap at max (dome azimuth)")
    position: float | None = setting(None, doc="position at start")
    tolerance: float | None = setting(None, min=0.0, doc="at_target / end switch window")
    stall_detect: float | None = setting(None, min=0.0, doc="seconds before a stalled motor is reported")


@dataclass(frozen=True)
class SimSensorSection:
    """A simulated sensor behind a point (``[plcs.<name>.sim.sensors.<point>]``)."""

    model: Literal["temperature", "pressure", "humidity", "wind_speed", "wind_direction",
                   "rain", "uptime", "constant"] = setting(doc="what the value behaves like")
    mean: float | None = setting(None, doc="mean value (model default when absent)")
    amplitude: float | None = setting(None, min=0.0, doc="slow variation amplitude")
    period: float | None = setting(None, min=1.0, doc="period of the slow variation, s")


@dataclass(frozen=True)
class SimSwitchSection:
    """A simulated switch (``[plcs.<name>.sim.switches.<point>]``): pump, light, fan."""

    feedback: str = setting("", doc="point that reports the switch state (e.g. a discrete input)")
    delay: float = setting(0.0, min=0.0, max=600.0, doc="seconds before the feedback follows")


@dataclass(frozen=True)
class PlcSimSection:
    """What the simulated PLC does behind the register map; the driver ignores it."""

    axes: dict[str, SimAxisSection] = setting(factory=dict, doc="physics of each PLC axis, by axis name")
    sensors: dict[str, SimSensorSection] = setting(factory=dict, doc="simulated sensors, by point name")
    switches: dict[str, SimSwitchSection] = setting(factory=dict, doc="simulated switches, by point name")
    seed: int = setting(1, doc="seed of the sensors' slow variations")
    watchdog_timeout: float = setting(
        2.0, min=0.0, max=3600.0, doc="seconds (wall clock) without a change of the PLC's watchdog point "
        "after which the simulated PLC program stops every axis, once the point was written (0 = never)")


@dataclass(frozen=True)
class PlcSection:
    """One PLC: ``[plcs.<name>]``."""

    transport: Literal["tcp", "rtu"] = setting("tcp", doc="Modbus TCP, or RTU over a serial line")
    host: str = setting("127.0.0.1", doc="tcp: PLC address")
    port: int = setting(502, min=0, max=65535, doc="tcp: PLC port")
    serial_port: str = setting("", doc="rtu: device path or pyserial URL (socket://host:port)")
    baudrate: int = setting(19200, min=50, max=4_000_000, doc="rtu: baud rate")
    parity: Literal["N", "E", "O"] = setting("N", doc="rtu: parity")
    stopbits: int = setting(1, min=1, max=2, doc="rtu: stop bits")
    bytesize: int = setting(8, min=7, max=8, doc="rtu: data bits")
    device_id: int = setting(1, min=0, max=247, doc="Modbus unit / device id")
    poll_interval: float = setting(0.1, min=0.001, max=60.0, doc="seconds between poll cycles")
    idle_poll_interval: float = setting(
        0.0, min=0.0, max=60.0, doc="seconds between poll cycles while the PLC rests: no axis of "
        "the map moving or commanded, nothing written for 2 s, no dome trajectory running (0 = "
        "always poll_interval). The watchdog point is written at every poll, so keep it well "
        "under the PLC program's watchdog time; a write brings the full rate back at once "
        "(tcs.drivers.modbus)")
    timeout: float = setting(1.0, min=0.01, max=60.0, doc="seconds to wait for each answer")
    reconnect_min: float = setting(0.2, min=0.0, max=600.0, doc="first reconnect delay, s")
    reconnect_max: float = setting(5.0, min=0.01, max=3600.0, doc="longest reconnect delay, s (doubles up to it)")
    word_order: Literal["big", "little"] = setting("big", doc="default word order of 32-bit values")
    max_gap: int = setting(8, min=0, max=100, doc="unused registers a single read may span")
    max_read_registers: int = setting(125, min=1, max=125, doc="registers per read request")
    max_read_bits: int = setting(2000, min=1, max=2000, doc="coils/inputs per read request")
    description: str = setting("", doc="free text")
    points: dict[str, PlcPoint] = setting(factory=dict, doc="the register map")
    watchdog: str = setting("tcs_watchdog", doc="holding point the driver increments at every poll, so the "
                            "PLC program can stop its axes when the TCS is gone (no such point: none)")
    sim: PlcSimSection | None = setting(None, doc="simulator parameters (ignored by the driver)")

    @cached_property
    def map(self) -> dict[str, RegisterPoint]:
        """The resolved register map: point name → :class:`RegisterPoint`."""
        resolved = {}
        for name, p in self.points.items():
            access = p.access or ("r" if p.kind in READ_ONLY_KINDS else "rw")
            resolved[name] = RegisterPoint(
                name=name, kind=p.kind, address=p.address, type=p.value_type,
                word_order=p.word_order or self.word_order, scale=p.scale, offset=p.offset,
                access=access, bits=tuple(sorted(p.bits.items(), key=lambda kv: kv[1])),
                unit=p.unit, description=p.description)
        return resolved

    def axis_names(self) -> list[str]:
        """Every axis of the map that follows the axis convention (``X_command``, ``X_target`` …)."""
        return [name[:-len("_command")] for name in self.map
                if name.endswith("_command") and not self.axis_problems(name[:-len("_command")])]

    def axis_problems(self, axis: str) -> list[tuple[str, str]]:
        """What is missing or wrong for ``axis`` to follow the axis convention ([] if fine)."""
        problems = []
        m = self.map
        want = {"target": ("holding", True), "command": ("holding", True),
                "position": (None, False), "status": (None, False)}
        for suffix, (kind, writable) in want.items():
            name = f"{axis}_{suffix}"
            p = m.get(name)
            if p is None:
                problems.append((f"points.{name}", f"missing: axis {axis!r} needs it"))
                continue
            if kind and p.kind != kind:
                problems.append((f"points.{name}.kind", f"must be {kind!r} for axis {axis!r}"))
            if writable and not p.writable:
                problems.append((f"points.{name}.access", f"axis {axis!r} writes it"))
            if not writable and not p.readable:
                problems.append((f"points.{name}.access", f"axis {axis!r} reads it"))
        status = m.get(f"{axis}_status")
        if status is not None:
            missing = [b for b in ("moving", "at_target", "fault") if b not in dict(status.bits)]
            if missing:
                problems.append((f"points.{axis}_status.bits", f"axis {axis!r} needs bits {missing}"))
        command = m.get(f"{axis}_command")
        if command is not None and command.type not in _INT_RANGE:
            problems.append((f"points.{axis}_command.type", "the command must be an integer type"))
        return problems

    def check(self):
        problems = []
        if self.transport == "tcp" and not self.host:
            problems.append(("host", "transport 'tcp' needs a host"))
        if self.transport == "rtu" and not self.serial_port:
            problems.append(("serial_port", "transport 'rtu' needs a serial_port (device path or URL)"))
        if self.reconnect_min > self.reconnect_max:
            problems.append(("reconnect_min", f"{self.reconnect_min} is above reconnect_max {self.reconnect_max}"))
        if self.idle_poll_interval and self.idle_poll_interval < self.poll_interval:
            problems.append(("idle_poll_interval", f"must be 0 (off) or at least poll_interval "
                                                   f"({self.poll_interval:g} s)"))
        for name in self.points:
            if not _NAME.match(name):
                problems.append((f"points.{name}", "point name must be an identifier (letters, digits, _)"))
        # Overlaps: each register (or bit) of one kind belongs to one point at most.
        owner: dict[tuple[str, int], str] = {}
        for name, p in self.map.items():
            for a in range(p.address, p.end):
                other = owner.get((p.kind, a))
                if other is not None:
                    o = self.map[other]
                    problems.append((f"points.{name}.address",
                                     f"{KIND_NAMES[p.kind]} {_span(p)} overlaps point {other!r} "
                                     f"({_span(o)})"))
                    break
                owner[(p.kind, a)] = name
        if self.sim is not None:
            problems.extend(self._sim_problems())
        return problems

    def _sim_problems(self):
        problems = []
        timeout = self.sim.watchdog_timeout
        if self.idle_poll_interval and timeout and self.watchdog in self.points \
                and self.idle_poll_interval > timeout / 2:
            problems.append(("idle_poll_interval", f"the simulated PLC's watchdog (sim.watchdog_timeout "
                                                   f"= {timeout:g} s) needs a write at least every "
                                                   f"{timeout / 2:g} s, at rest too"))
        for axis in self.sim.axes:
            problems.extend(self.axis_problems(axis))
        for name in self.sim.sensors:
            if name not in self.points:
                problems.append((f"sim.sensors.{name}", f"no point {name!r} in the register map"))
        for name, sw in self.sim.switches.items():
            if name not in self.points:
                problems.append((f"sim.switches.{name}", f"no point {name!r} in the register map"))
            elif not self.map[name].writable:
                problems.append((f"sim.switches.{name}", f"point {name!r} is not writable"))
            if sw.feedback and sw.feedback not in self.points:
                problems.append((f"sim.switches.{name}.feedback", f"no point {sw.feedback!r}"))
        return problems


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _span(p: RegisterPoint) -> str:
    return f"{p.address}" if p.count == 1 else f"{p.address}..{p.end - 1}"

