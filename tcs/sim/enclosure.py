"""The simulated dome / enclosure: which axes each enclosure type has, and their physics.

An enclosure is a set of PLC axes (:mod:`tcs.sim.plc_axis`) on one simulated PLC. The type is
decided by configuration — which axes the register map holds and the ``preset`` of each in
``[plcs.<name>.sim.axes.<axis>]`` — with the OpenTCI meaning of positions (spec §10, C.3):

=============  ==========================================  ==================================
type           axes (DOME[] index)                         positions
=============  ==========================================  ==================================
classic        az (0), slit (1), flap (2), seal (3)        az 0..360 deg; others 0 = closed
roll-roof      roof (1), seal (3)                          0 closed .. 100 open
clamshell      shell1 (1), shell2 (2), seal (3)            0 closed .. 90 open
fold           fold (1), seal (3)                          0 closed .. 180 open
=============  ==========================================  ==================================

:func:`enclosure_points` writes the register map of a type (used for the benchmark and to
write ``hwconfig/plc-sim-map.toml``); nothing in here imports the TCS's drivers.
"""

from __future__ import annotations

from tcs.sim.plc_axis import AxisParams, axis_points

PRESETS: dict[str, AxisParams] = {
    "azimuth": AxisParams(speed=4.0, acceleration=2.0, min=0.0, max=360.0, circular=True,
                          tolerance=0.05, stall_detect=1.0),
    "slit": AxisParams(speed=5.0, acceleration=5.0, min=0.0, max=100.0, tolerance=0.1),
    "flap": AxisParams(speed=5.0, acceleration=5.0, min=0.0, max=100.0, tolerance=0.1),
    "seal": AxisParams(speed=0.5, acceleration=1.0, min=0.0, max=1.0, tolerance=0.01),
    "roof": AxisParams(speed=4.0, acceleration=2.0, min=0.0, max=100.0, tolerance=0.1),
    "shell": AxisParams(speed=2.0, acceleration=2.0, min=0.0, max=90.0, tolerance=0.05),
    "fold": AxisParams(speed=3.0, acceleration=3.0, min=0.0, max=180.0, tolerance=0.05),
}

#: type -> ((axis name, preset, unit), ...) in DOME[] index order.
VARIANTS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "classic": (("az", "azimuth", "deg"), ("slit", "slit", "%"), ("flap", "flap", "%"),
                ("seal", "seal", "")),
    "roll-roof": (("roof", "roof", "%"), ("seal", "seal", "")),
    "clamshell": (("shell1", "shell", "deg"), ("shell2", "shell", "deg"), ("seal", "seal", "")),
    "fold": (("fold", "fold", "deg"), ("seal", "seal", "")),
}


def enclosure_points(variant: str, *, stride: int = 10) -> tuple[dict[str, dict], dict[str, dict]]:
    """(points, sim axes) of an enclosure type: axis i at holding/input ``stride * i``."""
    points: dict[str, dict] = {}
    axes: dict[str, dict] = {}
    for i, (name, preset, unit) in enumerate(VARIANTS[variant]):
        points.update(axis_points(name, stride * i, stride * i, unit, f"dome {name}"))
        axes[name] = {"preset": preset}
    return points, axes
