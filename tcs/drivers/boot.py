"""Boot of one CiA-402 node: wait for it, check who it is, configure it over SDO, start it.

Blocking, outside the cyclic phase (a plain call; from asyncio use ``asyncio.to_thread``).
:func:`boot_node` is the whole sequence; every failure is a :class:`~tcs.errors.HardwareError`
(or :class:`~tcs.errors.CommunicationError`) whose device names the drive and node, and whose
text names the step and object — "drive az (node 3): SDO write 0x6065:0 following-error window
aborted: 0x06090030 value range of parameter exceeded".

Sequence:

1. wait ``boot_timeout`` for a boot-up or heartbeat frame; after a quarter of it (at most
   0.25 s) without one, probe 0x1000 over SDO (a node booted earlier, heartbeat off), and if
   that fails too send NMT *reset communication* (it answers with boot-up);
1b. a drive found powered (a master restart while it was enabled, maybe moving) is brought to a
   controlled stop and disabled first (:mod:`tcs.drivers.takeover`);
2. NMT *enter pre-operational* (PDO remapping is only allowed there);
3. identity: 0x1000 must be a CiA-402 device; 0x1018 vendor / product / revision / serial
   must equal the hardware file — the fields it gives (a left-out revision accepts any
   firmware; a field the EDS has no sub-index for is not read, warned at start);
3b. when the EDS gives 0x6502 (supported drive modes) no default, the drive's own answer
   settles the mode and with it the PDO layout (the ``choose`` hook of :func:`boot_node`);
4. SDO configuration (:func:`configuration`): heartbeat producer (0x1017) and consumer of the
   TCS heartbeat (0x1016), SYNC period (0x1006, optional object) and interpolation period
   (0x60C2), software limits (0x607D), following-error window and time-out (0x6065/0x6066),
   max profile velocity (0x607F, optional), profile velocity / acceleration / deceleration /
   quick-stop deceleration (0x6081/0x6083/0x6084/0x6085), homing method / speeds / acceleration / offset
   (0x6098/0x6099/0x609A/0x607C; none for an ``absolute`` drive), the PDO layout
   (:mod:`tcs.drivers.pdo`; PDOs it does not use are switched off, a read-only COB-ID or
   transmission type is left as the drive has it), the ``[drives.<name>.sdo]`` raw writes in file order, and the
   default mode of operation (0x6060, read back from 0x6061 within ``mode_switch_timeout``);
   the drive's own watch of the master (:func:`master_loss_writes`: RPDO deadlines).
   Every write passes :func:`tcs.drivers.eds_check.usable_writes`: an object of
   :data:`OPTIONAL` the drive's EDS lacks is skipped; values were checked against the EDS
   limits at start (:func:`tcs.drivers.eds_check.check_config`);
5. read statusword, position and error code, NMT *start*, wait for heartbeat "operational".

Units: the driver scales user units to the drive's units itself: positions with
``increments_per_unit``, velocities with ``velocity_factor`` and accelerations with
``acceleration_factor`` (both default to ``increments_per_unit``); it does not touch the
drive's factor group (0x608F/0x6091/0x6092), which stays as commissioned (or is set with
``[drives.<name>.sdo]``).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from dataclasses import dataclass, replace
from typing import Any

import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from tcs.config.can import PDO_SUBS, CanSection, DriveSection, interpolation_period
from tcs.drivers.eds import (LOST, NAMES, OPTIONAL, limits, object_name,  # noqa: F401
                             raw_writes, usable_writes, variable)
from tcs.drivers.pdo import PdoLayout, configuration_writes
from tcs.drivers.pdo import _entry_count as pdo_entry_count
from tcs.drivers.takeover import stop_if_powered
from tcs.errors import CommunicationError, ConfigMismatch, ErrorNumber, HardwareError

NMT_START, NMT_PRE_OPERATIONAL, NMT_RESET_COMMUNICATION = 0x01, 0x80, 0x82
HB_BOOTUP, HB_OPERATIONAL, HB_PRE_OPERATIONAL, HB_STOPPED = 0x00, 0x05, 0x7F, 0x04
NMT_STATE_NAMES = {0x00: "boot-up", 0x04: "stopped", 0x05: "operational", 0x7F: "pre-operational"}
DEVICE_PROFILE_402 = 0x0192
MODE_READBACK_TIMEOUT = 1.0

SDO_ABORTS = {
    0x05040000: "SDO protocol timed out",
    0x06010000: "unsupported access",
    0x06010001: "write-only object",
    0x06010002: "read-only object",
    0x06020000: "object does not exist",
    0x06040041: "object cannot be mapped to a PDO",
    0x06040042: "PDO too long for the mapped objects",
    0x06060000: "access failed (hardware error)",
    0x06070010: "data type / length mismatch",
    0x06090011: "sub-index does not exist",
    0x06090030: "value range of parameter exceeded",
    0x06090031: "value too high",
    0x06090032: "value too low",
    0x08000000: "general error",
    0x08000020: "data cannot be stored",
    0x08000021: "data cannot be stored (local control)",
    0x08000022: "data cannot be stored in the present device state",
}

# The object tables (OPTIONAL, LOST, NAMES, object_name) live in tcs.drivers.eds, below the
# boot and the EDS check that share them; they are imported here for the boot's use.


class Sdo:
    """Blocking SDO access to one node with errors that name the drive, step and object."""

    def __init__(self, node: canopen.RemoteNode, device: str):
        self.node = node
        self.device = device

    def _fail(self, what: str, index: int, sub: int, exc: Exception) -> HardwareError:
        where = f"SDO {what} 0x{index:04X}:{sub} {object_name(index)}".rstrip()
        if isinstance(exc, SdoAbortedError):
            code = exc.code
            text = SDO_ABORTS.get(code, "abort")
            return HardwareError(self.device, f"{where} aborted: 0x{code:08X} {text}",
                                 ErrorNumber.LIBFAIL)
        return CommunicationError(self.device, f"{where}: no answer ({exc})")

    def write(self, index: int, sub: int, fmt: str, value: int) -> bool:
        """Write; returns False when an OPTIONAL object is missing, raises otherwise."""
        try:
            self.node.sdo.download(index, sub, struct.pack(fmt, value))
        except SdoAbortedError as exc:
            if index in OPTIONAL and exc.code in (0x06020000, 0x06090011):
                return False
            raise self._fail("write", index, sub, exc) from None
        except SdoCommunicationError as exc:
            raise self._fail("write", index, sub, exc) from None
        return True

    def read(self, index: int, sub: int, fmt: str) -> Any:
        try:
            data = self.node.sdo.upload(index, sub)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise self._fail("read", index, sub, exc) from None
        size = struct.calcsize(fmt)
        if len(data) < size:
            raise HardwareError(self.device, f"SDO read 0x{index:04X}:{sub} {object_name(index)}: "
                                             f"{len(data)} bytes, expected {size}")
        return struct.unpack(fmt, data[:size])[0]


@dataclass(frozen=True)
class BootResult:
    statusword: int
    position: int
    error_code: int
    mode: int


class HeartbeatWatch:
    """Last heartbeat time and NMT state of one node (fed from the notifier thread)."""

    def __init__(self, clock=time.monotonic):
        self._clock = clock
        self.time: float | None = None
        self.state: int | None = None
        self.bootups = 0
        self.event = threading.Event()

    def on_frame(self, cob_id: int, data: bytearray, timestamp: float) -> None:
        if not data:
            return
        self.state = data[0] & 0x7F
        self.time = self._clock()
        if self.state == HB_BOOTUP:
            self.bootups += 1
        self.event.set()

    def wait_state(self, states: set[int], timeout: float) -> bool:
        """Block until a heartbeat shows one of ``states`` (boot only)."""
        deadline = time.monotonic() + timeout
        while True:
            if self.state in states:
                return True
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.event.clear()
            if self.state in states:
                return True
            self.event.wait(min(remaining, 0.05))


def send_nmt(network: canopen.Network, command: int, node_id: int) -> None:
    network.send_message(0x000, bytes([command, node_id]))


def wait_for_node(network: canopen.Network, sdo: Sdo, hb: HeartbeatWatch, timeout: float,
                  device: str) -> None:
    """Step 1: boot-up or heartbeat within ``timeout``.

    A node that booted before the TCS listened and produces no heartbeat is found by one SDO
    read of 0x1000; one that does not answer that either gets NMT reset communication and
    must then send its boot-up within the rest of ``timeout``.
    """
    start = time.monotonic()
    if hb.state is not None or hb.event.wait(min(max(timeout / 4, 0.05), 0.25)):
        return
    try:
        sdo.read(0x1000, 0, "<I")
        return
    except HardwareError:
        pass
    send_nmt(network, NMT_RESET_COMMUNICATION, sdo.node.id)
    if not hb.event.wait(max(timeout - (time.monotonic() - start), 0.05)):
        raise CommunicationError(device, f"did not boot within {timeout:g} s (no boot-up, "
                                         "heartbeat or SDO answer, not even after NMT reset "
                                         "communication)")


def check_identity(sdo: Sdo, section: DriveSection) -> None:
    """Step 3: device profile 402 and the identity of the hardware file."""
    device_type = sdo.read(0x1000, 0, "<I")
    if device_type & 0xFFFF != DEVICE_PROFILE_402:
        raise HardwareError(sdo.device, f"device type 0x{device_type:08X} (0x1000) is not a "
                                        "CiA-402 drive (bits 0-15 must be 0x0192): another "
                                        "device at this node id, or a drive not set to the "
                                        "CiA-402 profile; correct the node id or the drive")
    ident = section.identity
    expected = [("vendor", 1, ident.vendor), ("product", 2, ident.product),
                ("revision", 3, ident.revision), ("serial", 4, ident.serial)]
    wrong = []
    for name, sub, want in expected:
        if want is None:  # left out of the hardware file: not checked (e.g. any firmware)
            continue
        if variable(sdo.node.object_dictionary, 0x1018, sub) is None:
            continue  # the drive's EDS has no such field (warned at start)
        got = sdo.read(0x1018, sub, "<I")
        if got != want:
            wrong.append(f"{name} 0x{got:08X} (hardware file: 0x{want:08X})")
    if wrong:
        raise HardwareError(sdo.device, "wrong identity (0x1018): " + ", ".join(wrong) +
                            " — another device at this node id, or the file is out of date")


def _u32(value: float, what: str, device: str) -> int:
    v = round(abs(value))
    if v > 0xFFFFFFFF:
        raise HardwareError(device, f"{what} {value:g} (drive units) does not fit the drive's U32")
    return v


def configuration(section: DriveSection, can: CanSection, device: str,
                  mode: int = 8) -> list[tuple[int, int, str, int]]:
    """Step 4 (without PDOs and mode): the SDO writes ``(index, sub, format, value)``; a drive
    run in interpolated position (``mode`` 7) also gets linear interpolation (0x60C0 = 0)."""
    k = section.increments_per_unit
    kv, ka = section.velocity_scale, section.acceleration_scale
    lo, hi = sorted((round(section.min_position * k), round(section.max_position * k)))
    micro = round(can.sync_period * 1e6)
    value, exponent = interpolation_period(can.sync_period)
    home = section.homing
    quick = section.quick_stop_deceleration or section.max_acceleration
    return [
        (0x1017, 0, "<H", round(section.heartbeat_period * 1000)),
        (0x1016, 1, "<I", can.node_id << 16 | round(section.heartbeat_consumer_timeout * 1000)),
        (0x1006, 0, "<I", micro),
        (0x60C2, 1, "<B", value),
        (0x60C2, 2, "<b", exponent),
        (0x607D, 1, "<i", lo),
        (0x607D, 2, "<i", hi),
        (0x6065, 0, "<I", _u32(section.following_error_window * k, "following-error window", device)),
        (0x6066, 0, "<H", round(section.following_error_timeout * 1000)),
        (0x607F, 0, "<I", _u32(section.max_velocity * kv, "max profile velocity", device)),
        (0x6081, 0, "<I", _u32(section.max_velocity * kv, "profile velocity", device)),
        (0x6083, 0, "<I", _u32(section.max_acceleration * ka, "profile acceleration", device)),
        (0x6084, 0, "<I", _u32(section.max_acceleration * ka, "profile deceleration", device)),
        (0x6085, 0, "<I", _u32(quick * ka, "quick-stop deceleration", device)),
        (0x6098, 0, "<b", home.method),
        (0x6099, 1, "<I", _u32(home.speed_switch * kv, "homing speed (switch)", device)),
        (0x6099, 2, "<I", _u32(home.speed_zero * kv, "homing speed (zero)", device)),
        (0x609A, 0, "<I", _u32(home.acceleration * ka, "homing acceleration", device)),
        (0x607C, 0, "<i", round(home.offset * k)),
        (0x6007, 0, "<h", section.abort_connection_option),
        (0x605A, 0, "<h", section.quick_stop_option),
        (0x605C, 0, "<h", section.disable_operation_option),
        (0x605E, 0, "<h", section.fault_reaction_option),
    ] + ([(0x60C0, 0, "<h", 0)] if mode == 7 else [])


def master_loss_writes(section: DriveSection, can: CanSection,
                       layouts: dict[str, PdoLayout]) -> list[tuple[int, int, str, int]]:
    """How the drive notices a lost master (a crashed control process, a cut bus) and stops
    by itself: the deadline of each cyclic RPDO (0x1400+n:5, event timer in ms; CiA-301
    deadline monitoring) is ``master_loss_timeout`` (default 3 SYNC periods), so the drive
    sees the setpoints stop within a few cycles even when SYNC stops with them; it then reacts
    per 0x6007 (``abort_connection_option``, 3 = quick stop) with 0x605A
    (``quick_stop_option``, 2 = ramp at 0x6085 and disable) — written by :func:`configuration`
    with the heartbeat consumer 0x1016 (the slower, independent watch) and 0x6085, which
    :class:`~tcs.drivers.can_system.CanDrives` caps at the axis's stop deceleration. Each
    write only as the drive's EDS allows (an absent event timer is skipped)."""
    timeout = section.master_loss_timeout
    if timeout is None:
        timeout = 3 * can.sync_period
    ms = min(0xFFFF, math.ceil(round(timeout * 1000, 6)))
    if ms <= 0:
        return []
    return [(0x1400 + pdo.number - 1, 5, "<H", ms) for pdo in layouts.values()
            if pdo.receive and pdo.synchronous]


