"""A drive's EDS: loading it, the one rule every boot write goes through, the drive's modes.

Below the boot (:mod:`tcs.drivers.boot`), the PDO mapping (:mod:`tcs.drivers.pdo`) and the
start-up check (:mod:`tcs.drivers.eds_check`), which all use it and nothing above:

* :func:`load_od` — the object dictionary of an EDS file (cached);
* :func:`verdict` / :func:`usable_writes` / :func:`raw_writes` — what the boot may write: an
  object that exists, is writable and takes the value within the EDS limits is written; an
  absent **optional** object (:data:`OPTIONAL`, what is lost without it in :data:`LOST`) is
  skipped; anything else is an error naming the drive and the object;
* :class:`ModeChoice`, :func:`offers`, :func:`modes_text` — 0x6502 and the modes (the choice
  itself, which needs the PDO layout, is :mod:`tcs.drivers.mode_choice`);
* the object names the messages use (:data:`NAMES`, :func:`object_name`).
"""


from __future__ import annotations

import logging
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen import objectdictionary as odmod
from canopen.objectdictionary import datatypes

from tcs.config.can import DriveSection
from tcs.config.eds_file import compact_entries, eds_source, expand_compact
from tcs.errors import ConfigMismatch, HardwareError
from tcs.resources import hwconfig_file

log = logging.getLogger(__name__)

#: Objects whose absence (abort 0x06020000 / 0x06090011) is no error: optional in CiA 301/402.
#: The EDS check (:mod:`tcs.drivers.eds_check`) skips them on a drive that lacks them.
OPTIONAL = {0x1006, 0x607F, 0x1016, 0x60C2, 0x607D, 0x6065, 0x6066, 0x6081, 0x6083, 0x6084,
            0x6085, 0x6099, 0x609A, 0x607C, 0x603F}

#: What is lost without an optional object (logged when skipped; the table of docs/configuration.md).
LOST = {
    0x1006: "the drive takes the SYNC period from the bus (no 0x1006 check)",
    0x1016: "THE DRIVE WILL NOT NOTICE A DEAD MASTER (no heartbeat consumer): if the TCS "
            "stops, the drive keeps its last command until its own RPDO/SYNC watchdog, if any",
    0x60C2: "the drive interpolates CSP setpoints over its own period (set it on the drive)",
    0x607D: "no software limits in the drive: only the TCS's own limits protect the axis",
    0x6065: "the drive's following-error window stays as commissioned",
    0x6066: "the drive's following-error time-out stays as commissioned",
    0x607F: "the drive's max profile velocity stays as commissioned",
    0x6081: "profile moves use the drive's commissioned velocity",
    0x6083: "profile moves use the drive's commissioned acceleration",
    0x6084: "profile deceleration stays as commissioned",
    0x6085: "quick stop decelerates as commissioned",
    0x6099: "homing speeds stay as commissioned",
    0x609A: "homing acceleration stays as commissioned",
    0x607C: "no home offset (set the vendor's object with [drives.<name>.sdo])",
    0x603F: "the error code comes from EMCY only (read by SDO on a fault)",
    0x6007: "the drive reacts to a lost connection (SYNC/RPDOs) as commissioned",
    0x605A: "quick stop behaves as commissioned",
    0x605C: "disable operation behaves as commissioned",
    0x605E: "the fault reaction is the drive's commissioned one",
}
#: The drive's own reactions to a lost master (written when the drive has them).
OPTIONAL |= {0x6007, 0x605A, 0x605C, 0x605E}
#: IP sub-mode select: drives with linear interpolation only may lack it.
OPTIONAL.add(0x60C0)
LOST[0x60C0] = "the drive interpolates IP data as commissioned (linear expected)"

