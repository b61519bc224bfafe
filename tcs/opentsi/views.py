"""Computed views the OpenTSI declaration reads: sky positions, the status list in OpenTSI
grammar, covers and dome shutters as 0…1, the sensor index table, event module names.

Nothing here holds telescope state (``docs/architecture.md`` rule 0): every object wraps parts
of the model and computes on each read; setters call the model's own methods. Only the OpenTSI
declaration (``tcs/opentsi/declaration.py``) uses this module.
"""

from __future__ import annotations

import math
import re

import erfa

from tcs.errors import ErrorNumber, RangeRefused, TcsError, gather_all
from tcs.pointing.orientation import to_normal

_UNSAFE = re.compile(r"[,:;|\r\n\"\\]+")


def _clean(text: str) -> str:
    return _UNSAFE.sub(" ", str(text)).strip()


# --------------------------------------------------------------------------- TELESCOPE.STATUS

class StatusView:
    """TELESCOPE.STATUS: GLOBAL, LIST (OpenTSI grammar), CLEAR by severity mask."""

    def __init__(self, telescope, error_table: dict[str, str], error_default: str, warning_default: str):
        self._telescope = telescope
        self._table = error_table
        self._error_default = error_default
        self._warning_default = warning_default

    @property
    def ops(self):
        return self._telescope.operations

    @property
    def global_state(self) -> int:
        return int(self._telescope.cabinet.error_state) & 0xF

    local_mode = 0

    def error_name(self, module: str, condition: str, bits: int) -> str:
        base = module.split("[", 1)[0]
        for key in (f"{module}:{condition}", f"{base}:{condition}", module, base):
            if key in self._table:
                return self._table[key]
        return self._error_default if bits & 3 else self._warning_default

    def entries(self) -> list[tuple[str, str, str, int, str]]:
        """(group, component, condition, bits, text) of every condition with ERROR_STATE bits."""
        cabinet = self._telescope.cabinet
        out = []
        for member in [cabinet, *cabinet.members()]:
            conditions = getattr(member, "conditions", None)
            if not callable(conditions):
                continue
            name = str(getattr(member, "module_name", ""))
            for condition, (bits, _active) in conditions().items():
                if bits & 0xF:
                    out.append((group_of(name), name, condition, bits & 0xF, condition))
        return out

    @property
    def list_text(self) -> str:
        """``<group>|<level>:<component>|<level>[;…]:<error>|<detail>|<level>|<component>[;…]``,
        groups separated by ``,``."""
        groups: dict[str, list] = {}
        for group, component, condition, bits, text in self.entries():
            groups.setdefault(group, []).append((component, condition, bits, text))
        parts = []
        for group, items in groups.items():
            level = 0
            components: dict[str, int] = {}
            for component, _c, bits, _t in items:
                level |= bits
                components[component] = components.get(component, 0) | bits
            comps = ";".join(f"{_clean(c)}|{b}" for c, b in components.items())
            errors = ";".join(f"{self.error_name(c, cond, b)}|{_clean(t)}|{b}|{_clean(c)}"
                              for c, cond, b, t in items)
            parts.append(f"{group}|{level}:{comps}:{errors}")
        return ",".join(parts)

    def clear(self, value: int):
        return self.ops.acknowledge_mask(value)

    def clear_panic(self, value: int):
        return self.ops.acknowledge_mask(value, 0x1)

    def clear_error(self, value: int):
        return self.ops.acknowledge_mask(value, 0x2)

    def clear_warning(self, value: int):
        return self.ops.acknowledge_mask(value, 0x4)

    def clear_info(self, value: int):
        return self.ops.acknowledge_mask(value, 0x8)


_GROUPS = {"AZ": "AZIMUTH", "HA": "AZIMUTH", "ZD": "ELEVATION", "DEC": "ELEVATION", "CABINET": "CABINET",
           "TELESCOPE": "TELESCOPE", "POINTING": "POINTING", "LOCAL": "LOCAL", "GPS": "LOCAL",
           "DEROTATOR": "DEROTATOR", "FOCUS": "FOCUS", "FILTER": "FILTER", "MIRROR": "PORT",
           "DOME": "DOME", "COVER": "COVER", "SENSOR": "AUXILIARY", "SWITCH": "AUXILIARY",
           "CONFIG": "TELESCOPE"}