def cycle_period_writes(section: DriveSection, can: CanSection, layouts: dict[str, PdoLayout],
                        period: float) -> list[tuple[int, int, str, int]]:
    """The writes that tell a running drive its SYNC now comes every ``period`` (the idle SYNC
    of :mod:`tcs.drivers.idle_sync`): its RPDO deadlines, as :func:`master_loss_writes` makes
    them for that period (a configured ``master_loss_timeout`` shorter than 3 periods is
    widened to 3 periods), then 0x1006. ``period`` = ``can.sync_period`` gives back exactly
    what the boot wrote. Write them in this order when the SYNC slows (after these writes)
    and in reverse order when it speeds up (before them)."""
    if period > can.sync_period and section.master_loss_timeout:
        section = replace(section, master_loss_timeout=max(section.master_loss_timeout, 3 * period))
    at = replace(can, sync_period=period)
    return master_loss_writes(section, at, layouts) + [(0x1006, 0, "<I", round(period * 1e6))]


def check_eds(od: canopen.ObjectDictionary, layouts: dict[str, PdoLayout], device: str) -> None:
    """The PDO mapping against the EDS: objects exist, may be mapped, enough entries (the
    start checked all of it; this guards a layout that changed since)."""
    remedy = "; remedy: leave [drives.<name>] pdo out (the TCS lays the PDOs out from the EDS)"
    for pdo in layouts.values():
        mapping = od.get(pdo.map_index())
        if mapping is None:
            raise ConfigMismatch(device, f"the EDS has no {pdo.name.upper()} "
                                         f"(0x{pdo.map_index():04X}){remedy}")
        entries, _why = pdo_entry_count(od, mapping)
        if len(pdo.indices) > entries:
            raise ConfigMismatch(device, f"{pdo.name.upper()} maps {len(pdo.indices)} objects; the "
                                         f"drive's 0x{pdo.map_index():04X} takes at most {entries}{remedy}")
        for index in pdo.indices:
            var = od.get_variable(index, PDO_SUBS.get(index, 0))
            if var is None:
                raise ConfigMismatch(device, f"the EDS has no object 0x{index:04X} for "
                                             f"{pdo.name.upper()}{remedy}")
            if not getattr(var, "pdo_mappable", True):
                raise ConfigMismatch(device, f"the EDS says 0x{index:04X} cannot be mapped to a "
                                             f"PDO{remedy}")


