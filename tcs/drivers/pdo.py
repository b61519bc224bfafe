"""PDO layouts of one drive: laid out from its EDS, the SDO writes that map them, the codecs.

:func:`plan_pdos` gives the layout of a drive run in a mode: without ``[drives.x] pdo``,
:func:`auto_layout` spreads what the mode needs (:func:`wanted_objects`: controlword and the
mode's setpoint — 0x607A in CSP/PP, 0x60C1:1 in IP, 0x60FF in CSV — in RPDOs sent every cycle;
statusword, position actual value, velocity and following error in TPDOs sent on every SYNC;
digital inputs and error code in an event-driven TPDO) over the PDOs the EDS describes
(:func:`pdo_slots`: RPDO1–4 / TPDO1–4, each with its number of mapping entries, the COB-ID and
the transmission types it accepts), within 64 bits per PDO and only with objects the EDS marks
mappable. Generic rules, no vendor tables: first fit in PDO number order. An object the cycle
cannot do without (:data:`ESSENTIAL`) that does not fit is a problem naming it and the PDOs
tried; the others are left out with a note (0x603F is then read by SDO on a fault). A
hand-written ``pdo`` is used as written, checked against the EDS the same way. On a drive
like our simulated one the result is the layout of docs/cia402.md: RPDO1 = 0x6040 + setpoint;
TPDO1 = 0x6041 + 0x6064; TPDO2 = 0x606C + 0x60F4 (SYNC); TPDO3 = 0x60FD + 0x603F (event).

The driver does not use canopen's PDO classes: it writes the communication and mapping
parameters itself (remap procedure of CiA 301: invalidate the COB-ID, sub0 = 0, entries, sub0 =
n, validate — only in pre-operational) and packs / unpacks frames with a precompiled
:class:`struct.Struct`, so the per-cycle path is one ``pack`` and one ``send`` per RPDO.

Used by the start check (:mod:`tcs.drivers.eds_check`), the mode choice
(:mod:`tcs.drivers.mode_choice`), the boot (:mod:`tcs.drivers.boot`), the driver and
``tcs-commission scan``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from tcs.config.can import (CYCLIC_TPDO_OBJECTS, PDO_OBJECTS, PDO_SUBS, SETPOINT_OBJECT,
                            SETPOINT_OBJECTS, DriveSection, default_mapping)
from tcs.drivers.eds import default_value, limits, load_od, variable

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


def predefined_cob_id(name: str, node_id: int) -> int:
    """The COB-ID of PDO ``name`` in CiA 301's predefined connection set."""
    base = 0x200 if name.startswith("rpdo") else 0x180
    return base + 0x100 * (int(name[4:]) - 1) + node_id


def layout(name: str, indices: tuple[int, ...], node_id: int,
           comm: tuple[int, int] | None = None) -> PdoLayout:
    """The layout of PDO ``name`` carrying ``indices`` for ``node_id``; ``comm`` = (COB-ID,
    transmission type) the drive accepts (:func:`pdo_slots`), else the predefined COB-ID and
    SYNC (or event for a TPDO of none of :data:`CYCLIC_TPDO_OBJECTS`)."""
    receive = name.startswith("rpdo")
    number = int(name[4:])
    if comm is not None:
        cob_id, transmission = comm
    else:
        cob_id = predefined_cob_id(name, node_id)
        if receive:
            transmission = SYNCHRONOUS
        else:
            transmission = SYNCHRONOUS if CYCLIC_TPDO_OBJECTS & set(indices) else EVENT
    fmt = "<" + "".join(_FORMATS[PDO_OBJECTS[i][1], PDO_OBJECTS[i][2]] for i in indices)
    return PdoLayout(name, number, cob_id, tuple(indices), transmission, struct.Struct(fmt))


