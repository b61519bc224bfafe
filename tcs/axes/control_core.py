"""The control process: the drivers' cycle and the axes' step in a process of their own.

``tcs-server`` with ``[can] control_process = true`` starts this module as a child process
(``python -m tcs.axes.control_core FD``; :class:`tcs.axes.control_process.ControlProcess` is
the other end). It owns everything the 10 ms cycle touches — the CAN bus, the CiA-402 drivers
with their boot and recovery, the simulated drives of an in-process (``virtual``) bus, the
:class:`~tcs.axes.axis.Axis` objects' control-loop side and the
:class:`~tcs.axes.control_loop.ControlLoop` — so that nothing the TPL2, OpenTSI or Alpaca
clients make the service do can take the interpreter from the loop: this process has its own
interpreter lock and, with ``[can] realtime_priority`` P, every thread of it runs SCHED_FIFO (the
cycle thread at P, the others at P − 1, with a 1 ms interpreter-lock switch interval).

How it talks to the service (one ``multiprocessing.connection.Connection`` on a socket pair,
pickled tuples; the service is the only peer):

* in: ``("setup", config, ut1_utc, log_level)`` first; ``("boot",)`` once the bus was
  claimed (on a shared bus: listened to, no other master; the service starts its PLCs in
  between, as in the threaded order); then ``("cmd", axis, seq, kind,
  value, future_id, cause)`` — an axis command exactly as :meth:`Axis._send` queues it in the
  threaded mode; ``("add", rid, axis, times, positions, now)`` — TRAJECTORY points
  (answered at once by this receiver thread, the queue has its own lock); ``("ut1_utc",
  value)``; ``("samples", rid, clear)``; ``("close",)``.
* out: ``("claimed",)``, then ``("ready", info)``, or ``("refused", kind, error)``; one
  ``("batch", snapshots, items, stats)`` per cycle with the readbacks of every axis (only
  ``(measured_ut1, sample)`` for an axis whose other readbacks are those it sent last: an
  idle telescope sends seven pairs of floats, and only every :data:`QUIET_EVERY` th SYNC
  period when nothing else happened: 20 batches a second, the newest times each), then the
  cycle's events, error conditions and completions in the order they happened (so a client
  that gets ``DATA OK`` reads the new state; the readbacks of every 10th SYNC period — of
  every 2nd cycle under the 5 times slower idle SYNC, ``tcs.drivers.idle_sync`` — also carry
  the counters and each drive's status for ``CABINET.CORE.DRIVE[]``); ``("reply", rid, ok,
  value)``; ``("log", name, level, text)``; ``("closed",)``.

The loop thread never blocks on the service: it appends to an outbox that a sender thread
drains (readbacks are coalesced to the newest if the service reads slowly). If the service
goes away (its end of the socket closes: a crash, kill -9) every axis is stopped and powered
off here, then the process ends without releasing the drives, so they record the lost master
as after a crash of the whole service.
"""

from __future__ import annotations

import collections
import gc
import logging
import os
import pickle
import signal
import sys
import threading
import time
from multiprocessing.connection import Connection

from tcs.axes.axis import TRAJECTORY, Axis
from tcs.errors import TcsError

log = logging.getLogger("tcs.control")

#: Readbacks sent per axis, in this order (``ControlProcess`` applies them by name).
READBACKS = ("power_state", "referenced", "real_position", "current_speed", "current_acc",
             "current_jerk", "motion_state", "limit_state", "target_position", "offset",
             "measured_ut1", "sample")
#: Where a snapshot holds ``measured_ut1``, ``sample`` (its times change every cycle) and the
#: drive status (every 10th cycle): what :func:`unchanged_key` leaves out.
MEASURED = 1 + READBACKS.index("measured_ut1")
SAMPLE = 1 + READBACKS.index("sample")
DRIVE = -1


def unchanged_key(snap: tuple) -> tuple:
    """What of a snapshot must be equal for the next one to go as an *unchanged* readback:
    everything but the times (``measured_ut1``, the times in ``sample``) and the drive status."""
    sample = snap[SAMPLE]
    return (snap[:MEASURED], snap[MEASURED + 1:SAMPLE], snap[SAMPLE + 1:DRIVE],
            None if sample is None else (sample[1], sample[3]))


