"""The cyclic phase: SYNC producer and the runner that calls the control loop once per SYNC.

Timing of cycle *k* (period *T*, ``tpdo_deadline`` *d*; default 0.5 with kernel SYNC, 0.8 when
the runner sends SYNC itself)::

    t_k            SYNC k on the bus. Drives latch the RPDO received in cycle k-1, sample,
                   and answer with their synchronous TPDOs.
    t_k .. t_k+dT  the runner waits until every expected synchronous TPDO of cycle k has
                   arrived (a barrier fed from the notifier thread) — or until t_k + dT.
    then           the callbacks run with :class:`Cycle` k: they read the drives' status of
                   cycle k, compute, and each drive's ``step()`` sends its RPDO, which the
                   drives buffer until
    t_k + T        SYNC k+1 applies it.

So a callback sees the status of cycle k and its RPDO reaches the drives before SYNC k+1 as
long as the callbacks finish within (1 - d)·T. When the runner sends SYNC itself, SYNC k+1
leaves the same thread after the callbacks, on the same ordered stream as their RPDOs, so an
RPDO can never miss its SYNC (a late callback delays the SYNC instead, counted in ``late``):
there the TPDOs may take longer (d = 0.8), which a remote bus needs — over socketcand a TPDO
crosses two processes, TCP and five thread hand-overs, a millisecond typically and several on
a busy machine. With kernel SYNC the next SYNC leaves on time whatever the runner does, so
d = 0.5 leaves half the period to the callbacks. Counters (:class:`CycleStats`):

* ``late`` — callbacks that ended after the next SYNC was due (their RPDOs may miss it);
* ``missed`` — SYNC slots skipped because the runner was still busy (no SYNC was sent then in
  thread mode; the kernel sent it anyway on socketcan, with no new setpoint behind it);
* ``tpdo_timeouts`` — cycles that ran at the deadline without every synchronous TPDO;
* ``retimed_again`` — cycles whose held setpoints were retimed and sent again before their
  SYNC (:data:`RETIME_AGAIN`: the runner was preempted while sending them);
* ``lateness`` — the last ``history`` SYNC send times minus their ideal schedule (thread mode)
  or SYNC receive intervals minus *T* accumulated on the ideal grid (socketcan).

When the runner sends SYNC itself, the frames a callback sends (the drives' RPDOs) are held
(:meth:`tcs.drivers.canbus.CanBus.hold_sends`) and go out just before the SYNC they were made
for — so a stall of this process (SIGSTOP, a starved host) never leaves a setpoint made before
it waiting in the drives for the first SYNC after it (the drives bridge the gap; that old
setpoint would pull their demand back). A runner that wakes a whole period or more late sends
the SYNC of the latest slot due (the ones before are ``missed``); held frames made for a slot
:data:`DROP_SLOTS` or more slots back are dropped (``dropped``; never twice in a row, or the
drives would count the RPDOs missing towards their time-out — a setpoint one or two slots
late still goes, as before): that SYNC goes without them,
and the cycle after says :attr:`Cycle.resumed` — the setpoints of the cycle before did not
reach the drives on time, so the callbacks re-anchor on where the drives really are (the
TPDOs of this SYNC) before their next setpoint. With kernel SYNC the RPDOs go at once (the
kernel's SYNC does not wait), and a cycle is resumed when :data:`DROP_SLOTS` or more SYNCs
passed since the one before it (the drives bridged at least two of them). The cycle's
``sync_time``/``next_sync`` are then when the SYNC went — the stamp the kernel gives the frame
as it passes the loopback, as an age on the monotonic clock — not when the notifier delivered
it: its latency varies by milliseconds on a busy host, and a trajectory sampled for the
notifier's time instead of the SYNC's runs the demand that much faster or slower over the
interval (issue 39 item 10). Not a fixed grid: the broadcast manager re-arms its timer from
when it fired (``ktime_get() + ival``, net/can/bcm.c), so its SYNCs drift later by the
timer's latency each period — a grid fitted to them was milliseconds off in the CI's emulated
VM.

A SYNC that goes out late (the runner woke late, or its callbacks overran the slot by less than
:data:`LATE_SYNC` of a period — a slot overrun by more is skipped) carries setpoints *moved on
by its lateness within its slot* along their stream (each held frame's ``retime``, given by the
driver: :meth:`tcs.drivers.cia402_drive.Cia402Drive._retimer`): a drive latches a setpoint at
the SYNC it gets and interpolates it over the nominal period from there, so a setpoint made for
the slot would run its demand faster than the stream over the shorter interval to the next,
on-time SYNC (issue 39 item 10; docs/motion.md). The setpoints the callbacks made, and every
bound on them, stay as made. ``retime = False`` sends them as made (the baseline of the jitter
bench); :attr:`CycleSource.retime_delays` notes SYNCs a preempted runner sent noticeably later
than the lateness it moved their setpoints on by.

Where the SYNC comes from: on ``socketcan`` the kernel broadcast manager sends it
(``bus.send_periodic``; the runner sees each SYNC through the socket's loopback). Elsewhere the
runner thread itself sends SYNC at ``t_k``: it sleeps to the slot, sends, waits for the
barrier, runs the callbacks. No SYNC counter byte is sent.

A resting telescope may slow the SYNC: :meth:`CycleSource.set_divider` ``(n)`` sends SYNC — and
runs the callbacks — every ``n``-th period from the next SYNC on (kernel SYNC: the broadcast
manager's task is replaced by one at ``n × period``); ``1`` is the normal rate again.
:class:`Cycle` then says when the next SYNC comes, lateness is measured on the slower grid,
the TPDOs have ``d × n × T`` (the same share of the longer cycle), and ``period`` stays the
nominal one. Only :mod:`tcs.drivers.idle_sync` calls it, after
telling the drives (0x1006, RPDO deadlines).

Threads: the runner is one dedicated thread (``tcs-cycle``), optionally with a real-time
priority (``realtime_priority``: SCHED_FIFO, so other processes cannot delay its wake-ups; the
GIL is still shared with the rest of the process); callbacks run in it and must not block.
``add_callback``/``expect_tpdos`` are for set-up before :meth:`start` (they are
lock-protected, so later is allowed). :meth:`stats` may be read from any thread.
"""

