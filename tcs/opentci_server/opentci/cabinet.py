"""The declaration of the CABINET module (spec §6), bound to :class:`tcs.model.cabinet.Cabinet`.

Kept apart from ``opentci.py`` only for size; it is part of the one declaration of the tree
(``OPENTCI`` lists it). Behaviour — what POWER, REINIT, STOP and the status list do — is
documented in ``tcs/model/cabinet.py`` and ``tcs/model/status_list.py``; the CORE layout in
``tcs/model/cabinet_info.py`` and the LOG[] layout in ``tcs/model/log_buffer.py``.
"""

from __future__ import annotations

from tcs.opentci_server.opentci.common import common
from tcs.errors import ErrorNumber
from tcs.opentci_server.tree import (CONFIGURE, FLOAT, INT, NOBODY, STRING, module, module_array, var,
                                     var_array)

#: CABINET.STATUS.TEXT[n]: the name of error number n (RTS2's ``rts2-opentpl-errors``).
_ERROR_TEXTS = tuple(next((e.name.lower() for e in ErrorNumber if e.value == n), "")
                     for n in range(max(e.value for e in ErrorNumber) + 1))


MANUAL_CONTROL = module(
    "MANUAL_CONTROL",
    var("ACTIVE", INT, get="active", set="set_active", min=0, max=1, long=True,
        info="1: manual control enabled (no paddle is fitted: the effective state MODE AND "
             "ACTIVE stays 0)"),
    var("BRIGHTNESS", FLOAT, get="brightness", set="set_brightness", min=0.0, max=1.0,
        info="brightness of the paddle's buttons 0..1 (stored)"),
    var("MODE", INT, get="mode", info="paddle key switch: 0 disabled (no paddle), 1 enabled"),
    var("SELECTION", INT, get="selection", info="selection made on the paddle (0: none)"),
    info="the optional hand paddle",
    bind="manual_control",
)

SETUP = module(
    "SETUP",
    var("MANUFACTURER", STRING, get="manufacturer", info="who built the cabinet"),
    var("VERSION_TEXT", STRING, get="version_text", info="versions of all components, '; '-separated"),
    var("HW_ID", STRING, get="hw_id", info="unique hardware id of the cabinet"),
    var("HW_VERSION", STRING, get="hw_version", info="hardware version of the cabinet"),
    var("SW_ID", STRING, get="sw_id", info="the control software"),
    var("SW_VERSION", STRING, get="sw_version", info="its version"),
    var("CONFIG_ID", STRING, get="config_id", info="id of the components on the telescope"),
    var("CONFIG_VERSION", STRING, get="config_version", info="version of that configuration"),
    var("PARAM_ID", STRING, get="param_id", info="hash of the hardware file"),
    var("PARAM_VERSION", STRING, get="param_version", info="version (or date) of the hardware file"),
    var("PARAM_NAME", STRING, get="param_name", info="name of the hardware file"),
    info="identification of the cabinet",
    bind="setup",
)

LOG = module_array(
    "LOG",
    var("TEXT", STRING, get="text", info="the log line: time, level, source, message"),
    var("TIME", FLOAT, get="time", info="UTC seconds since 1970 of the line (0: no line)"),
    var("LEVEL", STRING, get="level", info="INFO, WARNING, ERROR or CRITICAL"),
    var("SOURCE", STRING, get="source", info="logger that wrote it"),
    info="recent log lines of the service, newest first",
    bind=lambda cabinet: cabinet.log_buffer.entries,
)

STATUS = module(
    "STATUS",
    var("GLOBAL", INT, get="error_state", info="every ERROR_STATE OR'd"),
    LOG,
    var("LIST", STRING, get=lambda c: c.status_list.text(),
        info="Age:Error:Status:TotalCount:Count:Active:Device[:comment],… newest first; kept "
             "until CLEAR=-1 and across restarts"),
    var("CLEAR", INT, set="clear_status", min=-1, max=-1, rlevel=NOBODY, wlevel=CONFIGURE,
        info="write -1 to delete every LIST entry (configuration level: the record is the operators')"),
    var_array("TEXT", STRING, count=len(_ERROR_TEXTS), get=lambda c: _ERROR_TEXTS,
              info="TEXT[n]: the name of error number n (Appendix B)"),
    info="system status: error memory and log",
)

