"""The CAN bus and its CiA-402 drives in the hardware file: ``[can]`` and ``[drives.<name>]``.

``[can]`` names the python-can interface (``virtual`` in-process, ``socketcand`` for a CAN
gateway or the simulator in another process, ``socketcan`` on the cabinet computer), the SYNC
period of the cyclic phase and the TCS's own NMT node (heartbeat producer). Each
``[drives.<name>]`` table is one servo amplifier: node id, EDS, identity (checked at boot),
the scale ``increments_per_unit`` and everything the driver writes over SDO at boot (limits,
following-error window, homing, profile dynamics, heartbeat, PDO mapping). Positions,
velocities and accelerations are in user units (degrees, mm …); the driver converts.

What a drive accepts is checked here, before anything talks to the bus:

* ``sync_period`` must be a whole number of µs (0x1006 is U32 µs) that 0x60C2 can express as
  ``value × 10^exponent`` with ``value`` 1..255 and ``exponent`` −3..−6, between 1 and 100 ms,
  and not shorter than any drive's ``min_sync_period``;
* ``idle_sync_period`` (the slower SYNC of a resting telescope, :mod:`tcs.drivers.idle_sync`)
  is 0 or a whole multiple (2 or more) of ``sync_period``, at most ``heartbeat_period``;
* node ids 1..127, unique, and different from the TCS's own;
* a PDO mapping override carries at most 64 bits per PDO, maps only objects the driver knows,
  and keeps controlword + target position in RPDO1 (the driver sends one RPDO per cycle) and
  statusword + position actual value in a synchronous TPDO.

:func:`check_can_drives` holds the rules across ``[can]`` and ``[drives]``; ``HwConfig.check``
calls it. The PDO object table (:data:`PDO_OBJECTS`) and :func:`pdo_mapping` are shared with the
driver (``tcs.drivers``), which must map exactly what was validated here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from tcs.config.schema import setting

#: Objects the driver can map into PDOs: index -> (name, bits, signed, direction "r"/"t").
PDO_OBJECTS: dict[int, tuple[str, int, bool, str]] = {
    0x6040: ("controlword", 16, False, "r"),
    0x607A: ("target_position", 32, True, "r"),
    0x60B1: ("velocity_offset", 32, True, "r"),
    0x60C1: ("ip_data_record", 32, True, "r"),       # sub-index 1 (PDO_SUBS)
    0x60FF: ("target_velocity", 32, True, "r"),
    0x6041: ("statusword", 16, False, "t"),
    0x6064: ("position_actual", 32, True, "t"),
    0x606C: ("velocity_actual", 32, True, "t"),
    0x60F4: ("following_error_actual", 32, True, "t"),
    0x60FD: ("digital_inputs", 32, False, "t"),
    0x603F: ("error_code", 16, False, "t"),
    0x6061: ("mode_display", 8, True, "t"),
}

#: Sub-index mapped for objects that are records (0x60C1:1 interpolation data record).
PDO_SUBS: dict[int, int] = {0x60C1: 1}

#: The setpoint object each mode streams in RPDO1 (PP moves and homing use 0x607A).
SETPOINT_OBJECT: dict[str, int] = {"csp": 0x607A, "pp": 0x607A, "ip": 0x60C1, "csv": 0x60FF}
SETPOINT_OBJECTS = frozenset(SETPOINT_OBJECT.values())

#: Objects whose TPDO is sent on every SYNC; a TPDO with none of them is event driven.
CYCLIC_TPDO_OBJECTS = frozenset({0x6041, 0x6064, 0x606C, 0x60F4})

#: The mapping of docs/cia402.md ("The CSP cycle").
DEFAULT_PDO_MAPPING: dict[str, tuple[int, ...]] = {
    "rpdo1": (0x6040, 0x607A),
    "tpdo1": (0x6041, 0x6064),
    "tpdo2": (0x606C, 0x60F4),
    "tpdo3": (0x60FD, 0x603F),
}



def default_mapping(mode: str = "csp") -> dict[str, tuple[int, ...]]:
    """The default mapping for a drive run in ``mode``: RPDO1 carries the mode's setpoint
    object (0x607A in CSP/PP, 0x60C1:1 in IP, 0x60FF in CSV)."""
    mapping = dict(DEFAULT_PDO_MAPPING)
    mapping["rpdo1"] = (0x6040, SETPOINT_OBJECT.get(mode, 0x607A))
    return mapping


PDO_NAMES = ("rpdo1", "tpdo1", "tpdo2", "tpdo3", "tpdo4")
HOMING_METHODS = (1, 2, 17, 18, 19, 21, 33, 34, 35, 37)
_ENTRY = re.compile(r"^(?:0x)?([0-9a-fA-F]{4})(?::(?:0x)?0*0)?$")
_SDO_ENTRY = re.compile(r"^0x([0-9a-fA-F]{4}):(?:0x([0-9a-fA-F]{1,2})|(\d{1,3}))$")


def sdo_entry(key: str) -> tuple[int, int] | None:
    """``"0x6091:1"`` -> (0x6091, 1); None when the key is not ``0xINDEX:SUB``."""
    m = _SDO_ENTRY.match(key.strip())
    if not m:
        return None
    sub = int(m.group(2), 16) if m.group(2) else int(m.group(3))
    return (int(m.group(1), 16), sub) if sub <= 0xFF else None


def interpolation_period(seconds: float) -> tuple[int, int] | None:
    """0x60C2 (value, exponent) for a period, or None when the drive cannot express it.

    The smallest exponent magnitude wins: 10 ms -> (10, -3), 2.5 ms -> (25, -4).
    """
    micro = round(seconds * 1e6)
    if micro <= 0 or abs(micro - seconds * 1e6) > 1e-3:
        return None
    for exponent in (-3, -4, -5, -6):
        scale = 10 ** (6 + exponent)  # µs per unit of 10^exponent s
        if micro % scale == 0 and 1 <= micro // scale <= 255:
            return micro // scale, exponent
    return None


def pdo_mapping(override: dict[str, tuple[str, ...]]) -> tuple[dict[str, tuple[int, ...]], list[tuple[str, str]]]:
    """The effective PDO mapping (name -> object indices) and the problems of an override.

    An override replaces the whole default mapping; PDOs it does not name are disabled.
    Entries are written ``"0x6041"`` (sub-index 0 implied, or ``"0x6041:0"``).
    """
    if not override:
        return dict(DEFAULT_PDO_MAPPING), []
    problems: list[tuple[str, str]] = []
    mapping: dict[str, tuple[int, ...]] = {}
    seen: dict[int, str] = {}
    for name, entries in override.items():
        key = f"pdo.{name}"
        if name not in PDO_NAMES:
            hint = " (the driver sends one RPDO per cycle: map everything into rpdo1)" \
                if name.startswith("rpdo") else ""
            problems.append((key, f"unknown PDO; use one of {', '.join(PDO_NAMES)}{hint}"))
            continue
        direction = name[0]
        indices: list[int] = []
        for i, text in enumerate(entries):
            m = _ENTRY.match(text.strip())
            index = int(m.group(1), 16) if m else None
            if index is None or index not in PDO_OBJECTS:
                known = ", ".join(f"0x{k:04X}" for k, v in PDO_OBJECTS.items() if v[3] == direction)
                problems.append((f"{key}[{i}]", f"{text!r} is not an object the driver maps here "
                                                f"(known: {known})"))
                continue
            if PDO_OBJECTS[index][3] != direction:
                problems.append((f"{key}[{i}]", f"0x{index:04X} cannot go into a "
                                                f"{'receive' if direction == 'r' else 'transmit'} PDO"))
                continue
            if index in seen:
                problems.append((f"{key}[{i}]", f"0x{index:04X} is already mapped in {seen[index]}"))
                continue
            seen[index] = name
            indices.append(index)
        bits = sum(PDO_OBJECTS[i][1] for i in indices)
        if bits > 64:
            problems.append((key, f"maps {bits} bits; a PDO carries at most 64"))
        if indices:
            mapping[name] = tuple(indices)
    rpdo = mapping.get("rpdo1", ())
    if not any(k.startswith("pdo.rpdo") for k, _ in problems):
        if 0x6040 not in rpdo:
            problems.append(("pdo.rpdo1", "must map 0x6040 (controlword)"))
        if not SETPOINT_OBJECTS & set(rpdo):
            problems.append(("pdo.rpdo1", "must map a setpoint: 0x607A (target_position; CSP, "
                                          "PP), 0x60C1 (ip_data_record; IP) or 0x60FF "
                                          "(target_velocity; CSV)"))
    for index in (0x6041, 0x6064):
        if index not in seen:
            problems.append(("pdo", f"a TPDO must map 0x{index:04X} ({PDO_OBJECTS[index][0]})"))
    return mapping, problems


def _whole_ms(seconds: float) -> bool:
    return abs(seconds * 1000 - round(seconds * 1000)) < 1e-6


@dataclass(frozen=True)
class CanSection:
    interface: Literal["virtual", "socketcand", "socketcan"] = setting(
        "virtual", doc="python-can interface: virtual (in-process), socketcand (gateway / "
                       "tcs-sim process), socketcan (kernel CAN, production)")
    channel: str = setting("tcs-sim", doc="CAN channel: can0 / vcan0, the socketcand bus name, "
                                          "or the virtual channel name")
    host: str = setting("127.0.0.1", doc="socketcand server address")
    port: int = setting(29536, min=1, max=65535, doc="socketcand server port")
    bitrate: int = setting(1_000_000, min=10_000, max=1_000_000,
                           doc="bit rate (bit/s) for bus-load figures and interfaces that set it")
    options: dict[str, str] = setting(
        factory=dict, doc="extra python-can Bus keyword arguments (strings; 'true'/'false' and "
                          "integers are converted), e.g. tcp_tune = 'true' for socketcand")
    sync_period: float = setting(0.010, min=0.001, max=0.100,
                                 doc="SYNC period = control cycle = 0x1006/0x60C2 of the drives, s")
    tpdo_deadline: float | None = setting(
        None, min=0.1, max=0.9, doc="fraction of the SYNC period after which the cycle runs even "
                                    "if some synchronous TPDOs have not arrived (default 0.5 "
                                    "with kernel SYNC on socketcan, 0.8 when the cycle thread "
                                    "sends SYNC itself)")
    idle_sync_period: float = setting(
        0.0, min=0.0, max=1.0, doc="SYNC period while every drive rests disabled (0 = always "
                                   "sync_period): a whole multiple (2x or more) of sync_period, at "
                                   "most heartbeat_period. The drives' 0x1006 and RPDO "
                                   "deadlines follow it by SDO; a drive that refuses keeps the "
                                   "full rate for all; the first enable brings the full rate back "
                                   "before the power stage (tcs.drivers.idle_sync)")
    heartbeat_period: float = setting(0.1, min=0.01, max=10.0,
                                      doc="period of the TCS's own heartbeat, s (whole ms)")
    node_id: int = setting(127, min=1, max=127, doc="NMT node id of the TCS (its heartbeat COB-ID is 0x700 + id)")
    boot_timeout: float = setting(5.0, min=0.1, max=120.0,
                                  doc="seconds a drive may take to answer at boot")
    sdo_timeout: float = setting(0.5, min=0.05, max=10.0, doc="seconds per SDO response")
    control_process: bool = setting(
        False, doc="run the control loop, the drivers and (on a virtual bus) the simulated drives "
                   "in a process of their own, so that no client load can delay a cycle (the "
                   "service talks to it over a socket pair); false: a thread of the service")
    realtime_priority: int = setting(
        0, min=0, max=99, doc="SCHED_FIFO priority of the control-loop thread (1..99; 0 = normal "
                              "scheduling). Needs CAP_SYS_NICE or LimitRTPRIO (the systemd unit "
                              "grants it); refused by the system, the loop runs normally and says so")
    heartbeat_tolerance: float = setting(
        5.0, min=1.5, max=50.0, doc="drive heartbeat periods of silence before the TCS gives a drive "
                                    "up (a late heartbeat within this is jitter, not a loss); the axis "
                                    "is then quick-stopped")
    tpdo_stale_cycles: int = setting(
        30, min=2, max=10000, doc="consecutive SYNC cycles without a drive's synchronous TPDOs before "
                                  "its data counts as stale: an error of its axis (quick stop)")

    def check(self):
        problems = []
        if interpolation_period(self.sync_period) is None:
            problems.append(("sync_period", f"{self.sync_period!r} s is not a whole number of µs "
                                            "expressible in 0x60C2 (value 1..255 × 10^-3..10^-6 s)"))
        if not _whole_ms(self.heartbeat_period):
            problems.append(("heartbeat_period", "must be a whole number of milliseconds"))
        if self.idle_sync_period:
            ratio = self.idle_sync_period / self.sync_period
            if ratio < 2 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
                problems.append(("idle_sync_period", f"must be 0 (off) or a whole multiple (2 or more) "
                                                     f"of sync_period ({self.sync_period:g} s)"))
            elif self.idle_sync_period > self.heartbeat_period + 1e-12:
                problems.append(("idle_sync_period", f"must be at most heartbeat_period "
                                                     f"({self.heartbeat_period:g} s): the TCS "
                                                     "heartbeat is sent from the cycle"))
        for key, value in self.options.items():
            if key in ("interface", "channel", "host", "port", "bitrate"):
                problems.append((f"options.{key}", "set it in [can] itself, not in options"))
        return problems

    def bus_kwargs(self) -> dict:
        """Keyword arguments for ``can.Bus`` (interface, channel, and the interface's options)."""
        kwargs: dict = {"interface": self.interface, "channel": self.channel}
        if self.interface == "socketcand":
            # tcp_tune: TCP_NODELAY + quick ACK on the client socket. Without it every small
            # frame (SYNC, RPDO) waits for Nagle / delayed ACK and most cycles miss their TPDOs.
            kwargs.update(host=self.host, port=self.port, tcp_tune=True)
        for key, text in self.options.items():
            low = text.strip().lower()
            if low in ("true", "false"):
                kwargs[key] = low == "true"
            elif re.fullmatch(r"[+-]?\d+", low):
                kwargs[key] = int(low)
            else:
                kwargs[key] = text
        return kwargs


@dataclass(frozen=True, kw_only=True)
class IdentitySection:
    """Expected 0x1018 identity; a field left out is not checked (pin vendor and product,
    leave the revision out, and a firmware update does not block the boot)."""

    vendor: int | None = setting(None, min=0, max=0xFFFFFFFF, doc="0x1018:1 vendor id")
    product: int | None = setting(None, min=0, max=0xFFFFFFFF, doc="0x1018:2 product code")
    revision: int | None = setting(None, min=0, max=0xFFFFFFFF,
                                   doc="0x1018:3 revision number (leave out to accept any firmware)")
    serial: int | None = setting(None, min=0, max=0xFFFFFFFF, doc="0x1018:4 serial number (optional)")


@dataclass(frozen=True)
class HomingSection:
    method: Literal[1, 2, 17, 18, 19, 21, 33, 34, 35, 37] = setting(
        37, doc="0x6098 homing method (1/2 limit+index, 17/18 limit, 19/21 home switch, "
                "33/34 index, 35/37 current position)")
    speed_switch: float = setting(1.0, min=0.0, doc="0x6099:1 search-for-switch speed, units/s")
    speed_zero: float = setting(0.1, min=0.0, doc="0x6099:2 search-for-zero speed, units/s")
    acceleration: float = setting(10.0, min=0.0, doc="0x609A homing acceleration, units/s²")
    offset: float = setting(0.0, doc="0x607C home offset, units")
    timeout: float = setting(120.0, min=0.1, max=3600.0, doc="seconds homing may take")


@dataclass(frozen=True, kw_only=True)
class DriveSection:
    node_id: int = setting(min=1, max=127, doc="CANopen node id")
    identity: IdentitySection = setting(doc="expected 0x1018 identity")
    eds: str = setting("", doc="EDS file, relative to the hardware file (empty = the simulated "
                               "drive's hwconfig/eds/tcs-sim-drive.eds)")
    increments_per_unit: float = setting(doc="encoder increments per user unit (degree, mm …); "
                                             "negative reverses the direction")
    min_position: float = setting(doc="software limit written to 0x607D:1, units")
    max_position: float = setting(doc="software limit written to 0x607D:2, units")
    following_error_window: float = setting(doc="0x6065 following-error window, units")
    creep_distance: float | None = setting(
        None, min=0.0, max=1e9, doc="longest tcs-commission jog of this drive while it is not referenced "
        "(its position frame is arbitrary, so the limits cannot be checked), units; default 1 % of "
        "max_position - min_position; --unreferenced lifts it")
    following_error_timeout: float = setting(0.05, min=0.0, max=65.535,
                                             doc="0x6066 following-error time-out, s")
    max_velocity: float = setting(doc="0x6081 profile velocity for PP moves, units/s")
    max_acceleration: float = setting(doc="0x6083/0x6084 profile acceleration/deceleration, units/s²")
    quick_stop_deceleration: float | None = setting(
        None, min=0.0, doc="0x6085 quick-stop deceleration, units/s² (default max_acceleration)")
    homing: HomingSection = setting(factory=HomingSection, doc="homing (mode 6)")
    heartbeat_period: float = setting(0.1, min=0.01, max=10.0,
                                      doc="0x1017 drive heartbeat period, s; the TCS reports a "
                                          "drive silent for 1.5 periods")
    heartbeat_consumer_timeout: float = setting(
        0.5, min=0.01, max=65.535, doc="0x1016 time the drive waits for the TCS heartbeat "
                                       "before it faults, s")
    master_loss_timeout: float | None = setting(
        None, min=0.0, max=65.535,
        doc="s without the TCS's cyclic setpoints (RPDO) after which the drive stops by itself "
            "(0x1400:5 deadline monitoring, then 0x6007 → quick stop at 0x6085; optional "
            "object); default 3 SYNC periods, 0 = off")
    default_mode: Literal["csp", "pp"] = setting(
        "csp", doc="mode set at boot: pp (profile moves: filter wheel, M3) or csp = the "
                   "drive's streaming mode ('mode'); a trajectory axis switches to its "
                   "streaming mode when powered")
    mode: Literal["auto", "csp", "ip", "csv", "pp"] = setting(
        "auto", doc="operating mode of the axis: csp (cyclic synchronous position), ip "
                    "(interpolated position), csv (cyclic synchronous velocity, the TCS closes "
                    "the position loop), pp (profile position: axes that never stream, e.g. "
                    "filter wheel, M3); auto = the first of CSP, IP, CSV that 0x6502 offers (read "
                    "from the drive at boot when the EDS gives no default) and whose setpoint "
                    "the drive's PDOs can carry")
    csv_kp: float = setting(10.0, min=0.0, max=1000.0,
                            doc="CSV: proportional gain of the TCS position loop, 1/s "
                                "(velocity correction per unit of following error)")
    csv_ki: float = setting(20.0, min=0.0, max=100000.0,
                            doc="CSV: integral gain of the TCS position loop, 1/s²")
    csv_max_correction: float | None = setting(
        None, min=0.0, doc="CSV: largest velocity correction (P + I) added to the path's "
                           "velocity, units/s (default a tenth of max_velocity); the integral "
                           "is held within it")
    min_sync_period: float = setting(0.001, min=0.0001, max=0.1,
                                     doc="shortest SYNC period this drive accepts, s")
    pdo: dict[str, list[str]] = setting(
        factory=dict, doc="PDO layout written by hand, e.g. rpdo1 = ['0x6040', '0x607A']; used "
                          "as written (checked against the EDS). Leave it out: the TCS lays the "
                          "PDOs out from the EDS (mapping entries, mappability, COB-IDs)")
    velocity_factor: float | None = setting(
        None, doc="drive velocity units per user unit/s (0x6081, 0x607F, 0x6099, 0x606C); "
                  "default increments_per_unit (the drive counts increments/s); e.g. rpm")
    acceleration_factor: float | None = setting(
        None, doc="drive acceleration units per user unit/s² (0x6083-0x6085, 0x609A); "
                  "default increments_per_unit (increments/s²)")
    absolute: bool = setting(
        False, doc="absolute encoder, referenced by configuration: no homing run on any drive "
                   "(also drives without homing mode or with a read-only 0x6098); REFERENCED is "
                   "1 once powered, REINIT completes at once")
    sdo: dict[str, int] = setting(
        factory=dict, doc="raw SDO writes after the TCS's own configuration, in file order: "
                          "\"0x6091:1\" = 1 (index:sub = integer); checked against the EDS at start")
    enable_timeout: float = setting(2.0, min=0.05, max=600.0,
                                    doc="s from enable to Operation enabled (commutation search)")
    fault_reset_timeout: float = setting(1.0, min=0.05, max=600.0,
                                         doc="s for the drive to leave Fault after a reset")
    mode_switch_timeout: float = setting(1.0, min=0.05, max=600.0,
                                         doc="s for 0x6061 to show a newly written mode")
    sdo_timeout: float | None = setting(None, min=0.05, max=10.0,
                                        doc="s per SDO response (default can.sdo_timeout)")
    sdo_retries: int = setting(1, min=0, max=10, doc="SDO retries after a time-out")
    abort_connection_option: int = setting(
        3, min=0, max=3, doc="0x6007 reaction of the drive to a lost connection (SYNC/RPDOs/NMT): "
                             "0 none, 1 fault, 2 disable voltage, 3 quick stop (optional object)")
    quick_stop_option: int = setting(
        2, min=0, max=8, doc="0x605A quick stop option: 1/2 ramp (profile/quick-stop deceleration) "
                             "then switch on disabled, 5/6 ramp and stay (optional object)")
    disable_operation_option: int = setting(
        1, min=0, max=1, doc="0x605C disable operation option: 1 ramp down first (optional object)")
    fault_reaction_option: int = setting(
        2, min=0, max=2, doc="0x605E fault reaction: 1 ramp with the profile, 2 with the quick-stop "
                             "deceleration, 0 disable at once (optional object)")

    def check(self):
        problems = []
        if self.increments_per_unit == 0:
            problems.append(("increments_per_unit", "must not be zero"))
        if not self.min_position < self.max_position:
            problems.append(("max_position", f"must be above min_position ({self.min_position})"))
        for key in ("following_error_window", "max_velocity", "max_acceleration"):
            if not getattr(self, key) > 0:
                problems.append((key, "must be positive"))
        if not _whole_ms(self.heartbeat_period):
            problems.append(("heartbeat_period", "must be a whole number of milliseconds"))
        if not _whole_ms(self.heartbeat_consumer_timeout):
            problems.append(("heartbeat_consumer_timeout", "must be a whole number of milliseconds"))
        scale = abs(self.increments_per_unit) or 1.0
        for key in ("min_position", "max_position"):
            if abs(getattr(self, key) * scale) > 2**31 - 1:
                problems.append((key, "beyond the 32-bit position range of the drive"))
        problems.extend(pdo_mapping(self.pdo)[1])
        for key in ("velocity_factor", "acceleration_factor"):
            if getattr(self, key) is not None and not getattr(self, key) > 0:
                problems.append((key, "must be positive (the direction is increments_per_unit's sign)"))
        for key, value in self.sdo.items():
            if sdo_entry(key) is None:
                problems.append((f"sdo.{key}", "write entries as \"0xINDEX:SUB\" = value, "
                                               "e.g. \"0x6091:1\" = 1"))
        return problems

    @property
    def wanted_mode(self) -> str:
        """The configured streaming mode (``mode``: auto, csp, ip, csv or pp)."""
        return self.mode

    @property
    def profile_moves(self) -> bool:
        """Profile position is used (boot mode or the axis's mode): 0x6081/0x6083 needed."""
        return self.default_mode == "pp" or self.mode == "pp"

    @property
    def velocity_scale(self) -> float:
        """Drive velocity units per user unit/s (sign of ``increments_per_unit``)."""
        sign = -1.0 if self.increments_per_unit < 0 else 1.0
        return self.increments_per_unit if self.velocity_factor is None else sign * self.velocity_factor

    @property
    def acceleration_scale(self) -> float:
        """Drive acceleration units per user unit/s² (always used as a magnitude)."""
        return abs(self.increments_per_unit if self.acceleration_factor is None
                   else self.acceleration_factor)

    @property
    def raw_writes(self) -> list[tuple[str, int, int, int]]:
        """``[drives.x.sdo]`` as ``(key, index, sub, value)`` in file order."""
        out = []
        for key, value in self.sdo.items():
            entry = sdo_entry(key)
            if entry is not None:
                out.append((key, entry[0], entry[1], value))
        return out

    @property
    def mapping(self) -> dict[str, tuple[int, ...]]:
        """The effective PDO mapping (validated)."""
        return pdo_mapping(self.pdo)[0]


def check_can_drives(can: CanSection | None, drives: dict[str, DriveSection]) -> list[tuple[str, str]]:
    """Rules across ``[can]`` and ``[drives]`` (called by ``HwConfig.check``)."""
    problems: list[tuple[str, str]] = []
    if drives and can is None:
        problems.append(("can", "drives are configured but there is no [can] section"))
        return problems
    owner: dict[int, str] = {}
    for name, drive in drives.items():
        if drive is None:
            continue
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", name):
            problems.append((f"drives.{name}", "drive names are letters, digits and '_'"))
        if drive.node_id in owner:
            problems.append((f"drives.{name}.node_id",
                             f"node id {drive.node_id} is already used by drive {owner[drive.node_id]!r}"))
        else:
            owner[drive.node_id] = name
        if can is not None and drive.node_id == can.node_id:
            problems.append((f"drives.{name}.node_id",
                             f"node id {drive.node_id} is the TCS's own (can.node_id)"))
        if can is not None and can.sync_period < drive.min_sync_period - 1e-12:
            problems.append(("can.sync_period", f"{can.sync_period} s is shorter than drive "
                                                f"{name!r} accepts ({drive.min_sync_period} s)"))
        if can is not None and drive.master_loss_timeout and \
                drive.master_loss_timeout < 2 * can.sync_period - 1e-12:
            problems.append((f"drives.{name}.master_loss_timeout",
                             f"must be 0 (off) or at least 2 × can.sync_period "
                             f"({2 * can.sync_period:g} s)"))
        if can is not None and can.idle_sync_period:
            for key, index, sub, _ in drive.raw_writes:
                if (index, sub) == (0x1006, 0) or (0x1400 <= index <= 0x15FF and sub == 5):
                    problems.append((f"drives.{name}.sdo.{key}",
                                     "the idle SYNC (can.idle_sync_period) writes this object at "
                                     "rest and the boot's own value back after: set "
                                     "can.sync_period or master_loss_timeout instead, or "
                                     "can.idle_sync_period = 0"))
        if can is not None and drive.heartbeat_consumer_timeout < 1.5 * can.heartbeat_period:
            problems.append((f"drives.{name}.heartbeat_consumer_timeout",
                             f"must be at least 1.5 × can.heartbeat_period "
                             f"({1.5 * can.heartbeat_period:g} s)"))
    return problems