def layouts(mapping: dict[str, tuple[int, ...]], node_id: int,
            comm: dict[str, tuple[int, int]] | None = None) -> dict[str, PdoLayout]:
    """Layouts of every mapped PDO (unmapped ones are absent and get disabled at boot)."""
    comm = comm or {}
    return {name: layout(name, indices, node_id, comm.get(name))
            for name, indices in mapping.items() if indices}


def describe(pdos: dict[str, PdoLayout]) -> list[str]:
    """One line per PDO: ``RPDO1 0x201 SYNC: 0x6040 controlword + 0x607A target_position``."""
    out = []
    for pdo in sorted(pdos.values(), key=lambda p: (not p.receive, p.number)):
        kind = "SYNC" if pdo.synchronous else f"event ({pdo.transmission})"
        if pdo.transmission not in (SYNCHRONOUS, EVENT, 254) and not pdo.synchronous:
            kind = f"type {pdo.transmission}"
        objects = " + ".join(f"0x{i:04X}{f':{PDO_SUBS[i]}' if i in PDO_SUBS else ''} "
                             f"{PDO_OBJECTS[i][0]}" for i in pdo.indices)
        out.append(f"{pdo.name.upper()} 0x{pdo.cob_id:03X} {kind}: {objects} ({pdo.bits} bits)")
    return out


def configuration_writes(pdo: PdoLayout | None, name: str, node_id: int) -> list[tuple[int, int, str, int]]:
    """SDO writes ``(index, sub, struct format, value)`` that (re)map one PDO, in order.

    ``pdo`` None disables PDO ``name`` (COB-ID bit 31 set, no entries).
    """
    receive = name.startswith("rpdo")
    number = int(name[4:])
    comm = (0x1400 if receive else 0x1800) + number - 1
    mapping = (0x1600 if receive else 0x1A00) + number - 1
    default_cob = pdo.cob_id if pdo is not None else predefined_cob_id(name, node_id)
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


#: The objects the automatic layout carries, in the order they are placed: (index, group).
#: Groups: "r" RPDO (synchronous), "sync" TPDO on every SYNC, "event" TPDO on change.
#: The setpoint of the mode is inserted after the controlword (:func:`wanted_objects`).
AUTO_TPDO_OBJECTS = ((0x6041, "sync"), (0x6064, "sync"), (0x606C, "sync"), (0x60F4, "sync"),
                     (0x60FD, "event"), (0x603F, "event"))
#: Highest PDO number the layout uses (CiA 301's predefined connection set has four of each).
MAX_PDOS = 4


def wanted_objects(mode: str) -> list[tuple[int, str]]:
    """What a drive run in ``mode`` should carry in its PDOs, most important first."""
    return [(0x6040, "r"), (SETPOINT_OBJECT.get(mode, 0x607A), "r"), *AUTO_TPDO_OBJECTS]


@dataclass(frozen=True)
class PdoSlot:
    """One PDO a drive has, as its EDS describes it.

    ``entries``: how many objects its mapping takes (mapping sub-indices 1..n; 0 = none);
    ``cob_id``: the COB-ID it is used with (CiA 301's predefined connection set, or the EDS
    default's 11 bits when the COB-ID is read-only); ``sync_type`` / ``event_type``: the
    transmission types it accepts for synchronous (1) and event-driven (255, else 254) use,
    None where it accepts neither; ``why``: why the layout cannot use it (None: it can)."""

    name: str
    entries: int
    cob_id: int
    sync_type: int | None
    event_type: int | None
    why: str | None = None

    @property
    def receive(self) -> bool:
        return self.name.startswith("rpdo")

    def text(self) -> str:
        if self.why:
            return f"{self.name.upper()} ({self.why})"
        return f"{self.name.upper()} ({self.entries} entr{'y' if self.entries == 1 else 'ies'})"


def _accepts(var, value: int) -> bool:
    """Whether ``var`` (an EDS entry) can hold ``value``: writable within its limits, or
    read-only already holding it. An absent entry accepts anything (nothing is written)."""
    if var is None:
        return True
    if not var.writable:
        return default_value(var) == value
    lo, hi = limits(var)
    return (lo is None or value >= lo) and (hi is None or value <= hi)