DRIVE = module_array(
    "DRIVE",
    var("AXIS", STRING, get="axis_name", info="OpenTCI module the drive moves"),
    var("NAME", STRING, get="name", info="drive name in the hardware file"),
    var("STATE", STRING, get="state", info="CiA-402 state (none: no drive)"),
    var("STATUSWORD", INT, get="statusword", info="0x6041 statusword"),
    var("ERRORCODE", INT, get="error_code",
        info="EMCY / 0x603F error code of the fault, else its OpenTCI number; 0: no fault"),
    var("ERRORTEXT", STRING, get="error_text", info="the fault in words"),
    var("POSITION", FLOAT, get="position", info="actual position, user units"),
    var("VELOCITY", FLOAT, get="velocity", info="actual velocity, user units/s"),
    var("FOLLOWING_ERROR", FLOAT, get="following_error", info="following error, user units"),
    var("HEARTBEAT", INT, get="heartbeat", info="1 while the drive's heartbeat is seen"),
    info="servo drives, one per axis",
    bind=lambda cabinet: cabinet.core_drives(),
)

CYCLE = module(
    "CYCLE",
    var("CYCLES", INT, get=lambda c: c.loop_figure("cycles"), info="control-loop cycles run"),
    var("LATE", INT, get=lambda c: c.loop_figure("late"), info="cycles that ended after the next SYNC"),
    var("MISSED", INT, get=lambda c: c.loop_figure("missed"), info="SYNC slots skipped"),
    var("TPDO_TIMEOUTS", INT, get=lambda c: c.loop_figure("tpdo_timeouts"),
        info="cycles run without every drive's TPDO"),
    var("MAX_LATENESS", FLOAT, get=lambda c: c.loop_figure("max_lateness"), info="worst lateness, s"),
    var("REALTIME", INT, get=lambda c: c.loop_figure("realtime"),
        info="1 when the loop thread got its real-time priority (can.realtime_priority)"),
    var("SYNC_INTERVAL", FLOAT, get=lambda c: c.loop_figure("period") * c.loop_figure("sync_divider"),
        info="s between SYNCs now: can.sync_period, or can.idle_sync_period while every drive "
             "rests (the idle SYNC); 0 while no loop runs"),
    info="the cyclic control loop",
)

CORE = module(
    "CORE",
    DRIVE,
    CYCLE,
    info="hardware-dependent diagnostics (TYPE 1: CiA-402 cabinet)",
)

CABINET = module(
    "CABINET",
    *common("cabinet type ([cabinet] hw_type)"),
    var("POWER", INT, get="power", set="set_power", min=0, max=1, long=True,
        info="main power 0 off / 1 on, then every component; returns when reached"),
    var("POWER_STATE", FLOAT, get="power_state", info="-1 emergency off, 0 off, 1 on (all components)"),
    var("REFERENCED", FLOAT, get="referenced", info="mean REFERENCED of all axes, 0..1"),
    var("REINIT", INT, set="set_reinit", min=0, max=1, rlevel=NOBODY,
        info="reference 0 unreferenced / 1 all axes (main axes first); returns at once"),
    var("MODE", INT, get="mode", info="1: remote operation permitted"),
    MANUAL_CONTROL,
    SETUP,
    STATUS,
    var("STOP", INT, set="set_stop", min=0, max=1, rlevel=NOBODY,
        info="stop all movement and POWER/REINIT sequences; returns at once"),
    CORE,
    info="the control cabinet: power, referencing, status",
    bind=lambda root: root.telescope.cabinet,
)

__all__ = ["CABINET"]
