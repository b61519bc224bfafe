"""A simulated CiA-402 servo drive: a CANopen node a master cannot tell from a real drive.

:class:`SimDrive` is the CANopen side of one drive: NMT slave, boot-up, heartbeat producer
and consumer, SDO server, PDOs, EMCY producer. The CiA-402 application behind it (state
machine, modes, physics, homing) is :class:`tcs.sim.drive_logic.DriveLogic`; the object
dictionary comes from the EDS ``hwconfig/eds/tcs-sim-drive.eds``.

Threads: none of its own. Every drive on a bus shares the bus's
:class:`~tcs.sim.can_port.SimCanPort` (one receive thread, one timer thread); all handlers
run under the port's lock. Physics follows the injectable ``clock``; heartbeats, the heartbeat
consumer, event-TPDO timing and the poll that notices events between SYNCs use real time.
The poll runs every 10 ms while the drive may change by itself (power stage on, the motor
moving, homing or a stop ramp under way), was changed lately (:data:`LIVELY_FOR` s after an
RPDO with a new payload, an SDO request, an NMT command or fault injection) or sends an
event-driven TPDO on a timer shorter than :data:`REST_EVENT_TIMER`. A drive that rests lets
the bus's poll slow to 50 ms (:data:`tcs.sim.can_port.REST_POLL_PERIOD`): the supervision
below then notices a silent master up to that much later, and an event TPDO after a change
nobody sent over the bus (a test poking the logic) comes up to that much later.

CANopen behaviour (CiA-301):

* ``start()`` sends the boot-up message (0x700 + id, ``[0]``) after ``boot_delay`` and enters
  pre-operational; the heartbeat producer runs per 0x1017 (default 0 = off).
* NMT: start (1), stop (2), pre-operational (0x80), reset node (0x81: every object back to
  its default, the drive disabled, the homing reference lost, boot-up again), reset
  communication (0x82: objects 0x1000–0x1FFF back to defaults, boot-up again); a reset
  takes ``boot_delay`` like power-up, silent meanwhile. In stopped only NMT and heartbeat
  work; PDOs only in operational.
* Heartbeat consumer (0x1016: ``node << 16 | ms``): monitoring of a node starts with its first
  heartbeat; when one is late the drive sends EMCY 0x8130, faults, and — CiA-301's default
  error behaviour (0x1029 = 0) — drops from operational to pre-operational. It re-arms when
  the heartbeat comes back.
* SYNC: synchronous RPDOs received since the last SYNC are applied, the drive logic is
  stepped (CSP target latched), then synchronous TPDOs are sent (``tpdo_latency`` s later when
  :class:`~tcs.sim.drive_params.SimDriveParams` sets one: a drive that answers late, sampled at
  the SYNC all the same). An RPDO shorter than its mapping is dropped with EMCY 0x8210.
* The master watched (CiA-402 0x6007, "abort connection"): with a SYNC period in 0x1006, a
  drive enabled in operational that sees no SYNC for :data:`SYNC_LOSS_PERIODS` periods (at
  least :data:`SYNC_LOSS_MIN` s) reacts per 0x6007 with code 0x8250 (see
  :meth:`tcs.sim.drive_logic.DriveLogic.connection_lost`); so it does when NMT stop /
  pre-operational takes it out of operational while enabled, and when an RPDO with an event
  timer (0x1400:5, deadline monitoring) has not come for that long since its last reception
  (watched by the poll, in real time: SYNC may have stopped with the master). Missing
  RPDOs: see drive_logic.
* EMCY (0x1014, default 0x80 + id): ``[code lo, code hi, error register, 0, 0, 0, 0, 0]``.

Host stalls (what real drive hardware never has): the SYNC-loss, RPDO-time-out and heartbeat
consumer supervision above judge the master by real time, so a simulator thread that did not
run (a busy host, a stopped process) would see a "silent master" that was in fact its own
silence. The bus's port counts such stalls (:data:`tcs.sim.can_port.HOST_STALL`: no thread of
the port ran, or a frame waited that long unread); on one the drive *restarts* its
supervision windows (last SYNC and every consumed heartbeat count from now, the RPDO count
from 0) instead of faulting, and — with the real clock — its physics does not jump: the clock
of the physics leaves out the time nothing ran, so a move, a ramp or the following-error
timer resumes where it was. Supervision is also not judged while received frames wait unread,
and its windows are measured on the port's awake clock (``SimCanPort.awake``): on a host so
busy that the simulator's own wake-ups come late — which starves a master in the same
process (the ``virtual`` bus) just as much — they last longer in real time.
A SYNC is handled as of when the master sent it (``SimCanPort.frame_lag``: how long it waited
unread), and the poll does not move the physics on while frames wait unread: a drive latches its
setpoints at the SYNC on its own hardware, never after bridging the time its receive thread
was starved.
A master that is silent while the drive runs still faults it exactly as before (0x8250,
0x8130); so do :meth:`inject_fault`, :meth:`hold_heartbeat` and :meth:`set_responding`.

Fault injection (for tests): :meth:`inject_fault` ("overcurrent" 0x2310, "following_error"
0x8611, "encoder" 0x7305, "position_limit" 0x8612, "heartbeat" 0x8130, "rpdo_timeout"
0x8250, or any int code), :meth:`set_responding` (False = a dead node: sends nothing,
answers nothing), :meth:`hold_heartbeat` (late heartbeats), :meth:`mute_tpdos` and :meth:`set_refuse_sdo` (every SDO request aborted with 0x08000020).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import canopen

from tcs.config.eds_file import compact_entries, eds_source, expand_compact
from tcs.sim.can_port import SimCanPort, TimerHandle, open_port
from tcs.sim.drive_logic import (
    EMCY_ENCODER,
    EMCY_FOLLOWING_ERROR,
    EMCY_HEARTBEAT,
    EMCY_OVERCURRENT,
    EMCY_PDO_LENGTH,
    EMCY_POSITION_LIMIT,
    EMCY_RPDO_TIMEOUT,
    MODE_CSP,
    MODE_IP,
    DriveLogic,
    State,
    error_register_bits,
)
from tcs.resources import hwconfig_file
from tcs.sim.drive_params import SimDriveParams, store_options
from tcs.sim.object_store import ABORT_STORE, ObjectStore
from tcs.sim.pdo import PdoEngine
from tcs.sim.sdo_server import SdoServer

__all__ = ["DEFAULT_EDS", "FAULT_CODES", "SimDrive", "SimDriveParams"]

log = logging.getLogger(__name__)

DEFAULT_EDS = hwconfig_file("eds/tcs-sim-drive.eds")  # package data (tcs.resources)

#: Names accepted by :meth:`SimDrive.inject_fault` and the EMCY code each raises.
FAULT_CODES: dict[str, int] = {
    "overcurrent": EMCY_OVERCURRENT,
    "following_error": EMCY_FOLLOWING_ERROR,
    "encoder": EMCY_ENCODER,
    "position_limit": EMCY_POSITION_LIMIT,
    "heartbeat": EMCY_HEARTBEAT,
    "rpdo_timeout": EMCY_RPDO_TIMEOUT,
}

#: SYNC silence (in 0x1006 periods, and at least SYNC_LOSS_MIN s) that counts as a lost master.
SYNC_LOSS_PERIODS = 10
SYNC_LOSS_MIN = 0.5
#: Seconds a drive keeps the bus's poll at its full rate after a change it was sent.
LIVELY_FOR = 1.0
#: An event-driven TPDO timer (s) shorter than this keeps the poll at its full rate (at the
#: resting rate it would come up to a REST_POLL_PERIOD late).
REST_EVENT_TIMER = 0.25

# NMT states as the heartbeat reports them.
INITIALISING, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F
NMT_NAMES = {INITIALISING: "INITIALISING", STOPPED: "STOPPED", OPERATIONAL: "OPERATIONAL",
             PRE_OPERATIONAL: "PRE-OPERATIONAL"}

_od_cache: dict[tuple[str, int], canopen.ObjectDictionary] = {}
_od_lock = threading.Lock()


def _load_od(eds: str | Path, node_id: int) -> canopen.ObjectDictionary:
    key = (str(Path(eds).resolve()), node_id)
    with _od_lock:
        od = _od_cache.get(key)
        if od is None:
            if not Path(eds).is_file():
                raise FileNotFoundError(f"simulated drive {node_id}: EDS file {eds} not found")
            od = _od_cache[key] = canopen.import_od(eds_source(eds), node_id)
            expand_compact(od, compact_entries(eds))  # PDO mappings written with CompactSubObj
        return od


class SimDrive:
    """One simulated CiA-402 drive on a CAN bus.

    Parameters
    ----------
    bus_or_network:
        Where the drive sits: a python-can bus (read by the simulator only), a connected
        ``canopen.Network``, a :class:`SimCanPort`, or a dict of ``can.Bus`` keyword
        arguments. Drives given the same bus object share its threads.
    node_id:
        CANopen node id, 1–127.
    params:
        The physical axis (defaults: :class:`SimDriveParams`).
    clock:
        Time source of the physics (s); tests pass a fake clock they advance themselves.
    eds:
        The EDS describing the object dictionary.
    """

    def __init__(self, bus_or_network: Any, node_id: int, params: SimDriveParams | None = None,
                 clock: Callable[[], float] = time.monotonic, eds: str | Path = DEFAULT_EDS):
        if not 1 <= int(node_id) <= 127:
            raise ValueError(f"simulated drive: node id {node_id} outside 1..127")
        self.params = params if params is not None else SimDriveParams()
        problems = self.params.problems()
        if problems:
            raise ValueError(f"simulated drive {node_id}: " + "; ".join(problems))
        self.node_id = int(node_id)
        self._base_clock = clock
        self._compensate = clock is time.monotonic  # a test's own clock never stalls
        self._stall_offset = 0.0   # host stall time left out of the physics' clock, s
        self._stalls_seen = 0      # the port's stall count already handled
        self.host_stalls = 0       # stalls this drive rode out (tests, logs)
        self._od = _load_od(self.params.eds or eds, self.node_id)
        self._port: SimCanPort = open_port(bus_or_network)
        self.lock = self._port.lock
        self.nmt_state = INITIALISING
        self.responding = True
        self.refuse_sdo = False
        self.sync_count = 0
        #: (monotonic time, CSP target in user units, continuous) of each SYNC that applied a
        #: fresh CSP target while enabled: what the master commanded, for tests of the setpoint
        #: stream (IP: the interpolation data record); ``continuous`` is False for the first
        #: target after the drive was not following CSP targets (disabled, faulted, another
        #: mode) or after a SYNC that came without one
        self.csp_targets: collections.deque = collections.deque(maxlen=20000)
        self._csp_gap = True
        self.emcy_sent: list[int] = []
        self._rpdo_since_sync = False
        self._last_sync: float | None = None  # real time of the last SYNC while operational
        self._rpdo_seen: dict[int, float] = {}  # RPDO → last reception (port's awake clock), deadline armed
        self._rpdo_payload: dict[int, bytes] = {}  # COB-ID → last payload (a new one livens the poll)
        self._lively_until = 0.0  # monotonic time until which the poll keeps its full rate
        self._subscribed: dict[int, str] = {}
        self._rpdo_numbers: dict[int, int] = {}  # COB-ID -> RPDO number (by _update_comm)
        self._sync_cob = 0x080
        self._timers: list[TimerHandle] = []
        self._heartbeat_timer: TimerHandle | None = None
        self._heartbeat_period = 0
        self._heartbeat_hold = 0.0
        self._tpdos_muted = False
        self._consumers: dict[int, float] = {}       # node -> timeout (s)
        self._consumer_seen: dict[int, float] = {}   # node -> last heartbeat (real time)
        self._started = False
        self._stopped = False
        self._build()

    def clock(self) -> float:
        """Time of the physics (s): the given clock minus the host stalls ridden out."""
        return self._base_clock() - self._stall_offset

    def _build(self) -> None:
        """A freshly powered drive: objects at their defaults, application reset."""
        options = store_options(self._od, self.params, self.node_id)
        answers = options.pop("answers", {})
        self.store = ObjectStore(self._od, **options)
        for index, value in answers.items():  # (a placeholder default in the EDS: the real value)
            self.store.on_read(index, lambda sub, value=value: value)
        self.sdo = SdoServer(self.store)
        self.sdo.refuse_code = ABORT_STORE if self.refuse_sdo else None
        self.pdo = PdoEngine(self.store, lambda: self.nmt_state == PRE_OPERATIONAL,
                             timer_in_operational=self.params.pdo_timer_in_operational)
        old = getattr(self, "logic", None)
        params = self.params
        if old is not None:  # the motor does not jump when the firmware restarts
            old.update(self.clock())
            params = SimDriveParams(**{**vars(self.params), "position": old.axis.x,
                                       "absolute_home": old.absolute_home})
        self.logic = DriveLogic(self.store, params, self.clock(), self._on_logic_emcy)

    # -- life cycle --------------------------------------------------------------------------
    def start(self, powered: bool = False) -> None:
        """Boot: the boot-up message after ``boot_delay``, then heartbeats per 0x1017.
        ``powered``: the drive was powered before (a cabinet switched on before the software
        started): the boot-up message at once."""
        with self.lock:
            if self._started:
                return
            self._started = True
            self._stalls_seen = self._port.stalls
            self._lively_until = time.monotonic() + LIVELY_FOR
            self._port.add_poller(self._poll)
            if self.params.boot_delay > 0 and not powered:
                self._timers.append(self._port.call_later(self.params.boot_delay, self._boot))
            else:
                self._boot()

    def stop(self) -> None:
        """Leave the bus: timers cancelled, subscriptions dropped, the shared port released."""
        with self.lock:
            if self._stopped:
                return
            self._stopped = True
            self._port.remove_poller(self._poll)
            for timer in self._timers:
                timer.cancel()
            if self._heartbeat_timer is not None:
                self._heartbeat_timer.cancel()
            for cob_id in list(self._subscribed):
                self._port.unsubscribe(cob_id, self._on_frame)
            self._subscribed.clear()
        self._port.release()

    def __enter__(self) -> SimDrive:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _boot(self) -> None:
        if self._stopped or self.nmt_state != INITIALISING:
            return
        self.nmt_state = PRE_OPERATIONAL
        self._send(0x700 + self.node_id, b"\x00")
        self._update_comm()

    # -- fault injection ---------------------------------------------------------------------
    def inject_fault(self, kind: str | int) -> None:
        """Make the drive fault now with EMCY (see :data:`FAULT_CODES`; an int is a raw code)."""
        code = kind if isinstance(kind, int) else FAULT_CODES.get(kind)
        if code is None:
            raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_CODES)}")
        with self.lock:
            self._liven()
            self.logic.update(self.clock())
            self._raise_fault(code)

    def set_responding(self, responding: bool) -> None:
        """False: the node is dead on the bus (no heartbeat, PDO, EMCY or SDO answer)."""
        with self.lock:
            self._liven()
            self.responding = bool(responding)
            self._consumer_seen.clear()

    def mute_tpdos(self, muted: bool) -> None:
        """True: send no TPDO (the node otherwise works: heartbeat, SDO, RPDOs)."""
        with self.lock:
            self._liven()
            self._tpdos_muted = bool(muted)

    def hold_heartbeat(self, seconds: float) -> None:
        """Send no heartbeat for ``seconds`` (a late heartbeat; the node keeps working)."""
        with self.lock:
            self._liven()
            self._heartbeat_hold = time.monotonic() + seconds

    def set_refuse_sdo(self, refuse: bool) -> None:
        """True: abort every SDO request with 0x08000020 ("cannot be stored/transferred")."""
        with self.lock:
            self._liven()
            self.refuse_sdo = bool(refuse)
            self.sdo.refuse_code = ABORT_STORE if refuse else None

    # -- introspection (tests and benchmarks; never used by the TCS) --------------------------
    def _now(self):
        # (not past frames that wait unread, on the real clock: a SYNC among them is handled
        # as of when it was sent, and a reading taken meanwhile must not have moved the
        # physics on beyond that — the demand would have bridged on, and the SYNC's line
        # start from there: a reader's own artefact, 4.1 then 5.7 deg/s around one such SYNC)
        if not (self._compensate and self._port.receive_backlog()):
            self.logic.update(self.clock())
        return self.logic

    @property
    def position(self) -> float:
        """Position actual value in user units (what the drive reports, divided by the scale)."""
        with self.lock:
            lg = self._now()
            return (lg.axis.x - lg.zero) * lg.ipu() / self.params.increments_per_unit

    @property
    def physical_position(self) -> float:
        """Where the motor really is (user units, the frame of the switch positions)."""
        with self.lock:
            return self._now().axis.x

    @property
    def velocity(self) -> float:
        with self.lock:
            return self._now().axis.v

    @property
    def state(self) -> str:
        """CiA-402 state name, e.g. ``"OPERATION ENABLED"``."""
        with self.lock:
            return self._now().state.value

    @property
    def statusword(self) -> int:
        with self.lock:
            return self._now().statusword()

    @property
    def controlword(self) -> int:
        with self.lock:
            return self.logic.controlword

    @property
    def mode_display(self) -> int:
        with self.lock:
            return self.logic.mode

    @property
    def error_code(self) -> int:
        with self.lock:
            return self.store.get(0x603F, 0)

    @property
    def rpdo_missed(self) -> int:
        with self.lock:
            return self.logic.rpdo_missed

    @property
    def port(self) -> SimCanPort:
        """The bus's port, shared with every simulated node on the bus (``poll_period``,
        ``stalls``)."""
        return self._port

    @property
    def nmt_state_name(self) -> str:
        return NMT_NAMES.get(self.nmt_state, hex(self.nmt_state))

    def read_object(self, index: int, sub: int = 0) -> Any:
        """An object's current value (for tests; bypasses the bus and access rights)."""
        with self.lock:
            self.logic.update(self.clock())
            return self.store.value(index, sub)

    # -- sending -----------------------------------------------------------------------------
    def _send(self, cob_id: int, data: bytes) -> None:
        if self.responding and not self._stopped:
            self._port.send(cob_id, data)

    def _on_logic_emcy(self, code: int, register: int) -> None:
        self.emcy_sent.append(code)
        cob = self.store.get(0x1014, 0)
        if cob & 0x80000000 or self.nmt_state not in (PRE_OPERATIONAL, OPERATIONAL):
            return
        self._send(cob & 0x7FF, bytes([code & 0xFF, code >> 8, register & 0xFF, 0, 0, 0, 0, 0]))

    def _raise_fault(self, code: int) -> None:
        """Fault the drive; a drive already in fault still reports the new error by EMCY."""
        if not self.logic.fault(code):
            self._on_logic_emcy(code, self.store.get(0x1001, 0) | error_register_bits(code))

    # -- subscriptions -----------------------------------------------------------------------
    def _update_comm(self) -> None:
        """Follow the communication objects: subscriptions and heartbeat timers."""
        wanted: dict[int, str] = {0x000: "nmt"}
        if self.nmt_state != INITIALISING:
            wanted[0x600 + self.node_id] = "sdo"
            sync = self.store.get(0x1005, 0)
            self._sync_cob = sync & 0x7FF
            wanted.setdefault(self._sync_cob, "sync")
            self._rpdo_numbers = self.pdo.rpdo_cob_ids()
            for cob in self._rpdo_numbers:
                wanted.setdefault(cob, "rpdo")
            consumers = {}
            for sub in range(1, self.store.get(0x1016, 0) + 1):
                entry = self.store.get(0x1016, sub)
                node, ms = (entry >> 16) & 0xFF, entry & 0xFFFF
                if 1 <= node <= 127 and ms > 0:
                    consumers[node] = ms / 1000.0
                    wanted.setdefault(0x700 + node, "heartbeat")
            for node in list(self._consumer_seen):
                if node not in consumers:
                    del self._consumer_seen[node]
            self._consumers = consumers
            self.logic.rpdo_deadlines = self.pdo.rpdo_deadlines()
        else:
            self.logic.rpdo_deadlines = {}
            self._rpdo_numbers = {}
        for cob in [c for c in self._subscribed if c not in wanted]:
            self._port.unsubscribe(cob, self._on_frame)
        for cob in wanted:
            if cob not in self._subscribed:
                self._port.subscribe(cob, self._on_frame)
        self._subscribed = wanted
        period = self.store.get(0x1017, 0) if self.nmt_state != INITIALISING else 0
        if period != self._heartbeat_period:
            if self._heartbeat_timer is not None:
                self._heartbeat_timer.cancel()
                self._heartbeat_timer = None
            if period > 0:
                self._heartbeat_timer = self._port.call_every(period / 1000.0, self._heartbeat)
            self._heartbeat_period = period

    # -- receiving ---------------------------------------------------------------------------
    def _on_frame(self, cob_id: int, data: bytes) -> None:
        if self._stopped or not self.responding:
            return
        self._check_stall()
        kind = self._subscribed.get(cob_id)
        if kind == "nmt":
            self._on_nmt(data)
        elif kind == "heartbeat":
            self._consumer_seen[cob_id - 0x700] = self._port.awake
        elif self.nmt_state in (PRE_OPERATIONAL, OPERATIONAL):
            if kind == "sdo":
                self._on_sdo(data)
            elif cob_id == self._sync_cob:
                self._on_sync()
            elif kind == "rpdo" and self.nmt_state == OPERATIONAL:
                self._on_rpdo(cob_id, data)

    def _on_nmt(self, data: bytes) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id) or self.nmt_state == INITIALISING:
            return
        command = data[0]
        self._liven()
        if command in (0x02, 0x80) and self.nmt_state == OPERATIONAL:
            self.logic.update(self.clock())
            self.logic.connection_lost(None)  # leaving operational while enabled: 0x6007
        self._last_sync = None
        self._rpdo_seen.clear()
        if command == 0x01:
            self.nmt_state = OPERATIONAL
        elif command == 0x02:
            self.nmt_state = STOPPED
        elif command == 0x80:
            self.nmt_state = PRE_OPERATIONAL
        elif command in (0x81, 0x82):
            if command == 0x81:
                self._build()
            else:
                self.store.reset_range(0x1000, 0x1FFF)
                self.logic.install_identity()
                self.pdo.reset()
            self._consumer_seen.clear()
            self._rpdo_since_sync = False
            self.nmt_state = INITIALISING
            self._update_comm()
            if self.params.boot_delay > 0:
                self._timers.append(self._port.call_later(self.params.boot_delay, self._boot))
            else:
                self._boot()
            return
        self._update_comm()

    def _on_sdo(self, data: bytes) -> None:
        self._liven()
        self.logic.update(self.clock())
        response = self.sdo.handle(data)
        if response is not None:
            self._send(0x580 + self.node_id, response)
        if data and data[0] >> 5 in (0, 1):  # a download may have changed communication objects
            self._update_comm()

    def _on_rpdo(self, cob_id: int, data: bytes) -> None:
        n = self._rpdo_numbers.get(cob_id)
        if n is None:
            return
        if self._rpdo_payload.get(cob_id) != data:  # (the same payload again changes nothing)
            self._rpdo_payload[cob_id] = data
            self._liven()
        if not self.pdo.rpdo_synchronous(n):  # (applied now; a synchronous one at the SYNC)
            self.logic.update(self.clock())
        before = self.pdo.rpdo_length_errors
        self.pdo.receive(n, data)
        if self.pdo.rpdo_length_errors != before:
            self._on_logic_emcy(EMCY_PDO_LENGTH, self.store.get(0x1001, 0) | 0x10)
        else:
            self._rpdo_since_sync = True
            if n in self.logic.rpdo_deadlines:
                self._rpdo_seen[n] = self._port.awake

    def _on_sync(self) -> None:
        self.sync_count += 1
        # as of when the master sent it, as a drive handles it on its own hardware: a SYNC that
        # waited unread behind a starved receive thread latches the setpoints where the demand
        # was then, not after the demand bridged on by itself meanwhile (which pulled it back
        # by the wait's travel: 7.6 deg after 77 ms at 122 deg/s, a following-error stop)
        # (on the real clock only: a test's own clock does not run while a frame waits)
        self.logic.update(self.clock() - (self._port.frame_lag if self._compensate else 0.0))
        if self.nmt_state != OPERATIONAL:
            return
        self._last_sync = self._port.awake
        self.pdo.apply_sync_rpdos()
        fresh, self._rpdo_since_sync = self._rpdo_since_sync, False
        self.logic.on_sync(fresh)
        if self.logic.mode in (MODE_CSP, MODE_IP) and self.logic.state is State.OPERATION_ENABLED:
            if fresh:
                record = 0x607A if self.logic.mode == MODE_CSP else 0x60C1
                self.csp_targets.append((time.monotonic(),
                                         self.store.get(record, 0 if record == 0x607A else 1)
                                         / self.params.increments_per_unit, not self._csp_gap))
                self._csp_gap = False
            else:  # a SYNC without a setpoint: the drive bridged it (the next is no step)
                self._csp_gap = True
        else:
            self._csp_gap = True
        frames = self.pdo.on_sync(time.monotonic())
        if frames and self.params.tpdo_latency > 0:  # sampled now, sent later (drive_params)
            self._port.call_later(self.params.tpdo_latency, lambda: self._send_tpdos(frames))
        else:
            self._send_tpdos(frames)

    def _send_tpdos(self, frames) -> None:
        if self._tpdos_muted or self.nmt_state != OPERATIONAL:
            return
        for cob, payload in frames:
            self._send(cob, payload)

    # -- timers ------------------------------------------------------------------------------
    def _heartbeat(self) -> None:
        if self.nmt_state != INITIALISING and time.monotonic() >= self._heartbeat_hold:
            self._send(0x700 + self.node_id, bytes([self.nmt_state]))

    def _liven(self) -> None:
        """The drive was sent a change: the bus's poll at its full rate for :data:`LIVELY_FOR` s."""
        self._lively_until = time.monotonic() + LIVELY_FOR
        self._port.hurry()

    def _poll(self) -> bool:
        """The bus's poll (timer thread, under the lock): events between SYNCs, supervision,
        event TPDOs. Returns whether the drive needs the poll's full rate (see the module
        docstring)."""
        if self._stopped or self.nmt_state == INITIALISING:
            return False
        self._check_stall()
        backlog = self._port.receive_backlog()
        # (frames wait unread: the receive thread advances the physics to each one's own time
        # when it handles it — on the real clock; a test's own clock does not run meanwhile)
        if not (backlog and self._compensate):
            self.logic.update(self.clock())
        if self.responding and not backlog:
            self._supervise()  # (frames wait unread: the master is not judged silent meanwhile)
        return (time.monotonic() < self._lively_until or not self.logic.resting()
                or (self.nmt_state == OPERATIONAL and self.pdo.shortest_event_timer() < REST_EVENT_TIMER))

    def _supervise(self) -> None:
        now = self._port.awake  # supervision runs on the port's awake clock
        if self.nmt_state == OPERATIONAL:
            self._watch_rpdos(now)
            self._watch_sync(now)  # (the shorter time-out first, should a poll come late)
        for node, last in list(self._consumer_seen.items()):
            timeout = self._consumers.get(node)
            if timeout is not None and now - last > timeout:
                del self._consumer_seen[node]  # re-armed by the next heartbeat
                log.info("simulated drive %d: heartbeat of node %d lost", self.node_id, node)
                self._raise_fault(EMCY_HEARTBEAT)
                if self.nmt_state == OPERATIONAL:
                    self.nmt_state = PRE_OPERATIONAL
                    self._update_comm()
        if self.nmt_state == OPERATIONAL:
            for cob, payload in self.pdo.poll_events(time.monotonic()):
                self._send(cob, payload)

    def _check_stall(self) -> None:
        """Ride out a host stall the port noticed since the last look (under the lock)."""
        port = self._port
        if port.stalls != self._stalls_seen:
            self._stalls_seen = port.stalls
            self._on_host_stall(port.last_stall, port.last_gap)

    def _on_host_stall(self, stall: float, gap: float) -> None:
        """This drive's own host did not run for ``stall`` s (``gap`` of it nothing of the
        port ran): no silence of the master. Restart the supervision windows; leave the time
        nothing ran out of the physics (see the module docstring)."""
        now = self._port.awake
        period = self._port.poll_period  # (the gap the poll leaves anyway)
        if self._compensate and gap > period:
            self._stall_offset += gap - period
        if self._last_sync is not None:
            self._last_sync = now
        for node in self._consumer_seen:
            self._consumer_seen[node] = now
        for n in self._rpdo_seen:  # the RPDO deadlines too
            self._rpdo_seen[n] = now
        self.logic.missed_in_row = 0
        self.host_stalls += 1
        log.debug("simulated drive %d: its host stalled for %.2f s; supervision windows restarted",
                  self.node_id, stall)

    def _watch_rpdos(self, now: float) -> None:
        """An RPDO past its deadline (0x1400:5, armed by its first reception): the master is
        gone, react per 0x6007 with 0x8250 "RPDO time-out"."""
        deadlines = self.logic.rpdo_deadlines
        for n, last in list(self._rpdo_seen.items()):
            limit = deadlines.get(n)
            if limit is None:
                del self._rpdo_seen[n]
            elif now - last > limit:
                del self._rpdo_seen[n]  # re-armed by the next RPDO
                log.info("simulated drive %d: RPDO%d deadline (%.0f ms) passed", self.node_id,
                         n + 1, limit * 1e3)
                self.logic.update(self.clock())
                self.logic.connection_lost(EMCY_RPDO_TIMEOUT)

    def _watch_sync(self, now: float) -> None:
        """SYNC stopped while enabled (0x1006 > 0): the master is gone, react per 0x6007."""
        last = self._last_sync
        try:
            period = self.store.get(0x1006, 0) / 1e6
        except KeyError:
            return
        if last is None or period <= 0:
            return
        if now - last > max(SYNC_LOSS_PERIODS * period, SYNC_LOSS_MIN):
            self._last_sync = None  # re-armed by the next SYNC
            log.info("simulated drive %d: SYNC lost", self.node_id)
            self.logic.connection_lost(EMCY_RPDO_TIMEOUT)