def _entry_count(od, obj) -> tuple[int, str | None]:
    """(mapping entries, why the mapping cannot be written) of a mapping object: its
    sub-indices 1..n (``CompactSubObj`` = n), at most sub-index 0's HighLimit."""
    subs = getattr(obj, "subindices", None)
    if subs is None:  # a plain variable where a record is expected
        return 0, "its mapping object is not a record"
    compact = getattr(od, "tcs_compact", {}).get(obj.index)
    count = compact if compact else len([s for s in subs if s != 0])
    count = min(count, 8)
    sub0 = subs.get(0)
    if sub0 is not None:
        hi = sub0.max
        if isinstance(hi, int) and 0 <= hi < count:
            count = hi
        if not sub0.writable:
            return count, "fixed mapping (sub-index 0 read-only)"
    fixed = [s for s, v in subs.items() if s and s <= count and not v.writable]
    if fixed:
        return count, "fixed mapping (read-only entries)"
    return count, None


def pdo_slots(od, receive: bool, node_id: int) -> list[PdoSlot]:
    """The RPDOs (``receive``) or TPDOs of a drive (1..:data:`MAX_PDOS`) from its EDS."""
    out = []
    for number in range(1, MAX_PDOS + 1):
        name = f"{'rpdo' if receive else 'tpdo'}{number}"
        comm_index = (0x1400 if receive else 0x1800) + number - 1
        map_index = (0x1600 if receive else 0x1A00) + number - 1
        comm, mapping = od.get(comm_index), od.get(map_index)
        if comm is None or mapping is None:
            continue  # the drive does not have it
        entries, why = _entry_count(od, mapping)
        cob_var = variable(od, comm_index, 1)
        default = default_value(cob_var)
        cob_id = predefined_cob_id(name, node_id)
        if (cob_var is not None and not cob_var.writable and isinstance(default, int)
                and default & 0x7FF and not default & 0x20000000):
            cob_id = default & 0x7FF  # fixed by the drive (a DCF's literal ids are not: node 1's)
        if cob_var is None:
            why = why or "no COB-ID entry"
        elif not cob_var.writable and isinstance(default, int) and default & 0x80000000:
            why = why or "switched off for good (read-only COB-ID, bit 31 set)"
        type_var = variable(od, comm_index, 2)
        sync_type = SYNCHRONOUS if _accepts(type_var, SYNCHRONOUS) else None
        event_type = next((t for t in (EVENT, 254) if _accepts(type_var, t)), None)
        if sync_type is None and event_type is None:
            t = default_value(type_var)
            why = why or f"transmission type fixed to {t}"
        if not entries and not why:
            why = "no mapping entries"
        out.append(PdoSlot(name, entries, cob_id, sync_type, event_type, why))
    return out


@dataclass
class PdoPlan:
    """The PDO layout of one drive run in one mode: ``mapping`` (name -> objects), ``comm``
    (name -> (COB-ID, transmission type)), ``problems`` (key, text), ``notes``."""

    mapping: dict[str, tuple[int, ...]]
    comm: dict[str, tuple[int, int]]
    problems: list[tuple[str, str]]
    notes: list[str]

    def layouts(self, node_id: int) -> dict[str, PdoLayout]:
        return layouts(self.mapping, node_id, self.comm)


def _object_text(index: int) -> str:
    sub = f":{PDO_SUBS[index]}" if index in PDO_SUBS else ""
    return f"0x{index:04X}{sub} ({PDO_OBJECTS[index][0]})"


def plan_pdos(section: DriveSection, od, mode: str, node_id: int) -> PdoPlan:
    """The PDO layout of a drive run in ``mode`` from its EDS (see :func:`auto_layout`), or
    the hand-written ``[drives.x] pdo`` checked against the EDS."""
    if section.pdo:
        return _override_plan(section, od, mode, node_id)
    return auto_layout(od, mode, node_id)