def merge_unchanged(pending: tuple, unchanged: tuple) -> tuple:
    """A full snapshot not sent yet, with the times of a later unchanged readback."""
    return (*pending[:MEASURED], unchanged[0], *pending[MEASURED + 1:SAMPLE], unchanged[1],
            *pending[SAMPLE + 1:])


def drive_tuple(st) -> tuple | None:
    """The drive's status as ``CABINET.CORE.DRIVE[]`` shows it, as plain data (or None):
    (name, state, statusword, fault as :func:`error_tuple`, fault code, position, velocity,
    following error, heartbeat ok)."""
    if st is None:
        return None
    fault = st.fault
    return (st.name, st.state.value, st.statusword, error_tuple(fault),
            getattr(fault, "code", None), st.position, st.velocity, st.following_error,
            st.heartbeat_ok)


def bus_figures(can) -> dict | None:
    """The CAN bus's health as plain data (for ``/metrics``): state, error counters, traffic and
    load."""
    bus = getattr(can, "bus", None)
    if bus is None or not hasattr(bus, "health"):
        return None
    h = bus.health()
    traffic = bus.traffic
    return {"state": h.state, "error_frames": h.error_frames, "bus_off": h.bus_off_count,
            "send_failures": h.send_failures, "receive_failures": h.receive_failures,
            "rx_frames": traffic.rx_frames, "tx_frames": traffic.tx_frames, "bits": traffic.bits,
            "bitrate": bus.section.bitrate, "load": bus.bus_load()}


#: s added to the stopping time an orphaned control process waits for (late cycles, jerk).
STOP_MARGIN = 2.0


def orphan_stop_time(axes) -> float:
    """How long an orphaned control process waits for its axes to stop before it powers them
    off: the longest stop from full speed at the configured stop deceleration (``[axes]
    max_velocity`` / ``stop_deceleration``, default 2 × max_acceleration) plus
    :data:`STOP_MARGIN` — never a fixed time a slow-braking axis could outlast."""
    longest = 0.0
    for axis in axes:
        section = axis.section
        stop = section.stop_deceleration or 2 * section.max_acceleration
        longest = max(longest, abs(section.max_velocity) / stop)
    return longest + STOP_MARGIN


def error_tuple(error: BaseException | None):
    """An exception as plain data: (class name, message, number, keyword)."""
    if error is None:
        return None
    if isinstance(error, TcsError):
        return (type(error).__name__, error.message, error.number, error.keyword)
    return ("TcsError", f"{type(error).__name__}: {error}", 13, None)


#: A quiet cycle (every axis unchanged but for its times, nothing else to tell) wakes the
#: sender only every this many SYNC periods: an idle telescope sends 20 batches a second, not
#: 100 (under the idle SYNC every cycle is that long: each one). Any change, event, completion
#: or reply goes at the end of its cycle as before.
QUIET_EVERY = 5


class Outbox:
    """What the loop and the other threads hand to the sender thread (never blocks them)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: list = []          # events, conditions, completions, in order
        self._snapshots: dict = {}      # axis index -> newest readbacks
        self._stats = None
        self._other: collections.deque = collections.deque()  # replies, logs, …
        self._quiet = 0                 # quiet cycles held since the last wake-up
        self.wake = threading.Event()

    def item(self, entry: tuple) -> None:
        with self._lock:
            self._items.append(entry)

    def cycle(self, snapshots: dict, stats, periods: int = 1) -> None:
        """A cycle's readbacks (and counters); ``periods``: SYNC periods it stands for."""
        with self._lock:
            pending = self._snapshots
            for index, snap in snapshots.items():
                old = pending.get(index)
                if old is not None and len(snap) == 2 and len(old) > 2:
                    snap = merge_unchanged(old, snap)  # (the change not sent yet stays)
                pending[index] = snap
            if stats is not None:
                self._stats = stats
            if self._stats is None and not self._items \
                    and all(len(snap) == 2 for snap in pending.values()):
                self._quiet += periods
                if self._quiet < QUIET_EVERY:
                    return  # (held: the next cycle's batch carries the newest times)
            self._quiet = 0
        self.wake.set()

    def message(self, msg: tuple) -> None:
        self._other.append(msg)
        self.wake.set()

    def take(self):
        with self._lock:
            batch = None
            if self._snapshots or self._items or self._stats is not None:
                batch = ("batch", self._snapshots, self._items, self._stats)
                self._snapshots, self._items, self._stats = {}, [], None
        others = []
        while self._other:
            others.append(self._other.popleft())
        return batch, others