def group_of(module: str) -> str:
    """The function group of an OpenTCI module in TELESCOPE.STATUS.LIST."""
    return _GROUPS.get(module.split("[", 1)[0], "TELESCOPE")


# --------------------------------------------------------------------------- event names

_EVENT_PREFIX = {"AZ", "ZD", "HA", "DEC", "DEROTATOR", "FOCUS", "FILTER", "DOME"}


def event_source(name: str) -> str:
    """The OpenTSI module an OpenTCI module's events are reported under."""
    base = name.split("[", 1)[0]
    if base in _EVENT_PREFIX:
        return f"POSITION.INSTRUMENTAL.{name}"
    if base == "MIRROR":
        return "POSITION.INSTRUMENTAL.PORT_SELECT"
    if base in ("CABINET", "CONFIG"):
        return "TELESCOPE"
    if base == "LOCAL" or base == "GPS":
        return "POSITION.LOCAL"
    if base in ("COVER", "SENSOR", "SWITCH"):
        return f"AUXILIARY.{name}"
    return name


# --------------------------------------------------------------------------- POSITION

class Position:
    """POSITION.EQUATORIAL / HORIZONTAL / LOCAL from the encoders and the clock."""

    def __init__(self, telescope):
        self._t = telescope

    @property
    def _p(self):
        p = self._t.pointing
        if p is None:
            raise TcsError("no POINTING module (main axes not configured)", ErrorNumber.INVMODE)
        return p

    @property
    def ra_j2000(self) -> float:
        return self._p.current.ra

    @property
    def dec_j2000(self) -> float:
        return self._p.current.dec

    def _apparent(self) -> tuple[float, float]:
        p = self._p
        place = p.place()
        utc = p.utc()
        d1, d2 = erfa.dtf2d("UTC", *_ymdhms(utc))
        tt1, tt2 = erfa.utctai(d1, d2)
        tt1, tt2 = erfa.taitt(tt1, tt2)
        ri, di, eo = erfa.atci13(math.radians(place.ra * 15.0), math.radians(place.dec), 0.0, 0.0, 0.0,
                                 0.0, tt1, tt2)
        return float(erfa.anp(ri - eo)) * 12.0 / math.pi, math.degrees(float(di))

    @property
    def ra_current(self) -> float:
        return self._apparent()[0]

    @property
    def dec_current(self) -> float:
        return self._apparent()[1]

    @property
    def parallactic_angle(self) -> float:
        return self._p.current.pa

    def _horizontal(self) -> tuple[float, float]:
        """Observed (az, zd) the axes point to, model removed, normal orientation."""
        p = self._p
        place = p.place()
        n1, n2, _reverse = to_normal(place.ideal1, place.ideal2, p.mount)
        if p.mount == "AZ-ZD":
            return float(n1) % 360.0, float(n2)
        az, el = erfa.hd2ae(math.radians(float(n1)), math.radians(float(n2)), math.radians(p.latitude))
        return math.degrees(float(az)) % 360.0, 90.0 - math.degrees(float(el))

    @property
    def az(self) -> float:
        return self._horizontal()[0]

    @property
    def zd(self) -> float:
        return self._horizontal()[1]

    @property
    def alt(self) -> float:
        return 90.0 - self._horizontal()[1]

    @property
    def dome(self) -> float:
        parts = self._t.dome or []
        if not parts or parts[0] is None:
            raise TcsError("no rotating dome", ErrorNumber.INVMODE)
        return parts[0].real_position

    @property
    def derotator(self) -> float:
        rotator, _port = self._p.active_derotator()
        return rotator.real_position

    # LOCAL
    @property
    def utc(self) -> float:
        return self._t.local.utc()

    @property
    def jd(self) -> float:
        return self._t.local.utc() / 86400.0 + 2440587.5

    @property
    def sidereal_time(self) -> float:
        return self._p.sidereal_time


def _ymdhms(utc: float):
    import datetime as _dt
    t = _dt.datetime.fromtimestamp(utc, _dt.timezone.utc)
    return t.year, t.month, t.day, t.hour, t.minute, t.second + t.microsecond * 1e-6


# --------------------------------------------------------------------------- AUXILIARY

