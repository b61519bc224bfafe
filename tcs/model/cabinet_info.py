"""What the cabinet tells about itself: CABINET.SETUP (spec §6.2) and CABINET.CORE (§6.3).

:class:`CabinetSetup` computes the identification strings once, at start, from the hardware
file:

============== ==================================================================================
MANUFACTURER   ``[cabinet] manufacturer``
VERSION_TEXT   ``; ``-separated versions of the parts: the TCS, Python, the bus libraries, and
               every drive's configured identity (``drive az node 1 0x…:0x…:rev 0x…``)
HW_ID          ``[cabinet] hw_id``;  HW_VERSION ``[cabinet] hw_version``
SW_ID          ``tcs`` (this software); SW_VERSION its package version
CONFIG_ID      ``[cabinet] config_id``, or ``drives-<hash>`` of the drives' identities (node,
               vendor, product, revision, serial) when empty — it changes when a drive does
CONFIG_VERSION ``[cabinet] config_version``
PARAM_ID       first 16 hex digits of the SHA-256 of the hardware file's bytes
PARAM_VERSION  ``[cabinet] param_version``, or the file's modification time (UTC, ISO 8601)
PARAM_NAME     ``[cabinet] param_name``, or the hardware file's name
============== ==================================================================================

CORE layout (``TYPE`` 1, the CiA-402 cabinet of this project), read live on every GET:

* ``CORE.DRIVE[i]`` — one element per axis, in the axes' order: ``AXIS`` (module name),
  ``NAME`` (drive name), ``STATE`` (CiA-402 state as text, ``none`` when the axis has no
  drive), ``STATUSWORD``, ``ERRORCODE`` (the drive's EMCY / 0x603F code when it reported one,
  else the fault's OpenTCI number, 0 without fault), ``ERRORTEXT``, ``POSITION``, ``VELOCITY``,
  ``FOLLOWING_ERROR`` (user units), ``HEARTBEAT`` (1 while the drive's heartbeat is seen).
* ``CORE.CYCLE`` — the control loop's counters from ``cabinet.loop_stats``: ``CYCLES``,
  ``LATE``, ``MISSED``, ``TPDO_TIMEOUTS``, ``MAX_LATENESS`` (s), ``REALTIME`` (1 when
  the loop thread runs with its real-time priority) and ``SYNC_INTERVAL`` (s between SYNCs
  now: the period, or the idle SYNC's while every drive rests); 0 while no loop runs.

Nothing here changes state; any thread may read.
"""

from __future__ import annotations

import hashlib
import logging
import platform
import time
from collections.abc import Mapping
from importlib import metadata
from typing import Any, Callable

import tcs
from tcs.config import HwConfig

log = logging.getLogger(__name__)

#: Libraries whose versions VERSION_TEXT lists when installed.
LIBRARIES = ("canopen", "python-can", "pymodbus", "ruckig", "pyerfa")


class CabinetSetup:
    """The CABINET.SETUP strings of one hardware file."""

    def __init__(self, config: HwConfig):
        c = config.cabinet
        self.manufacturer = c.manufacturer
        self.hw_id = c.hw_id
        self.hw_version = c.hw_version
        self.sw_id = "tcs"
        self.sw_version = tcs.__version__
        self.config_id = c.config_id or _drives_id(config)
        self.config_version = c.config_version
        data = _file_bytes(config)
        self.param_id = hashlib.sha256(data if data is not None else repr(config).encode()).hexdigest()[:16]
        self.param_version = c.param_version or _file_time(config)
        self.param_name = c.param_name or config.source.name
        self.version_text = "; ".join(_versions(config))


def _file_bytes(config: HwConfig) -> bytes | None:
    try:
        return config.source.read_bytes()
    except OSError:
        return None


def _file_time(config: HwConfig) -> str:
    try:
        mtime = config.source.stat().st_mtime
    except OSError:
        return ""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(mtime))


def _identity(drive) -> str:
    ident = drive.identity
    def hex8(value):  # a field left out of the file (not checked at boot)
        return "any" if value is None else f"0x{value:08X}"
    text = f"{hex8(ident.vendor)}:{hex8(ident.product)}:rev {hex8(ident.revision)}"
    return text if ident.serial is None else f"{text}:sn {ident.serial}"


def _drives_id(config: HwConfig) -> str:
    if not config.drives:
        return "no-drives"
    text = ";".join(f"{name}={d.node_id}:{_identity(d)}" for name, d in sorted(config.drives.items()))
    return "drives-" + hashlib.sha256(text.encode()).hexdigest()[:12]


def _versions(config: HwConfig) -> list[str]:
    parts = [f"tcs {tcs.__version__}", f"Python {platform.python_version()}"]
    for name in LIBRARIES:
        try:
            parts.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            pass
    for name, drive in config.drives.items():
        parts.append(f"drive {name} node {drive.node_id} {_identity(drive)}")
    return parts


class DriveDiagnostics:
    """``CORE.DRIVE[i]``: the live drive status of one axis."""

    def __init__(self, axis: Any):
        self.axis = axis

    def _status(self):
        get = getattr(self.axis, "drive_status", None)
        if get is None:
            return None
        try:
            return get()
        except Exception:  # diagnostics must read even when the axis is broken
            log.debug("drive_status of %s failed", self.axis_name, exc_info=True)
            return None

    @property
    def axis_name(self) -> str:
        return str(getattr(self.axis, "module_name", ""))

    @property
    def name(self) -> str:
        s = self._status()
        return s.name if s is not None else ""

    @property
    def state(self) -> str:
        s = self._status()
        return "none" if s is None else str(getattr(s.state, "value", s.state))

    @property
    def statusword(self) -> int:
        s = self._status()
        return s.statusword if s is not None else 0

    @property
    def error_code(self) -> int:
        s = self._status()
        fault = None if s is None else s.fault
        if fault is None:
            return 0
        code = getattr(fault, "code", None)
        return int(code) if code is not None else int(getattr(fault, "number", 1))

    @property
    def error_text(self) -> str:
        s = self._status()
        return "" if s is None or s.fault is None else str(s.fault)

    @property
    def position(self) -> float:
        s = self._status()
        return s.position if s is not None else 0.0

    @property
    def velocity(self) -> float:
        s = self._status()
        return s.velocity if s is not None else 0.0

    @property
    def following_error(self) -> float:
        s = self._status()
        return s.following_error if s is not None else 0.0

    @property
    def heartbeat(self) -> int:
        s = self._status()
        return int(bool(s is not None and s.heartbeat_ok))


def loop_figure(source: Callable[[], Any] | None, name: str) -> float:
    """One counter of the control loop's statistics (a mapping or an object), 0 when absent."""
    if source is None:
        return 0.0
    try:
        stats = source()
        value = stats.get(name) if isinstance(stats, Mapping) else getattr(stats, name, None)
        return float(value) if value is not None else 0.0
    except Exception:  # diagnostics: never fail a GET because the loop is gone
        log.debug("loop_stats failed", exc_info=True)
        return 0.0


__all__ = ["CabinetSetup", "DriveDiagnostics", "loop_figure"]
