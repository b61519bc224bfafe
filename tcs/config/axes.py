"""Axes and the in-process simulation in the hardware file: ``[axes.<name>]`` and
``[simulation]``.

Each ``[axes.<name>]`` table is one OpenTCI axis module bound to one drive of ``[drives]``:
which module it is (``AZ``, ``ZD``, ``HA``, ``DEC``, ``DEROTATOR``, ``FOCUS``, ``FILTER``,
``MIRROR``; ``index`` for arrays — the port index of spec App. C.2 for derotators and filters),
its software limits (``REALPOS!MIN``/``!MAX``), its period for cyclic axes, its dynamics for
ruckig, the on-target tolerance, the size of its trajectory buffer, and for discrete axes
(filter wheels, M3) the drive position of each integer position.

``[simulation]`` lists simulated drives that ``tcs-server`` starts in the same process on the
``virtual`` bus (the default telescope): per drive the physics of :class:`SimDriveParams`.
A real cabinet's file has no ``[simulation]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from tcs.config.schema import setting

AXIS_MODULES = ("AZ", "ZD", "HA", "DEC", "DEROTATOR", "FOCUS", "FILTER", "MIRROR")
ARRAY_MODULES = ("DEROTATOR", "FILTER", "ZD")
TRAJECTORY_MODULES = ("AZ", "ZD", "HA", "DEC", "DEROTATOR")
DISCRETE_MODULES = ("FILTER", "MIRROR")


@dataclass(frozen=True)
class AxisSection:
    module: Literal["AZ", "ZD", "HA", "DEC", "DEROTATOR", "FOCUS", "FILTER", "MIRROR"] = setting(
        doc="OpenTCI module this axis serves")
    drive: str = setting(doc="name of its drive in [drives]")
    min: float = setting(doc="software limit, user units (REALPOS!MIN)")
    max: float = setting(doc="software limit, user units (REALPOS!MAX)")
    max_velocity: float = setting(doc="units/s (CURRSPEED!MAX)", min=1e-9)
    max_acceleration: float = setting(doc="units/s² (CURRACC!MAX)", min=1e-9)
    max_jerk: float = setting(doc="units/s³ (CURRJRK!MAX)", min=1e-9)
    index: int | None = setting(None, min=0, max=11, doc="element of a module array (port index for "
                                                         "DEROTATOR/FILTER, 0/1 for ZD-ZD)")
    cyclic: float = setting(0.0, min=0.0, doc="period of a rotary axis (360.0), 0 = not cyclic")
    stop_deceleration: float = setting(0.0, min=0.0, doc="deceleration of STOP, units/s² "
                                                         "(0 = 2 × max_acceleration)")
    tolerance: float = setting(0.001, min=0.0, doc="on target when |REALPOS - demand| ≤ this")
    trajectory_buffer: int = setting(120, min=2, max=100000, doc="TRAJECTORY.BUFFER[] size")
    positions: dict[str, float] = setting(
        factory=dict, doc="discrete axes: integer position (as a string key) -> drive position")
    hw_type: int = setting(1, min=1, doc="TYPE of the module")
    park: float | None = setting(None, doc="park position, user units (OpenTSI TELESCOPE.READY=0, "
                                           "Alpaca Park and tcs-client park move the axis there; "
                                           "OpenTCI PARKPOS reads it); absent: the axis is not parked")
    names: dict[str, str] = setting(
        factory=dict, doc="discrete axes: integer position (string key) -> name (filter names)")

    def check(self):
        problems = []
        if self.min >= self.max:
            problems.append(("max", f"must be greater than min ({self.min})"))
        if self.park is not None and not self.min <= self.park <= self.max:
            problems.append(("park", f"{self.park} is outside [{self.min}, {self.max}]"))
        if self.module in ARRAY_MODULES[:2] and self.index is None:
            problems.append(("index", f"{self.module} is an array: give its index (port)"))
        if self.module in DISCRETE_MODULES:
            if not self.positions:
                problems.append(("positions", f"{self.module} moves between discrete positions: list them"))
            for key in self.names:
                if key not in self.positions:
                    problems.append((f"names.{key}", f"no position {key} in positions"))
            for key, value in self.positions.items():
                if not key.lstrip("-").isdigit():
                    problems.append((f"positions.{key}", "keys are the integer positions, e.g. \"0\""))
                elif not self.min <= value <= self.max:
                    problems.append((f"positions.{key}", f"{value} is outside [{self.min}, {self.max}]"))
        return problems


@dataclass(frozen=True)
class SimDriveSection:
    max_velocity: float = setting(5.0, min=1e-9, doc="motor limit, units/s")
    max_acceleration: float = setting(5.0, min=1e-9, doc="motor limit, units/s²")
    position: float = setting(0.0, doc="position at power-up, units")
    negative_limit_switch: float | None = setting(
        None, doc="position of the negative limit switch, units (active at and below it); absent: none")
    positive_limit_switch: float | None = setting(
        None, doc="position of the positive limit switch, units (active at and above it); absent: none")
    home_switch: float | None = setting(
        None, doc="position of the home switch's edge, units (active at and above it); absent: none")
    home_switch_active_below: bool = setting(
        False, doc="the home switch is active at and below its edge instead (homing methods 5/6/21/22)")
    index_pulse_spacing: float = setting(1.0, min=1e-9, doc="the encoder's index pulse comes at every "
                                                             "multiple of this, units")
    serial: int = setting(1, min=0, max=0xFFFFFFFF, doc="0x1018:4 serial number of the simulated drive "
                                                       "(when [drives] identity gives none)")
    revision: int | None = setting(None, min=0, max=0xFFFFFFFF,
                                   doc="0x1018:3 of the simulated drive (default: [drives] identity, "
                                       "else the EDS's RevisionNumber): another firmware")
    eds: str = setting("", doc="EDS the simulated drive behaves as (absent objects, access, "
                               "limits, mappability, modes of 0x6502); empty = the drive's eds")
    velocity_factor: float | None = setting(
        None, min=1e-12, doc="the simulated drive's velocity units per user unit/s (e.g. rpm); "
                             "default increments_per_unit")
    acceleration_factor: float | None = setting(
        None, min=1e-12, doc="its acceleration units per user unit/s²; default increments_per_unit")
    boot_time: float = setting(0.2, min=0.0, max=60.0,
                               doc="s from power-up or NMT reset to the boot-up message")
    objects: dict[str, int] = setting(
        factory=dict, doc="values of objects the EDS gives no default, \"0xINDEX:SUB\" = integer "
                          "(else built-ins)")

    def check(self):
        from tcs.config.can import sdo_entry
        return [(f"objects.{key}", "write entries as \"0xINDEX:SUB\" = value")
                for key in self.objects if sdo_entry(key) is None]


@dataclass(frozen=True)
class SimulationSection:
    drives: dict[str, SimDriveSection] = setting(factory=dict, doc="simulated drives by drive name")


def check_axes(config) -> list[tuple[str, str]]:
    """Rules across ``[axes]``, ``[drives]`` and the mount (called by ``HwConfig.check``)."""
    problems = []
    seen: dict[tuple, str] = {}
    drives_used: dict[str, str] = {}
    for name, axis in config.axes.items():
        key = (axis.module, axis.index)
        if key in seen:
            problems.append((f"axes.{name}", f"{axis.module}"
                             f"{'' if axis.index is None else f'[{axis.index}]'} is already axis {seen[key]!r}"))
        seen[key] = name
        if axis.drive not in config.drives:
            problems.append((f"axes.{name}.drive", f"no drive {axis.drive!r} in [drives] "
                                                   f"(known: {', '.join(config.drives) or 'none'})"))
        elif axis.drive in drives_used:
            problems.append((f"axes.{name}.drive", f"drive {axis.drive!r} already moves axis "
                                                   f"{drives_used[axis.drive]!r}"))
        drives_used.setdefault(axis.drive, name)
    modules = {a.module for a in config.axes.values()}
    needed = {"AZ-ZD": {"AZ", "ZD"}, "RA-DEC": {"HA", "DEC"}, "ZD-ZD": {"ZD"}}[config.mount.type]
    if config.axes and not needed <= modules:
        problems.append(("axes", f"a {config.mount.type} mount needs axes {sorted(needed)}; "
                                 f"configured: {sorted(modules)}"))
    for name in config.simulation.drives if config.simulation else ():
        if name not in config.drives:
            problems.append((f"simulation.drives.{name}", f"no drive {name!r} in [drives]"))
    return problems