from __future__ import annotations

import collections
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import can

from tcs.drivers.canbus import SYNC_COB_ID, CanBus
from tcs.errors import TcsError

log = logging.getLogger(__name__)

#: Held frames made for a SYNC slot this many slots or more before the one due are dropped (a
#: stall); frames one or two slots late still go: a drive's RPDO deadline (by default 3
#: periods, ``master_loss_timeout``) must keep seeing RPDOs through the late cycles of a busy
#: host, and each dropped setpoint lets an extrapolating drive run on at the stream's speed
#: for a period more (past a path that brakes); a setpoint one or two periods late pulls such
#: a drive back by at most that many periods' travel.
DROP_SLOTS = 3
#: A runner whose callbacks end less than this share of a period after the next SYNC slot
#: still sends that SYNC, late (thread mode); beyond it the slot is skipped.
LATE_SYNC = 0.5
#: Held setpoints whose sending took the runner longer than :data:`RETIME_DELAY_NOTED` (it was
#: preempted) are retimed and sent again, at most this many times, before their SYNC.
RETIME_AGAIN = 2
#: With kernel SYNC, a SYNC frame's stamp older than this (s) when it is handled is taken as of
#: another clock: the SYNC's time is then when it was heard.
MAX_SYNC_AGE = 1.0
#: A SYNC sent more than this (s) after its setpoints were moved on by its lateness is noted in
#: :attr:`CycleSource.retime_delays`.
RETIME_DELAY_NOTED = 0.0005


@dataclass(frozen=True)
class Cycle:
    """What a callback gets: the cycle number, when its SYNC went out, when the next is due;
    ``resumed``: the setpoints of the cycle before did not reach the drives on time (a gap:
    the drives bridged it; re-anchor on their readback); ``previous_sync``: when the SYNC of
    the cycle before went out (None for the first)."""

    index: int
    sync_time: float
    next_sync: float
    tpdos_complete: bool
    resumed: bool = False
    previous_sync: float | None = None


@dataclass(frozen=True)
class CycleStats:
    cycles: int = 0
    late: int = 0
    missed: int = 0
    tpdo_timeouts: int = 0
    callback_errors: int = 0
    sync_failures: int = 0
    max_callback: float = 0.0
    dropped: int = 0  # cycles whose held RPDOs were dropped (their SYNC was skipped or late)
    retimed_again: int = 0  # held setpoints retimed and sent again (the runner was preempted)