def pdo_writes(od: canopen.ObjectDictionary, writes: list[tuple[int, int, str, int]]
               ) -> list[tuple[int, int, str, int]]:
    """A PDO's (re)configuration as this drive takes it: no COB-ID writes where the EDS makes
    the COB-ID read-only (used as it is), no transmission-type write where it is absent or
    read-only (the layout chose a PDO whose type fits), no inhibit time / event timer (RPDO
    deadline) outside the EDS limits (left as commissioned)."""
    out = []
    for index, sub, fmt, value in writes:
        var = variable(od, index, sub)
        if 0x1400 <= index < 0x1600 or 0x1800 <= index < 0x1A00:
            if sub in (1, 2) and (var is None or not var.writable):
                continue
            if sub in (3, 5) and var is not None and not _within(var, value):
                continue  # inhibit time / event timer the drive does not take: as commissioned
        out.append((index, sub, fmt, value))
    return out


def _within(var, value: int) -> bool:
    lo, hi = limits(var)
    return (lo is None or value >= lo) and (hi is None or value <= hi)


def read_supported_modes(sdo: Sdo) -> int | None:
    """0x6502 (supported drive modes) read from the drive, None when it does not answer it."""
    try:
        return sdo.read(0x6502, 0, "<I")
    except HardwareError:
        return None


