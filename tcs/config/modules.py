"""Hardware-file sections that map OpenTCI modules onto PLC axes and points.

``[dome]``, ``[[covers]]``, ``[[sensors]]``, ``[[switches]]`` and ``[interlocks]`` say which
``[plcs.<name>]`` axis or point backs which module; a section that is absent is a module that
does not exist. PLC things are named ``"<plc>.<name>"``: an axis of the axis convention
(:mod:`tcs.config.plc`) or a point of the register map::

    [dome]                      # DOME[] (spec §10) and CONFIG.DOME (§7)
    type = "classic"            # classic | roll-roof | clamshell | fold
    diameter = 6.5              # m, CONFIG.DOME.DIAMETER

    [dome.rotation]             # one table per part; the part decides the DOME[] index
    axis = "dome.az"
    max_velocity = 4.0          # CURRSPEED!MAX (the PLC runs the motion at its own speed)

    [dome.slit]
    axis = "dome.slit"
    max = 100.0                 # fully open; 0 (min) is closed (App. C.3)
    max_velocity = 5.0
    timeout = 60.0              # a move that takes longer fails with 7 (timeout)

    [[covers]]                  # one COVER; several make COVER[0], COVER[1], … in file order
    axes = ["telescope.cover1", "telescope.cover2"]   # petals moved together
    max = 90.0
    max_velocity = 15.0

    [[sensors]]                 # SENSOR[0], SENSOR[1], … in file order
    point = "dome.temp_outside" # NAME/DESCRIPTION/UNIT default to the point's own

    [[switches]]                # SWITCH[0], … ; VALUE writes the point, reads the feedback
    point = "dome.dome_lights"
    feedback = "dome.dome_lights_on"

    [interlocks]                # the weather interlock of the dome and the covers
    rain = "dome.rain"          # true while it rains
    wind = "dome.wind_speed"
    wind_limit = 15.0           # refuse opening above this (the point's unit)
    close_on_rain = true        # close by themselves when rain is detected
    release_after = 600.0       # s of good weather before opening is allowed again

Parts of each dome type and their ``DOME[]`` index (spec §10): classic — rotation 0, slit 1,
flap 2, seal 3; roll-roof — roof 1, seal 3; fold — fold 1, seal 3; clamshell — shell1 1,
shell2 2, seal 3. (Appendix C.3 numbers the fold and clamshell parts from 0; §10's table,
with the same index for "open/close" on every type, is what this project follows.)

:func:`check_modules` checks every reference against ``[plcs]`` (``HwConfig.check`` calls it),
so a mapping that names a missing PLC, axis or point is refused when the file is loaded.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from tcs.config.schema import setting

DOME_TYPES = ("classic", "roll-roof", "clamshell", "fold")
#: type -> part names by DOME[] index (None: no part at that index).
DOME_PARTS: dict[str, tuple[str | None, ...]] = {
    "classic": ("rotation", "slit", "flap", "seal"),
    "roll-roof": (None, "roof", None, "seal"),
    "fold": (None, "fold", None, "seal"),
    "clamshell": (None, "shell1", "shell2", "seal"),
}
REQUIRED_PARTS = {"classic": ("rotation",), "roll-roof": ("roof",), "fold": ("fold",),
                  "clamshell": ("shell1", "shell2")}
ALL_PARTS = ("rotation", "slit", "flap", "seal", "roof", "fold", "shell1", "shell2")
#: Parts that open the enclosure: the weather interlock guards them unless told otherwise.
OPENING_PARTS = frozenset({"slit", "flap", "roof", "fold", "shell1", "shell2"})


@dataclass(frozen=True, kw_only=True)
class PlcMotionSection:
    """What every PLC-driven OpenTCI axis (a DOME[] part, a COVER) says about its motion."""

    min: float = setting(0.0, doc="closed / lowest position (REALPOS!MIN); App. C.3: 0 = closed")
    max: float | None = setting(None, doc="fully open / highest position (REALPOS!MAX); rotation: 360")
    max_velocity: float = setting(min=1e-9, doc="units/s, CURRSPEED!MAX (the PLC sets the real speed)")
    max_acceleration: float | None = setting(None, min=1e-9,
                                             doc="units/s², CURRACC!MIN/!MAX only; default max_velocity/s")
    timeout: float = setting(120.0, min=0.1, max=3600.0, doc="s a move may take before it fails with 7")
    tolerance: float = setting(0.1, min=0.0, doc="on-target window of the TCS's own checks, units")
    interlock: bool | None = setting(None, doc="guarded by [interlocks] (default: opening parts and covers)")
    hw_type: int = setting(1, min=1, doc="TYPE of the module")

    def _motion_problems(self, default_max: float | None = None) -> list[tuple[str, str]]:
        hi = self.max if self.max is not None else default_max
        if hi is None:
            return [("max", "missing: the fully open (highest) position")]
        if self.min >= hi:
            return [("max", f"{hi} must be above min ({self.min})")]
        return []


@dataclass(frozen=True, kw_only=True)
class DomeAxisSection(PlcMotionSection):
    """One part of the dome (``[dome.<part>]``)."""

    axis: str = setting(doc="the PLC axis, '<plc>.<axis>'")


@dataclass(frozen=True, kw_only=True)
class CoverSection(PlcMotionSection):
    """One mirror cover (``[[covers]]``): one PLC axis, or several petals moved together."""

    axes: list[str] = setting(doc="PLC axes '<plc>.<axis>' moved together (all on one PLC)")
    name: str = setting("", doc="free text for the log (e.g. 'M1 cover')")

    def check(self):
        problems = self._motion_problems()
        if not self.axes:
            problems.append(("axes", "must name at least one PLC axis"))
        plcs = {a.split(".", 1)[0] for a in self.axes}
        if len(plcs) > 1:
            problems.append(("axes", f"the petals of one cover must be on one PLC, not {sorted(plcs)}"))
        return problems


@dataclass(frozen=True)
class DomeSection:
    """The dome (``[dome]``): its type, size and parts."""

    type: Literal["classic", "roll-roof", "clamshell", "fold"] = setting(doc="kind of enclosure")
    diameter: float = setting(0.0, min=0.0, max=1000.0, doc="m, CONFIG.DOME.DIAMETER")
    rotation: DomeAxisSection | None = setting(None, doc="classic: azimuth of the slit, DOME[0]")
    slit: DomeAxisSection | None = setting(None, doc="classic: the slit, DOME[1]")
    flap: DomeAxisSection | None = setting(None, doc="classic: the flap, DOME[2]")
    seal: DomeAxisSection | None = setting(None, doc="any type: the seal, DOME[3]")
    roof: DomeAxisSection | None = setting(None, doc="roll-roof: the roof, DOME[1]")
    fold: DomeAxisSection | None = setting(None, doc="fold enclosure: open/close, DOME[1]")
    shell1: DomeAxisSection | None = setting(None, doc="clamshell: first shell, DOME[1]")
    shell2: DomeAxisSection | None = setting(None, doc="clamshell: second shell, DOME[2]")
    trajectory_buffer: int = setting(120, min=2, max=100000, doc="DOME[0].TRAJECTORY.BUFFER[] size")
    lead: float = setting(1.0, min=0.0, max=60.0, doc="s DOME[0] aims ahead on its trajectory")
    track_tolerance: float = setting(2.0, min=0.0, max=180.0,
                                     doc="deg: DOME[0] on target (MOTION_STATE bit 3) while following")

    def parts(self) -> dict[int, tuple[str, DomeAxisSection]]:
        """Configured parts by DOME[] index."""
        out = {}
        for index, part in enumerate(DOME_PARTS[self.type]):
            if part is not None and getattr(self, part) is not None:
                out[index] = (part, getattr(self, part))
        return out

    def check(self):
        problems = []
        allowed = [p for p in DOME_PARTS[self.type] if p]
        for part in ALL_PARTS:
            section = getattr(self, part)
            if section is None:
                continue
            if part not in allowed:
                problems.append((part, f"a {self.type} dome has no {part} (its parts: {', '.join(allowed)})"))
                continue
            problems.extend((f"{part}.{key}", text) for key, text in
                            section._motion_problems(360.0 if part == "rotation" else None))
        for part in REQUIRED_PARTS[self.type]:
            if getattr(self, part) is None:
                problems.append((part, f"missing: a {self.type} dome needs [dome.{part}]"))
        return problems


@dataclass(frozen=True)
class SensorSection:
    """One ``SENSOR[]`` (``[[sensors]]``): a readable PLC point."""

    point: str = setting(doc="'<plc>.<point>' (a bit of a register: '<plc>.<point>.<bit>')")
    name: str = setting("", doc="NAME; default: the point's name")
    description: str = setting("", doc="DESCRIPTION; default: the point's description")
    unit: str = setting("", doc="UNIT; default: the point's unit")
    hw_type: int = setting(1, min=1, doc="TYPE of the module")


@dataclass(frozen=True)
class SwitchSection:
    """One ``SWITCH[]`` (``[[switches]]``): a writable coil or integer register."""

    point: str = setting(doc="'<plc>.<point>' written by SET VALUE (a coil or an integer register)")
    feedback: str = setting("", doc="'<plc>.<point>' read by GET VALUE; default: the point itself")
    name: str = setting("", doc="NAME; default: the point's name")
    description: str = setting("", doc="DESCRIPTION; default: the point's description")
    unit: str = setting("", doc="UNIT; default: the point's unit")
    min: int | None = setting(None, doc="lowest VALUE; default 0")
    max: int | None = setting(None, doc="highest VALUE; default 1 for a coil, the register's range")
    hw_type: int = setting(1, min=1, doc="TYPE of the module")

    def check(self):
        if self.min is not None and self.max is not None and self.min > self.max:
            return [("max", f"{self.max} is below min {self.min}")]
        return []


@dataclass(frozen=True)
class InterlockSection:
    """The weather interlock of the dome's opening parts and the covers (``[interlocks]``)."""

    rain: str = setting("", doc="'<plc>.<point>' true (non-zero) while it rains; empty: no rain sensor")
    wind: str = setting("", doc="'<plc>.<point>' wind speed; empty: no wind sensor")
    wind_limit: float = setting(0.0, min=0.0, doc="refuse opening above this wind (0: no limit)")
    close_on_rain: bool = setting(True, doc="close the guarded parts by themselves when rain is detected")
    close_on_wind: bool = setting(False, doc="close them by themselves when the wind is above the limit")
    release_after: float = setting(600.0, min=0.0, max=86400.0,
                                   doc="s the weather must stay good before opening is allowed again")

    def check(self):
        problems = []
        if self.wind_limit > 0 and not self.wind:
            problems.append(("wind", "wind_limit needs the wind point"))
        if self.close_on_wind and not self.wind_limit:
            problems.append(("close_on_wind", "needs a wind_limit"))
        return problems