NAMES = {
    0x1000: "device type", 0x1006: "SYNC period", 0x1016: "consumer heartbeat time",
    0x1017: "producer heartbeat time", 0x1018: "identity", 0x603F: "error code",
    0x6041: "statusword", 0x6060: "modes of operation", 0x6061: "modes of operation display",
    0x6064: "position actual value", 0x6065: "following-error window",
    0x6066: "following-error time-out", 0x607C: "home offset", 0x607D: "software position limit",
    0x607F: "max profile velocity",
    0x6081: "profile velocity", 0x6083: "profile acceleration", 0x6084: "profile deceleration",
    0x6085: "quick-stop deceleration", 0x6098: "homing method", 0x6099: "homing speeds",
    0x609A: "homing acceleration", 0x60C2: "interpolation time period",
    0x60C0: "interpolation sub-mode", 0x60C1: "interpolation data record",
    0x6007: "abort connection option", 0x605A: "quick stop option",
    0x605C: "disable operation option", 0x605E: "fault reaction option",
}


def object_name(index: int) -> str:
    if 0x1400 <= index < 0x1C00:
        kind = "RPDO" if index < 0x1800 else "TPDO"
        number = (index & 0xFF) + 1
        what = "mapping" if index & 0x0200 else "communication"
        return f"{kind}{number} {what}"
    return NAMES.get(index, "")



SIM_EDS = hwconfig_file("eds/tcs-sim-drive.eds")  # package data (tcs.resources)

#: 0x6502 bits of the modes (bit n = mode n + 1 up to CST).
MODE_BITS = {1: 0, 2: 1, 3: 2, 4: 3, 6: 5, 7: 6, 8: 7, 9: 8, 10: 9}
MODE_NAMES = {1: "profile position (PP)", 3: "profile velocity (PV)", 6: "homing (HM)",
              7: "interpolated position (IP)", 8: "cyclic synchronous position (CSP)",
              9: "cyclic synchronous velocity (CSV)"}
MODE_SHORT = {1: "PP", 2: "VL", 3: "PV", 4: "TQ", 6: "HM", 7: "IP", 8: "CSP", 9: "CSV", 10: "CST"}
#: ``[drives.x] mode`` values and the 0x6060 mode they stand for.
MODE_KEYS = {"pp": 1, "ip": 7, "csp": 8, "csv": 9}
#: The modes a trajectory axis can stream in, in the order ``mode = "auto"`` prefers them.
CYCLIC_PREFERENCE = ("csp", "ip", "csv")
#: Objects of homing mode (not written for an ``absolute`` drive).
HOMING_OBJECTS = frozenset({0x6098, 0x6099, 0x609A, 0x607C})

_FORMATS = {datatypes.INTEGER8: "<b", datatypes.UNSIGNED8: "<B", datatypes.INTEGER16: "<h",
            datatypes.UNSIGNED16: "<H", datatypes.INTEGER32: "<i", datatypes.UNSIGNED32: "<I",
            datatypes.INTEGER64: "<q", datatypes.UNSIGNED64: "<Q", datatypes.BOOLEAN: "<B",
            datatypes.REAL32: "<f", datatypes.REAL64: "<d"}

_cache: dict[tuple[str, float, int], canopen.ObjectDictionary] = {}
_cache_lock = threading.Lock()


def load_od(path: str | os.PathLike, node_id: int) -> canopen.ObjectDictionary:
    """The object dictionary of an EDS (cached per file, modification time and node id)."""
    p = Path(path).resolve()
    key = (str(p), p.stat().st_mtime, node_id)
    with _cache_lock:
        od = _cache.get(key)
        if od is None:
            od = _cache[key] = read_od(p, node_id)
        return od


def read_od(path: str | os.PathLike, node_id: int) -> canopen.ObjectDictionary:
    """``canopen.import_od`` of an EDS, plus what it drops: ``od.tcs_compact`` = {index: n}
    of the arrays written with ``CompactSubObj=n`` (canopen keeps only their sub-index 1, so a
    PDO mapping written that way would seem to take one object)."""
    od = canopen.import_od(eds_source(path), node_id)  # (any encoding, repeated keys: eds_file)
    expand_compact(od, compact_entries(path))
    return od


