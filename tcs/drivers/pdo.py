"""PDO layouts of one drive: the SDO writes that map them and the codecs of their frames.

The mapping is the validated one of the hardware file (:func:`tcs.config.can.pdo_mapping`,
default docs/cia402.md: RPDO1 = 0x6040 + the mode's setpoint (0x607A in CSP/PP, 0x60C1:1 in
IP, 0x60FF in CSV); TPDO1 = 0x6041 + 0x6064; TPDO2 = 0x606C +
0x60F4, both synchronous; TPDO3 = 0x60FD + 0x603F, event driven). The driver does not use
canopen's PDO classes: it writes the communication and mapping parameters itself (remap
procedure of CiA 301: invalidate the COB-ID, sub0 = 0, entries, sub0 = n, validate — only in
pre-operational) and packs / unpacks frames with a precompiled :class:`struct.Struct`, so the
per-cycle path is one ``pack`` and one ``send``.

The default mapping adapts to the drive's EDS (:func:`eds_mapping`): an object the EDS does
not mark PDO-mappable (0x603F on some drives) or lacks is left out of its PDO — the error code
is then read by SDO on a fault, never every cycle — and a PDO left empty is disabled. The
objects the cycle cannot do without (controlword, target position, statusword, position
actual value) must be mappable: otherwise the start is refused. A ``pdo`` override in the
hardware file is checked against the EDS the same way and used as it is.

Only the boot code (:mod:`tcs.drivers.cia402_drive`) and the cycle use this module.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from tcs.config.can import (CYCLIC_TPDO_OBJECTS, PDO_OBJECTS, PDO_SUBS, SETPOINT_OBJECT,
                            SETPOINT_OBJECTS, DriveSection, default_mapping)

#: Objects the cycle cannot do without (RPDO1 / a synchronous TPDO); of the setpoint objects
#: only the one of the drive's mode (:func:`essential`).
ESSENTIAL = {0x6040: "the drive cannot be commanded", 0x607A: "no setpoints can be streamed",
             0x60C1: "no interpolation data (IP setpoints) can be streamed",
             0x60FF: "no velocity commands (CSV) can be streamed",
             0x6041: "the drive state cannot be followed", 0x6064: "the position cannot be read"}


def essential(mode: str) -> dict[int, str]:
    """The objects the cycle needs in ``mode`` (csp, ip, csv, pp)."""
    keep = SETPOINT_OBJECT.get(mode, 0x607A)
    return {i: why for i, why in ESSENTIAL.items() if i not in SETPOINT_OBJECTS or i == keep}

_FORMATS = {(8, True): "b", (8, False): "B", (16, True): "h", (16, False): "H",
            (32, True): "i", (32, False): "I"}

#: Transmission type: on every SYNC (1) / event driven, manufacturer specific (255).
SYNCHRONOUS = 1
EVENT = 255
#: Event-driven TPDOs: inhibit time (100 µs units) and event timer (ms), so a changing input
#: cannot flood the bus and a steady one is still refreshed.
EVENT_INHIBIT_100US = 100   # 10 ms
EVENT_TIMER_MS = 500


@dataclass(frozen=True)
class PdoLayout:
    """One PDO: its name (``rpdo1``, ``tpdo2`` …), number 1..4, COB-ID and mapped objects."""

    name: str
    number: int
    cob_id: int
    indices: tuple[int, ...]
    transmission: int
    codec: struct.Struct

    @property
    def receive(self) -> bool:
        """An RPDO (TCS -> drive)."""
        return self.name.startswith("rpdo")

    @property
    def synchronous(self) -> bool:
        return self.transmission == SYNCHRONOUS

    @property
    def bits(self) -> int:
        return sum(PDO_OBJECTS[i][1] for i in self.indices)

    def comm_index(self) -> int:
        return (0x1400 if self.receive else 0x1800) + self.number - 1

    def map_index(self) -> int:
        return (0x1600 if self.receive else 0x1A00) + self.number - 1

    def map_entries(self) -> list[int]:
        """0x16xx / 0x1Axx sub-entries: index << 16 | sub-index << 8 | bit length."""
        return [i << 16 | PDO_SUBS.get(i, 0) << 8 | PDO_OBJECTS[i][1] for i in self.indices]

    def names(self) -> tuple[str, ...]:
        return tuple(PDO_OBJECTS[i][0] for i in self.indices)


def layout(name: str, indices: tuple[int, ...], node_id: int) -> PdoLayout:
    """The layout of PDO ``name`` carrying ``indices`` for ``node_id``."""
    receive = name.startswith("rpdo")
    number = int(name[4:])
    base = 0x200 if receive else 0x180
    cob_id = base + 0x100 * (number - 1) + node_id
    if receive:
        transmission = SYNCHRONOUS
    else:
        transmission = SYNCHRONOUS if CYCLIC_TPDO_OBJECTS & set(indices) else EVENT
    fmt = "<" + "".join(_FORMATS[PDO_OBJECTS[i][1], PDO_OBJECTS[i][2]] for i in indices)
    return PdoLayout(name, number, cob_id, tuple(indices), transmission, struct.Struct(fmt))


def layouts(mapping: dict[str, tuple[int, ...]], node_id: int) -> dict[str, PdoLayout]:
    """Layouts of every mapped PDO (unmapped ones are absent and get disabled at boot)."""
    return {name: layout(name, indices, node_id) for name, indices in mapping.items() if indices}


def configuration_writes(pdo: PdoLayout | None, name: str, node_id: int) -> list[tuple[int, int, str, int]]:
    """SDO writes ``(index, sub, struct format, value)`` that (re)map one PDO, in order.

    ``pdo`` None disables PDO ``name`` (COB-ID bit 31 set, no entries).
    """
    receive = name.startswith("rpdo")
    number = int(name[4:])
    comm = (0x1400 if receive else 0x1800) + number - 1
    mapping = (0x1600 if receive else 0x1A00) + number - 1
    default_cob = (0x200 if receive else 0x180) + 0x100 * (number - 1) + node_id
    invalid = 0x80000000
    writes = [(comm, 1, "<I", invalid | default_cob)]
    if pdo is None:
        return writes
    writes.append((comm, 2, "<B", pdo.transmission))
    if not receive and not pdo.synchronous:
        writes.append((comm, 3, "<H", EVENT_INHIBIT_100US))
        writes.append((comm, 5, "<H", EVENT_TIMER_MS))
    writes.append((mapping, 0, "<B", 0))
    for sub, entry in enumerate(pdo.map_entries(), start=1):
        writes.append((mapping, sub, "<I", entry))
    writes.append((mapping, 0, "<B", len(pdo.indices)))
    writes.append((comm, 1, "<I", pdo.cob_id))
    return writes


def _mappable(od, index: int, receive: bool) -> str | None:
    """Why ``index`` cannot go into a PDO of this drive (None: it can)."""
    obj = od.get(index)
    if obj is None:
        return "the drive has no such object"
    var = obj if not hasattr(obj, "subindices") else obj.subindices.get(PDO_SUBS.get(index, 0))
    if var is None:
        return "the drive has no such object"
    if not getattr(var, "pdo_mappable", False):
        return "the EDS says it cannot be mapped to a PDO"
    if len(var) != PDO_OBJECTS[index][1]:
        return f"it is {len(var)} bits long on this drive, the TCS maps {PDO_OBJECTS[index][1]}"
    if receive and not var.writable or not receive and not var.readable:
        return "its access type does not allow this direction"
    return None


def eds_mapping(section: DriveSection, od, mode: str = "csp") -> tuple[
        dict[str, tuple[int, ...]], list[tuple[str, str]], list[str]]:
    """The PDO mapping of one drive run in ``mode`` given its EDS: (mapping, problems (key,
    text), notes).

    Without an override, the default for the mode (docs/cia402.md; RPDO1 carries 0x607A in
    CSP/PP, 0x60C1:1 in IP, 0x60FF in CSV) minus what this drive cannot map; an override must
    be mappable as written and carry the mode's setpoint object.
    """
    problems: list[tuple[str, str]] = []
    notes: list[str] = []
    mapping: dict[str, tuple[int, ...]] = {}
    needed = essential(mode)
    source = section.mapping if section.pdo else default_mapping(mode)
    setpoint = SETPOINT_OBJECT.get(mode, 0x607A)
    if section.pdo and setpoint not in source.get("rpdo1", ()):
        problems.append(("pdo.rpdo1", f"must map 0x{setpoint:04X} ({PDO_OBJECTS[setpoint][0]}), "
                                      f"the setpoint of mode {mode.upper()}"))
    for name, indices in source.items():
        receive = name.startswith("rpdo")
        number = int(name[4:])
        map_index = (0x1600 if receive else 0x1A00) + number - 1
        comm_index = (0x1400 if receive else 0x1800) + number - 1
        if od.get(map_index) is None or od.get(comm_index) is None:
            lost = [i for i in indices if i in needed]
            if section.pdo or lost:
                problems.append((f"pdo.{name}", f"the drive has no {name.upper()} "
                                                f"(0x{comm_index:04X}/0x{map_index:04X})"))
            else:
                notes.append(f"the drive has no {name.upper()}: "
                             f"{', '.join(f'0x{i:04X}' for i in indices)} not transmitted")
            continue
        kept = []
        for i, index in enumerate(indices):
            why = _mappable(od, index, receive)
            if why is None:
                kept.append(index)
            elif section.pdo:
                problems.append((f"pdo.{name}[{i}]", f"0x{index:04X} ({PDO_OBJECTS[index][0]}): {why}"))
            elif index in needed:
                problems.append(("pdo", f"0x{index:04X} ({PDO_OBJECTS[index][0]}) cannot be in "
                                        f"{name.upper()}: {why} — {needed[index]}; give a "
                                        f"mappable layout with [drives.<name>] pdo = {{…}} or use "
                                        f"another drive"))
            else:
                extra = " (read by SDO on a fault)" if index == 0x603F else ""
                notes.append(f"0x{index:04X} ({PDO_OBJECTS[index][0]}) left out of "
                             f"{name.upper()}: {why}{extra}")
        entries = len([s for s in getattr(od.get(map_index), "subindices", {}) if s != 0])
        if entries and len(kept) > entries:
            problems.append((f"pdo.{name}", f"maps {len(kept)} objects; the drive's "
                                            f"{name.upper()} takes at most {entries}"))
        if kept:
            mapping[name] = tuple(kept)
    return mapping, problems, notes


def mapping_for(section: DriveSection, eds, node_id: int,
                mode: str = "csp") -> dict[str, tuple[int, ...]]:
    """The effective mapping of a drive run in ``mode`` from its EDS file (the configured one
    if unreadable)."""
    from tcs.drivers.eds import load_od
    fallback = section.mapping if section.pdo else default_mapping(mode)
    try:
        od = load_od(eds, node_id)
    except Exception:  # reported at boot, naming the drive
        return fallback
    mapping, problems, _ = eds_mapping(section, od, mode)
    return fallback if problems else mapping