# ----------------------------------------------------------------------------- cross checks


def split_ref(ref: str) -> tuple[str, str]:
    """``"<plc>.<name>"`` → (plc, name); the name may itself contain a dot (a named bit)."""
    plc, _, name = ref.partition(".")
    return plc, name


def check_modules(config) -> list[tuple[str, str]]:
    """References of the module sections against ``[plcs]`` (called by ``HwConfig.check``)."""
    problems: list[tuple[str, str]] = []
    users: dict[str, str] = {}

    def plc_of(ref: str, key: str):
        plc, name = split_ref(ref)
        if not plc or not name:
            problems.append((key, f"{ref!r} must be '<plc>.<name>'"))
            return None, name
        section = config.plcs.get(plc)
        if section is None:
            problems.append((key, f"no PLC {plc!r} in [plcs] (known: {', '.join(config.plcs) or 'none'})"))
        return section, name

    def axis(ref: str, key: str) -> None:
        section, name = plc_of(ref, key)
        if section is None:
            return
        for sub, problem in section.axis_problems(name):
            problems.append((key, f"PLC axis {ref!r} does not follow the axis convention: "
                                  f"plcs.{split_ref(ref)[0]}.{sub}: {problem}"))
        if ref in users:
            problems.append((key, f"PLC axis {ref!r} already moves {users[ref]}"))
        users.setdefault(ref, key)

    def point(ref: str, key: str, *, write: bool = False):
        section, name = plc_of(ref, key)
        if section is None:
            return None
        base, _, bit = name.partition(".")
        p = section.map.get(base)
        if p is None:
            problems.append((key, f"PLC {split_ref(ref)[0]!r} has no point {base!r}"))
            return None
        if bit and bit not in dict(p.bits):
            problems.append((key, f"point {base!r} has no bit {bit!r} (bits: {', '.join(dict(p.bits)) or 'none'})"))
            return None
        if write and (bit or not p.writable):
            problems.append((key, f"point {name!r} is not writable"))
            return None
        if not write and not p.readable:
            problems.append((key, f"point {name!r} is not readable"))
            return None
        return p

    if config.dome is not None:
        for part in ALL_PARTS:
            section = getattr(config.dome, part)
            if section is not None:
                axis(section.axis, f"dome.{part}.axis")
    for i, cover in enumerate(config.covers):
        for j, ref in enumerate(cover.axes):
            axis(ref, f"covers[{i}].axes[{j}]")
    names: dict[str, str] = {}
    for i, sensor in enumerate(config.sensors):
        point(sensor.point, f"sensors[{i}].point")
        name = (sensor.name or split_ref(sensor.point)[1]).upper()
        if name in names:
            problems.append((f"sensors[{i}].name", f"{name!r} is already {names[name]}"))
        names.setdefault(name, f"sensors[{i}]")
    names.clear()
    for i, switch in enumerate(config.switches):
        p = point(switch.point, f"switches[{i}].point", write=True)
        if p is not None and p.type != "bool" and not p.is_integer:
            problems.append((f"switches[{i}].point", f"point {p.name!r} is not an integer or a coil "
                                                     f"(SWITCH VALUE is an INT)"))
        if switch.feedback:
            point(switch.feedback, f"switches[{i}].feedback")
        name = (switch.name or split_ref(switch.point)[1]).upper()
        if name in names:
            problems.append((f"switches[{i}].name", f"{name!r} is already {names[name]}"))
        names.setdefault(name, f"switches[{i}]")
    lock = config.interlocks
    if lock is not None:
        if lock.rain:
            point(lock.rain, "interlocks.rain")
        if lock.wind:
            point(lock.wind, "interlocks.wind")
    return problems
