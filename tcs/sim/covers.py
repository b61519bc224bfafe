"""Simulated mirror covers: PLC axes that open over time between two end switches.

A cover is a :class:`~tcs.sim.plc_axis.SimPlcAxis` with the ``cover`` preset: 0 = closed
(``closed`` end switch), 90 = fully open (``open`` end switch), a few seconds for a full
stroke (spec §9, C.3: "0 if the protective cover is closed and non-zero if not"). Petal covers
driven by one motor are one axis; independently driven petals are several.
"""

from __future__ import annotations

from tcs.sim.plc_axis import AxisParams, axis_points

PRESETS: dict[str, AxisParams] = {
    "cover": AxisParams(speed=15.0, acceleration=30.0, min=0.0, max=90.0, tolerance=0.1,
                        stall_detect=0.5),
}


def cover_points(names: list[str], *, hbase: int = 100, ibase: int = 100,
                 stride: int = 10) -> tuple[dict[str, dict], dict[str, dict]]:
    """(points, sim axes) of covers ``names``, cover i at ``hbase/ibase + stride * i``."""
    points: dict[str, dict] = {}
    axes: dict[str, dict] = {}
    for i, name in enumerate(names):
        points.update(axis_points(name, hbase + stride * i, ibase + stride * i, "deg", f"mirror cover {name}"))
        axes[name] = {"preset": "cover"}
    return points, axes