def set_mode(sdo: Sdo, mode: int, timeout: float = MODE_READBACK_TIMEOUT) -> int:
    """Write 0x6060 and poll 0x6061 until it reads ``mode`` back (blocking)."""
    sdo.write(0x6060, 0, "<b", mode)
    deadline = time.monotonic() + timeout
    while True:
        shown = sdo.read(0x6061, 0, "<b")
        if shown == mode:
            return shown
        if time.monotonic() > deadline:
            raise HardwareError(sdo.device, f"mode {mode} requested, 0x6061 still shows {shown}")
        time.sleep(0.01)


def boot_node(network: canopen.Network, sdo: Sdo, hb: HeartbeatWatch, section: DriveSection,
              can: CanSection, layouts: dict[str, PdoLayout], mode: int,
              start: callable = None, choose: callable = None) -> BootResult:
    """Steps 1–5 for one node. ``start()`` runs just before NMT start (subscribe TPDOs);
    ``choose(sdo) -> (layouts, mode)``, after the identity check, may settle the mode and
    PDO layout from what the drive answers (0x6502 read over SDO)."""
    node_id = section.node_id
    device = sdo.device
    od = sdo.node.object_dictionary
    wait_for_node(network, sdo, hb, can.boot_timeout, device)
    stop_if_powered(sdo, section)  # a drive still enabled (master restart): controlled stop first
    send_nmt(network, NMT_PRE_OPERATIONAL, node_id)
    check_identity(sdo, section)
    # Every write passes the EDS rule (tcs.drivers.eds_check): optional objects the drive
    # lacks are skipped; values were range-checked at start.
    if choose is not None:  # what only the drive can tell (0x6502 without an EDS default)
        layouts, mode = choose(sdo)
    writes = usable_writes(od, configuration(section, can, device, mode), section, device)
    for index, sub, fmt, value in writes:
        sdo.write(index, sub, fmt, value)
    check_eds(od, layouts, device)
    for name in ("rpdo1", "rpdo2", "rpdo3", "rpdo4", "tpdo1", "tpdo2", "tpdo3", "tpdo4"):
        comm = (0x1400 if name[0] == "r" else 0x1800) + int(name[4:]) - 1
        if layouts.get(name) is None and (od.get(comm) is None or od.get(comm + 0x200) is None):
            continue  # the drive has no such PDO: nothing to disable
        writes = pdo_writes(od, configuration_writes(layouts.get(name), name, node_id))
        for index, sub, fmt, value in usable_writes(od, writes, section, device):
            sdo.write(index, sub, fmt, value)
    for index, sub, fmt, value in usable_writes(od, pdo_writes(od, master_loss_writes(section, can, layouts)),
                                                section, device):
        sdo.write(index, sub, fmt, value)
    for index, sub, fmt, value in raw_writes(od, section, device):  # [drives.x.sdo], in order
        sdo.write(index, sub, fmt, value)
    shown = set_mode(sdo, mode, section.mode_switch_timeout)
    code = od.get_variable(0x603F, 0)
    result = BootResult(statusword=sdo.read(0x6041, 0, "<H"), position=sdo.read(0x6064, 0, "<i"),
                        error_code=sdo.read(0x603F, 0, "<H") if code is not None and code.readable
                        else 0, mode=shown)
    if start is not None:
        start()
    send_nmt(network, NMT_START, node_id)
    if not hb.wait_state({HB_OPERATIONAL}, can.boot_timeout):
        state = NMT_STATE_NAMES.get(hb.state, hb.state)
        raise CommunicationError(device, f"NMT start sent, but the heartbeat still shows {state}")
    return result
