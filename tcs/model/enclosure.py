"""DOME[] (spec §10), CONFIG.DOME (§7) and COVER / COVER[] (§9), built from the hardware file.

Every part is a :class:`~tcs.model.plc_axis_module.PlcAxisModule` on PLC axes. The dome's type
decides what each ``DOME[]`` index means (§10's table):

=============  =============================================================
classic        0 rotation (slit azimuth, degrees, CYCLIC 360, OFFSET and
               TRAJECTORY), 1 slit, 2 flap, 3 seal
roll-roof      1 roof, 3 seal
fold           1 open/close, 3 seal
clamshell      1 first shell, 2 second shell, 3 seal
=============  =============================================================

Indices without a part are absent elements of the array (their members answer UNKNOWN);
positions follow App. C.3: 0 = closed. ``CONFIG.DOME.CAPABILITIES`` (:class:`DomeInfo`): bit 0
the rotation, bit 1 the opening part at index 1 (slit, roof, fold, first shell), bit 2 the one
at index 2 (flap, second shell), bit 3 the seal, bit 4 a roll-roof, bit 5 a clamshell. A fold
enclosure has no type bit of its own (bits 1 and 3 only). ``DIAMETER`` is metres.

Covers: one ``[[covers]]`` entry is the plain module ``COVER`` (spec §3: "if only one instance
is available, the module should not be defined as an array"); several are ``COVER[0]``,
``COVER[1]`` … in file order. A cover with several PLC axes (the petals of one mirror cover)
moves them together and reads closed only when every petal is closed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from tcs.config.modules import OPENING_PARTS, CoverSection, DomeSection, split_ref
from tcs.drivers.modbus import PlcDriver
from tcs.drivers.plc_axis import PlcAxis
from tcs.model.plc_axis_group import AxisGroup, PlcAxisSettings
from tcs.model.plc_axis_module import PlcAxisModule
from tcs.model.plc_trajectory import PlcTrajectory

#: CONFIG.DOME.CAPABILITIES bits (spec §7).
CAP_ROTATION, CAP_SLIT, CAP_FLAP, CAP_SEAL, CAP_ROLL_ROOF, CAP_CLAMSHELL = 1, 2, 4, 8, 16, 32


@dataclass(frozen=True)
class DomeInfo:
    """Domain object of ``CONFIG.DOME``."""

    capabilities: int
    diameter: float

    @classmethod
    def from_section(cls, dome: DomeSection) -> DomeInfo:
        parts = dome.parts()
        caps = 0
        for index, bit in ((0, CAP_ROTATION), (1, CAP_SLIT), (2, CAP_FLAP), (3, CAP_SEAL)):
            if index in parts:
                caps |= bit
        caps |= {"roll-roof": CAP_ROLL_ROOF, "clamshell": CAP_CLAMSHELL}.get(dome.type, 0)
        return cls(caps, dome.diameter)


def _group(refs, drivers: dict[str, PlcDriver]) -> AxisGroup:
    axes = []
    for ref in refs:
        plc, name = split_ref(ref)
        axes.append(PlcAxis(drivers[plc], name))
    return AxisGroup(axes)


def build_dome(dome: DomeSection, drivers: dict[str, PlcDriver], *, events, ut1: Callable[[], float],
               main_power: Callable[[], bool]) -> list[PlcAxisModule | None]:
    """The ``DOME[]`` elements by index (None where the type has no configured part)."""
    parts = dome.parts()
    elements: list[PlcAxisModule | None] = [None] * (max(parts) + 1)
    for index, (part, section) in parts.items():
        rotation = part == "rotation"
        guarded = section.interlock if section.interlock is not None else part in OPENING_PARTS
        module = PlcAxisModule(f"DOME[{index}]", _group([section.axis], drivers),
                               PlcAxisSettings.from_section(section, cyclic=rotation), events=events,
                               main_power=main_power, hw_type=section.hw_type,
                               offset_allowed=rotation, guarded=guarded)
        if rotation:
            module.trajectory = PlcTrajectory(module, dome.trajectory_buffer, dome.lead,
                                              dome.track_tolerance, ut1)
        elements[index] = module
    return elements


def build_covers(covers: list[CoverSection], drivers: dict[str, PlcDriver], *, events,
                 main_power: Callable[[], bool]) -> list[PlcAxisModule]:
    """The covers in file order (named ``COVER`` when there is one, else ``COVER[i]``)."""
    out = []
    for i, section in enumerate(covers):
        name = "COVER" if len(covers) == 1 else f"COVER[{i}]"
        guarded = section.interlock if section.interlock is not None else True
        out.append(PlcAxisModule(name, _group(section.axes, drivers), PlcAxisSettings.from_section(section),
                                 events=events, main_power=main_power, hw_type=section.hw_type,
                                 guarded=guarded))
    return out