def auto_layout(od, mode: str, node_id: int) -> PdoPlan:
    """Spread what ``mode`` needs (:func:`wanted_objects`) over the PDOs the drive has.

    Generic rules, no vendor tables: an object goes in only when the EDS marks it mappable in
    that direction with the size the TCS uses; it goes into the first PDO (by number) that
    still has a mapping entry and room within 64 bits and accepts the transmission type of
    its group — RPDO objects and the cyclic TPDO objects synchronous (type 1), the others
    event driven (type 255/254), or into a synchronous TPDO with room when no PDO is left for
    them. Objects the cycle cannot do without (controlword, the mode's setpoint, statusword,
    position actual value) that do not fit are problems naming them and the PDOs tried; the
    others are left out with a note."""
    needed = essential(mode)
    problems: list[tuple[str, str]] = []
    notes: list[str] = []
    slots = {True: pdo_slots(od, True, node_id), False: pdo_slots(od, False, node_id)}
    content: dict[str, list[int]] = {}
    kind: dict[str, str] = {}   # name -> "sync" / "event" (TPDOs), "r"
    for index, group in wanted_objects(mode):
        receive = group == "r"
        why = _mappable(od, index, receive)
        if why is not None:
            if index in needed:
                problems.append(("pdo", f"{_object_text(index)} cannot be mapped: {why} — "
                                        f"{needed[index]}"))
            else:
                extra = " (read by SDO on a fault)" if index == 0x603F else ""
                notes.append(f"{_object_text(index)} left out of the PDOs: {why}{extra}")
            continue
        bits = PDO_OBJECTS[index][1]

        def fits(slot: PdoSlot, want: str) -> bool:
            if slot.why:
                return False
            have = content.get(slot.name, [])
            if len(have) >= slot.entries or sum(PDO_OBJECTS[i][1] for i in have) + bits > 64:
                return False
            if receive:
                return slot.sync_type is not None or slot.event_type is not None
            used = kind.get(slot.name)
            if want == "sync":
                return slot.sync_type is not None and used in (None, "sync")
            return slot.event_type is not None and used in (None, "event")

        order = [(s, group) for s in slots[receive]]
        if group == "event":  # no free PDO left: every SYNC in a synchronous one
            order += [(s, "sync") for s in slots[receive] if kind.get(s.name) == "sync"]
        if receive:  # synchronous RPDOs first (applied at SYNC)
            order.sort(key=lambda sg: sg[0].sync_type is None)
        chosen = next(((s, g) for s, g in order if fits(s, g)), None)
        if chosen is None:
            tried = ", ".join(s.text() for s in slots[receive]) or (
                "none: the EDS describes no " + ("RPDO (0x1400-0x1403 with 0x1600-0x1603)" if receive
                                                 else "TPDO (0x1800-0x1803 with 0x1A00-0x1A03)"))
            placed = "; ".join(f"{n.upper()} = {' + '.join(f'0x{i:04X}' for i in v)}"
                               for n, v in content.items() if n.startswith('rpdo' if receive else 'tpdo'))
            text = (f"{_object_text(index)} does not fit in the drive's "
                    f"{'RPDOs' if receive else 'TPDOs'} (tried {tried}"
                    f"{'; already used: ' + placed if placed else ''})")
            if index in needed:
                problems.append(("pdo", f"{text} — {needed[index]}"))
            else:
                notes.append(f"{text}: not transmitted" + (" (read by SDO on a fault)" if index == 0x603F else ""))
            continue
        slot, want = chosen
        content.setdefault(slot.name, []).append(index)
        kind.setdefault(slot.name, "r" if receive else want)
    mapping = {n: tuple(v) for n, v in content.items()}
    comm = {}
    for receive in (True, False):
        for slot in slots[receive]:
            if slot.name not in mapping:
                continue
            k = kind[slot.name]
            if receive:
                ttype = slot.sync_type if slot.sync_type is not None else slot.event_type
            else:
                ttype = slot.sync_type if k == "sync" else slot.event_type
            comm[slot.name] = (slot.cob_id, ttype)
    return PdoPlan(mapping, comm, problems, notes)


