"""One CiA-402 drive on CANopen, behind the :class:`~tcs.drivers.drive.Drive` interface.

How it works
------------
* :meth:`Cia402Drive.boot` (blocking, see :mod:`tcs.drivers.boot`) configures the node and
  subscribes its TPDOs, heartbeat and EMCY. From then on the notifier thread only *stores*
  what arrives: the unpacked TPDO objects (``_raw``), the heartbeat time and NMT state, the
  last EMCY decoded into a :class:`~tcs.drivers.emcy.DriveFault`.
* Requests (``enable()``, ``move_to()`` …) only record what is wanted, under a small lock.
* :meth:`Cia402Drive.step` — once per SYNC period, in the control-loop thread, after the
  synchronous TPDOs of this cycle arrived (:class:`tcs.drivers.cycle.CycleSource`) — decodes
  the statusword, looks up the controlword in the table of :mod:`tcs.drivers.cia402`, runs the
  small handshakes (fault reset, mode switch, homing, profile move), and sends the RPDOs of
  its layout (usually one: controlword + setpoint; two when the drive's RPDO1 takes one
  object, :mod:`tcs.drivers.pdo`) while the node is operational. It never blocks: the
  rare SDO transfers it needs (mode switch with read-back of 0x6061, a new profile velocity)
  go to the :class:`~tcs.drivers.worker.SdoWorker` and are polled in later cycles.
* :meth:`Cia402Drive.status` builds a frozen :class:`~tcs.drivers.drive.DriveStatus` from
  those fields, from any thread.
* A streamed CSP/IP setpoint goes with a ``retime`` (:meth:`_retimer`): when the cycle source
  holds the RPDO for a SYNC that then goes out late, the setpoint is moved on by that lateness
  along its stream — a drive interpolates it over the nominal period from the SYNC it got
  (:mod:`tcs.drivers.cycle`, docs/motion.md "Speed over real time").

Safety rules kept here
----------------------
* Modes: the one of :attr:`Cia402Drive.mode_choice` (``[drives.x] mode``, or for ``auto``
  CSP, IP or CSV as 0x6502 offers them and the PDOs can carry their setpoint; 0x6502 read from
  the drive at the first boot when the EDS gives no default, :mod:`tcs.drivers.mode_choice`)
  streams the axis's setpoints: CSP sends 0x607A; IP
  sends the interpolation data record 0x60C1:1 with controlword bit 4 "enable IP" set in
  Operation enabled and takes setpoints only once statusword bit 12 "IP active" shows; CSV
  sends a target velocity 0x60FF from a position loop closed here (:meth:`_csv_step`:
  feed-forward + PI on the following error, within the speed and acceleration limits) and
  supervises the following error itself (window and time-out of the hardware file: a
  violation is a fault of the axis with the same controlled stop).
* Until the axis layer gives a setpoint after enabling, the target sent is the actual
  position latched when Operation enabled (or the cyclic mode) began — the drive never
  jumps; in CSV the loop holds that position.
* A fault, a lost heartbeat, stale TPDOs, a bus fault (bus-off, error passive) or a drive that
  leaves Operation enabled by itself sets the wanted state to *disabled*: after a fault reset
  (rising edge of bit 7, transition 15) the drive stays in Switch on disabled until
  ``enable()`` is requested again.
* **Controlled stop, never a cut at speed.** Whatever asks for *disabled* (the cases above,
  POWER=0, a fault of the axis), a drive in Operation enabled or Quick stop active that is not
  at rest gets *quick stop* (0x0002, transition 11: it ramps with 0x6085 and, per 0x605A,
  ends in Switch on disabled); *disable voltage* (0x0000) follows only at standstill, or
  after ``stop_timeout`` = max velocity / quick-stop deceleration + 1 s whatever it reports.
  A drive given up for silence (OFFLINE) gets quick stop for ``stop_timeout``, then disable.
* Timing tolerates jitter: the drive's heartbeat is lost only after ``can.heartbeat_tolerance``
  periods of silence (default 5), its data is stale only after ``can.tpdo_stale_cycles``
  cycles in a row without its synchronous TPDOs (default 30). A genuine loss therefore stops
  the axis within tolerance × period (detection) + ``stop_timeout``.
* Setpoints and move targets are clamped to the software limits of the hardware file.
* The TCS's own stall is no silence of the drive: when a cycle (:meth:`note_cycle`) comes
  more than :data:`HOST_STALL` s after the previous one (the process was starved or stopped), the
  heartbeat window restarts at that step — heartbeats the drive sent meanwhile may still wait
  unread in the receive queue. A drive silent while the TCS runs is lost as before.

Units: the interface is in user units; the wire in increments (``increments_per_unit``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import canopen

from tcs.config.can import CanSection, DriveSection
from tcs.drivers import cia402 as sm
from tcs.drivers.boot import (HB_OPERATIONAL, HB_PRE_OPERATIONAL, HB_STOPPED, NMT_STATE_NAMES,
                              BootResult, HeartbeatWatch, Sdo, boot_node, cycle_period_writes,
                              pdo_writes, read_supported_modes, set_mode)
from tcs.drivers.canbus import HEARTBEAT_BASE, CanBus
from tcs.drivers.cia402 import Want
from tcs.drivers.drive import CYCLIC_MODES, DriveState, DriveStatus, Mode, Progress
from tcs.drivers.eds import decode_modes, read_od, supported_modes, usable_writes, variable
from tcs.drivers.mode_choice import choose_mode, drive_mode
from tcs.drivers.emcy import DriveFault, decode_emcy
from tcs.drivers.handshakes import HomingRun, ProfileMove
from tcs.drivers.pdo import PdoLayout, describe, layouts_for
from tcs.drivers.worker import Job, SdoWorker
from tcs.errors import (CommunicationError, ConfigMismatch, ErrorNumber, HardwareError, RangeRefused,
                        TcsError)

log = logging.getLogger(__name__)

ENABLE_TIMEOUT = 2.0          # default of [drives.x] enable_timeout (s to Operation enabled)
FAULT_RESET_TIMEOUT = 1.0     # default of [drives.x] fault_reset_timeout (s to leave Fault)
EMCY_BASE = 0x080
#: A gap (s) between two cycles' steps longer than this is a stall of the TCS's own host.
HOST_STALL = 0.1
#: A streamed setpoint going out with a late SYNC is moved on along its stream by at most this
#: many periods of lateness (the cycle source drops older ones: tcs.drivers.cycle.DROP_SLOTS).
RETIME_MAX_PERIODS = 4


class Cia402Drive:
    """A CiA-402 servo drive on a :class:`CanBus` (implements :class:`tcs.drivers.drive.Drive`).

    Parameters
    ----------
    bus:
        The open bus.
    name:
        The drive's name in the hardware file (``[drives.<name>]``).
    section:
        Its validated table.
    can:
        The ``[can]`` table (SYNC period, TCS node id, timeouts).
    eds:
        Path of the EDS (resolved against the hardware file).
    worker:
        The bus's SDO worker (started before the cyclic phase).
    clock:
        Monotonic clock.
    """

    def __init__(self, bus: CanBus, name: str, section: DriveSection, can: CanSection, *,
                 eds: str | Path, worker: SdoWorker, clock: Callable[[], float] = time.monotonic):
        self.name = name
        self.section = section
        self.node_id = section.node_id
        self.device = f"drive {name} (node {section.node_id})"
        self._bus = bus
        self._can = can
        self._eds = Path(eds)
        self._worker = worker
        self._clock = clock
        self._scale = section.increments_per_unit
        self._lo = min(section.min_position, section.max_position)
        self._hi = max(section.min_position, section.max_position)
        #: the mode of operation (hardware file ``mode``, or what 0x6502 offers) and why
        self.mode_choice = drive_mode(section, eds, section.node_id)
        chosen = Mode(self.mode_choice.number)
        #: the mode trajectories are streamed in (None: a PP-only drive, discrete axes)
        self.cyclic_mode: Mode | None = chosen if chosen in CYCLIC_MODES else None
        self._default_mode = Mode.PP if section.default_mode == "pp" else chosen  # at boot
        self.layouts: dict[str, PdoLayout] = {}
        self._rpdos: list[PdoLayout] = []
        self._use_layouts(layouts_for(section, eds, section.node_id, self.mode_choice.mode))
        self._subscriptions: list[tuple[int, Callable]] = []
        self._node: canopen.RemoteNode | None = None
        self._sdo: Sdo | None = None
        # notifier-side fields
        self._raw: dict[int, int] = {}
        self._raw_time = float("-inf")
        self._hb = HeartbeatWatch(clock)
        self._hb_timeout = can.heartbeat_tolerance * section.heartbeat_period
        self._last_step: float | None = None   # the previous step (cycle thread)
        self._cycle_step = 0.0                 # the time between SYNCs at the previous step
        self._slow_sync = 0.0                  # how much longer than sync_period that is
        self._stall_mark = float("-inf")       # the step after the latest own stall
        self._sync_time = float("-inf")   # last synchronous TPDO (notifier)
        self._seen_sync_time = float("-inf")
        self._stale_cycles = 0
        self._stale_fault: TcsError | None = None
        self._bus_fault: TcsError | None = None
        quick = section.quick_stop_deceleration or section.max_acceleration
        self.stop_timeout = abs(section.max_velocity) / max(abs(quick), 1e-9) + 1.0
        # the longest a fault reaction (0x605E: a ramp with 0x6084 or 0x6085) may brake before
        # a fault reset asked meanwhile is given up
        slowest = min(abs(quick), section.max_acceleration)   # (max_acceleration > 0: checked)
        self.reaction_timeout = abs(section.max_velocity) / max(slowest, 1e-9) + 1.0
        # the longest an enable (mode switch by SDO, then enable_timeout) or a disable (quick
        # stop to standstill first) may take before this driver itself reports it failed
        sdo = (section.sdo_timeout or can.sdo_timeout) * (section.sdo_retries + 1)
        self.power_timeout = max(section.enable_timeout + section.mode_switch_timeout + sdo,
                                 self.stop_timeout)
        self._standstill = max(1.0, 1e-3 * abs(section.max_velocity * section.velocity_scale))
        self._stopping_since: float | None = None
        self._offline_since: float | None = None
        self._bootups_at_boot = 0
        self._emcy: DriveFault | None = None
        self._emcy_count = 0
        # boot
        self._booted = False
        self._boot_error: TcsError | None = None
        # requests (any thread, under _lock)
        self._lock = threading.Lock()
        self._want = Want.DISABLED
        self._want_since = 0.0
        self._reset_requested = False
        self._mode_wanted: Mode | None = None
        self._homing_requested = False
        self._move_request: tuple[int, float | None] | None = None
        self._halt_requested = False
        # control-loop side
        self._setpoint: int | None = None
        self._setpoint_velocity: float | None = None  # the stream's velocity there, units/s
        self._setpoint_fresh = False  # set_setpoint was called since the last step
        self._stream: tuple[int, float] | None = None  # the last streamed (target, velocity inc/s)
        self._velocity_ff = 0
        # CSV: the position loop closed here (feed-forward + PI), following-error supervision
        self._period = can.sync_period
        self._csv_targets: list[tuple[float, int]] = []  # (when reached, target) of the last cycles
        self._sync_times: tuple[float, float] | None = None  # this cycle's SYNC and the next one's
        self._resumed = False                  # this cycle follows a gap (Cycle.resumed)
        #: the axis's own limits (limit_motion): velocity, acceleration, deceleration; None:
        #: the drive table's (max_velocity, max_acceleration)
        self._motion_limits: tuple[float, float, float] | None = None
        self._csv_integral = 0.0               # user units/s
        self._csv_velocity = 0.0               # last command, user units/s
        self._csv_error = 0.0                  # following error, user units
        self._fe_since: float | None = None
        self._fe_fault: TcsError | None = None
        self._velocity_cmd = 0                 # 0x60FF sent (drive velocity units)
        self._mode: int | None = None
        self._mode_job: Job | None = None
        self._reset_phase = 0
        self._reset_since = 0.0
        self._reset_asked = 0.0
        self._reached_enabled = False
        self._hold = 0
        self._cw = 0
        self._target_sent: int | None = None
        self._request_error: TcsError | None = None
        self._homing: HomingRun | None = None
        self._homing_mode_before: Mode | None = None
        self._homed = False
        self._move: ProfileMove | None = None
        self._halted = False  # halt (controlword bit 8) held in PP until the next move's set-point
        self._profile_velocity = round(abs(section.max_velocity * section.velocity_scale))
        self.rpdos_sent = 0
        self.steps = 0
        self._code_job: Job | None = None
        self._boot_count = 0
        self._lost_position = False
        self._reboot_wanted = False
        self.reboots = 0  # boot-ups seen after a successful boot (power blip, reset)
        # idle SYNC (tcs.drivers.idle_sync): whether the power stage may be switched on now
        self.may_enable: Callable[[], bool] = lambda: True
        self._state: DriveState | None = None  # the latest step's state (cycle thread)

    def _use_layouts(self, pdos: dict[str, PdoLayout]) -> None:
        """The PDO layout (:func:`tcs.drivers.pdo.plan_pdos`); every RPDO is sent each cycle,
        in number order (controlword and setpoint may sit in different RPDOs)."""
        self.layouts = pdos
        self._rpdos = sorted((p for p in pdos.values() if p.receive), key=lambda p: p.number)
        self._code_mapped = any(0x603F in p.indices for p in pdos.values())

    @property
    def bridging_limit(self) -> float | None:
        """The longest the drive bridges missing setpoints by itself, s: the RPDO deadline the
        boot writes (``master_loss_timeout``, default 3 SYNC periods; 0x1400+n:5) — past it
        the drive stops per 0x6007. None: no deadline (the drive holds or runs on unbounded)."""
        timeout = self.section.master_loss_timeout
        if timeout is None:
            timeout = 3 * self._can.sync_period
        return timeout if timeout > 0 else None

    @property
    def referenced_by_configuration(self) -> bool:
        """``absolute = true``: the axis is referenced by configuration, no homing ever runs."""
        return self.section.absolute

    def _choose_at_boot(self, sdo: Sdo) -> tuple[dict[str, PdoLayout], int]:
        """Boot hook (after the identity check): the EDS gives 0x6502 no default, so the
        drive's own answer settles the mode (and with it the PDO layout) — logged with where
        the value came from. A drive that answers nothing keeps the start's choice."""
        od = sdo.node.object_dictionary
        read = read_supported_modes(sdo)
        name = self._eds.name
        if read is None:
            log.info("%s: 0x6502 (supported drive modes): no default in %s and not readable "
                     "from the drive; mode %s kept (%s)", self.device, name,
                     self.mode_choice.mode.upper(), self.mode_choice.reason)
            return self.layouts, int(self._default_mode)
        source = f"read from the drive over SDO; {name} gives no default"
        choice = choose_mode(self.section, od, name, modes=read, source=source)
        log.info("%s: 0x6502 (supported drive modes) = 0x%08X = %s (%s)", self.device, read,
                 decode_modes(read), source)
        if choice.problem is not None:
            raise ConfigMismatch(self.device, choice.problem)
        if not self.section.absolute and not read >> 5 & 1:  # bit 5: homing mode
            raise ConfigMismatch(self.device, f"0x6502 (supported drive modes) = 0x{read:08X} = "
                                              f"{decode_modes(read)} ({source}) has no homing mode; "
                                              f"remedy: absolute = true when the encoder is absolute "
                                              f"(referenced by configuration)")
        previous = self.mode_choice
        if choice.mode == previous.mode:
            self.mode_choice = choice
            return self.layouts, int(self._default_mode)
        chosen = Mode(choice.number)
        if chosen not in CYCLIC_MODES and self.cyclic_mode is not None:
            raise ConfigMismatch(self.device, f"{choice.reason}: the drive offers no cyclic mode "
                                             f"(CSP, IP, CSV) its PDOs can carry, and its axis "
                                             f"streams trajectories; remedy: a drive or firmware "
                                             f"with one of them, or use it for an axis that never "
                                             f"streams (mode = 'pp')")
        if self._boot_count:  # the axis runs in the first boot's mode: never switch under it
            raise ConfigMismatch(self.device, f"the drive now answers {choice.reason}, unlike at "
                                             f"its first boot (mode {previous.mode.upper()}); "
                                             f"remedy: set [drives.<name>] mode = '{previous.mode}' "
                                             f"or restart the TCS")
        self.mode_choice = choice
        self.cyclic_mode = chosen if chosen in CYCLIC_MODES else None
        if self.section.default_mode != "pp":
            self._default_mode = chosen
        self._use_layouts(layouts_for(self.section, self._eds, self.node_id, choice.mode))
        log.warning("%s: mode %s, not %s as assumed at start: %s; PDOs: %s", self.device,
                    choice.mode.upper(), previous.mode.upper(), choice.reason,
                    "; ".join(describe(self.layouts)))
        return self.layouts, int(self._default_mode)

    # ================================================================= idle SYNC
    #: States without a power stage: a drive in one of them cannot move (the idle SYNC's test).
    RESTING_STATES = frozenset({DriveState.NOT_READY, DriveState.SWITCH_ON_DISABLED,
                                DriveState.READY_TO_SWITCH_ON, DriveState.FAULT})

    @property
    def boot_count(self) -> int:
        """Successful boots so far (a new one means its configuration was written again)."""
        return self._boot_count

    def resting(self) -> bool:
        """Cycle thread: booted, its power stage off by the latest status (a resting state,
        no stale data), not wanted enabled, and no request or SDO job of its own under way —
        or not booted at all (then it is not on the cycle). The idle SYNC needs every drive so."""
        if not self._booted:
            return True
        with self._lock:
            asked = (self._want is not Want.DISABLED or self._reset_requested
                     or self._homing_requested or self._move_request is not None
                     or self._halt_requested)
        homing, move = self._homing, self._move  # (kept after they end, for their result)
        return (not asked and self._state in self.RESTING_STATES and self._stale_fault is None
                and self._mode_job is None and not self._reset_phase
                and (homing is None or homing.progress is not Progress.RUNNING)
                and (move is None or move.progress is not Progress.RUNNING))

    def write_cycle_period(self, period: float, done: list | None = None,
                           only: set | None = None) -> None:
        """Blocking (the idle SYNC's job): tell the drive that SYNC comes every ``period`` —
        0x1006 and its RPDO deadlines (:func:`tcs.drivers.boot.cycle_period_writes`), each
        as its EDS allows. Slower: deadlines first; faster: 0x1006 first. Each ``(index,
        sub)`` written is appended to ``done``; ``only`` limits the writes to those."""
        sdo, node = self._sdo, self._node
        if not self._booted or sdo is None or node is None:
            return
        od = node.object_dictionary
        writes = usable_writes(od, pdo_writes(od, cycle_period_writes(self.section, self._can,
                                                                      self.layouts, period)),
                               self.section, self.device)
        if period <= self._can.sync_period:
            writes.reverse()
        for index, sub, fmt, value in writes:
            if only is None or (index, sub) in only:
                sdo.write(index, sub, fmt, value)
                if done is not None:
                    done.append((index, sub))

    # ================================================================= boot (blocking)
    @property
    def sync_tpdo_ids(self) -> list[int]:
        """COB-IDs of the TPDOs this drive sends on every SYNC (for the cycle's barrier)."""
        return [p.cob_id for n, p in self.layouts.items() if not p.receive and p.synchronous]

    def boot(self) -> None:
        """Wait for the node, check its identity, configure it, start it (blocking).

        Raises
        ------
        HardwareError, CommunicationError
            Naming this drive and node, the step and the object that failed.
        """
        if self._boot_count > 0 and self._hb.bootups != self._bootups_at_boot:
            self._lost_position = True  # a boot-up since the last boot: power blip or reset
        self._booted = False
        # (the last boot's error stays while this one tries: a drive retried for ever keeps
        # showing why it is not there)
        try:
            result = self._boot()
        except TcsError as exc:
            self._boot_error = exc
            self._bootups_at_boot = self._hb.bootups
            raise
        except Exception as exc:  # canopen / python-can internals: still name the node
            self._boot_error = HardwareError(self.device, f"boot failed: {exc!r}")
            self._bootups_at_boot = self._hb.bootups
            raise self._boot_error from exc
        with self._lock:
            self._want = Want.DISABLED
            self._reset_requested = False
            self._mode_wanted = None
            self._homing_requested = False
            self._move_request = None
            self._halt_requested = False
        self._halted = False
        self._raw = {0x6041: result.statusword, 0x6064: result.position, **self._raw}
        self._raw_time = self._clock()
        self._hold = self._raw.get(0x6064, result.position)
        self._mode = result.mode
        self._mode_job = None
        self._reset_phase = 0
        self._reached_enabled = False
        self._homing = self._move = None
        self._homed = self.section.absolute  # referenced by configuration
        self._setpoint = None
        self._stale_cycles, self._stale_fault = 0, None
        self._stopping_since = self._offline_since = None
        if result.error_code and not self._emcy:
            self._emcy = DriveFault(self.device, result.error_code)
        self._bootups_at_boot = self._hb.bootups
        self._boot_error = None
        self._last_step = None
        self._boot_count += 1
        self._reboot_wanted = False
        self.reboots += self._lost_position
        self._lost_position = False
        self._booted = True

    def _boot(self) -> BootResult:
        network = self._bus.network
        if network is None:
            raise CommunicationError(self.device, "the CAN bus is not open")
        if not self._eds.is_file():
            raise HardwareError(self.device, f"EDS file {self._eds} not found", ErrorNumber.INTERNAL)
        self._unsubscribe()
        try:
            od = read_od(self._eds, self.node_id)
        except Exception as exc:
            raise HardwareError(self.device, f"cannot read EDS {self._eds}: {exc}",
                                ErrorNumber.INTERNAL) from exc
        if self.node_id in network.nodes:
            del network[self.node_id]
        node = canopen.RemoteNode(self.node_id, od)
        node.sdo.RESPONSE_TIMEOUT = self.section.sdo_timeout or self._can.sdo_timeout
        node.sdo.MAX_RETRIES = self.section.sdo_retries
        network.add_node(node)
        self._node = node
        self._sdo = Sdo(node, self.device)
        self._hb = HeartbeatWatch(self._clock)
        self._emcy = None
        self._raw = {}
        self._subscribe(HEARTBEAT_BASE + self.node_id, self._hb.on_frame)
        self._subscribe(EMCY_BASE + self.node_id, self._on_emcy)

        def subscribe_tpdos() -> None:
            for pdo in self.layouts.values():
                if not pdo.receive:
                    self._subscribe(pdo.cob_id, self._tpdo_handler(pdo))

        # 0x6502 without an EDS default: the drive's answer settles the mode at boot
        ask = supported_modes(od) is None and variable(od, 0x6502, 0) is not None
        return boot_node(network, self._sdo, self._hb, self.section, self._can, self.layouts,
                         int(self._default_mode), start=subscribe_tpdos,
                         choose=self._choose_at_boot if ask else None)

    def release(self) -> None:
        """Clean stop: switch the drive's consumer of the TCS heartbeat off (0x1016:1 = 0;
        blocking SDO). The driver stops stepping it (it is not booted any more)."""
        sdo = self._sdo
        if sdo is None:
            return
        self._booted = False
        sdo.write(0x1016, 1, "<I", 0)

    def close(self) -> None:
        """Forget the node (unsubscribe; the bus stays open). The drive is offline after."""
        self._booted = False
        self._unsubscribe()
        network = self._bus.network
        if network is not None and self._node is not None and network.nodes.get(self.node_id) is self._node:
            del network[self.node_id]
        self._node = None

    def _subscribe(self, cob_id: int, callback: Callable) -> None:
        self._bus.network.subscribe(cob_id, callback)
        self._subscriptions.append((cob_id, callback))

    def _unsubscribe(self) -> None:
        network = self._bus.network
        for cob_id, callback in self._subscriptions:
            if network is not None and callback in network.subscribers.get(cob_id, ()):
                network.unsubscribe(cob_id, callback)
        self._subscriptions.clear()

    # ================================================================= notifier thread
    def _tpdo_handler(self, pdo: PdoLayout) -> Callable:
        unpack, indices, size, clock = pdo.codec.unpack_from, pdo.indices, pdo.codec.size, self._clock
        synchronous = pdo.synchronous

        def on_tpdo(cob_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < size:
                return
            raw = self._raw
            for index, value in zip(indices, unpack(data)):
                raw[index] = value
            self._raw_time = clock()
            if synchronous:
                self._sync_time = self._raw_time
        return on_tpdo

    def _on_emcy(self, cob_id: int, data: bytearray, timestamp: float) -> None:
        fault = decode_emcy(self.device, data)
        self._emcy_count += 1
        if fault is None:
            return  # error reset: the state (statusword) tells whether the fault is gone
        self._emcy = fault
        log.warning("%s", fault)

    # ================================================================= requests (any thread)
    def enable(self) -> None:
        self._refuse_if_unusable("enable")
        with self._lock:
            if self._want is not Want.ENABLED:
                self._want, self._want_since = Want.ENABLED, self._clock()
            self._request_error = None

    def disable(self) -> None:
        with self._lock:
            self._want, self._want_since = Want.DISABLED, self._clock()
            self._homing_requested = False
            self._move_request = None

    def quick_stop(self) -> None:
        with self._lock:
            self._want, self._want_since = Want.QUICK_STOP, self._clock()
            self._homing_requested = False
            self._move_request = None

    def halt(self) -> None:
        """End a homing run or a profile move with the drive's normal deceleration: homing by
        clearing its start bit (the drive stops, "interrupted"), a PP move by the halt bit
        (profile deceleration 0x6084), held until the next move's set-point. Any thread."""
        with self._lock:
            self._halt_requested = True
            self._homing_requested = False
            self._move_request = None

    def fault_reset(self) -> None:
        with self._lock:
            self._reset_requested = True

    def set_bus_fault(self, error: TcsError | None) -> None:
        """The bus is faulty (bus-off, error passive: ``error``) or well again (None). Any
        thread; a fault makes this drive's axis stop (controlled) like a drive fault."""
        self._bus_fault = error

    def request_reboot(self) -> None:
        """The link to the node was lost and is back (bus reopened): boot it again once it is
        not wanted enabled; its position may have been lost meanwhile (REFERENCED)."""
        self._reboot_wanted = True
        if self._boot_count > 0:
            self._lost_position = True

    def needs_reboot(self) -> bool:
        """True when the node must be booted again: it sent a boot-up since it was booted
        (power blip, reset) or its heartbeat shows pre-operational / stopped (it lost the TCS
        heartbeat) — and the driver no longer wants it enabled. Any thread."""
        hb = self._hb
        if self._want is Want.ENABLED:
            return False
        if self._reboot_wanted:
            return True
        if not self._booted:
            # A failed boot is retried (with the supervisor's back-off) for as long as it
            # fails, silent node or not: a failed boot replaced the heartbeat watch, so
            # "while it shows life" meant a node silent at that moment was never tried again.
            return self._boot_error is not None
        if hb.time is None:
            return False
        if hb.bootups != self._bootups_at_boot:
            return True
        fresh = self._clock() - hb.time <= self._hb_timeout
        return fresh and hb.state in (HB_PRE_OPERATIONAL, HB_STOPPED)

    def set_mode(self, mode: Mode) -> None:
        try:
            mode = Mode(mode)
        except ValueError:
            raise RangeRefused(f"{self.device}: mode {mode!r} is not one of "
                               f"{[m.name for m in Mode]}") from None
        with self._lock:
            self._mode_wanted = mode

    def set_setpoint(self, position: float, velocity: float | None = None) -> None:
        """CSP target for the next SYNC, clamped to the software limits (control-loop thread)."""
        position = min(max(position, self._lo), self._hi)
        self._setpoint = round(position * self._scale)
        self._setpoint_velocity, self._setpoint_fresh = velocity, True
        kv = self.section.velocity_scale
        self._velocity_ff = round(velocity * kv) if velocity is not None else 0

    def start_homing(self) -> None:
        self._refuse_if_unusable("start homing")
        with self._lock:
            self._homing_requested = True
            self._move_request = None

    def move_to(self, position: float, velocity: float | None = None) -> None:
        self._refuse_if_unusable("move")
        if not self._lo <= position <= self._hi:
            raise TcsError(f"{self.device}: target {position:g} outside the software limits "
                           f"[{self._lo:g}, {self._hi:g}]", ErrorNumber.SOFTLIMIT)
        if velocity is not None and not 0 < velocity <= self.section.max_velocity:
            raise RangeRefused(f"{self.device}: velocity {velocity:g} not in (0, "
                               f"{self.section.max_velocity:g}]")
        with self._lock:
            self._move_request = (round(position * self._scale), velocity)

    def _refuse_if_unusable(self, what: str) -> None:
        """Refuse at once what cannot work: a drive not booted or in fault."""
        if not self._booted:
            raise CommunicationError(self.device, f"cannot {what}: not booted" + (
                f" ({self._boot_error.message})" if self._boot_error else ""))
        fault = self.status().fault
        if fault is not None:
            raise TcsError(f"cannot {what}: {fault.message}", fault.number)

    # ================================================================= status (any thread)
    def _observe(self, now: float) -> tuple[DriveState, TcsError | None, bool]:
        """(state, fault, heartbeat ok) as of now."""
        if not self._booted:
            return DriveState.OFFLINE, self._boot_error, False
        hb = self._hb
        last = self._last_step
        if last is not None and now - last > HOST_STALL + self._slow_sync and last > self._stall_mark:
            # the process stalled inside a cycle (after note_cycle): the same rule, once per gap
            self._stall_mark = now
        hb_ok = hb.time is not None and now - max(hb.time, self._stall_mark) <= self._hb_timeout
        if not hb_ok:
            silent = now - hb.time if hb.time is not None else float("inf")
            return DriveState.OFFLINE, CommunicationError(
                self.device, f"no heartbeat for {silent:.2f} s (expected every "
                             f"{self.section.heartbeat_period:g} s)"), False
        if hb.bootups != self._bootups_at_boot or hb.state != HB_OPERATIONAL:
            why = "rebooted" if hb.bootups != self._bootups_at_boot else \
                f"in NMT state {NMT_STATE_NAMES.get(hb.state, hb.state)}"
            if self._emcy is not None:  # e.g. 0x8130: it lost the TCS heartbeat and left operational
                return DriveState.OFFLINE, self._emcy, True
            return DriveState.OFFLINE, CommunicationError(
                self.device, f"{why}: it must be booted again"), True
        if self._stale_fault is not None:  # its state is unknown: the last one is history
            return DriveState.OFFLINE, self._emcy or self._stale_fault, True
        sw = self._raw.get(0x6041, 0)
        state = sm.decode_state(sw) or DriveState.NOT_READY
        fault = self._bus_fault or self._fe_fault
        if state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            fault = self._emcy or fault
            code = self._raw.get(0x603F, 0)
            if fault is None and code:
                fault = DriveFault(self.device, code)
            if fault is None:
                fault = HardwareError(self.device, f"in fault (statusword 0x{sw:04X}), no error code")
        return state, fault, hb_ok

    def status(self) -> DriveStatus:
        now = self._clock()
        state, fault, hb_ok = self._observe(now)
        raw = self._raw
        sw = raw.get(0x6041, 0)
        inputs = raw.get(0x60FD, 0)
        k = self._scale
        homing, move = self._homing, self._move
        mode = raw.get(0x6061, self._mode)
        following = (self._csv_error if mode == Mode.CSV else raw.get(0x60F4, 0) / k)
        try:
            mode = Mode(mode) if mode is not None else None
        except ValueError:
            pass
        return DriveStatus(
            name=self.name, state=state, position=raw.get(0x6064, 0) / k,
            velocity=raw.get(0x606C, 0) / self.section.velocity_scale,
            following_error=following,
            statusword=sw, controlword=self._cw, mode=mode, fault=fault,
            warning=self._emcy if fault is not self._emcy else None,
            request_error=self._request_error,
            limit_negative=bool(inputs & 1), limit_positive=bool(inputs & 2),
            home_switch=bool(inputs & 4),
            homing=homing.progress if homing else Progress.IDLE,
            homing_progress=homing.fraction if homing else 0.0, homed=self._homed,
            move=move.progress if move else Progress.IDLE,
            target_reached=bool(sw & sm.SW_TARGET_REACHED),
            setpoint=self._target_sent / k if self._target_sent is not None else None,
            heartbeat_ok=hb_ok, heartbeat_age=now - max(self._hb.time, self._stall_mark)
            if self._hb.time is not None else float("inf"), booted=self._booted, age=now - self._raw_time,
            reboots=self.reboots)

    # ================================================================= the cycle
    def step(self) -> None:
        """One cycle: decide the controlword and target from the latest TPDO, send one RPDO."""
        if not self._booted:
            return
        now = self._clock()
        self.steps += 1
        self._watch_tpdos()
        state, fault, hb_ok = self._observe(now)
        self._state = state
        self._fetch_error_code(state)
        raw = self._raw
        sw = raw.get(0x6041, 0)
        actual = raw.get(0x6064, self._hold)

        with self._lock:
            want = self._want
            if fault is not None or (state is DriveState.OFFLINE):
                want = self._set_want(Want.DISABLED, now)
            elif (self._reached_enabled and want is Want.ENABLED
                  and state is not DriveState.OPERATION_ENABLED):
                self._request_error = HardwareError(
                    self.device, f"left operation enabled by itself (now {state.value}); "
                                 "not re-enabling")
                want = self._set_want(Want.DISABLED, now)
            elif (want is Want.ENABLED and state is not DriveState.OPERATION_ENABLED
                  and now - self._want_since > self.section.enable_timeout):
                self._request_error = HardwareError(
                    self.device, f"enable timed out in state {state.value}", ErrorNumber.TIMEOUT)
                want = self._set_want(Want.DISABLED, now)
            reset, self._reset_requested = self._reset_requested, False
            mode_wanted = self._mode_wanted
            homing_req, self._homing_requested = self._homing_requested, False
            move_req, self._move_request = self._move_request, None
            halt_req, self._halt_requested = self._halt_requested, False
        if halt_req:
            stopped = TcsError(f"{self.device}: halted", ErrorNumber.TARGETCHANGE)
            self._end_homing(stopped)
            self._end_move(stopped)
            self._halted = True
        self._reached_enabled = (want is Want.ENABLED and
                                 (self._reached_enabled or state is DriveState.OPERATION_ENABLED))

        if fault is not None or want is not Want.ENABLED:
            why = fault or TcsError(f"{self.device}: aborted ({want.value} requested)",
                                    ErrorNumber.LIBFAIL)
            self._end_homing(why)
            self._end_move(why)

        if state is DriveState.OFFLINE:
            # Heartbeat lost or node not operational: if it still listens it may still be
            # moving, so it gets a quick stop for stop_timeout, then disable voltage; one RPDO
            # per cycle either way.
            if self._offline_since is None:
                self._offline_since = now
            self._stopping_since = None
            stopping = now - self._offline_since <= self.stop_timeout
            self._velocity_cmd = self._csv_reset()
            self._send(sm.QUICK_STOP if stopping else sm.DISABLE_VOLTAGE, actual)
            return
        self._offline_since = None

        # --- fault reset: 0x0000 one cycle, then 0x0080 until Fault is left (15) ----------
        # (asked during the fault reaction, while the drive still brakes and ignores it:
        # 0x0000 until the drive is in Fault, so that bit 7 rises there — the reset acts on
        # its rising edge only; the time-out counts from Fault, the reaction has its own)
        if reset and state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            self._reset_phase, self._reset_since, self._reset_asked = 1, now, now
        elif reset:
            self._emcy = None  # nothing to reset: forget the last warning
        if reset:
            self._fe_fault, self._fe_since = None, None  # the TCS's own (CSV) following error
        # the idle SYNC's gate: no power stage before the full SYNC rate is back on the drives
        gated = (want is Want.ENABLED and not self.may_enable()
                 and state not in (DriveState.OPERATION_ENABLED, DriveState.QUICK_STOP_ACTIVE))
        cw = self._controlled(sm.controlword(Want.DISABLED if gated else want, state), state, sw, now)
        if self._reset_phase:
            if state not in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
                self._reset_phase = 0
                self._emcy = None
            elif state is DriveState.FAULT_REACTION_ACTIVE:
                if now - self._reset_asked > self.reaction_timeout:
                    self._reset_phase = 0
                    self._request_error = HardwareError(
                        self.device, f"fault reset not done: the drive's fault reaction did not end "
                                     f"within {self.reaction_timeout:.1f} s")
                else:
                    cw = sm.DISABLE_VOLTAGE
                    self._reset_phase, self._reset_since = 1, now
            elif now - self._reset_since > self.section.fault_reset_timeout:
                self._reset_phase = 0
                self._request_error = HardwareError(self.device, "fault reset did not clear the fault")
            else:
                cw = sm.DISABLE_VOLTAGE if self._reset_phase == 1 else sm.FAULT_RESET
                self._reset_phase = 2

        # --- long requests and the mode of operation they need ----------------------------
        if homing_req and self._begin_homing(now, want):
            mode_wanted = Mode.HM
        if move_req is not None and self._begin_move(now, want, *move_req):
            mode_wanted = Mode.PP
        self._drive_mode(mode_wanted)

        # --- target: hold the actual position unless commanding in OE --------------------
        enabled = state is DriveState.OPERATION_ENABLED and want is Want.ENABLED
        mode = self._mode
        ready = enabled and self._mode_job is None
        if want is Want.ENABLED and not gated and mode == Mode.IP and self._mode_job is None \
                and not self._reset_phase:
            # enable IP (bit 4) with enable operation: IP is active from the first cycle in
            # Operation enabled, and the record sent with it is the actual position
            cw |= sm.CW_ENABLE_IP
        # streaming: CSP; IP once the drive shows IP active (statusword bit 12); CSV
        streaming = ready and mode in CYCLIC_MODES and (mode != Mode.IP or bool(sw & sm.SW_MODE_12))
        if not streaming:
            self._hold = actual
            self._setpoint = None
        target = self._hold
        homing, move = self._homing, self._move
        if streaming and self._setpoint is not None:
            target = self._setpoint
        self._velocity_cmd = self._csv_step(target, actual, now) if (
            streaming and mode == Mode.CSV) else self._csv_reset()
        if homing is not None and homing.progress is Progress.RUNNING:
            if ready and mode == Mode.HM:
                cw |= homing.step(now, sw)
            else:
                homing.waiting(now, "operation enabled in homing mode")
            if homing.progress is not Progress.RUNNING:
                self._homing_ended(homing)
        if move is not None and move.progress is Progress.RUNNING and ready and mode == Mode.PP:
            bits = move.step(now, sw, actual)
            if bits & sm.CW_NEW_SETPOINT:
                self._halted = False  # released with the new set-point: no resuming the old one
            cw |= bits
            target = move.target
            if move.progress is not Progress.RUNNING:
                self._move_ended(move)
        if self._halted and mode == Mode.PP:
            cw |= sm.CW_HALT
        stream = None
        if streaming and mode in (Mode.CSP, Mode.IP) and self._setpoint is not None:
            stream = self._stream_motion(target)
        else:
            self._stream, self._setpoint_fresh = None, False
        self._send(cw, target, stream)

    def _stream_motion(self, target: int) -> tuple[float, float]:
        """The setpoint stream's velocity (increments/s) and acceleration (increments/s²) at
        ``target``: the axis's velocity for it (or, when it gave none, the difference from the
        last target over the period; 0 when it made no setpoint this cycle: the last one is
        held), the acceleration from the last one's."""
        period = self._cycle_step or self._can.sync_period
        last, v = self._stream, self._setpoint_velocity
        fresh, self._setpoint_fresh = self._setpoint_fresh, False
        if not fresh:  # (the axis made no setpoint this cycle: the last one is held, not moved on)
            v = 0.0
        elif v is not None:
            v *= self._scale
        elif last is not None:
            v = (target - last[0]) / period
        else:
            v = 0.0
        a = (v - last[1]) / period if last is not None else 0.0
        self._stream = (target, v)
        return v, a

    def note_cycle(self, now: float, step: float = 0.0, cycle=None) -> None:
        """The cycle thread starts a cycle (before anything reads this drive's status in it):
        a cycle more than :data:`HOST_STALL` after the previous one *was due* means this
        process stalled (see the docstring); ``step`` is the time between SYNCs now (longer
        under the idle SYNC, :mod:`tcs.drivers.idle_sync`); ``cycle`` the
        :class:`~tcs.drivers.cycle.Cycle` (its SYNC times, whether it follows a gap: the CSV
        loop works in real time)."""
        if cycle is not None:
            self._sync_times = (cycle.sync_time, cycle.next_sync)
            self._resumed = cycle.resumed
        last, self._last_step = self._last_step, now
        # (the longer of the steps before and now: the SYNC may have slowed or sped up between)
        self._slow_sync = max(0.0, max(step, self._cycle_step) - self._can.sync_period)
        self._cycle_step = step
        if last is not None and now - last > HOST_STALL + self._slow_sync:
            self._stall_mark = now
            log.debug("%s: the TCS stalled for %.2f s; the heartbeat window restarts", self.device,
                      now - last)

    def _fetch_error_code(self, state: DriveState) -> None:
        """0x603F not in a TPDO (not mappable on this drive): read it by SDO once per fault
        without an EMCY — never every cycle."""
        if self._code_mapped:
            return
        if state not in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            if self._code_job is not None:
                self._code_job = None
                self._raw.pop(0x603F, None)
            return
        node, sdo = self._node, self._sdo
        if self._code_job is not None or self._emcy is not None or sdo is None or node is None:
            return
        var = node.object_dictionary.get_variable(0x603F, 0)
        if var is None or not var.readable:
            return
        raw = self._raw

        def read() -> None:
            raw[0x603F] = sdo.read(0x603F, 0, "<H")
        self._code_job = self._worker.submit(read, f"{self.name} error code")

    def _watch_tpdos(self) -> None:
        """Count cycles in a row without this drive's synchronous TPDOs (control loop)."""
        if self._sync_time != self._seen_sync_time or not self.sync_tpdo_ids:
            self._seen_sync_time = self._sync_time
            self._stale_cycles = 0
            if self._stale_fault is not None:
                log.warning("%s: TPDOs again", self.device)
                self._stale_fault = None
            return
        self._stale_cycles += 1
        limit = self._can.tpdo_stale_cycles
        if self._stale_cycles >= limit and self._stale_fault is None and self._hb.state == HB_OPERATIONAL:
            self._stale_fault = CommunicationError(
                self.device, f"no TPDO for {self._stale_cycles} cycles: its data is stale")
            log.warning("%s", self._stale_fault)

    def _at_rest(self, state: DriveState, sw: int) -> bool:
        """Standing still by the latest TPDOs (velocity actual value; in Quick stop active
        also statusword bit 10). Unknown velocity counts as moving."""
        if state is DriveState.QUICK_STOP_ACTIVE and sw & sm.SW_TARGET_REACHED:
            return True
        velocity = self._raw.get(0x606C)
        return velocity is not None and abs(velocity) <= self._standstill and self._stale_fault is None

    def _controlled(self, cw: int, state: DriveState, sw: int, now: float) -> int:
        """Never cut the power of a moving drive: disable voltage (9, 12) becomes quick stop
        (11, or stays in 11) until the drive stands still or ``stop_timeout`` has passed."""
        if cw == sm.DISABLE_VOLTAGE and state in (DriveState.OPERATION_ENABLED,
                                                  DriveState.QUICK_STOP_ACTIVE):
            if self._at_rest(state, sw):
                return cw
            if self._stopping_since is None:
                self._stopping_since = now
                log.info("%s: quick stop before disabling (moving)", self.device)
            if now - self._stopping_since <= self.stop_timeout:
                return sm.QUICK_STOP
            return cw
        self._stopping_since = None
        return cw

    def _set_want(self, want: Want, now: float) -> Want:
        if self._want is not want:
            self._want, self._want_since = want, now
        return want

    # ----------------------------------------------------------------- CSV position loop
    def _csv_reset(self) -> int:
        """Not streaming in CSV: no velocity command, the loop starts afresh."""
        self._csv_targets.clear()
        self._csv_integral = self._csv_velocity = self._csv_error = 0.0
        self._fe_since = None
        return 0

    def limit_motion(self, max_velocity: float, max_acceleration: float,
                     deceleration: float | None = None) -> None:
        """The axis's own limits (``[axes.*]``, user units): the CSV loop's velocity command
        stays within them — never the drive table's looser ones. Control-loop thread (or
        before the cyclic phase)."""
        dec = max(abs(deceleration or max_acceleration), abs(max_acceleration))
        self._motion_limits = (abs(max_velocity), abs(max_acceleration), dec)

    def _csv_step(self, target: int, actual: int, now: float) -> int:
        """CSV: the velocity (drive units) for the next SYNC period.

        The target sent in cycle k is where a CSP drive would be one period after SYNC k+1
        (latched at k+1, interpolated over one period): each target is kept with that time,
        on the real clock (the next SYNC's time + one period). The velocity command applied
        from SYNC k+1 is the feed-forward (target_k − target_k−1) / (the real time between
        their times) plus a PI correction on the following error e = demand − actual_k, the
        demand being the target stream *at the real time of SYNC k* (interpolated between
        the kept targets): the drive integrates the command in real time, so a late SYNC
        (the drive ran on at the old speed for longer) is no error — comparing with
        target_k−2 made every late cycle one (and skipped ones tripped the supervision). The
        correction is clamped to ``csv_max_correction``; the integral is held within it; the
        command stays within the axis's speed (:meth:`limit_motion`, else the drive table's
        ``max_velocity``) and changes by no more than its acceleration (speeding up) or its
        stop deceleration (slowing down) × T per cycle. After a gap (:attr:`Cycle.resumed`:
        the drive kept the last command meanwhile) the loop starts afresh from the drive's
        actual velocity: no error is judged until two targets span the SYNC again. |e|
        beyond ``following_error_window`` for longer than ``following_error_timeout`` is a
        following-error fault of the axis (controlled stop): a drive that runs away from
        the stream is still caught.
        """
        sec, k, period = self.section, self._scale, self._period
        history = self._csv_targets
        sync, nxt = self._sync_times if self._sync_times is not None else (now, now + period)
        if self._resumed:
            history.clear()
            self._csv_integral = 0.0
            self._csv_velocity = self._raw.get(0x606C, 0) / sec.velocity_scale
            self._resumed = False
        history.append((nxt + period, target))
        if len(history) > 4:
            del history[0]
        if len(history) >= 2:
            (t1, p1), (t2, p2) = history[-2], history[-1]
            feed_forward = (p2 - p1) / k / max(t2 - t1, 0.25 * period)
        else:
            feed_forward = self._csv_velocity
        demand = None
        for (ta, pa), (tb, pb) in zip(history, history[1:]):
            if ta <= sync <= tb:
                demand = pa + (pb - pa) * (sync - ta) / max(tb - ta, 1e-9)
                break
        limit = sec.csv_max_correction if sec.csv_max_correction is not None else 0.1 * sec.max_velocity
        if demand is None:  # (a fresh start: nothing spans this SYNC yet)
            error = 0.0
        else:
            error = (demand - actual) / k
            self._csv_integral = min(max(self._csv_integral + sec.csv_ki * error * period, -limit), limit)
        self._csv_error = error
        correction = min(max(sec.csv_kp * error + self._csv_integral, -limit), limit)
        velocity = feed_forward + correction
        vmax, acc, dec = self._motion_limits or (abs(sec.max_velocity), abs(sec.max_acceleration),
                                                 abs(sec.max_acceleration))
        vmax = min(vmax, abs(sec.max_velocity))
        velocity = min(max(velocity, -vmax), vmax)
        v0 = self._csv_velocity
        up, down = acc * period, dec * period
        lo = v0 - (down if v0 > 0 else up)
        hi = v0 + (up if v0 >= 0 else down)
        velocity = min(max(velocity, lo), hi)
        self._csv_velocity = velocity
        window = abs(sec.following_error_window)
        if abs(error) > window:
            if self._fe_since is None:
                self._fe_since = now
            elif now - self._fe_since >= sec.following_error_timeout and self._fe_fault is None:
                self._fe_fault = HardwareError(
                    self.device, f"following error {error:.4g} beyond the window {window:g} for "
                                 f"{sec.following_error_timeout:g} s (CSV: supervised by the TCS)")
                log.warning("%s", self._fe_fault)
        else:
            self._fe_since = None
        return round(velocity * sec.velocity_scale)

    def _send(self, cw: int, target: int, stream: tuple[float, float] | None = None) -> None:
        """One cycle's RPDOs; ``stream``: ``target`` is a streamed CSP/IP setpoint moving at
        this (velocity, acceleration), increments/s and /s² — held for a SYNC that goes out
        late, it is moved on along the stream by the lateness (:meth:`_retimer`)."""
        values = {0x6040: cw, 0x607A: target, 0x60B1: self._velocity_ff, 0x60C1: target,
                  0x60FF: self._velocity_cmd}
        self._cw, self._target_sent = cw, target
        if stream is not None and not self._bus.holding():
            stream = None  # (sent at once — kernel SYNC —: never retimed, nothing to build)
        for rpdo in self._rpdos:  # (usually one; more when the drive's RPDO1 is small)
            retime = None
            if stream is not None and (0x607A in rpdo.indices or 0x60C1 in rpdo.indices):
                retime = self._retimer(rpdo, values, target, *stream)
            try:
                self._bus.send(rpdo.cob_id, rpdo.codec.pack(*(values[i] for i in rpdo.indices)),
                               retime)
            except TcsError:
                return  # recorded in the bus health; the drive faults on missing RPDOs
        self.rpdos_sent += 1

    def _retimer(self, rpdo, values: dict, target: int, v: float, a: float):
        """The RPDO again for a SYNC ``late`` s after the slot its setpoint was made for:
        the setpoint where its stream is by then — a drive latches a setpoint at the SYNC it
        gets and interpolates it over the nominal period from there, so one made for an
        earlier slot would run its demand that much faster over the shorter interval to the
        next, on-time SYNC (issue 39 item 10: 5.4°/s over 100 ms against 5 with SYNCs 0-9 ms
        late). At the stream's velocity; a stream that slows down is extrapolated with its
        deceleration and never past where it stops, never beyond the software limits, and
        by at most :data:`RETIME_MAX_PERIODS` periods."""
        lo = min(math.ceil(self._lo * self._scale), target)
        hi = max(math.floor(self._hi * self._scale), target)
        cap = RETIME_MAX_PERIODS * self._can.sync_period

        def retime(late: float) -> bytes:
            late = min(late, cap)
            if v * a < 0:  # slowing down: not past its stop
                late = min(late, -v / a)
                shift = v * late + a * late * late / 2
            else:
                shift = v * late
            moved = min(max(target + round(shift), lo), hi)
            now = {**values, 0x607A: moved, 0x60C1: moved}
            return rpdo.codec.pack(*(now[i] for i in rpdo.indices))
        return retime

    # ----------------------------------------------------------------- mode switching
    def _drive_mode(self, wanted: Mode | None) -> None:
        """Start/finish the SDO mode switch; the mode counts only once 0x6061 reads it."""
        job = self._mode_job
        if job is not None:
            if not job.done:
                return
            self._mode_job = None
            if job.error is not None:
                err = job.error if isinstance(job.error, TcsError) else HardwareError(
                    self.device, f"mode switch failed: {job.error!r}")
                self._request_error = err
                with self._lock:
                    self._mode_wanted = None
                self._end_homing(err)
                self._end_move(err)
                return
            self._mode = job.result
        shown = self._raw.get(0x6061)
        if shown is not None:
            self._mode = shown
        if wanted is not None and wanted != self._mode and self._sdo is not None:
            sdo, mode = self._sdo, int(wanted)
            timeout = self.section.mode_switch_timeout
            self._mode_job = self._worker.submit(lambda: set_mode(sdo, mode, timeout), f"{self.name} mode")
        with self._lock:
            if self._mode_wanted == wanted:
                self._mode_wanted = None

    # ----------------------------------------------------------------- homing
    def _begin_homing(self, now: float, want: Want) -> bool:
        """Start a homing run (True), or fail it at once when the drive is not being enabled."""
        self._end_move(TcsError(f"{self.device}: move superseded by homing", ErrorNumber.TARGETCHANGE))
        home = self.section.homing
        previous = self._homing
        self._halted = False
        self._homing = HomingRun(self.device, home.method, home.timeout, now)
        self._request_error = None
        if self.section.absolute:  # referenced by configuration: nothing runs on the drive
            self._homing.progress, self._homing.fraction = Progress.DONE, 1.0
            self._homing_ended(self._homing)
            return False
        if want is not Want.ENABLED:
            self._homing.fail(TcsError(f"{self.device}: homing needs the drive enabled "
                                             "(request enable first)", ErrorNumber.INVMODE))
            self._homing_ended(self._homing)
            return False
        if previous is None or previous.progress is not Progress.RUNNING:
            current = self._mode if self._mode in (*CYCLIC_MODES, Mode.PP) else None
            self._homing_mode_before = Mode(current) if current is not None else self._default_mode
        self._homed = False
        return True

    def _homing_ended(self, run: HomingRun) -> None:
        """Done or failed: remember the result, go back to the mode used before homing."""
        if run.progress is Progress.DONE:
            self._homed = True
        elif run.error is not None:
            self._request_error = run.error
            log.warning("%s", run.error)
        with self._lock:
            if self._mode_wanted is None and self._homing_mode_before is not None:
                self._mode_wanted = self._homing_mode_before

    def _end_homing(self, error: TcsError) -> None:
        run = self._homing
        if run is not None and run.progress is Progress.RUNNING:
            run.fail(error)
            self._homing_ended(run)

    # ----------------------------------------------------------------- profile position
    def _begin_move(self, now: float, want: Want, target: int, velocity: float | None) -> bool:
        """Start a profile move (True), or fail it at once when the drive is not being enabled."""
        self._end_homing(TcsError(f"{self.device}: homing superseded by a move", ErrorNumber.TARGETCHANGE))
        self._request_error = None
        speed = round(abs((velocity or self.section.max_velocity) * self.section.velocity_scale))
        v = abs(velocity or self.section.max_velocity)  # user units from here
        distance = abs(target - self._raw.get(0x6064, 0)) / abs(self._scale)
        deadline = now + 5.0 + 2.0 * (distance / v + v / self.section.max_acceleration)
        window = round(abs(self.section.following_error_window * self._scale))
        job = None
        if want is Want.ENABLED and speed != self._profile_velocity and self._sdo is not None:
            sdo = self._sdo
            job = self._worker.submit(lambda: sdo.write(0x6081, 0, "<I", speed), f"{self.name} velocity")
            self._profile_velocity = speed
        self._move = ProfileMove(self.device, target, window, deadline, now, job, self._scale)
        if want is not Want.ENABLED:
            self._move.fail(TcsError(f"{self.device}: a move needs the drive enabled "
                                           "(request enable first)", ErrorNumber.INVMODE))
            self._move_ended(self._move)
            return False
        return True

    def _move_ended(self, move: ProfileMove) -> None:
        if move.error is not None:
            self._request_error = move.error
            log.warning("%s", move.error)

    def _end_move(self, error: TcsError) -> None:
        move = self._move
        if move is not None and move.progress is Progress.RUNNING:
            move.fail(error)
            self._move_ended(move)
