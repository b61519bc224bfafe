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
    max_connections: int = setting(512, min=1, max=10000, doc="connections served at once")
    admin_reserve: int = setting(4, min=0, max=100, doc="connections beyond max_connections kept for "
                                 "level-0 users (anyone else who lands there is dropped at login)")
    max_per_address: int = setting(300, min=1, max=10000, doc="connections from one client address")
    max_pending_per_address: int = setting(
        256, min=1, max=10000, doc="connections from one address not logged in yet (a burst of "
        "clients reconnecting through one SSH tunnel logs in within it)")
    login_timeout: float = setting(10.0, min=0.5, max=3600.0,
                                   doc="seconds a connection may stay without logging in")
    idle_timeout: float = setting(0.0, min=0.0, max=1e7,
                                  doc="seconds without a command before a connection is closed (0 = never)")
    max_in_flight: int = setting(64, min=1, max=100000, doc="commands in flight per connection (TOOMANY past it)")
    max_line_length: int = setting(65536, min=256, max=16 * 1024 * 1024, doc="longest accepted line in bytes")
    auth_fail_delay: float = setting(1.0, min=0.0, max=60.0, doc="seconds before answering AUTH FAILED "
                                     "(doubles with each failure on the connection, up to auth_backoff_max)")
    auth_max_failures: int = setting(3, min=1, max=100, doc="failed logins before the connection is dropped")
    auth_backoff_failures: int = setting(
        5, min=0, max=100000, doc="failed logins of one user name (any address, any port) within "
        "auth_backoff_window after which its logins are checked only after a back-off")
    auth_backoff_window: float = setting(300.0, min=0.0, max=86400.0,
                                         doc="seconds in which failed logins of a name are counted")
    auth_backoff_max: float = setting(
        8.0, min=0.0, max=600.0, doc="longest back-off (seconds) before a login of a name under attack "
        "is checked; the right password then logs in (late, never refused)")
    auth_lockout_failures: int = setting(
        0, min=0, max=100000, doc="no longer used (the address lock-out is gone: see auth_backoff_*); "
        "accepted so that older hardware files still load")
    auth_lockout_time: float = setting(0.0, min=0.0, max=86400.0, doc="no longer used (see auth_lockout_failures)")
    tls_cert: str = setting("", doc="PEM certificate chain; with tls_key, TLS is served (see tls_port)")
    tls_key: str = setting("", doc="PEM private key of tls_cert")
    tls_port: int = setting(0, min=0, max=65535, doc="with TLS: 0 = the port itself speaks TLS only; "
                            "else a second, TLS-only listener on this port beside the plain one")
    max_output: int = setting(1024 * 1024, min=4096, max=1024 * 1024 * 1024,
                              doc="bytes of unsent replies before a connection's input is paused")
    max_output_hard: int = setting(8 * 1024 * 1024, min=4096, max=1024 * 1024 * 1024,
                                   doc="bytes of unsent replies after which a connection is dropped")
    output_stall_timeout: float = setting(
        30.0, min=0.1, max=3600.0, doc="seconds a connection may stay paused with unread replies before it is dropped")
    work_slice: float = setting(0.002, min=0.0001, max=1.0,
                                doc="seconds of command work before the server yields to the event loop")
    work_rest: float = setting(-1.0, min=-1.0, max=100.0, doc="after a full work slice under load, rest this "
                               "many times as long (command work takes at most 1/(1+work_rest) of the loop); "
                               "-1 (default): 0 when the control loop runs in its own process "
                               "([can] control_process = true), 1.0 when it shares the service's interpreter")
    reuse_reply: float = setting(0.005, min=0.0, max=0.01,
                                 doc="seconds a GET reply answers the same GET line again while nothing "
                                     "changed (readbacks, PLC polls, commands, events); 0 reads every GET")
    abort_timeout: float = setting(5.0, min=0.1, max=600.0, doc="seconds ABORT waits before COMMAND TIMEOUT")
    max_objects: int = setting(20000, min=1, max=10_000_000,
                               doc="objects (array elements count one each) one GET or SET may address")
    allow_system_control: bool = setting(
        False, doc="SERVER.SHUTDOWN, SYSTEM.SHUTDOWN and SYSTEM.REBOOT over TPL2 (level 0) are allowed")
    max_reply_bytes: int = setting(4 * 1024 * 1024, min=1024, max=1024 * 1024 * 1024,
                                   doc="bytes of values one GET may answer; objects past it answer DIMENSION")

    def check(self):
        problems = []
        if bool(self.tls_cert) != bool(self.tls_key):
            problems.append(("tls_key" if self.tls_cert else "tls_cert",
                             "tls_cert and tls_key go together"))
        if self.max_output_hard < self.max_output:
            problems.append(("max_output_hard", "must not be below max_output"))
        return problems


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
