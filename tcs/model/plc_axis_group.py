"""The PLC side of a generic axis on PLC axes: its figures and a group of PLC axes moved as one.

:class:`PlcAxisSettings` holds what the generic-axis declaration reads as ``axis.section``
(limits, speed figures, period, tolerance, timeout), made from a ``[dome.<part>]`` or
``[[covers]]`` section. :class:`AxisGroup` wraps one or more
:class:`~tcs.drivers.plc_axis.PlcAxis` of one PLC behind the PlcAxis interface (``state``,
``move``, ``stop``, ``reset``), so a mirror cover of two petals is one OpenTCI module. Used
only by :class:`tcs.model.plc_axis_module.PlcAxisModule`.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

from tcs.drivers.modbus import PlcSnapshot
from tcs.drivers.plc_axis import AxisState, PlcAxis


@dataclass(frozen=True)
class PlcAxisSettings:
    """The figures the generic axis declaration reads as ``axis.section``."""

    min: float
    max: float
    max_velocity: float
    max_acceleration: float
    max_jerk: float
    cyclic: float
    tolerance: float
    timeout: float

    @classmethod
    def from_section(cls, section, *, cyclic: bool = False) -> PlcAxisSettings:
        """From a :class:`~tcs.config.modules.PlcMotionSection` (rotation: 0..360, cyclic)."""
        hi = section.max if section.max is not None else 360.0
        acc = section.max_acceleration or section.max_velocity
        return cls(min=section.min, max=hi, max_velocity=section.max_velocity, max_acceleration=acc,
                   max_jerk=10.0 * acc, cyclic=(hi - section.min) if cyclic else 0.0,
                   tolerance=section.tolerance, timeout=section.timeout)


class AxisGroup:
    """PLC axes of one driver moved as one; a group of one is a plain axis.

    The combined state follows App. C.3 (0 = closed, non-zero = not closed): the position is
    the most open petal's, the group is moving while any petal moves, at target / closed /
    open only when every petal is, faulted when any is.
    """

    def __init__(self, axes: list[PlcAxis]):
        if not axes or len({id(a.driver) for a in axes}) != 1:
            raise ValueError("an axis group needs one or more axes of one PLC")
        self.axes = list(axes)
        self.driver = axes[0].driver
        self.device = "+".join(a.device for a in axes)

    def state(self, snapshot: PlcSnapshot) -> AxisState:
        states = [a.state(snapshot) for a in self.axes]
        if len(states) == 1:
            return states[0]
        speeds = [s.speed for s in states if s.speed is not None]
        return AxisState(
            position=max(s.position for s in states), target=max(s.target for s in states),
            speed=max(speeds, key=abs) if speeds else None,
            moving=any(s.moving for s in states), at_target=all(s.at_target for s in states),
            closed=all(s.closed for s in states), open=all(s.open for s in states),
            fault=any(s.fault for s in states), stalled=any(s.stalled for s in states),
            cycle=snapshot.cycle, time=snapshot.time)

    def accepted(self, snapshot: PlcSnapshot) -> bool:
        """The PLC took the last command (``X_command`` reads 0 again) on every axis."""
        return all(not snapshot.get(f"{a.name}_command", 0) for a in self.axes)

    async def move(self, target: float) -> int:
        return max(await asyncio.gather(*(a.move(target) for a in self.axes)))

    async def stop(self) -> int:
        return max(await asyncio.gather(*(a.stop() for a in self.axes)))

    async def reset(self) -> int:
        return max(await asyncio.gather(*(a.reset() for a in self.axes)))
