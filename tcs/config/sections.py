"""The sections of a hardware file that every telescope has: server, users, site, time, mount,
state. Hardware sections (CAN bus and drives, axes, PLCs, GPS) live in their own modules and
are listed in :class:`tcs.config.hwconfig.HwConfig`.

Each class is the schema of one TOML table (see :mod:`tcs.config.schema`); the documented
defaults are what ``hwconfig/sim.toml`` relies on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from tcs.config.passwords import check_format
from tcs.config.schema import setting


@dataclass(frozen=True)
class ServerSection:
    host: str = setting("127.0.0.1", doc="address the TPL2 server binds to")
    port: int = setting(65432, min=0, max=65535, doc="TCP port (0 = any free port)")
    opentsi_port: int = setting(-1, min=-1, max=65535, doc="TCP port of the OpenTSI tree "
                                                           "(-1 = not served, 0 = any free port)")
    line_ending: Literal["LF", "CRLF"] = setting("LF", doc="line end the server sends (RTS2 needs CRLF)")
    implicit_auth: bool = setting(False, doc="log every connection in without AUTH (RTS2, NTM clients)")
    implicit_user: str = setting("", doc="user whose levels implicit authentication grants")
    greeting: str = setting("OpenTCI telescope", doc="free text of the greeting's MESSAGE")
    max_connections: int = setting(64, min=1, max=10000, doc="connections served at once")
    max_in_flight: int = setting(64, min=1, max=100000, doc="commands in flight per connection (TOOMANY past it)")
    max_line_length: int = setting(65536, min=256, max=16 * 1024 * 1024, doc="longest accepted line in bytes")
    auth_fail_delay: float = setting(1.0, min=0.0, max=60.0, doc="seconds before answering AUTH FAILED")
    auth_max_failures: int = setting(3, min=1, max=100, doc="failed logins before the connection is dropped")
    abort_timeout: float = setting(5.0, min=0.1, max=600.0, doc="seconds ABORT waits before COMMAND TIMEOUT")

    def check(self):
        return []


@dataclass(frozen=True)
class UserSection:
    name: str = setting(doc="login name")
    password: str = setting(doc="salted hash from tcs-passwd (never plaintext)")
    rlevel: int = setting(0, min=0, max=9, doc="read level (0 = most privileged)")
    wlevel: int = setting(0, min=0, max=9, doc="write level (0 = most privileged)")

    def check(self):
        problem = check_format(self.password)
        return [("password", problem)] if problem else []


@dataclass(frozen=True)
class SiteSection:
    latitude: float = setting(0.0, min=-90.0, max=90.0, doc="geodetic latitude, degrees north")
    longitude: float = setting(0.0, min=-180.0, max=360.0, doc="longitude, degrees east")
    height: float = setting(0.0, min=-500.0, max=10000.0, doc="height above sea level, m")
    longitude_west_positive: bool = setting(
        False, doc="serve LOCAL.LONGITUDE positive towards west (for clients that expect it)")


@dataclass(frozen=True)
class TimeSection:
    tai_utc: float = setting(37.0, min=0.0, max=100.0, doc="TAI-UTC, leap seconds")
    ut1_utc: float = setting(0.0, min=-1.0, max=1.0, doc="UT1-UTC, seconds")


MOUNTS = ("AZ-ZD", "RA-DEC", "ZD-ZD")


@dataclass(frozen=True)
class MountSection:
    type: Literal["AZ-ZD", "RA-DEC", "ZD-ZD"] = setting("AZ-ZD", doc="active mount (CONFIG.MOUNT)")
    options: list[Literal["AZ-ZD", "RA-DEC", "ZD-ZD"]] = setting(
        factory=tuple, doc="mounts the hardware can do (CONFIG.MOUNTOPTIONS); default: type")
    orientation: float = setting(0.0, min=-360.0, max=360.0, doc="ZD-ZD tube orientation (CONFIG.ORIENTATION)")

    def check(self):
        if self.options and self.type not in self.options:
            return [("type", f"{self.type!r} is not among options {list(self.options)}")]
        return []


@dataclass(frozen=True)
class StateSection:
    path: str = setting("", doc="directory for persistent state; empty = $STATE_DIRECTORY, "
                                "else $XDG_STATE_HOME/tcs/<file stem>, else ~/.local/state/tcs/<file stem>")


@dataclass(frozen=True)
class CabinetSection:
    manufacturer: str = setting("tcs project", doc="CABINET.SETUP.MANUFACTURER")
    hw_id: str = setting("SIM-0001", doc="CABINET.SETUP.HW_ID")
    hw_version: str = setting("1", doc="CABINET.SETUP.HW_VERSION")
    config_id: str = setting("", doc="CABINET.SETUP.CONFIG_ID")
    config_version: str = setting("1", doc="CABINET.SETUP.CONFIG_VERSION")
    hw_type: int = setting(1, min=1, doc="CABINET.TYPE: identifies the cabinet and its CORE layout")
    param_name: str = setting("", doc="CABINET.SETUP.PARAM_NAME (empty = the hardware file's name)")
    param_version: str = setting("", doc="CABINET.SETUP.PARAM_VERSION (empty = the file's "
                                         "modification time, UTC)")
    log_lines: int = setting(20, min=1, max=1000, doc="size of CABINET.STATUS.LOG[] (newest first)")