def variable(od: canopen.ObjectDictionary, index: int, sub: int) -> odmod.ODVariable | None:
    """The entry (index, sub) of ``od`` or None when the drive does not have it."""
    obj = od.get(index)
    if obj is None:
        return None
    if isinstance(obj, odmod.ODVariable):
        return obj if sub == 0 else None
    return obj.subindices.get(sub)


def limits(var: odmod.ODVariable) -> tuple[int | float | None, int | float | None]:
    """(low, high) a write must respect: the EDS limits within the data type's range."""
    lo, hi = var.min, var.max
    if var.data_type in datatypes.INTEGER_TYPES:
        bits = len(var)
        if var.data_type in datatypes.SIGNED_TYPES:
            tlo, thi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        else:
            tlo, thi = 0, (1 << bits) - 1
        lo = tlo if lo is None else max(lo, tlo)
        hi = thi if hi is None else min(hi, thi)
    return lo, hi


def value_format(var: odmod.ODVariable) -> str | None:
    """The struct format of a numeric object (None for strings, domains …)."""
    return _FORMATS.get(var.data_type)


def default_value(var: odmod.ODVariable | None):
    if var is None:
        return None
    return var.value if var.value is not None else var.default


def supported_modes(od: canopen.ObjectDictionary) -> int | None:
    """0x6502 as the EDS gives it (its default value), or None when unknown — also for a
    default of 0 (no mode at all: a placeholder some EDS files carry, the drive fills it)."""
    value = default_value(variable(od, 0x6502, 0))
    return int(value) if isinstance(value, int) and value else None


def decode_modes(modes: int) -> str:
    """0x6502 as mode names: ``"PP, HM, IP"`` (``"none"`` for 0)."""
    names = [MODE_SHORT[m] for m, bit in MODE_BITS.items() if modes >> bit & 1]
    return ", ".join(names) or "none"


def offers(modes: int | None, key: str) -> bool:
    """Whether 0x6502 ``modes`` offers mode ``key`` (csp, ip, csv, pp); unknown = yes."""
    return modes is None or bool(modes >> MODE_BITS[MODE_KEYS[key]] & 1)


@dataclass(frozen=True)
class ModeChoice:
    """The operating mode of one drive: ``mode`` (csp, ip, csv or pp), why, 0x6502 and what
    is wrong with the configured mode (``problem``, None when it fits)."""

    mode: str
    reason: str
    offered: int | None
    problem: str | None = None

    @property
    def cyclic(self) -> bool:
        return self.mode in CYCLIC_PREFERENCE

    @property
    def number(self) -> int:
        return MODE_KEYS[self.mode]


def modes_text(modes: int | None, eds_name: str = "EDS") -> str:
    if modes is None:
        return f"0x6502 (supported drive modes) not stated in {eds_name}"
    return f"0x6502 (supported drive modes) = 0x{modes:08X} = {decode_modes(modes)} ({eds_name})"


@dataclass(frozen=True)
class Verdict:
    """What to do with one write: ``write``, ``skip`` (with why) or ``error`` (with why)."""

    action: str
    why: str = ""


def verdict(od: canopen.ObjectDictionary, index: int, sub: int, value, optional: bool) -> Verdict:
    """The one rule every boot write goes through (see the module docstring)."""
    var = variable(od, index, sub)
    if var is None:
        what = "object" if od.get(index) is None else "sub-index"
        if optional:
            return Verdict("skip", f"the drive has no {what} 0x{index:04X}:{sub}")
        return Verdict("error", f"the drive has no {what} 0x{index:04X}:{sub}")
    if not var.writable:
        if default_value(var) == value:
            return Verdict("skip", f"0x{index:04X}:{sub} is read-only and already {value}")
        if optional:
            return Verdict("skip", f"0x{index:04X}:{sub} is read-only on this drive "
                                   f"(fixed to {default_value(var)})")
        return Verdict("error", f"0x{index:04X}:{sub} is read-only on this drive (fixed to "
                                f"{default_value(var)}), {value} is wanted")
    lo, hi = limits(var)
    checked = range_value(var, value)
    if isinstance(checked, (int, float)) and (lo is not None and checked < lo or hi is not None and checked > hi):
        return Verdict("error", f"0x{index:04X}:{sub} = {value} is outside the drive's range "
                                f"{'' if lo is None else lo}..{'' if hi is None else hi}")
    return Verdict("write")