class CycleSource:
    """Produces SYNC every ``period`` and runs the callbacks once per SYNC.

    Parameters
    ----------
    bus:
        The open :class:`CanBus`.
    period:
        SYNC period, s (``can.sync_period``).
    tpdo_deadline:
        Fraction of the period after SYNC when the callbacks run even if TPDOs are missing;
        None: 0.5 with kernel SYNC, 0.8 when the runner sends SYNC (see the module docstring).
    kernel_sync:
        Use the kernel's ``send_periodic`` for SYNC; default: when the bus is socketcan.
    history:
        How many lateness samples to keep.
    clock:
        Monotonic clock (tests may replace it only with another real-time clock).
    realtime_priority:
        SCHED_FIFO priority of the runner thread, 1..99; 0 keeps normal scheduling. When the
        system refuses it the runner goes on normally; :attr:`realtime` tells which.
    """

    def __init__(self, bus: CanBus, period: float, *, tpdo_deadline: float | None = None,
                 kernel_sync: bool | None = None, history: int = 100_000,
                 clock: Callable[[], float] = time.monotonic, realtime_priority: int = 0):
        self.bus = bus
        self.period = float(period)
        self.kernel_sync = bus.kernel_periodic if kernel_sync is None else kernel_sync
        self._tpdo_deadline = None if tpdo_deadline is None else float(tpdo_deadline)
        self._clock = clock
        self._callbacks: list[Callable[[Cycle], None]] = []
        self._lock = threading.Lock()
        self._expected: set[int] = set()
        self._seen: set[int] = set()
        self._arrived = threading.Event()
        self._sync_seen = threading.Condition()
        self._sync_count = 0
        self._sync_time = 0.0   # when the last SYNC went (its frame's stamp)
        self._sync_heard = 0.0  # when this process heard it
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._periodic = None
        self._stats = CycleStats()
        self.lateness: collections.deque[float] = collections.deque(maxlen=history)
        self.callback_time: collections.deque[float] = collections.deque(maxlen=history)
        self.last_error: TcsError | Exception | None = None
        self.realtime_priority = int(realtime_priority)
        self.realtime = False  # the runner got its real-time priority
        self.max_lateness = 0.0  # worst lateness since start, s
        self._divider = 1  # SYNC every this many periods (set_divider)
        self._sync_msg = None  # the kernel's periodic SYNC frame
        #: held setpoints going out with a late SYNC are moved on along their stream by its
        #: lateness (the frames' ``retime``; see the module docstring). False: sent as made
        #: (the benchmark's baseline, tools/bench/sync_jitter.py)
        self.retime = True
        #: how many times at most held setpoints are retimed and sent again when sending them
        #: took the runner too long (:data:`RETIME_AGAIN`; 0: never — the bench's baseline)
        self.retime_again = RETIME_AGAIN
        #: (send time, delay) of the SYNCs that went more than :data:`RETIME_DELAY_NOTED` s
        #: after the lateness their setpoints were moved on by was taken (the newest
        #: ``history``; tests and the jitter bench leave those SYNCs out of their judgement)
        self.retime_delays: collections.deque[tuple[float, float]] = collections.deque(maxlen=history)
        #: when the runner skipped SYNC slots (thread mode; the newest ``history``): the
        #: planner's stream slips a step there, the drives bridge it
        self.skips: collections.deque[float] = collections.deque(maxlen=history)

    @property
    def tpdo_deadline(self) -> float:
        """The TPDO wait as a fraction of the period (the default follows ``kernel_sync``,
        which may still be changed before :meth:`start`)."""
        if self._tpdo_deadline is not None:
            return self._tpdo_deadline
        return 0.5 if self.kernel_sync else 0.8

    @tpdo_deadline.setter
    def tpdo_deadline(self, value: float | None) -> None:
        self._tpdo_deadline = None if value is None else float(value)

    @property
    def divider(self) -> int:
        """SYNC every this many periods (1 normally; see :meth:`set_divider`)."""
        return self._divider

    def set_divider(self, n: int) -> None:
        """SYNC and the callbacks every ``n``-th period from the next SYNC on (1 = every
        period). Any thread; the drives must have been told first (tcs.drivers.idle_sync)."""
        n = max(1, int(n))
        with self._lock:
            if n == self._divider:
                return
            self._divider = n
            periodic = self._periodic
            if periodic is not None:  # kernel SYNC: a new task at the new rate
                self._periodic = self.bus.bus.send_periodic(self._sync_msg, self.period * n)
                periodic.stop()
        log.debug("SYNC every %d period(s) of %g s now", n, self.period)

    # ---------------------------------------------------------------- set-up
    def add_callback(self, callback: Callable[[Cycle], None]) -> None:
        """Run ``callback(cycle)`` once per SYNC, in the runner thread, in the order added."""
        with self._lock:
            self._callbacks.append(callback)

    def remove_callback(self, callback: Callable[[Cycle], None]) -> None:
        with self._lock:
            self._callbacks.remove(callback)

    def expect_tpdos(self, cob_ids: Iterable[int]) -> None:
        """Wait for these synchronous TPDO COB-IDs after each SYNC before the callbacks run."""
        network = self.bus.network
        with self._lock:
            for cob_id in cob_ids:
                if cob_id not in self._expected:
                    self._expected.add(cob_id)
                    network.subscribe(cob_id, self._on_tpdo)

    def forget_tpdos(self, cob_ids: Iterable[int]) -> None:
        """Stop waiting for these COB-IDs (a drive that went away)."""
        network = self.bus.network
        with self._lock:
            for cob_id in cob_ids:
                if cob_id in self._expected:
                    self._expected.discard(cob_id)
                    if network is not None and cob_id in network.subscribers:
                        network.unsubscribe(cob_id, self._on_tpdo)
            if self._expected <= self._seen:
                self._arrived.set()

    # ---------------------------------------------------------------- run
    def start(self) -> None:
        """Start SYNC and the runner thread."""
        if self._thread is not None:
            return
        self._stop.clear()
        self.bus.heartbeat_from_cycle()  # the TCS heartbeat now proves the loop works
        if self.kernel_sync:
            self.bus.network.subscribe(SYNC_COB_ID, self._on_sync)
            msg = self._sync_msg = can.Message(arbitration_id=SYNC_COB_ID, data=b"",
                                               is_extended_id=False)
            with self._lock:
                self._periodic = self.bus.bus.send_periodic(msg, self.period * self._divider)
            target = self._run_kernel
        else:
            target = self._run_thread
        self._thread = threading.Thread(target=self._with_priority, args=(target,), name="tcs-cycle",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop SYNC and the runner (the drives then fault on missing RPDOs if enabled)."""
        self._stop.set()
        self._arrived.set()
        with self._sync_seen:
            self._sync_seen.notify_all()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
        self.bus.heartbeat_to_periodic()
        with self._lock:
            periodic, self._periodic = self._periodic, None
        if periodic is not None:
            periodic.stop()
            t = getattr(periodic, "thread", None)
            if t is not None:
                t.join(timeout=2.0)
        network = self.bus.network
        if network is not None:
            if self.kernel_sync and SYNC_COB_ID in network.subscribers:
                network.unsubscribe(SYNC_COB_ID, self._on_sync)

    @property
    def running(self) -> bool:
        return self._thread is not None

    def stats(self) -> CycleStats:
        return self._stats

    # ---------------------------------------------------------------- notifier side
    def _on_tpdo(self, cob_id: int, data: bytearray, timestamp: float) -> None:
        # Notifier thread: only set arithmetic and an Event.
        seen = self._seen
        seen.add(cob_id)
        if len(seen) >= len(self._expected) and self._expected <= seen:
            self._arrived.set()

    def _on_sync(self, cob_id: int, data: bytearray, timestamp: float) -> None:
        # Reset the TPDO barrier here, in the notifier thread, so the TPDOs that follow this
        # SYNC on the bus are counted for it whatever the runner is doing.
        self._new_cycle()
        heard = self._clock()
        # (when the SYNC went: the kernel stamps a frame as it passes the loopback, the virtual
        # bus as it is sent — wall-clock stamps, taken here as an age; the notifier's latency,
        # milliseconds on a busy host, is not the SYNC's. A stamp of another clock, or none:
        # when it was heard)
        age = time.time() - timestamp if timestamp else 0.0
        if not 0.0 <= age < MAX_SYNC_AGE:
            age = 0.0
        with self._sync_seen:
            self._sync_count += 1
            self._sync_time, self._sync_heard = heard - age, heard
            self._sync_seen.notify_all()

    # ---------------------------------------------------------------- runner
    def _with_priority(self, target: Callable[[], None]) -> None:
        if self.realtime_priority > 0:
            try:  # pid 0: this thread (Linux schedules threads)
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.realtime_priority))
                self.realtime = True
                log.info("control cycle runs with real-time priority %d (SCHED_FIFO)",
                         self.realtime_priority)
            except (OSError, AttributeError) as exc:
                log.warning("control cycle: real-time priority %d refused (%s); running with "
                            "normal scheduling (grant CAP_SYS_NICE or LimitRTPRIO)",
                            self.realtime_priority, exc)
        target()

    def _late(self, lateness: float) -> None:
        self.lateness.append(lateness)
        if lateness > self.max_lateness:
            self.max_lateness = lateness

    def _new_cycle(self) -> None:
        self._seen = set()
        self._arrived.clear()
        if not self._expected:
            self._arrived.set()

    def _cycle(self, index: int, sync_time: float, next_sync: float, step: float,
               held: list | None = None, resumed: bool = False,
               previous: float | None = None, heard: float | None = None) -> None:
        # (``step``: this cycle's length, the period times the divider — a resting
        # telescope's slower SYNC leaves its TPDOs the same share of its longer cycle;
        # ``held``: where this thread's sends go until the next SYNC, None: sent at once;
        # ``heard``: when this thread heard the SYNC (kernel SYNC: later than ``sync_time``,
        # when it went) — the TPDOs that follow it come through the same notifier)
        deadline = (sync_time if heard is None else heard) + self.tpdo_deadline * step
        complete = self._arrived.wait(max(0.0, deadline - self._clock()))
        if self._stop.is_set():
            return
        cycle = Cycle(index, sync_time, next_sync, complete, resumed, previous)
        errors = 0
        with self._lock:
            callbacks = list(self._callbacks)
        if held is not None:
            self.bus.hold_sends(held)
        try:
            for callback in callbacks:
                try:
                    callback(cycle)
                except Exception as exc:  # a failing callback must not stop the SYNC
                    errors += 1
                    self.last_error = exc
                    log.exception("cycle callback %r failed", callback)
        finally:
            if held is not None:
                self.bus.hold_sends(None)
        end = self._clock()
        self.bus.beat(end)  # the TCS heartbeat: only from a cycle whose work is done
        spent = end - sync_time
        self.callback_time.append(spent)
        s = self._stats
        self._stats = CycleStats(
            cycles=s.cycles + 1, late=s.late + (end > next_sync), missed=s.missed,
            tpdo_timeouts=s.tpdo_timeouts + (not complete),
            callback_errors=s.callback_errors + errors, sync_failures=s.sync_failures,
            max_callback=max(s.max_callback, spent), dropped=s.dropped,
            retimed_again=s.retimed_again)

    def _count(self, **delta: int) -> None:
        s = self._stats
        self._stats = CycleStats(**{**s.__dict__, **{k: getattr(s, k) + v for k, v in delta.items()}})

    def _run_thread(self) -> None:
        """SYNC from this thread: sleep to the slot, send, wait for TPDOs, run callbacks."""
        period = self.period
        index = 0
        slot = self._clock() + period
        held: list = []            # the last cycle's RPDOs, sent just before the next SYNC
        held_for = -1              # the index of the SYNC they were made for
        retimed_at = None          # when the held frames' lateness was taken
        previous: float | None = None  # when the previous SYNC went out
        dropped_last = False       # the last held frames were dropped
        while not self._stop.is_set():
            delay = slot - self._clock()
            if delay > 0 and self._stop.wait(delay):
                break
            self._new_cycle()
            step = period * self._divider
            now = self._clock()
            if now - slot >= step:  # woke a whole period or more late (stopped, starved):
                skipped = int((now - slot) // step)  # this SYNC takes the latest slot due
                self._count(missed=skipped)
                self.skips.append(now)
                slot += skipped * step
                index += skipped
            resumed = False
            if held:
                # (never two drops in a row: a drive faults after a few SYNCs without an RPDO,
                # and the frames after a drop come from a cycle that re-anchored)
                if index - held_for < DROP_SLOTS or dropped_last:
                    # (a SYNC later than its slot: each setpoint goes where its stream is by
                    # then — the drive interpolates it over the nominal period from this SYNC
                    # on, so a setpoint made for the slot would run the demand that much faster
                    # over the shorter interval to the next, on-time SYNC. The lateness within
                    # this slot only: the planner's stream goes one step per SYNC, and a slot
                    # skipped before is the stream's slip, not a step it owes)
                    retimed_at = self._clock()
                    late = retimed_at - slot if self.retime else 0.0
                    for cob_id, data, retime in held:
                        if retime is not None and late > 0:
                            data = retime(late)
                        self._send_held(cob_id, data)
                    # (preempted while sending them — a busy host — the retimed ones again,
                    # moved on by the lateness now: a drive latches the last it got before
                    # its SYNC; what is left is a preemption after the last look at the clock)
                    for _ in range(self.retime_again):
                        now = self._clock()
                        if not self.retime or now - retimed_at <= RETIME_DELAY_NOTED:
                            break
                        retimed_at, late = now, now - slot
                        self._count(retimed_again=1)
                        for cob_id, _data, retime in held:
                            if retime is not None:
                                self._send_held(cob_id, retime(late))
                else:  # made for a skipped slot, or a whole period late: stale
                    resumed = True
                    self._count(dropped=1)
                    log.debug("cycle %d: %d held frame(s) dropped (%.1f ms late)", index,
                              len(held), (now - slot) * 1e3)
                dropped_last = resumed
                held = []
            else:
                dropped_last = False
            sent = self._clock()
            try:
                self.bus.send(SYNC_COB_ID, b"")
            except TcsError as exc:
                self.last_error = exc
                self._count(sync_failures=1)
            if retimed_at is not None:
                # (how much later than the lateness its setpoints were moved on by this SYNC
                # went: the runner preempted in between, a busy host's share of the jitter)
                delay = self._clock() - retimed_at
                if delay > RETIME_DELAY_NOTED:
                    self.retime_delays.append((sent, delay))
                retimed_at = None
            self._late(sent - slot)
            self._cycle(index, sent, slot + step, step, held, resumed, previous)
            previous, held_for = sent, index + 1
            index += 1
            slot += step
            now = self._clock()
            if now - slot >= LATE_SYNC * step:  # overran: skip the slots long past, keep the grid
                # (a slot less than LATE_SYNC periods past still gets its SYNC, late, its
                # setpoints moved on by the lateness: a skipped slot is a step of the planner's
                # stream left out — the drive's demand stalls for it, and the drive's
                # extrapolation from that short step makes the next line too fast)
                skipped = int((now - slot) / step - LATE_SYNC) + 1
                self._count(missed=skipped)
                self.skips.append(now)
                slot += skipped * step
                index += skipped

    def _send_held(self, cob_id: int, data) -> None:
        try:
            self.bus.send(cob_id, data)
        except TcsError as exc:  # (recorded in the bus health)
            self.last_error = exc

    def _run_kernel(self) -> None:
        """SYNC from the kernel: wake on each SYNC seen in the loopback, then as above."""
        period = self.period
        seen = 0
        first_time = None
        first_count = 0
        divider = self._divider
        previous: float | None = None
        while not self._stop.is_set():
            with self._sync_seen:
                while self._sync_count == seen and not self._stop.is_set():
                    self._sync_seen.wait(0.5)
                count, sync_time, heard = self._sync_count, self._sync_time, self._sync_heard
            if self._stop.is_set():
                break
            if self._divider != divider:  # a new rate: a new grid from this SYNC on
                divider, first_time = self._divider, None
            step = period * divider
            if first_time is None:
                first_time, first_count = sync_time, count
            elif count > seen + 1:
                self._count(missed=count - seen - 1)
            # (the last cycle's setpoints were made for SYNC seen + 1 and latched at the first
            # SYNC after they went: DROP_SLOTS or more SYNCs on, the drives bridged that long —
            # the same bound as the held frames' drop above; a setpoint one or two SYNCs late
            # is let be, as there: re-anchoring on every late cycle of a loaded host cost more
            # than the step it avoids)
            resumed = previous is not None and count - seen >= DROP_SLOTS
            seen = count
            self._late(sync_time - (first_time + (count - first_count) * step))
            # (the cycle's times are when the SYNC went — a setpoint is sampled for when its
            # SYNC really comes, not for the notifier's latency after one; the wait for the
            # TPDOs counts from when it was heard: they come through the same notifier)
            self._cycle(count, sync_time, sync_time + step, step, None, resumed, previous, heard)
            previous = sync_time
