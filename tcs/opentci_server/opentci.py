"""The one declaration of the OpenTCI tree (spec OpenTCI 2.5, protocol doc §8).

Every variable name the server answers to is written here and nowhere else: lookup,
``!MEMBERS``/``!INDEX``, the generated reference (``tools/opentci_reference.py``) and the tests
that walk every variable are derived from it. Each module is bound to a domain object of the
telescope model (``bind=``); a module whose object is absent is not configured and does not
exist. Getters and setters name attributes and methods of those objects; long-running
setters return an awaitable (see ``tcs/opentci_server/tree.py``).

The root object is :class:`Root`: the telescope model plus the server's own information.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tcs.opentci_server.opentci_axes import AXES
from tcs.opentci_server.opentci_cabinet import CABINET
from tcs.opentci_server.opentci_common import common
from tcs.opentci_server.opentci_enclosure import ENCLOSURE
from tcs.opentci_server.opentci_pointing import POINTING
from tcs.opentci_server.tree import (CONFIGURE, FLOAT, INT, OPERATE, READ_ALL, STRING, Tree, module,
                                     sysvar, var)


@dataclass
class Root:
    telescope: Any
    server: Any


def _host(address: str) -> str:
    """``1.2.3.4:5678`` -> ``1.2.3.4``; ``::1:5678`` -> ``::1`` (TPL2 §9: the address only)."""
    host, sep, port = address.rpartition(":")
    return host if sep and port.isdigit() else address


SERVER = module(
    "SERVER",
    var("UPTIME", FLOAT, get="uptime", info="seconds since the server started"),
    var("STARTTIME", FLOAT, get="starttime", info="start of the server, UTC seconds since 1970"),
    var("VERSION", STRING, get="version", info="server software version"),
    module("INFO",
           var("DEVICE", STRING, get="device", info="what this server controls"),
           var("VENDOR", STRING, get="vendor", info="software vendor"),
           var("MANUFACTURER", STRING, get="manufacturer", info="manufacturer of the cabinet"),
           info="server identification"),
    module("CONNECTION",
           sysvar("ID", INT, get="id", info="number of this connection (CONN n of the greeting)"),
           sysvar("ADDRESS", STRING, get=lambda conn: _host(conn.address), info="client address (no port)"),
           sysvar("USERNAME", STRING, get="username", info="user logged in on this connection"),
           sysvar("RLEVEL", INT, get="rlevel", info="read level of this connection"),
           sysvar("WLEVEL", INT, get="wlevel", info="write level of this connection"),
           sysvar("EVENTMASK", INT, get="eventmask", set="set_eventmask", min=0, max=15,
                  info="events sent here: bit 0 ERROR, 1 WARN, 2 INFO, 3 DEBUG"),
           sysvar("ABORT_ON_DISCONNECT", INT, get="abort_on_disconnect", set="set_abort_on_disconnect",
                  min=0, max=1, info="1: a disconnect aborts this connection's running commands"),
           sysvar("STARTTIME", FLOAT, get="starttime", info="when this connection was opened, UTC"),
           sysvar("UPTIME", FLOAT, get="uptime", info="seconds since this connection was opened"),
           info="per-connection settings (each connection sees its own)"),
    info="the TPL2 server itself",
    bind=lambda root: root.server,
)

LOCAL = module(
    "LOCAL",
    *common(),
    var("UTC", FLOAT, get="utc", info="UTC, seconds since 1970"),
    var("UT1", FLOAT, get="ut1", info="UT1, seconds since 1970: the time base of trajectories"),
    var("TAI", FLOAT, get="tai", info="TAI, seconds since 1970"),
    var("UT1-UTC", FLOAT, get="ut1_utc", set="set_ut1_utc", min=-1.0, max=1.0, wlevel=CONFIGURE,
        info="UT1 - UTC in seconds (persisted)"),
    var("TAI-UTC", FLOAT, get="tai_utc", set="set_tai_utc", min=0.0, max=100.0, wlevel=CONFIGURE,
        info="TAI - UTC, leap seconds (persisted)"),
    var("LATITUDE", FLOAT, get="latitude", set="set_latitude", min=-90.0, max=90.0, wlevel=CONFIGURE,
        info="site latitude, degrees north; writing sets SYNCPOS=0"),
    var("LONGITUDE", FLOAT, get="served_longitude", set="set_served_longitude", min=-360.0, max=360.0,
        wlevel=CONFIGURE, info="site longitude, degrees east (see the README for west-positive sites); "
                               "writing sets SYNCPOS=0"),
    var("HEIGHT", FLOAT, get="height", set="set_height", min=-500.0, max=10000.0, wlevel=CONFIGURE,
        info="site height above sea level, m; writing sets SYNCPOS=0"),
    var("SYNCPOS", INT, get="syncpos", set="set_syncpos", min=0, max=1, wlevel=CONFIGURE,
        info="1: the site follows the GPS when one is configured"),
    info="time base and geographic position",
    bind=lambda root: root.telescope.local,
)

CONFIG = module(
    "CONFIG",
    *common(),
    var("MOUNTOPTIONS", STRING, get="mount_options", info="mounts the hardware can do"),
    var("MOUNT", STRING, get="mount", set="set_mount", wlevel=CONFIGURE,
        info="active mount; switching needs the hardware file and a restart"),
    var("ORIENTATION", FLOAT, get="orientation", set="set_orientation", min=-360.0, max=360.0,
        wlevel=CONFIGURE, info="ZD-ZD tube orientation when ZD[0]=0, degrees (persisted)"),
    module("DOME",
           var("CAPABILITIES", INT, get="capabilities",
               info="bit 0 AZ rotation, 1 slit, 2 flap, 3 seal, 4 roll-roof, 5 clamshell"),
           var("DIAMETER", FLOAT, get="diameter", info="dome diameter, m"),
           info="the attached dome", bind="dome"),
    info="configuration of the telescope",
    bind=lambda root: root.telescope.mount_config,
)

#: The modules of the OpenTCI tree in the order they are numbered.
OPENTCI = (SERVER, LOCAL, CONFIG, CABINET, *AXES, *POINTING, *ENCLOSURE)


def build_tree(telescope: Any, server: Any) -> Tree:
    """The tree for ``telescope`` as served by ``server``."""
    return Tree.build(OPENTCI, Root(telescope, server), info="OpenTCI 2.5 telescope")


__all__ = ["OPENTCI", "Root", "build_tree", "common", "OPERATE", "READ_ALL"]