def range_value(var: odmod.ODVariable, value):
    """The part of ``value`` the EDS limits of ``var`` apply to.

    0x1016:n (consumer heartbeat time) is ``node id << 16 | ms``: many EDS files give it a
    HighLimit of the 16-bit time only (0xFFFF), so a limit below 0x10000 bounds the time part
    (bits 0-15), never the node id in bits 16-23. Likewise a PDO COB-ID's limit below
    0x80000000 does not bound bit 31 (the PDO switched off, part of every remap).
    """
    if (var.index == 0x1016 and var.subindex >= 1 and isinstance(value, int)
            and var.max is not None and var.max <= 0xFFFF):
        return value & 0xFFFF
    if ((0x1400 <= var.index < 0x1600 or 0x1800 <= var.index < 0x1A00) and var.subindex == 1
            and isinstance(value, int) and var.max is not None and var.max < 0x80000000):
        return value & 0x7FFFFFFF  # a PDO COB-ID: bit 31 (PDO switched off) is no number
    return value


def is_optional(index: int, sub: int, section: DriveSection) -> bool:
    """Whether the boot may do without object (index, sub) on this drive."""
    if 0x1800 <= index <= 0x1803 and sub in (3, 5):
        return True  # inhibit time / event timer of an event-driven TPDO
    if 0x1400 <= index <= 0x1403 and sub == 5:
        return True  # RPDO deadline (master loss): without it, 0x1016 and SYNC loss remain
    if index in (0x6081, 0x6083) and section.profile_moves:
        return False
    return index in OPTIONAL


def usable_writes(od: canopen.ObjectDictionary, writes, section: DriveSection, device: str):
    """The boot's writes that the drive takes; skipped ones dropped, errors raised.

    ``writes`` are ``(index, sub, format, value)``; homing objects are dropped for an
    ``absolute`` drive.
    """
    out = []
    for index, sub, fmt, value in writes:
        if section.absolute and index in HOMING_OBJECTS:
            continue
        v = verdict(od, index, sub, value, is_optional(index, sub, section))
        if v.action == "write":
            out.append((index, sub, fmt, value))
        elif v.action == "error":
            remedy = ("leave [drives.<name>] pdo out (the TCS lays the PDOs out from the EDS)"
                      if 0x1400 <= index < 0x1C00 else
                      "correct the hardware file (tcs-server --check-config names the key and "
                      "the range the EDS allows)")
            raise ConfigMismatch(device, f"{v.why}; remedy: {remedy}")
    return out


def raw_writes(od: canopen.ObjectDictionary, section: DriveSection, device: str):
    """``[drives.x.sdo]`` as boot writes ``(index, sub, format, value)`` (checked at start)."""
    out = []
    for key, index, sub, value in section.raw_writes:
        var = variable(od, index, sub)
        fmt = value_format(var) if var is not None else None
        if fmt is None:
            raise HardwareError(device, f"sdo.{key}: no numeric object 0x{index:04X}:{sub}")
        out.append((index, sub, fmt, float(value) if fmt in ("<f", "<d") else value))
    return out


def eds_path(section: DriveSection, resolve) -> Path:
    """The drive's EDS as a path (the simulated drive's when none is configured)."""
    return Path(resolve(section.eds)) if section.eds else SIM_EDS
