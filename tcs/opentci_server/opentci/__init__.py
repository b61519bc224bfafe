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

from tcs.opentci_server.opentci.axes import AXES
from tcs.opentci_server.opentci.cabinet import CABINET
from tcs.opentci_server.opentci.common import common
from tcs.opentci_server.opentci.enclosure import ENCLOSURE
from tcs.opentci_server.opentci.pointing import POINTING
from tcs.opentci_server.server_module import ServerModule, account_form, command_rate
from tcs.opentci_server.tree import (CONFIGURE, FLOAT, INT, NOBODY, OPERATE, READ_ALL, STRING, Tree, module,
                                     module_array, sysvar, var)

ADMIN = 0  # SERVER.CLIENT[], ACCOUNTS.*, LOG.CLEAR/EVENTMASK: server administration is level 0


@dataclass
class Root:
    telescope: Any
    server: Any


def _host(address: str) -> str:
    """``1.2.3.4:5678`` -> ``1.2.3.4``; ``::1:5678`` -> ``::1`` (TPL2 §9: the address only)."""
    host, sep, port = address.rpartition(":")
    return host if sep and port.isdigit() else address


def _module_of(conn):
    return ServerModule.of(conn.server)


SERVER = module(
    "SERVER",
    var("UPTIME", FLOAT, get="uptime", info="seconds since the server started"),
    var("STARTTIME", FLOAT, get="starttime", info="start of the server, UTC seconds since 1970"),
    var("VERSION", STRING, get="version", info="server software version"),
    var("LOAD", FLOAT, get="load", info="CPU time the server used per second (1.0: one core busy)"),
    var("LOAD_DETAIL", STRING, get="load_detail", info="load: CPU, connections, command rate, commands running"),
    var("SHUTDOWN", INT, set="shutdown", min=1, max=1, rlevel=NOBODY, wlevel=ADMIN,
        info="1 stops the server; refused (FAILED 6) unless [server] allow_system_control"),
    module("INFO",
           var("DEVICE", STRING, get="device", info="what this server controls"),
           var("VENDOR", STRING, get="vendor", info="software vendor"),
           var("MANUFACTURER", STRING, get="manufacturer", info="manufacturer of the cabinet"),
           var("FLAGS", STRING, get="flags",
               info="optional TPL2 features offered, comma-separated (empty: no ENC, no sub-servers)"),
           var("INFO", STRING, get="info", info="interface and software versions"),
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
           sysvar("PASSWORD", STRING, set=lambda conn, v: _module_of(conn).change_password(conn.username, v),
                  rlevel=NOBODY, info="write: a new password for the user of this connection (kept "
                                      "hashed in the state directory; the next login needs it)"),
           sysvar("COMMAND_RATE", FLOAT, get=command_rate,
                  info="commands per second this connection sent over the last 10 s"),
           info="per-connection settings (each connection sees its own)"),
    module_array("CLIENT",
                 var("ID", INT, get="id", rlevel=ADMIN, info="connection number (0: slot empty)"),
                 var("ADDRESS", STRING, get="address", rlevel=ADMIN, info="client address"),
                 var("USERNAME", STRING, get="username", rlevel=ADMIN, info="user logged in"),
                 var("RLEVEL", INT, get="rlevel", rlevel=ADMIN, info="read level (-1: not logged in)"),
                 var("WLEVEL", INT, get="wlevel", rlevel=ADMIN, info="write level (-1: not logged in)"),
                 var("EVENTMASK", INT, get="eventmask", rlevel=ADMIN, info="its SERVER.CONNECTION.EVENTMASK"),
                 var("ABORT_ON_DISCONNECT", INT, get="abort_on_disconnect",
                     rlevel=ADMIN, info="its SERVER.CONNECTION.ABORT_ON_DISCONNECT"),
                 var("STARTTIME", FLOAT, get="starttime", rlevel=ADMIN, info="when the connection was opened, UTC"),
                 var("UPTIME", FLOAT, get="uptime", rlevel=ADMIN, info="seconds since it was opened (0: slot empty)"),
                 var("COMMAND_RATE", FLOAT, get="command_rate", rlevel=ADMIN, info="commands per second, last 10 s"),
                 var("DROP", INT, set="drop", min=1, max=1, rlevel=NOBODY, wlevel=ADMIN,
                     info="1 closes this connection"),
                 var("BLOCK", INT, set="block", min=1, max=1, rlevel=NOBODY, wlevel=ADMIN,
                     info="1 blocks the user of this connection (ACCOUNTS) and closes it"),
                 info="every connection slot, open connections by number first (read at level 0)",
                 bind=lambda m: m.client_slots()),
    module("ACCOUNTS",
           var("USERNAMES", STRING, get="usernames", rlevel=ADMIN, info="every account's name, comma-separated"),
           var("BLOCKED", STRING, get="blocked_names", set="set_blocked", rlevel=ADMIN, wlevel=ADMIN,
               info="blocked users, comma-separated; write names to block them"),
           var("UNBLOCKED", STRING, get="unblocked_names", set="set_unblocked", rlevel=ADMIN, wlevel=ADMIN,
               info="users that may log in, comma-separated; write names to unblock them"),
           var("LIST", STRING, get="account_list", rlevel=ADMIN,
               info="name:rlevel:wlevel:blocked:source (file or tpl2), comma-separated"),
           var("ADD", STRING, set="add_account", rlevel=NOBODY, wlevel=ADMIN,
               info="write name:password:rlevel:wlevel to add a user (kept hashed)"),
           var("REMOVE", STRING, set="remove_account", rlevel=NOBODY, wlevel=ADMIN,
               info="write a name to remove a user added over TPL2"),
           var("BLOCK", STRING, set="block_account", rlevel=NOBODY, wlevel=ADMIN,
               info="write a name: no more logins for that user"),
           var("UNBLOCK", STRING, set="unblock_account", rlevel=NOBODY, wlevel=ADMIN,
               info="write a name to allow its logins again"),
           module("MODIFY",
                  sysvar("TYPE", INT, get=lambda c: account_form(c).type,
                         set=lambda c, v: setattr(account_form(c), "type", int(v)), min=0, max=0,
                         rlevel=ADMIN, wlevel=ADMIN, info="account type: 0 a user with a password (the only one)"),
                  sysvar("USERNAME", STRING, get=lambda c: account_form(c).username,
                         set=lambda c, v: _module_of(c).load_form(c, v), rlevel=ADMIN, wlevel=ADMIN,
                         info="login name; writing an existing one loads that account into the form"),
                  sysvar("NAME", STRING, get=lambda c: account_form(c).fullname,
                         set=lambda c, v: setattr(account_form(c), "fullname", str(v)), rlevel=ADMIN,
                         wlevel=ADMIN, info="descriptive name of the user"),
                  sysvar("PASSWORD", STRING, set=lambda c, v: setattr(account_form(c), "password", str(v)),
                         rlevel=NOBODY, wlevel=ADMIN, info="new password (kept hashed; ADD needs one)"),
                  *(sysvar(f"{kind}_{rw}LEVEL", INT, get=lambda c, a=f"{kind.lower()}_{rw.lower()}level":
                           getattr(account_form(c), a),
                           set=lambda c, v, a=f"{kind.lower()}_{rw.lower()}level": setattr(account_form(c), a, int(v)),
                           min=0, max=9, rlevel=ADMIN, wlevel=ADMIN, info=text.format(rw="read" if rw == "R" else "write"))
                    for kind, text in (("DEFAULT", "{rw} level of a login that asks for none"),
                                       ("MIN", "most privileged {rw} level a login may ask for"))
                    for rw in ("R", "W")),
                  sysvar("BLOCKED", INT, get=lambda c: account_form(c).blocked,
                         set=lambda c, v: setattr(account_form(c), "blocked", int(v)), min=0, max=1,
                         rlevel=ADMIN, wlevel=ADMIN, info="1: no logins"),
                  sysvar("ADD", INT, set=lambda c, v: _module_of(c).form_add(c), min=1, max=1, rlevel=NOBODY,
                         wlevel=ADMIN, info="1 adds the form as a new account (FAILED 5 if it exists)"),
                  sysvar("UPDATE", INT, set=lambda c, v: _module_of(c).form_update(c), min=1, max=1,
                         rlevel=NOBODY, wlevel=ADMIN,
                         info="1 writes the form to the account USERNAME (never more privilege than "
                              "the hardware file gives)"),
                  sysvar("REMOVE", INT, set=lambda c, v: _module_of(c).form_remove(c), min=1, max=1,
                         rlevel=NOBODY, wlevel=ADMIN, info="1 removes the account USERNAME (one added over TPL2)"),
                  info="one account's form (each connection has its own): USERNAME, fields, then ADD, "
                       "UPDATE or REMOVE"),
           info="user accounts: the hardware file's, changed or added over TPL2 (persisted)"),
    module("LOG",
           var("EVENTS", STRING, get="log_events",
               info="recent events, oldest first: '<unix time> <extended id> EVENT ...' per line"),
           var("COUNT", INT, get="log_count", info="events in EVENTS"),
           var("CLEAR", INT, set="clear_log", min=1, max=1, rlevel=NOBODY, wlevel=ADMIN,
               info="1 empties the log"),
           var("EVENTMASK", INT, get="log_eventmask", set="set_log_eventmask", min=0, max=15,
               wlevel=ADMIN, info="levels logged: bit 0 ERROR, 1 WARN, 2 INFO, 3 DEBUG"),
           info="the event log a client connecting late can read"),
    module("SYSTEM",
           var("ARCHITECTURE", STRING, get="architecture", info="machine architecture"),
           var("CPUS", INT, get="cpus", info="processors"),
           var("HOSTNAME", STRING, get="hostname", info="host name"),
           var("LOAD", FLOAT, get="system_load", info="1-minute load average"),
           var("OSTYPE", STRING, get="ostype", info="operating system"),
           var("OSVERSION", STRING, get="osversion", info="its release"),
           var("STARTTIME", FLOAT, get="system_starttime", info="boot time, UTC seconds since 1970"),
           var("UPTIME", FLOAT, get="system_uptime", info="seconds since boot"),
           var("REBOOT", INT, set="reboot", min=1, max=1, rlevel=NOBODY, wlevel=ADMIN,
               info="1 reboots the computer; refused (FAILED 6) unless [server] allow_system_control"),
           var("SHUTDOWN", INT, set="shutdown", min=1, max=1, rlevel=NOBODY, wlevel=ADMIN,
               info="1 stops the server; refused (FAILED 6) unless [server] allow_system_control"),
           info="the computer the server runs on"),
    info="the TPL2 server itself",
    bind=lambda root: ServerModule.of(root.server, getattr(root, "telescope", None)),
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
        wlevel=CONFIGURE, info="site longitude, degrees east (see docs/opentci.md for west-positive sites); "
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