class Fraction:
    """An axis (cover, shutter) as 0…1: REALPOS / max; TARGETPOS 1 opens, 0 closes."""

    def __init__(self, axis):
        self.axis = axis

    @property
    def realpos(self) -> float:
        stale = getattr(self.axis, "stale", None)
        if stale is not None:  # the PLC is lost: an error, not the last position
            raise stale
        s = self.axis.section
        span = (s.max - s.min) or 1.0
        return min(1.0, max(0.0, (self.axis.real_position - s.min) / span))

    @property
    def targetpos(self) -> int:
        s = self.axis.section
        return 1 if self.axis.target_position >= (s.min + s.max) / 2 else 0

    def set_targetpos(self, value: int):
        s = self.axis.section
        return self.axis.set_target(s.max if int(value) else s.min)


class DomeShutters:
    """AUXILIARY.DOME: TARGETPOS bit mask (bit 0 all shutters, bit i part i), REALPOS 0…1 (the
    most open shutter), OPEN_MASK (bit i: part i fully open)."""

    def __init__(self, parts):
        self.parts = {i: Fraction(p) for i, p in enumerate(parts) if p is not None and i in (1, 2)}

    @property
    def targetpos(self) -> int:
        return sum(1 << i for i, f in self.parts.items() if f.targetpos)

    def set_targetpos(self, value: int):
        value = int(value)
        waits = []
        for i, f in self.parts.items():
            want = bool(value & 1) or bool(value & (1 << i))
            waits.append(f.set_targetpos(1 if want else 0))

        async def run() -> None:
            await gather_all(*waits)
        return run()

    @property
    def realpos(self) -> float:
        return max((f.realpos for f in self.parts.values()), default=0.0)

    @property
    def open_mask(self) -> int:
        return sum(1 << i for i, f in self.parts.items() if f.realpos >= 0.999)


def dome_shutters(telescope):
    parts = telescope.dome or []
    view = DomeShutters(parts)
    return view if view.parts else None


def covers(telescope) -> Fraction | None:
    cover = telescope.peripherals.cover
    if cover is None:
        covers = telescope.peripherals.covers
        cover = covers[0] if covers else None
    return Fraction(cover) if cover is not None else None


def aux_sensors(telescope) -> list:
    """AUXILIARY.SENSOR[i] → SENSOR[j] by ``[opentsi] sensors`` (default the same index)."""
    sensors = list(telescope.peripherals.sensors)
    table = list(telescope.config.opentsi.sensors) or list(range(len(sensors)))
    return [sensors[j] if 0 <= j < len(sensors) else None for j in table]


class Environment:
    """TELESCOPE.ENVIRONMENT (measured) and CONFIG.ENVIRONMENT (the refraction's inputs)."""

    def __init__(self, telescope):
        self._t = telescope

    def _sensor(self, unit: str) -> float:
        for s in self._t.peripherals.sensors:
            if s.unit == unit:
                return s.value
        raise TcsError(f"no sensor in {unit}", ErrorNumber.INVMODE)

    @property
    def temperature(self) -> float:
        return self._sensor("°C")

    @property
    def pressure(self) -> float:
        return self._sensor("hPa")

    @property
    def _refraction(self):
        p = self._t.pointing
        if p is None:
            raise TcsError("no POINTING module", ErrorNumber.INVMODE)
        return p.refraction

    @property
    def refraction_temperature(self) -> float:
        return self._refraction.temperature

    @property
    def refraction_pressure(self) -> float:
        return self._refraction.pressure

    def set_refraction_temperature(self, value: float) -> None:
        r = self._refraction
        r.set_temperature(value)
        r.set_mode(2)

    def set_refraction_pressure(self, value: float) -> None:
        r = self._refraction
        r.set_pressure(value)
        r.set_mode(2)


def mount_name(telescope) -> str:
    """OpenTSI spells the equatorial mount HA-DEC."""
    mount = telescope.mount_config.mount
    return "HA-DEC" if mount == "RA-DEC" else mount


def mount_options(telescope) -> str:
    text = telescope.mount_config.mount_options
    return text.replace("RA-DEC", "HA-DEC")


def check_index(value: int, count: int, what: str) -> None:
    if not 0 <= value < count:
        raise RangeRefused(f"{what} {value} is outside 0…{count - 1}")


__all__ = ["StatusView", "Position", "Fraction", "DomeShutters", "Environment", "event_source",
           "group_of", "aux_sensors", "covers", "dome_shutters", "mount_name", "mount_options"]
