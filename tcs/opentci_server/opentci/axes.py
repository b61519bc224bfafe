"""Declaration of the OpenTCI axis modules (spec §5): AZ, ZD / ZD[], HA, DEC, DEROTATOR[],
FOCUS, FILTER[], MIRROR — one generic axis (§5.1) with its TRAJECTORY (§5.1.1).

Bound to :class:`tcs.axes.axis.Axis` objects of the telescope; which modules exist follows the
hardware file's ``[axes]`` (and so the mount). Part of the one declaration of the tree
(``opentci.py`` lists these modules).
"""

from __future__ import annotations

from tcs.opentci_server.opentci.common import common
from tcs.opentci_server.tree import FLOAT, INT, NOBODY, OPERATE, module, module_array, var


def _lo(axis):
    return float(min(axis.positions)) if axis.discrete else axis.section.min


def _hi(axis):
    return float(max(axis.positions)) if axis.discrete else axis.section.max


def _offset_wlevel(axis) -> int:
    """OFFSET is read-only where the part takes none: discrete axes (FILTER, MIRROR) and the
    PLC parts other than the dome rotation (slit, flap, seal, covers)."""
    return OPERATE if getattr(axis, "offset_allowed", not getattr(axis, "discrete", False)) else NOBODY


def _speed_wlevel(axis) -> int:
    """CURRSPEED is read-only where the hardware sets the speed itself (PLC parts)."""
    return OPERATE if getattr(axis, "speed_writable", True) else NOBODY


TRAJECTORY = module(
    "TRAJECTORY",
    module_array("BUFFER",
                 var("TIME", FLOAT, get="time", set="set_time", info="UT1 of the point, s since 1970"),
                 var("TARGETPOS", FLOAT, get="targetpos", set="set_targetpos",
                     info="position of the point (same unit as TARGETPOS)"),
                 info="staging area of (TIME, TARGETPOS) points", bind=lambda t: t.buffer),
    var("ADDPOINTS", INT, get="addpoints", set="set_addpoints", min=1,
        info="move BUFFER[0..n-1] into the running queue; reads the last count"),
    var("FREEPOINTS", INT, get="freepoints", info="points that still fit into the queue"),
    var("RUN", INT, get="run", set="set_run", min=0, max=1, long=True,
        info="1 runs until the queue ran empty or was aborted; 0 aborts and frees the buffers"),
    var("STARTTIME", FLOAT, get="starttime", info="UT1 of the first queued point"),
    var("RUNTIME", FLOAT, get="runtime", info="seconds of trajectory left"),
    info="time-stamped positions to follow (tracking)",
    bind="trajectory",
)


def _measured(attr: str):
    """Getter of a measured value: the axis's ``stale`` error (FAILED 4) while its drive gives
    no fresh data (offline, stale TPDOs, no control process), so a frozen position — or a
    power or motion state — never reads as live."""
    def get(axis):
        stale = getattr(axis, "stale", None)
        if stale is not None:
            raise stale
        return getattr(axis, attr)
    return get


def axis_members():
    """The variables of the generic axis (§5.1), in the spec's order."""
    return (
        *common(),
        var("POWER", INT, get=lambda a: 1 if _measured("power_state")(a) == 1.0 else 0, set="set_power", min=0, max=1,
            long=True, info="0 off, 1 on; returns when reached"),
        var("POWER_STATE", FLOAT, get=_measured("power_state"), info="-1 emergency off, 0 off, 0.75 standby, 1 on"),
        var("LIMIT_STATE", INT, get=_measured("limit_state"),
            info="bits 0/1 hardware min/max, 7 hardware blocking, 8/9 software min/max, 15 software blocking"),
        var("MOTION_STATE", INT, get=_measured("motion_state"),
            info="bits 0 moving, 1 trajectory, 2 blocked, 3 on target, 4 limited by speed/acc/jerk"),
        var("REFERENCED", FLOAT, get="referenced", info="0 not referenced … 1 referenced (progress)"),
        var("REINIT", INT, set="set_reinit", min=0, max=1, rlevel=NOBODY,
            info="reference: 0 if not referenced, 1 force; returns at once"),
        var("REALPOS", FLOAT, get=_measured("real_position"), min=_lo, max=_hi,
            info="measured position; !MIN/!MAX are the software limits"),
        var("CYCLIC", FLOAT, get="cyclic", info="period of a rotary axis (0: not cyclic)"),
        var("CURRPOS", FLOAT, get=_measured("current_position"), info="REALPOS - OFFSET"),
        var("CURRSPEED", FLOAT, get=_measured("current_speed"), set="set_speed", min=0.0, wlevel=_speed_wlevel,
            max=lambda a: a.section.max_velocity,
            info="speed, units/s; writing lowers the speed of new motion"),
        var("CURRACC", FLOAT, get="current_acc", min=lambda a: -a.section.max_acceleration,
            max=lambda a: a.section.max_acceleration, info="acceleration, units/s²"),
        var("CURRJRK", FLOAT, get="current_jerk", min=lambda a: -a.section.max_jerk,
            max=lambda a: a.section.max_jerk, info="jerk, units/s³"),
        var("TARGETPOS", FLOAT, get="target_position", set="set_target", min=_lo, max=_hi, long=True,
            info="demanded position (user frame); returns on arrival, a newer target supersedes"),
        var("OFFSET", FLOAT, get="offset", set="set_offset", long=True, wlevel=_offset_wlevel,
            info="added to every positioning request; returns when reached"),
        var("TARGETDISTANCE", FLOAT, get=_measured("target_distance"), info="TARGETPOS - CURRPOS"),
        var("STOP", INT, set="set_stop", min=0, max=1, wlevel=OPERATE, rlevel=NOBODY,
            info="quick stop, cancels targets and trajectories; returns at once"),
        var("PARKPOS", FLOAT, get=lambda a: getattr(a, "park_position", None),
            info="park position (TCS extension: the hardware file's park or SetPark's, OFFSET "
                 "included; NULL: not parked); tcs-client park moves there, then powers off"),
        TRAJECTORY,
    )


def _axis(name: str, info: str):
    return module(name, *axis_members(), info=info, bind=lambda root: root.telescope.axis(name))


def _axis_array(name: str, info: str):
    return module_array(name, *axis_members(), info=info,
                        bind=lambda root: root.telescope.axis_array(name))


AXES = (
    _axis("AZ", "azimuth, degrees, 0 = north, east positive"),
    _axis("ZD", "zenith distance, degrees"),
    _axis_array("ZD", "zenith distance axes of a ZD-ZD mount, degrees"),
    _axis("HA", "hour angle axis, degrees"),
    _axis("DEC", "declination axis, degrees"),
    _axis_array("DEROTATOR", "derotators by port (0 Cassegrain, 2 Nasmyth 1, 3 Nasmyth 2 …), degrees"),
    _axis("FOCUS", "focus, mm from the innermost M2 position"),
    _axis_array("FILTER", "filter wheels by port; integer positions"),
    _axis("MIRROR", "M3: integer port positions"),
)
