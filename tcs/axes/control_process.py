"""The service's end of the control process (``[can] control_process = true``).

:class:`ControlProcess` starts :mod:`tcs.axes.control_core` as a child process, hands it the
hardware configuration and waits until it has claimed the bus, booted the drives and started
the loop. Then the telescope model builds one :class:`RemoteAxis` per ``[axes]`` entry: the
asyncio side of :class:`~tcs.axes.axis.Axis` unchanged (every check a SET makes before
anything moves runs here, at once, on the newest readbacks), with its command queue on the
other side of a socket instead of a lock. The loop side — the drive, the planner, the follower,
the trajectory queue — lives in the child.

Threads here: the event loop sends commands (one lock around the connection); the
``tcs-control-recv`` thread receives, applies each cycle's readbacks to the axes, then hands
events to the event hub, error conditions to the axes' health and completions to the event
loop (``call_soon_threadsafe``), in the child's order. ``TRAJECTORY.ADDPOINTS`` is a short
round trip (the child's receiver adds the points under the queue's own lock and answers with
the queue's new size), so a refusal is the SET's reply as before.

If the child ends on its own (a crash, kill -9), the service stays up and its clients stay
connected:

1. every axis reads stale (``FAILED 4``) and gets a latched ``control process`` error
   (ERROR_STATE, STATUS.LIST); pending SETs fail;
2. the drives stop themselves: their RPDO deadline (``master_loss_timeout``, see
   :func:`tcs.drivers.boot.master_loss_writes`) passes and they quick-stop at 0x6085, capped at
   the axis's stop deceleration; the service also commands that quick stop itself on any
   path it still has (:meth:`ControlProcess.quick_stop_all`: on a socketcand or socketcan
   bus, a controlword *quick stop* by SDO to every drive; a ``virtual`` bus died with the
   child);
3. the child is started again in place (:meth:`ControlProcess._respawn`): it claims the bus,
   boots and takes the drives over (:mod:`tcs.drivers.takeover`: a drive still powered is
   stopped and disabled), the same axis objects read its readbacks; every drive is off and
   drive faults stay until an operator acknowledges them (``ERROR_STATE=0``), the
   ``control process`` error too — nothing moves until commanded. During the respawn the
   watchdog stays fed (the service works on it); after :data:`RESPAWN_TRIES` failed starts
   :meth:`RemoteLoop.healthy` turns false and systemd restarts the whole service.
"""

from __future__ import annotations

import asyncio
import bisect
import itertools
import logging
import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection
from types import SimpleNamespace

import tcs.errors as errors_module
from tcs.axes import trajectory as trajectory_module
from tcs.axes.axis import Axis, complete_futures
from tcs.axes.control_core import READBACKS
from tcs.axes.trajectory import AddResult
from tcs.drivers.drive import DriveState, DriveStatus
from tcs.errors import CommunicationError, ErrorNumber, TcsError
from tcs.state_epoch import bump as bump_epoch

log = logging.getLogger(__name__)

START_TIMEOUT = 120.0  # s for the child to boot every drive and start (boot timeouts are per drive)
REPLY_TIMEOUT = 5.0    # s for a round trip (TRAJECTORY points, figures)
CLOSE_TIMEOUT = 30.0   # s for the child to release the drives and end
RESPAWN_TRIES = 3      # starts of a new control process after a crash before giving up
RESPAWN_BACKOFF = 2.0  # s between them


def rebuild_error(data) -> TcsError | None:
    """The exception of :func:`tcs.axes.control_core.error_tuple`, same class where known."""
    if data is None:
        return None
    name, message, number, keyword = data
    from tcs.drivers import bus_check
    cls = None
    for module in (errors_module, trajectory_module, bus_check):
        cls = cls or getattr(module, name, None)
    if not (isinstance(cls, type) and issubclass(cls, TcsError)):
        cls = TcsError
    error = cls.__new__(cls)
    Exception.__init__(error, message)
    error.message, error.number, error.keyword = message, int(number), keyword
    return error


class ControlProcessGone(CommunicationError):
    pass


