"""Declaration of DOME[] (spec §10), COVER / COVER[] (§9), SENSOR[] / SWITCH[] (§13) and GPS (§11).

DOME[] parts and covers are generic axes: the same :func:`axis_members` declaration as the
drive axes, bound to :class:`tcs.model.plc_axis_module.PlcAxisModule` objects (a TRAJECTORY
only where the object has one: the dome rotation). Sensors, switches and the GPS are bound to
:mod:`tcs.model.aux_io` and :mod:`tcs.model.gps_module`. What exists follows the hardware file
(``[dome]``, ``[[covers]]``, ``[[sensors]]``, ``[[switches]]``, ``[gps]``; see
:mod:`tcs.config.modules`). Part of the one declaration of the tree (``opentci.py`` lists
:data:`ENCLOSURE`).
"""

from __future__ import annotations

from tcs.opentci_server.opentci.axes import axis_members
from tcs.opentci_server.opentci.common import common
from tcs.opentci_server.tree import FLOAT, INT, STRING, module, module_array, var


def _peripherals(root):
    return root.telescope.peripherals


DOME = module_array(
    "DOME", *axis_members(),
    info="dome parts by index: classic 0 rotation (deg), 1 slit, 2 flap, 3 seal; roll-roof and "
         "fold 1 open/close, 3 seal; clamshell 1 and 2 shells, 3 seal; 0 = closed",
    bind=lambda root: _peripherals(root).dome,
)

_COVER_INFO = "mirror cover, 0 = closed; TARGETPOS completes at the end position"

COVER = module("COVER", *axis_members(), info=_COVER_INFO, bind=lambda root: _peripherals(root).cover)

COVER_ARRAY = module_array("COVER", *axis_members(), info=_COVER_INFO,
                           bind=lambda root: _peripherals(root).cover_array)


def _text_members():
    return (
        var("NAME", STRING, get="name", info="name"),
        var("DESCRIPTION", STRING, get="description", info="what it is"),
        var("UNIT", STRING, get="unit", info="unit of VALUE"),
    )


SENSOR = module_array(
    "SENSOR", *common(), *_text_members(),
    var("VALUE", FLOAT, get="value", info="latest reading in UNIT (FLOAT: see the notes); returns at once"),
    info="sensors read from the PLCs",
    bind=lambda root: _peripherals(root).sensors,
)

SWITCH = module_array(
    "SWITCH", *common(), *_text_members(),
    var("VALUE", INT, get="value", set="set_value", min=lambda s: s.min, max=lambda s: s.max,
        info="switch state (read from its feedback); writing completes when the PLC took it"),
    info="switches on the PLCs (pumps, lamps, fans)",
    bind=lambda root: _peripherals(root).switches,
)

GPS = module(
    "GPS", *common(),
    var("TIME", FLOAT, get="time", info="receiver UTC, s since 1970, while the receiver's time is valid "
                                        "(also while it disagrees with the system clock); NULL otherwise"),
    # extensions (docs/gps.md): what the receiver's fix is worth
    var("TIME_OFFSET", FLOAT, get="time_offset",
        info="extension: GPS time minus the system clock, s; NULL without a valid GPS time"),
    var("SATELLITES", INT, get="satellites",
        info="extension: satellites used (the combined GN count, else the sum per constellation); NULL: unknown"),
    var("FIX_QUALITY", INT, get="fix_quality",
        info="extension: GGA fix quality of the last position sentence: 0 none, 1 autonomous, 2 differential, "
             "3 PPS, 4 RTK, 5 RTK float, 9 SBAS (fixes); 6 dead reckoning, 7 manual, 8 simulator (not fixes)"),
    var("CONSTELLATIONS", STRING, get="constellations",
        info="extension: per talker 'GP GPS used/in view quality; GL …'"),
    var("SUMMARY", STRING, get="status_text",
        info="extension: the receiver's state in words (fix, satellites, time and why not)"),
    module("POS",
           var("LAT", FLOAT, get="latitude", info="latitude of the last fix, degrees north (NULL: none yet)"),
           var("LON", FLOAT, get="longitude", info="longitude of the last fix, degrees east (NULL: none yet)"),
           var("HEIGHT", FLOAT, get="height", info="height of the last fix above sea level, m"),
           info="position of the last fix"),
    info="the GPS receiver (events 24-27 are sent as LOCAL's)",
    bind=lambda root: _peripherals(root).gps,
)

#: The modules of this file, in the order they are numbered.
ENCLOSURE = (DOME, COVER, COVER_ARRAY, SENSOR, SWITCH, GPS)

__all__ = ["ENCLOSURE"]