class ForwardingHandler(logging.Handler):
    """Log records of this process go to the service's log (journal, CABINET.LOG)."""

    def __init__(self, outbox: Outbox) -> None:
        super().__init__()
        self.outbox = outbox

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            if record.exc_info:
                text += "\n" + logging.Formatter().formatException(record.exc_info)
            self.outbox.message(("log", record.name, record.levelno, text))
        except Exception:
            pass


class CoreAxis(Axis):
    """The control-loop side of an axis in the control process: futures are ids, events,
    error conditions and completions go to the outbox (the service's twin,
    :class:`tcs.axes.control_process.RemoteAxis`, holds the asyncio side)."""

    def __init__(self, index: int, outbox: Outbox, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.index = index
        self.outbox = outbox
        self.received_seq = 0   # newest command put into the queue (receiver thread)
        self.applied_seq = 0    # newest command the loop has taken (a readback is after it)
        self._active: dict[str, int] = {}  # conditions raised here and still active
        self.send_drive = False  # this cycle's snapshot carries the drive status (CORE.DRIVE[])
        self._sent_key: tuple | None = None  # unchanged_key of the last full snapshot

    def receive(self, seq: int, kind: str, value, future_id, cause) -> None:
        with self._lock:
            self._commands.append((kind, value, future_id, cause))
            self.received_seq = seq

    def cycle(self, t: float, now: float, measured: float | None = None) -> None:
        self.applied_seq = self.received_seq  # (taken before the queue is drained: ≤ applied)
        super().cycle(t, now, measured)

    # -- what the base class hands to the asyncio world ------------------------------------
    def emit(self, level: str, number: int, text: str = "", cause=None) -> None:
        self.outbox.item(("event", level, self.module_name, int(number), text, cause))

    def raise_condition(self, name: str, bits: int = 2, text: str = "") -> None:
        self._active[name] = bits
        self.outbox.item(("raise", self.index, name, bits, text))

    def clear_condition(self, name: str) -> None:
        if self._active.pop(name, None) is not None:
            self.outbox.item(("clear", self.index, name))

    def conditions(self) -> dict[str, tuple[int, bool]]:
        return {name: (bits, True) for name, bits in self._active.items()}

    def _flush(self) -> None:
        if self._completions:
            batch, self._completions = self._completions, []
            for future_id, error in batch:
                self.outbox.item(("done", future_id, error_tuple(error)))

    # -- readbacks ---------------------------------------------------------------------------
    def snapshot(self):
        """This cycle's readbacks, for the time the drive measured them (``measured_ut1``)."""
        t = self.measured_ut1
        fault = self._fault
        stale = self.stale
        q = self.queue
        follower = self.follower
        path = None
        if follower is not None and self.motion_state & TRAJECTORY and len(q):
            try:
                path = (*follower.path_sample(t), t)
            except TcsError:  # (emptied meanwhile)
                path = None
        snap = (self.applied_seq, *(getattr(self, name) for name in READBACKS),
                None if stale is None else (stale.message, stale.number),
                None if fault is None else error_tuple(fault),
                self._homing, self._ack_pending,
                (len(q), q.start_time, q.end_time, q.free_points_at(t)),
                None if follower is None else (follower.state.value, follower.end_reason),
                path, drive_tuple(self.last_status) if self.send_drive else None)
        key = unchanged_key(snap)
        if key == self._sent_key and snap[DRIVE] is None:
            return (snap[MEASURED], snap[SAMPLE])  # unchanged: only its times (RemoteAxis.apply)
        self._sent_key = key
        return snap


class Core:
    """Everything of the control process; :meth:`run` is its main thread (the receiver)."""

    def __init__(self, conn: Connection):
        self.conn = conn
        self.outbox = Outbox()
        self.axes: list[CoreAxis] = []
        self.can = None
        self.sims = None
        self.loop = None
        self.bus_lock = None
        self.ut1_utc = 0.0
        self._running = True
        self._stats_every = 10  # nominal SYNC periods between counters (10 times a second)
        self._slots = 0         # nominal periods since the last counters

    def ut1(self) -> float:
        return time.time() + self.ut1_utc

    # -- sender (the only thread that writes to the connection) -------------------------------
    def _sender(self) -> None:
        while self._running or self.outbox.wake.is_set():
            self.outbox.wake.wait(0.5)
            self.outbox.wake.clear()
            batch, others = self.outbox.take()
            try:
                for msg in others:
                    self.conn.send(msg)
                if batch is not None:  # (plain data: pickle's own dumps, not the reducers' pickler)
                    self.conn.send_bytes(pickle.dumps(batch, pickle.HIGHEST_PROTOCOL))
            except (OSError, EOFError, ValueError):
                return  # the service is gone: the receiver sees it too

    # -- set-up --------------------------------------------------------------------------------
    def start(self, config) -> dict:
        """Claim the bus, start the simulated drives, boot, build the axes, start the loop."""
        from tcs.axes.control_loop import ControlLoop
        from tcs.drivers.can_system import CanDrives

        can_section = config.can
        info: dict = {"realtime": False}
        if can_section.realtime_priority > 0:
            try:  # before any thread is made: every thread of this process inherits it
                # one below the cycle thread's own (tcs.drivers.cycle): a woken cycle thread
                # preempts the others at once instead of queueing behind a FIFO peer
                others = os.sched_param(max(1, can_section.realtime_priority - 1))
                os.sched_setscheduler(0, os.SCHED_FIFO, others)
                # and the threads made before this one (receiver, log forwarder): a normal
                # thread holding the interpreter lock, preempted by other processes, would keep
                # the cycle thread waiting for as long as the machine is busy
                for tid in os.listdir("/proc/self/task"):
                    try:
                        os.sched_setscheduler(int(tid), os.SCHED_FIFO, others)
                    except OSError:  # (ended meanwhile)
                        pass
                info["realtime"] = True
                # and they hand the interpreter lock over after 1 ms, not 5: the cycle thread
                # waits for it behind threads of the same process (simulated drives, receiver)
                sys.setswitchinterval(0.001)
            except (OSError, AttributeError) as exc:
                log.warning("control process: real-time priority %d refused (%s); running with "
                            "normal scheduling (grant CAP_SYS_NICE or LimitRTPRIO)",
                            can_section.realtime_priority, exc)
        if can_section.interface != "virtual":
            from tcs.drivers.bus_check import claim
            can = CanDrives.from_config(config)
            self.bus_lock = claim(can)  # held until this process ends (refused: nothing sent)
            self.can = can
        # the bus is ours: the service starts its PLCs and GPS, then lets the drives boot
        self.outbox.message(("claimed",))
        if self.conn.recv()[0] != "boot":
            raise TcsError("control process: the service ended the start")
        if self.can is not None:
            self.can.bus.start_heartbeat()
        else:
            if config.simulation is not None and config.simulation.drives:
                from tcs.sim.drive_network import start_simulated_drives
                self.sims = start_simulated_drives(config)
            self.can = CanDrives.from_config(config)
            self.can.open()
        failures = self.can.boot()
        info["failures"] = {name: error_tuple(e) for name, e in failures.items()}
        info["conditions"] = {name: list(report.conditions)
                              for name, report in self.can.eds_reports.items()}
        for index, (name, section) in enumerate(config.axes.items()):
            self.axes.append(CoreAxis(index, self.outbox, name, section,
                                      self.can.drives[section.drive], None, self.ut1,
                                      can_section.sync_period))
        self.loop = ControlLoop(self.axes, self.can.cycle, self.ut1)
        self.can.cycle.add_callback(self._publish)
        # What start-up made (configuration, EDS, object dictionaries, the simulated drives)
        # lives as long as this process: out of the collector's sight, so that a full
        # collection during the loop walks only what was made since (one over the ~36,000
        # objects of the simulated telescope took 10-15 ms, a cycle and a half)
        gc.collect()
        gc.freeze()
        self.can.start()
        return info

    def _publish(self, cycle) -> None:
        """After the loop's step (same thread): readbacks and counters to the outbox."""
        # counters and CORE.DRIVE[] 10 times a second, also when the idle SYNC (one cycle per
        # `divider` periods) slows the cycle
        periods = self.can.cycle.divider
        self._slots += periods
        drives = self._slots >= self._stats_every
        if drives:
            self._slots = 0
        for axis in self.axes:
            axis.send_drive = drives
        snaps = {axis.index: axis.snapshot() for axis in self.axes}
        stats = None
        if drives:
            stats = dict(self.loop.stats(), last_cycle=self.loop.last_cycle,
                         bus=bus_figures(self.can))
        self.outbox.cycle(snaps, stats, periods)

    # -- receiver ----------------------------------------------------------------------------
    def run(self) -> int:
        """Set up from the first message, serve the service's messages until ``close``."""
        setup = self.conn.recv()
        _, config, self.ut1_utc, level = setup
        root = logging.getLogger()
        root.handlers[:] = [ForwardingHandler(self.outbox)]
        root.setLevel(level)
        sender = threading.Thread(target=self._sender, name="tcs-control-send", daemon=True)
        sender.start()
        try:
            info = self.start(config)
        except BaseException as exc:
            if not isinstance(exc, TcsError):
                log.exception("control process: start failed")
            self.outbox.message(("refused", type(exc).__name__, error_tuple(exc)))
            self._end(sender)
            return 1
        self.outbox.message(("ready", info))
        closed = False
        while True:
            try:
                msg = self.conn.recv()
            except (EOFError, OSError):
                break
            kind = msg[0]
            if kind == "cmd":
                _, index, seq, what, value, future_id, cause = msg
                self.axes[index].receive(seq, what, value, future_id, cause)
            elif kind == "add":
                _, rid, index, times, positions, now = msg
                self._add_points(rid, self.axes[index], times, positions, now)
            elif kind == "ut1_utc":
                self.ut1_utc = float(msg[1])
            elif kind == "samples":
                self.outbox.message(("reply", msg[1], True, self.loop.samples(msg[2])))
            elif kind == "close":
                closed = True
                break
        if closed:
            self._close()
        else:
            self._orphaned()
        self._end(sender)
        return 0

    def _add_points(self, rid, axis: CoreAxis, times, positions, now) -> None:
        try:
            result = axis.queue.add_points(times, positions, now)
        except TcsError as exc:
            self.outbox.message(("reply", rid, False, error_tuple(exc)))
            return
        q = axis.queue
        summary = (len(q), q.start_time, q.end_time, q.free_points_at(self.ut1()))
        self.outbox.message(("reply", rid, True, (tuple(result), summary)))

    # -- the end -------------------------------------------------------------------------------
    def _close(self) -> None:
        """The service stops (it stopped and powered off the axes first): release the
        drives (no faults left behind), close the bus, stop the simulated drives."""
        try:
            if self.can is not None:
                self.can.release()
                self.can.close()
        finally:
            if self.sims is not None:
                self.sims.stop()
        self.outbox.message(("closed",))

    def _orphaned(self) -> None:
        """The service died: stop every axis (controlled), power it off, leave the bus. Its log
        went to the service: from now on to stderr (under systemd: the journal)."""
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        logging.getLogger().handlers[:] = [handler]
        log.critical("control process: the service is gone; stopping and powering off every axis")
        for axis in self.axes:
            axis.receive(axis.received_seq, "stop", None, None, None)
        deadline = time.monotonic() + orphan_stop_time(self.axes)
        while time.monotonic() < deadline and any(a.motion_state & 1 for a in self.axes):
            time.sleep(0.02)
        for axis in self.axes:
            axis.receive(axis.received_seq, "power", False, None, None)
        deadline = time.monotonic() + max(
            (getattr(a.drive, "power_timeout", 0.0) for a in self.axes), default=0.0) + STOP_MARGIN
        while time.monotonic() < deadline and any(a.power_state != 0.0 for a in self.axes):
            time.sleep(0.02)
        log.critical("control process: axes stopped and powered off: %s", ", ".join(
            f"{a.name} {'stopped' if not a.motion_state & 1 else 'MOVING'} "
            f"{'off' if a.power_state == 0.0 else 'ON'}" for a in self.axes) or "none")
        if self.can is not None:
            self.can.close()  # not released: the drives record the lost master
        if self.sims is not None:
            self.sims.stop()

    def _end(self, sender: threading.Thread) -> None:
        self._running = False
        self.outbox.wake.set()
        sender.join(5.0)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # Ctrl-C in a terminal and systemd's SIGTERM reach the whole process group: the service
    # stops the motion first and then ends this process itself ("close"); if the service is
    # gone instead, the closed socket tells (see Core._orphaned).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    conn = Connection(int(argv[0]))
    try:
        return Core(conn).run()
    finally:
        conn.close()


if __name__ == "__main__":
    code = main()
    # (a start that failed half-way may leave a bus or simulator thread behind: end anyway)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