def _override_plan(section: DriveSection, od, mode: str, node_id: int) -> PdoPlan:
    """The hand-written ``pdo = {…}``, checked against the EDS (mappable, entries, PDOs)."""
    problems: list[tuple[str, str]] = []
    notes: list[str] = []
    mapping: dict[str, tuple[int, ...]] = {}
    source = section.mapping
    setpoint = SETPOINT_OBJECT.get(mode, 0x607A)
    if setpoint not in source.get("rpdo1", ()):
        problems.append(("pdo.rpdo1", f"must map 0x{setpoint:04X} ({PDO_OBJECTS[setpoint][0]}), "
                                      f"the setpoint of mode {mode.upper()}"))
    slots = {s.name: s for r in (True, False) for s in pdo_slots(od, r, node_id)}
    comm = {}
    for name, indices in source.items():
        receive = name.startswith("rpdo")
        number = int(name[4:])
        map_index = (0x1600 if receive else 0x1A00) + number - 1
        comm_index = (0x1400 if receive else 0x1800) + number - 1
        slot = slots.get(name)
        if slot is None:
            problems.append((f"pdo.{name}", f"the drive has no {name.upper()} "
                                            f"(0x{comm_index:04X}/0x{map_index:04X})"))
            continue
        kept = []
        for i, index in enumerate(indices):
            why = _mappable(od, index, receive)
            if why is None:
                kept.append(index)
            else:
                problems.append((f"pdo.{name}[{i}]", f"0x{index:04X} ({PDO_OBJECTS[index][0]}): {why}"))
        if len(kept) > slot.entries:
            problems.append((f"pdo.{name}", f"maps {len(kept)} objects; the drive's "
                                            f"{name.upper()} takes at most {slot.entries}"))
        elif slot.why and kept:
            problems.append((f"pdo.{name}", f"the drive's {name.upper()} cannot be used: {slot.why}"))
        if kept:
            mapping[name] = tuple(kept)
            sync = receive or bool(CYCLIC_TPDO_OBJECTS & set(kept))
            ttype = slot.sync_type if sync else slot.event_type
            if ttype is None:
                problems.append((f"pdo.{name}", f"the drive's {name.upper()} does not take "
                                                f"transmission type {'1 (SYNC)' if sync else '255 (event)'}"))
            else:
                comm[name] = (slot.cob_id, ttype)
    return PdoPlan(mapping, comm, problems, notes)


def eds_mapping(section: DriveSection, od, mode: str = "csp") -> tuple[
        dict[str, tuple[int, ...]], list[tuple[str, str]], list[str]]:
    """(mapping, problems (key, text), notes) of :func:`plan_pdos` (node id of ``section``)."""
    plan = plan_pdos(section, od, mode, section.node_id)
    return plan.mapping, plan.problems, plan.notes


def layouts_for(section: DriveSection, eds, node_id: int, mode: str = "csp") -> dict[str, PdoLayout]:
    """The PDO layouts of a drive run in ``mode`` from its EDS file (the default mapping if
    the file is unreadable or the layout has problems: the start reported them)."""
    try:
        od = load_od(eds, node_id)
    except Exception:  # reported at boot, naming the drive
        return layouts(section.mapping if section.pdo else default_mapping(mode), node_id)
    plan = plan_pdos(section, od, mode, node_id)
    if plan.problems:
        return layouts(section.mapping if section.pdo else default_mapping(mode), node_id)
    return plan.layouts(node_id)


def mapping_for(section: DriveSection, eds, node_id: int,
                mode: str = "csp") -> dict[str, tuple[int, ...]]:
    """The effective mapping of a drive run in ``mode`` from its EDS file."""
    return {n: p.indices for n, p in layouts_for(section, eds, node_id, mode).items()}