class ControlProcess:
    """The child process and the connection to it (see the module docstring)."""

    def __init__(self, config, local, events):
        self.config = config
        self.local = local          # LocalTime: UT1−UTC is sent to the child when it changes
        self.events = events
        self.axes: list[RemoteAxis] = []
        self.info: dict = {}
        self.proc: subprocess.Popen | None = None
        self.conn: Connection | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self._send_lock = threading.Lock()
        self._ids = itertools.count(1)
        self._futures: dict[int, asyncio.Future] = {}
        self._replies: dict[int, list] = {}
        self._reply_ready = threading.Condition()
        self._reader: threading.Thread | None = None
        self._closed = threading.Event()
        self._gone: TcsError | None = None
        self._ut1_utc_sent: float | None = None
        self.stats: dict = {}
        self._attach_lock = threading.Lock()
        self._early: list = []      # conditions from the child before the axes were attached
        self._closing = False       # close() was called: no respawn
        self._recovery: threading.Thread | None = None
        self.respawning = False     # a new child is being started after a crash
        self.respawns = 0
        self.given_up = False       # RESPAWN_TRIES starts failed

    # -- start -------------------------------------------------------------------------------
    def claim(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start the child; it opens the bus and, on a shared bus, listens for another master
        before it sends anything (blocking: call it off the event loop).

        Raises
        ------
        AnotherMaster, TcsError
            What the child refused with (another master on the bus, a drive configuration
            its EDS rejects, a bus that cannot be opened …), or that it did not start.
        """
        self.loop = loop
        parent, child = socket.socketpair()
        try:
            # -P: the working directory is not put on the child's sys.path (a folder named
            # tcs there, such as <state>/tcs/<file> or a clone's parent, would shadow the package)
            self.proc = subprocess.Popen(
                [sys.executable, "-P", "-m", "tcs.axes.control_core", str(child.fileno())],
                pass_fds=(child.fileno(),), close_fds=True)
        finally:
            child.close()
        self.conn = Connection(parent.detach())
        self._ut1_utc_sent = self.local.ut1_utc
        self.conn.send(("setup", self.config, self._ut1_utc_sent, logging.getLogger().getEffectiveLevel()))
        self._expect("claimed")

    def boot(self) -> dict:
        """Let the child boot the drives and start the loop; returns what it reports
        (``failures``: drives that did not boot, ``conditions``: EDS warnings, ``realtime``)."""
        self.conn.send(("boot",))
        self.info = self._expect("ready")
        self._reader = threading.Thread(target=self._read, name="tcs-control-recv", daemon=True)
        self._reader.start()
        return self.info

    def _expect(self, what: str):
        """Wait for the child's ``what`` message (its log lines are logged meanwhile)."""
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not self.conn.poll(remaining):
                self._kill()
                raise TcsError(f"control process did not start within {START_TIMEOUT:g} s",
                               ErrorNumber.TIMEOUT)
            try:
                msg = self.conn.recv()
            except (EOFError, OSError):
                self._kill()
                raise TcsError("control process ended while starting (see the log)",
                               ErrorNumber.LIBFAIL) from None
            if msg[0] == "log":
                self._log(msg)
            elif msg[0] == what:
                return msg[1] if len(msg) > 1 else None
            elif msg[0] == "refused":
                self._wait_exit(5.0)
                self.proc = None
                raise rebuild_error(msg[2])

    # -- commands ----------------------------------------------------------------------------
    def send(self, msg: tuple) -> None:
        if self._gone is not None:
            raise self._gone
        try:
            with self._send_lock:
                self.conn.send(msg)
        except (OSError, ValueError):
            raise ControlProcessGone("CABINET", "the control process has ended") from None

    def command(self, axis: int, seq: int, kind: str, value, future, cause) -> None:
        future_id = None
        if future is not None:
            future_id = next(self._ids)
            self._futures[future_id] = future
        try:
            self.send(("cmd", axis, seq, kind, value, future_id, cause))
        except TcsError as exc:
            self._futures.pop(future_id, None)
            if future is not None and not future.done():
                future.set_exception(exc)

    def call(self, kind: str, *args):
        """A round trip to the child's receiver; returns the value or raises its error."""
        rid = next(self._ids)
        with self._reply_ready:
            self._replies[rid] = None
        self.send((kind, rid, *args))
        deadline = time.monotonic() + REPLY_TIMEOUT
        with self._reply_ready:
            while self._replies.get(rid) is None and self._gone is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    self._replies.pop(rid, None)
                    raise TcsError(f"control process did not answer within {REPLY_TIMEOUT:g} s",
                                   ErrorNumber.TIMEOUT)
                self._reply_ready.wait(remaining)
            reply = self._replies.pop(rid, None)
        if reply is None:
            raise self._gone
        ok, value = reply
        if not ok:
            raise rebuild_error(value)
        return value

    # -- receiving -----------------------------------------------------------------------------
    def _read(self) -> None:
        conn = self.conn
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            except Exception:
                log.exception("control process: unreadable message")
                continue
            kind = msg[0]
            try:
                if kind == "batch":
                    self._batch(msg[1], msg[2], msg[3])
                elif kind == "reply":
                    with self._reply_ready:
                        if msg[1] in self._replies:
                            self._replies[msg[1]] = (msg[2], msg[3])
                            self._reply_ready.notify_all()
                elif kind == "log":
                    self._log(msg)
                elif kind == "closed":
                    self._closed.set()
            except Exception:
                log.exception("control process: handling %s failed", kind)
        if not self._closed.is_set() and conn is self.conn:
            self._lost()

    def _batch(self, snapshots: dict, items: list, stats) -> None:
        # (the child's loop runs before the model has built the axes: a start-up batch
        # carries readbacks and statistics, which are kept, and nothing for an axis)
        if stats is not None:
            self.stats = stats
        axes = self.axes
        for index, snap in snapshots.items():
            if index < len(axes):
                axes[index].apply(snap)
        bump_epoch()  # (after: a GET reply kept meanwhile is not used again)
        loop = self.loop
        done = []
        for item in items:
            what = item[0]
            if what == "event":
                _, level, source, number, text, cause = item
                self.events.emit(level, source, number, text, cause)
            elif what == "done":
                future = self._futures.pop(item[1], None)
                if future is not None:
                    done.append((future, rebuild_error(item[2])))
            elif what in ("raise", "clear"):
                with self._attach_lock:
                    if item[1] >= len(self.axes):  # (before attach: replayed by attach)
                        self._early.append(item)
                        continue
                self._condition(item)
        if done and loop is not None:
            try:
                loop.call_soon_threadsafe(complete_futures, done)
            except RuntimeError:
                pass
        ut1_utc = self.local.ut1_utc
        if ut1_utc != self._ut1_utc_sent:
            self._ut1_utc_sent = ut1_utc
            try:
                self.send(("ut1_utc", ut1_utc))
            except TcsError:
                pass

    def _condition(self, item) -> None:
        if item[0] == "raise":
            self.axes[item[1]].raise_condition(item[2], item[3], item[4])
        else:
            self.axes[item[1]].clear_condition(item[2])

    def attach(self, axes: list) -> None:
        """The model's axes, by index; error conditions the child raised before they
        existed are applied now, in order."""
        with self._attach_lock:
            self.axes = axes
            early, self._early = self._early, []
        for item in early:
            self._condition(item)

    @staticmethod
    def _log(msg) -> None:
        _, name, level, text = msg
        logging.getLogger(name).log(level, "%s", text)

    def _lost(self) -> None:
        """The child ended without being asked: nothing moves under our control any more."""
        error = ControlProcessGone("CABINET", "the control process has ended: the drives "
                                   "stop by themselves; a new one is started (acknowledge "
                                   "with ERROR_STATE=0)")
        self._gone = error
        code = self.proc.poll() if self.proc is not None else None
        log.critical("control process ended (exit status %s): every axis is stale; the drives "
                     "stop by themselves when the setpoints stop", code)
        for axis in self.axes:
            axis.stale = error
            axis.raise_condition("control process", 2, error.message)
        bump_epoch()  # every axis reads stale from now on (tcs.state_epoch)
        pending, self._futures = list(self._futures.values()), {}
        with self._reply_ready:
            self._reply_ready.notify_all()
        if self.loop is not None and pending:
            try:
                self.loop.call_soon_threadsafe(complete_futures, [(f, error) for f in pending])
            except RuntimeError:
                pass
        if not self._closing:
            self.respawning = True
            self._recovery = threading.Thread(target=self._recover, name="tcs-control-respawn",
                                              daemon=True)
            self._recovery.start()

    # -- after a crash -------------------------------------------------------------------------
    def quick_stop_all(self) -> int:
        """Command *quick stop* (controlword 0x0002 by expedited SDO) to every drive of the
        hardware file over a bus connection of this process's own — the path the service
        still has when the control process died (blocking; ``virtual``: none, 0 sent).
        Returns the number of drives it was sent to."""
        can_section = self.config.can
        if can_section.interface == "virtual":
            return 0
        import can as python_can
        from tcs.drivers.canbus import probe_socketcand
        try:
            if can_section.interface == "socketcand":
                probe_socketcand(can_section.host, can_section.port)
            bus = python_can.Bus(**can_section.bus_kwargs())
        except Exception as exc:
            log.error("quick stop after the crash: cannot open the bus (%s); the drives stop "
                      "by their own watch of the master", exc)
            return 0
        sent = 0
        try:
            for section in self.config.drives.values():
                frame = bytes([0x2B, 0x40, 0x60, 0x00, 0x02, 0x00, 0x00, 0x00])
                try:
                    bus.send(python_can.Message(arbitration_id=0x600 + section.node_id, data=frame,
                                                is_extended_id=False))
                    sent += 1
                except Exception as exc:
                    log.error("quick stop of node %d failed: %s", section.node_id, exc)
        finally:
            try:
                bus.shutdown()
            except Exception:
                pass
        log.warning("quick stop commanded to %d drives over a bus connection of the service", sent)
        return sent

    def _recover(self) -> None:
        """(thread) Stop the drives, then start a new control process in place."""
        try:
            self.quick_stop_all()
            for attempt in range(1, RESPAWN_TRIES + 1):
                if self._closing:
                    return
                try:
                    self._respawn()
                    return
                except Exception as exc:
                    log.error("control process: restart %d of %d failed: %s", attempt,
                              RESPAWN_TRIES, exc)
                    time.sleep(RESPAWN_BACKOFF)
            self.given_up = True
            log.critical("control process could not be restarted; giving up (the systemd "
                         "watchdog is withheld: restart tcs-server)")
        finally:
            self.respawning = False

    def _respawn(self) -> None:
        """Start a new child, let it claim the bus and take the drives over, attach the axes."""
        from tcs.model.health import ERROR, WARNING
        if self.proc is not None:
            self._wait_exit(5.0)
        try:
            self.conn.close()
        except OSError:
            pass
        reader = self._reader
        if reader is not None and reader is not threading.current_thread():
            reader.join(5.0)
        self._reader = None
        self._closed.clear()
        self.stats = {}
        log.warning("control process: starting a new one (the drives are taken over; faults "
                    "stay until acknowledged, nothing moves until commanded)")
        self.claim(self.loop)
        for axis in self.axes:
            axis.respawned()
        info = self.boot()  # (readbacks from here on; the axes read fresh again)
        self.info = info
        self._gone = None
        self.respawns += 1
        for axis in self.axes:
            failure = info.get("failures", {}).get(axis.section.drive)
            if failure is not None:
                axis.raise_condition("drive offline", ERROR, rebuild_error(failure).message)
            for condition, text in info.get("conditions", {}).get(axis.section.drive, ()):
                axis.raise_condition(condition, WARNING, text)
            axis.clear_condition("control process")  # (latched until ERROR_STATE=0)
        log.warning("control process restarted (pid %d)", self.proc.pid)

    # -- figures -------------------------------------------------------------------------------
    def samples(self, clear: bool = False):
        """(lateness list, loop time list, cycle counters) of the child's cycle source."""
        return self.call("samples", clear)

    # -- the end -------------------------------------------------------------------------------
    def release(self) -> None:
        """(Done by :meth:`close` in the child: the drives are released before the bus closes.)"""

    def close(self) -> None:
        """Ask the child to release the drives, close the bus and end (blocking)."""
        self._closing = True
        recovery = self._recovery
        if recovery is not None and recovery is not threading.current_thread():
            recovery.join(START_TIMEOUT + 10.0)  # (a respawn under way ends first)
        if self.proc is None:
            return
        if self._reader is None:  # claimed the bus but never booted (the start failed later)
            try:
                self.conn.send(("close",))
            except OSError:
                pass
            self._wait_exit(10.0)
            self.conn.close()
            self.proc = None
            return
        if self._gone is None and self.proc.poll() is None:
            try:
                self.send(("close",))
                self._closed.wait(CLOSE_TIMEOUT)
            except TcsError:
                pass
        self._wait_exit(CLOSE_TIMEOUT if self._closed.is_set() else 1.0)
        if self._reader is not None:
            self._reader.join(5.0)
        try:
            self.conn.close()
        except OSError:
            pass
        self.proc = None

    def _wait_exit(self, timeout: float) -> None:
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            log.error("control process did not end; killing it")
            self._kill()

    def _kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class RemoteQueue:
    """``axis.queue`` of a :class:`RemoteAxis`: points go to the child's queue, sizes and
    times are the child's (from each cycle's readbacks and each ADDPOINTS answer)."""

    def __init__(self, process: ControlProcess, index: int, capacity: int):
        self.process = process
        self.index = index
        self.capacity = capacity
        self.summary = (0, None, None, capacity)  # len, start, end, free points
        #: the points sent since the child's queue was last empty, for :meth:`sample`
        self._mirror_t: list[float] = []
        self._mirror_p: list[float] = []

    def __len__(self) -> int:
        return self.summary[0]

    def sample(self, t: float, freeze: bool = False) -> tuple[float, float, float]:
        """The queued path at ``t`` from the points sent (what the safety envelope judges before
        RUN=1): linear between the points, held outside them; the child's queue itself
        interpolates more smoothly, which the envelope's margin covers. No points: NOPOINTS."""
        ts, ps = self._mirror_t, self._mirror_p
        if not ts or not self.summary[0]:
            raise TcsError("trajectory queue is empty", ErrorNumber.NOPOINTS)
        if t <= ts[0]:
            return ps[0], 0.0, 0.0
        if t >= ts[-1]:
            return ps[-1], 0.0, 0.0
        i = bisect.bisect_right(ts, t) - 1
        v = (ps[i + 1] - ps[i]) / (ts[i + 1] - ts[i])
        return ps[i] + v * (t - ts[i]), v, 0.0

    @property
    def start_time(self):
        return self.summary[1]

    @property
    def end_time(self):
        return self.summary[2]

    @property
    def free_points(self) -> int:
        return self.capacity - self.summary[0]

    def free_points_at(self, now: float) -> int:
        return self.summary[3]

    def remaining(self, now: float) -> float:
        end = self.summary[2]
        return max(0.0, end - now) if end is not None and self.summary[0] else 0.0

    def add_points(self, times, positions, now: float | None = None) -> AddResult:
        times, positions = [float(x) for x in times], [float(x) for x in positions]
        was_empty = not self.summary[0]
        result, summary = self.process.call("add", self.index, times, positions, now)
        self.summary = summary
        added = AddResult(*result)
        if was_empty:
            self._mirror_t, self._mirror_p = [], []
        if added.accepted:
            # (the accepted ones are the batch's last: points already past are dropped first)
            self._mirror_t += times[len(times) - added.accepted:]
            self._mirror_p += positions[len(positions) - added.accepted:]
        start = self.summary[1]
        if start is not None:  # what the child's queue already dropped (a night of tracking)
            drop = max(0, bisect.bisect_left(self._mirror_t, start) - 1)
            if drop:
                del self._mirror_t[:drop], self._mirror_p[:drop]
        return added


class RemoteFollower:
    """``axis.follower`` of a :class:`RemoteAxis`: the child follower's state and path."""

    def __init__(self, queue: RemoteQueue) -> None:
        self.queue = queue
        self.state = SimpleNamespace(value="idle")
        self.end_reason: str | None = None
        self.path = None  # (position, velocity, UT1) of the path at the last readback

    def path_position(self, t: float) -> float:
        path = self.path
        if path is None:
            raise TcsError("trajectory queue is empty", ErrorNumber.NOPOINTS)
        p, v, t0 = path
        return p + v * (t - t0)

    @property
    def running(self) -> bool:
        return self.state.value in ("intercepting", "following")

    def runtime(self, t: float) -> float:
        return self.queue.remaining(t) if self.running else 0.0


class RemoteAxis(Axis):
    """The asyncio side of an axis whose loop side runs in the control process."""

    def __init__(self, process: ControlProcess, index: int, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.process = process
        self.index = index
        self.queue = RemoteQueue(process, index, self.section.trajectory_buffer)
        if self.follower is not None:
            self.follower = RemoteFollower(self.queue)
        self._seq = 0
        self._reference_seq = 0
        self._stale_key = None

    def respawned(self) -> None:
        """A new control process counts commands from 0; its first readback sets ``stale``."""
        self._seq = 0
        self._reference_seq = 0
        self._stale_key = ()

    def _send(self, kind: str, value=None, future=None) -> None:
        from tcs.model.events import current_cause
        self._seq += 1
        if kind == "reference":
            self._reference_seq = self._seq  # REFERENCED reads 0 from now on (set by reference())
        self.process.command(self.index, self._seq, kind, value, future, current_cause.get())

    def cycle(self, t: float, now: float, measured: float | None = None) -> None:
        raise RuntimeError("a RemoteAxis is stepped in the control process")

    def drive_status(self) -> DriveStatus | None:
        """The drive's status from the child's readbacks (``CABINET.CORE.DRIVE[]``, ten
        times a second); None once the control process is gone (never the last value)."""
        raw = getattr(self, "_drive_readback", None)
        if raw is None or self.process._gone is not None:
            return None
        name, state, statusword, fault, code, position, velocity, following, hb_ok = raw
        error = rebuild_error(fault)
        if error is not None and code is not None:
            error.code = code
        return DriveStatus(name, DriveState(state), position=position, velocity=velocity,
                           following_error=following, statusword=statusword, fault=error,
                           heartbeat_ok=hb_ok)

    def apply(self, snap) -> None:
        """One cycle's readbacks from the child (receiver thread): a full snapshot, or
        ``(measured_ut1, sample)`` when nothing but the times changed since the last full one
        (:meth:`tcs.axes.control_core.CoreAxis.snapshot`)."""
        if len(snap) == 2:
            self.measured_ut1, self.sample = snap
            return
        applied = snap[0]
        values = snap[1:1 + len(READBACKS)]
        stale, fault, homing, ack, queue, follower, path, drive = snap[1 + len(READBACKS):]
        if drive is not None:
            self._drive_readback = drive
        for name, value in zip(READBACKS, values):
            if name == "referenced" and applied < self._reference_seq:
                continue  # the child has not taken the REINIT yet: it still reads the old value
            setattr(self, name, value)
        if stale != self._stale_key:
            self._stale_key = stale
            self.stale = None if stale is None else rebuild_error(("CommunicationError", *stale, None))
        if (None if self._fault is None else (self._fault.message, self._fault.number)) != \
                (None if fault is None else (fault[1], fault[2])):
            self._fault = rebuild_error(fault)
        self._homing, self._ack_pending = homing, ack
        self.queue.summary = queue
        if follower is not None and self.follower is not None:
            self.follower.state = SimpleNamespace(value=follower[0])
            self.follower.end_reason = follower[1]
            self.follower.path = path


class RemoteLoop:
    """``telescope.control_loop`` when the loop runs in the control process."""

    def __init__(self, process: ControlProcess, period: float):
        self.process = process
        self.period = period

    @property
    def alive(self) -> bool:
        """False while no control process runs (nothing to wait for at stop)."""
        return self.process._gone is None

    def stats(self) -> dict:
        s = dict(self.process.stats)
        s.pop("last_cycle", None)
        s.setdefault("realtime", int(bool(self.process.info.get("realtime"))))
        return s

    def healthy(self, max_age_periods: float = 10.0, within: float | None = None) -> bool:
        """As :meth:`tcs.axes.control_loop.ControlLoop.healthy`, from the child's statistics
        (its monotonic clock is this one's)."""
        process = self.process
        if process.respawning:
            return True  # a new control process is being started (bounded: RESPAWN_TRIES)
        last = process.stats.get("last_cycle")
        if process._gone is not None or last is None:
            return False
        # (stats come every 10th cycle: allow for that)
        age = max_age_periods * self.period if within is None else within
        return time.monotonic() - last < age + 10 * self.period

    def samples(self, clear: bool = False):
        return self.process.samples(clear)
