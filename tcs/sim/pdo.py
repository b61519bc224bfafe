"""PDOs of a simulated CANopen node: configuration rules, packing, SYNC and event timing.

The configuration lives in the node's :class:`ObjectStore` (0x1400–0x1403 / 0x1600–0x1603 for
RPDOs, 0x1800–0x1803 / 0x1A00–0x1A03 for TPDOs), so a master reads and changes it by SDO; the
write hooks here enforce what real devices enforce (CiA-301):

* PDO parameters can only be changed in NMT pre-operational: otherwise abort 0x08000022 —
  except the event timer (sub-index 5), which CiA 301 lets change while the PDO is valid (a
  master slows its SYNC and widens the RPDO deadlines in operational, ``tcs.drivers.idle_sync``);
* mapping entries can only be written while the PDO is invalid (COB-ID bit 31) and its
  sub-index 0 is 0 (the procedure: invalidate, sub0 = 0, entries, sub0 = n, validate);
* an entry must name an existing, PDO-mappable object of the right direction, 8/16/32 bits
  long (or a dummy 0x0002–0x0007 in an RPDO): else abort 0x06040041;
* sub-index 0 = n with more than 64 bits mapped: abort 0x06040042; n above the mapping
  entries the EDS gives the PDO (sub-indices 1..n of 0x16xx/0x1Axx; none when it has only
  sub-index 0): abort 0x06090031;
* the COB-ID of a valid PDO cannot be changed without invalidating it first (0x06090030);
* transmission types: RPDO 0–240 synchronous (applied at the next SYNC), 254/255 at once;
  TPDO 0 (at SYNC when changed), 1–240 (every n-th SYNC), 254/255 (on change, at most once
  per inhibit time 100 µs units, and at least every event-timer ms when that is not 0);
  the RTR-only types 252/253 are refused (0x06090030);
* RPDO event timer (sub-index 5, ms): deadline monitoring — :meth:`PdoEngine.rpdo_deadlines`
  tells the node how long it may wait for each RPDO (the node reacts, see ``cia402_drive``).

:class:`PdoEngine` is pure logic: the node hands it received PDO frames, SYNCs and polls, and
it returns frames to send. Nothing here knows CiA-402.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from canopen.objectdictionary import datatypes

from tcs.sim.object_store import (
    ABORT_NOT_MAPPABLE,
    ABORT_PDO_LENGTH,
    ABORT_STATE,
    ABORT_VALUE_HIGH,
    ABORT_VALUE_RANGE,
    ObjectStore,
    SdoAbort,
)

RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
COUNT = 4
COB_INVALID = 0x80000000
_DUMMY_BITS = {0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}
_FORMATS = {datatypes.INTEGER8: "b", datatypes.INTEGER16: "h", datatypes.INTEGER32: "i",
            datatypes.UNSIGNED8: "B", datatypes.UNSIGNED16: "H", datatypes.UNSIGNED32: "I"}


@dataclass
class _TpdoRuntime:
    sync_counter: int = 0
    last_data: bytes | None = None
    last_sent: float = float("-inf")
    pending: bool = False


@dataclass
class PdoEngine:
    """PDO behaviour of one node over its object store.

    Parameters
    ----------
    store:
        The node's objects; mapping hooks are installed on construction.
    is_pre_operational:
        ``() -> bool``: whether PDO parameters may be changed now.
    timer_in_operational:
        Whether the event timers may be changed in any NMT state (CiA 301); False: only in
        pre-operational, as the other parameters.
    """

    store: ObjectStore
    is_pre_operational: object
    timer_in_operational: bool = True
    _rpdo_buffer: dict[int, bytes] = field(default_factory=dict)
    _tpdo: list[_TpdoRuntime] = field(default_factory=lambda: [_TpdoRuntime() for _ in range(COUNT)])
    rpdo_received: int = 0
    rpdo_length_errors: int = 0
    _compiled: dict[int, list] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for n in range(COUNT):
            for base in (RPDO_COMM, TPDO_COMM):
                self.store.on_write(base + n, self._comm_hook(base, n))
            for base in (RPDO_MAP, TPDO_MAP):
                self.store.on_write(base + n, self._map_hook(base, n))

    def reset(self) -> None:
        """Forget buffered RPDOs and TPDO timing (NMT reset communication)."""
        self._compiled.clear()
        self._rpdo_buffer.clear()
        self._tpdo = [_TpdoRuntime() for _ in range(COUNT)]

    # -- configuration rules -----------------------------------------------------------------
    def _check_state(self) -> None:
        self._compiled.clear()  # the mapping may change: recompile on next use
        if not self.is_pre_operational():
            raise SdoAbort(ABORT_STATE, "PDO parameters change only in pre-operational")

    def _comm_hook(self, base: int, n: int):
        def hook(sub: int, value: int) -> None:
            # the event timer (an RPDO's deadline) may change while the PDO is valid, in
            # operational too (CiA 301: only the COB-ID, the type and the inhibit time need it
            # invalid)
            if sub == 5 and self.timer_in_operational:
                self._compiled.clear()
                return
            self._check_state()
            if sub == 1:
                old = self.store.get(base + n, 1)
                if not old & COB_INVALID and not value & COB_INVALID and (old & 0x7FF) != (value & 0x7FF):
                    raise SdoAbort(ABORT_VALUE_RANGE, "invalidate the PDO before changing its COB-ID")
                if value & 0x20000000:
                    raise SdoAbort(ABORT_VALUE_RANGE, "29-bit COB-IDs are not supported")
            elif sub == 2 and (241 <= value <= 253):
                raise SdoAbort(ABORT_VALUE_RANGE, "transmission type not supported")
            if base == TPDO_COMM:
                self._tpdo[n] = _TpdoRuntime()
        return hook

    def _map_hook(self, base: int, n: int):
        receive = base == RPDO_MAP
        comm = (RPDO_COMM if receive else TPDO_COMM) + n

        def hook(sub: int, value: int) -> None:
            self._check_state()
            if not self.store.get(comm, 1) & COB_INVALID:
                raise SdoAbort(ABORT_STATE, "invalidate the PDO before changing its mapping")
            if sub == 0:
                if value > self.entries(base, n):
                    raise SdoAbort(ABORT_VALUE_HIGH, f"the PDO takes at most {self.entries(base, n)} "
                                                     f"mapped objects")
                bits = 0
                for i in range(1, value + 1):
                    entry = self.store.get(base + n, i)
                    if entry == 0:
                        raise SdoAbort(ABORT_NOT_MAPPABLE, f"mapping entry {i} is empty")
                    bits += entry & 0xFF
                if bits > 64:
                    raise SdoAbort(ABORT_PDO_LENGTH, f"{bits} bits mapped")
                return
            if self.store.get(base + n, 0) != 0:
                raise SdoAbort(ABORT_STATE, "set sub-index 0 to 0 before changing entries")
            if value != 0:
                self._check_entry(value, receive)
        return hook

    def _check_entry(self, entry: int, receive: bool) -> None:
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        if receive and index in _DUMMY_BITS and sub == 0:
            if bits != _DUMMY_BITS[index]:
                raise SdoAbort(ABORT_NOT_MAPPABLE)
            return
        var = self.store.variable(index, sub)
        if not var.pdo_mappable or bits != len(var) or bits % 8:
            raise SdoAbort(ABORT_NOT_MAPPABLE)
        if receive and not var.writable or not receive and not var.readable:
            raise SdoAbort(ABORT_NOT_MAPPABLE)

    def entries(self, base: int, n: int) -> int:
        """How many objects PDO mapping ``base + n`` takes: the mapping sub-indices its EDS
        has (1..8; a mapping with only sub-index 0 takes none)."""
        obj = self.store.od.get(base + n)
        subs = getattr(obj, "subindices", None)
        if subs is None:
            return 0
        compact = getattr(self.store.od, "tcs_compact", {}).get(base + n)
        return min(8, compact or len([s for s in subs if s != 0]))

    # -- helpers -----------------------------------------------------------------------------
    def _entries(self, base: int, n: int) -> list[tuple[int, int, int, object]]:
        """(index, sub, bits, ODVariable or None for a dummy) of the mapped objects."""
        compiled = self._compiled.get(base + n)
        if compiled is None:
            compiled = []
            for i in range(1, self.store.get(base + n, 0) + 1):
                entry = self.store.get(base + n, i)
                index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
                var = None if index in _DUMMY_BITS else self.store.variable(index, sub)
                compiled.append((index, sub, bits, var))
            self._compiled[base + n] = compiled
        return compiled

    def cob_id(self, comm_base: int, n: int) -> int | None:
        """The PDO's COB-ID, or None when it is invalid."""
        value = self.store.get(comm_base + n, 1)
        return None if value & COB_INVALID else value & 0x7FF

    def rpdo_cob_ids(self) -> dict[int, int]:
        """COB-ID → RPDO number (0-based) of every valid RPDO."""
        return {cob: n for n in range(COUNT) if (cob := self.cob_id(RPDO_COMM, n)) is not None}

    def rpdo_deadlines(self) -> dict[int, float]:
        """RPDO number (0-based) → deadline (s) of every valid RPDO whose event timer
        (sub-index 5: CiA-301's deadline monitoring of a received PDO) is set."""
        out = {}
        for n in self.rpdo_cob_ids().values():
            try:
                ms = self.store.get(RPDO_COMM + n, 5)
            except KeyError:  # (an EDS without the sub-index)
                continue
            if ms > 0:
                out[n] = ms / 1000.0
        return out

    # -- receive -----------------------------------------------------------------------------
    def receive(self, n: int, data: bytes) -> bool:
        """An RPDO frame arrived (node operational). Returns True if applied at once.

        Synchronous RPDOs are buffered until :meth:`apply_sync_rpdos`; a frame shorter than the
        mapping is dropped (CiA-301: "PDO not processed due to length error").
        """
        entries = self._entries(RPDO_MAP, n)
        length = sum(e[2] for e in entries) // 8
        if len(data) < length:
            self.rpdo_length_errors += 1
            return False
        self.rpdo_received += 1
        if self.rpdo_synchronous(n):
            self._rpdo_buffer[n] = bytes(data[:length])
            return False
        self._apply(n, bytes(data[:length]))
        return True

    def apply_sync_rpdos(self) -> set[int]:
        """Apply the synchronous RPDOs received since the last SYNC; returns their numbers."""
        applied = set(self._rpdo_buffer)
        buffered, self._rpdo_buffer = self._rpdo_buffer, {}
        for n, data in sorted(buffered.items()):
            self._apply(n, data)
        return applied

    def rpdo_synchronous(self, n: int) -> bool:
        """Whether RPDO ``n`` waits for the next SYNC (transmission type 0-240)."""
        return self.store.get(RPDO_COMM + n, 2) <= 240

    def has_sync_rpdo(self) -> bool:
        """Whether any valid RPDO is synchronous (its absence can be noticed at SYNC)."""
        return any(self.rpdo_synchronous(n) for n in self.rpdo_cob_ids().values())

    def _apply(self, n: int, data: bytes) -> None:
        offset = 0
        for _index, _sub, bits, var in self._entries(RPDO_MAP, n):
            size = bits // 8
            chunk = data[offset:offset + size]
            offset += size
            if var is None:
                continue
            try:
                self.store.write_value(var, self.store.decode(var, chunk))
            except SdoAbort:
                pass  # a refused value in a PDO is ignored, as devices do

    # -- transmit ----------------------------------------------------------------------------
    def _packer(self, n: int) -> tuple[struct.Struct, list[tuple[int, int, int, int]]]:
        """The compiled layout of TPDO ``n``: a struct and (index, sub, min, max) per entry."""
        key = -1 - n
        compiled = self._compiled.get(key)
        if compiled is None:
            fmt, fields = "<", []
            for index, sub, bits, var in self._entries(TPDO_MAP, n):
                code = _FORMATS.get(var.data_type, "")
                if not code:
                    raise SdoAbort(ABORT_NOT_MAPPABLE)
                size = struct.calcsize(code) * 8
                lo, hi = ((-(1 << (size - 1)), (1 << (size - 1)) - 1) if code.islower()
                          else (0, (1 << size) - 1))
                fmt += code
                fields.append((index, sub, lo, hi))
            compiled = self._compiled[key] = (struct.Struct(fmt), fields)
        return compiled

    def _pack(self, n: int) -> bytes:
        packer, fields = self._packer(n)
        value = self.store.wire_value
        return packer.pack(*[min(hi, max(lo, int(value(index, sub)))) for index, sub, lo, hi in fields])

    def _tpdo_comm(self, n: int) -> tuple[int | None, int, float, float]:
        """(COB-ID or None, transmission type, inhibit s, event timer s) of TPDO ``n``."""
        key = 100 + n
        compiled = self._compiled.get(key)
        if compiled is None:
            st = self.store
            compiled = self._compiled[key] = (self.cob_id(TPDO_COMM, n), st.get(TPDO_COMM + n, 2),
                                              st.get(TPDO_COMM + n, 3) * 1e-4, st.get(TPDO_COMM + n, 5) * 1e-3)
        return compiled

    def on_sync(self, now: float) -> list[tuple[int, bytes]]:
        """TPDO frames due at this SYNC."""
        frames = []
        for n in range(COUNT):
            cob, ttype, _inhibit, _timer = self._tpdo_comm(n)
            if cob is None or ttype > 240:
                continue
            rt = self._tpdo[n]
            if ttype == 0:
                data = self._pack(n)
                if data != rt.last_data:
                    frames.append((cob, data))
                    rt.last_data, rt.last_sent = data, now
                continue
            rt.sync_counter += 1
            if rt.sync_counter >= ttype:
                rt.sync_counter = 0
                data = self._pack(n)
                frames.append((cob, data))
                rt.last_data, rt.last_sent = data, now
        return frames

    def shortest_event_timer(self) -> float:
        """The shortest event timer (s) of the valid event-driven TPDOs (inf: none)."""
        timers = [timer for cob, ttype, _inhibit, timer in map(self._tpdo_comm, range(COUNT))
                  if cob is not None and ttype >= 254 and timer > 0]
        return min(timers, default=float("inf"))

    def poll_events(self, now: float) -> list[tuple[int, bytes]]:
        """Event-driven TPDO frames due now (``now`` in seconds, any monotonic clock)."""
        frames = []
        for n in range(COUNT):
            cob, ttype, inhibit, timer = self._tpdo_comm(n)
            if cob is None or ttype < 254:
                continue
            rt = self._tpdo[n]
            if now - rt.last_sent < inhibit:
                continue
            data = self._pack(n)
            if data != rt.last_data or (timer > 0 and now - rt.last_sent >= timer):
                frames.append((cob, data))
                rt.last_data, rt.last_sent = data, now
        return frames
