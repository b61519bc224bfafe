"""The simulator's side of one CAN bus: receive dispatch, sending and one timer thread.

Every simulated node on a bus shares one :class:`SimCanPort`, so a bus with N drives costs
one receive thread (a python-can ``Notifier``, or the notifier of a canopen ``Network`` the
port was given) and one timer thread, whatever N is.

* ``subscribe(cob_id, callback)`` — ``callback(cob_id, data: bytes)`` runs in the receive
  thread for every frame with that identifier.
* ``send(cob_id, data)`` — thread-safe.
* ``call_later(delay, callback)`` / ``call_every(period, callback)`` — run ``callback()`` in
  the timer thread (real time: heartbeats, boot delays); they return a handle whose
  ``cancel()`` stops it. A periodic timer runs on the grid of its period (multiples of it on
  the monotonic clock), so timers of one period — every drive's heartbeat — and the poll
  share one wake-up of the timer thread instead of one each.
* ``add_poller(callback)`` runs ``callback()`` every :data:`POLL_PERIOD`, all the pollers of
  the bus in one wake-up. A poller returns whether it needs that rate: when none does (every
  drive of the bus rests: no power stage, nothing moving, nothing changed lately) the poll
  slows to :data:`REST_POLL_PERIOD` (``poll_period`` tells which); a node that changes
  (a new RPDO payload, an SDO request, NMT, fault injection) calls ``hurry()``, and the full
  rate is back from the next :data:`POLL_PERIOD` grid point. A resting bus of seven drives
  then wakes the simulator a fifth as often (issue 27: the idle simulated telescope's wake-ups
  preempted the TPL2 server's requests).
* ``lock`` — one re-entrant lock held around every callback (received frames and timers), so
  the nodes' state is only ever touched by one thread at a time; code outside the port that
  touches a node (tests, fault injection) takes it too.
* Host stalls — real drive hardware never stops; the simulator's threads do when their host
  is busy (or the process is stopped). The port notices: when none of its threads ran for
  more than :data:`HOST_STALL` s (the gap between two wake-ups of the poll timer or the
  receive thread; normally at most a :data:`REST_POLL_PERIOD`), or a frame is handled more
  than :data:`HOST_STALL` s after it was sent (the receive thread fell behind), it counts a
  stall in ``stalls`` (``last_stall``: its length). The nodes restart their supervision windows on it (see
  :class:`tcs.sim.cia402_drive.SimDrive`). ``receive_backlog()`` tells whether frames wait
  unread (python-can's ``virtual`` bus; 0 where it cannot be known). ``awake`` is the port's
  *awake clock* (s): real time, except that a wake-up later than :data:`AWAKE_STEPS` poll
  periods counts only that much — on a starved host (where a master in the same
  process starves as well) supervision windows measured on it run slower, on an idle host at
  real speed.

Ports are made by :func:`open_port` from a python-can bus, a canopen ``Network``, an existing
port, or a dict of ``can.Bus`` keyword arguments; ports made for the same bus object are
shared and reference-counted (``release`` closes what the port opened when the last user is
gone; a bus or network handed in by the caller is never shut down).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import can

from tcs.virtual_can import open_bus

log = logging.getLogger(__name__)

FrameCallback = Callable[[int, bytes], None]

#: Seconds the receive thread waits for a frame before checking whether it must stop.
RECEIVE_CYCLE = 0.05
#: Real-time period (s) of the pollers (one timer wake-up for all the nodes of a bus).
POLL_PERIOD = 0.01
#: The pollers' period (s) while none of them needs :data:`POLL_PERIOD` (a resting bus).
REST_POLL_PERIOD = 0.05
#: A gap (s) in the port's own threads longer than this is a stall of the simulator's host.
HOST_STALL = 0.1
#: The longest a received frame's wait (its send stamp to its handling) is taken as real: a
#: longer one comes from a stamp of another clock (a gateway's)
MAX_FRAME_LAG = 5.0
#: Most the awake clock advances from one wake-up of the port's threads to the next, in
#: periods of the poll (the slower one's while the bus rests).
AWAKE_STEPS = 2


def _next_on_grid(t: float, period: float) -> float:
    """The first multiple of ``period`` after ``t`` (by more than a microsecond: a timer that
    ran a hair early does not run twice)."""
    return (math.floor((t + 1e-6) / period) + 1) * period


class TimerHandle:
    """A scheduled timer callback; ``cancel()`` makes sure it never runs again."""

    __slots__ = ("callback", "period", "cancelled")

    def __init__(self, callback: Callable[[], None], period: float | None):
        self.callback = callback
        self.period = period
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class _Receiver(can.Listener):
    """The port's notifier listener. A receive error (a kernel interface taken down and up
    again: "Network is down") is logged and survived, as a real drive survives it: without
    ``on_error`` python-can ends the receive thread, and every simulated node of the port
    went deaf for good — and reported the master's heartbeat lost (0x8130) at once."""

    def __init__(self, port: SimCanPort):
        self._port = port
        self._last_error = 0.0

    def on_message_received(self, msg: can.Message) -> None:
        self._port._on_message(msg)

    def on_error(self, exc: Exception) -> None:
        now = time.monotonic()
        if now - self._last_error > 5.0:
            log.warning("simulated bus: receive failed (%s); still listening", exc)
        self._last_error = now
        time.sleep(0.05)  # a bus that stays down must not spin the thread

    def stop(self) -> None:
        pass


class SimCanPort:
    """One simulated bus attachment shared by every simulated node on it.

    Use :func:`open_port` rather than the constructor.
    """

    def __init__(self, bus: can.BusABC | None = None, network: Any = None, owns_bus: bool = False):
        self.lock = threading.RLock()
        self._bus = bus
        self._network = network
        self._owns_bus = owns_bus
        self._subscribers: dict[int, list[FrameCallback]] = {}
        self._heap: list[tuple[float, int, TimerHandle]] = []
        self._seq = itertools.count()
        self._cond = threading.Condition()
        self._closed = False
        self._users = 0
        self._send_lock = threading.Lock()
        self._pollers: list[Callable[[], object]] = []
        self._poll_timer: TimerHandle | None = None
        self.poll_period = POLL_PERIOD  # the pollers' period now (POLL_PERIOD or REST_POLL_PERIOD)
        self._awake_step = AWAKE_STEPS * POLL_PERIOD
        self._notifier: can.Notifier | None = None
        if network is not None:
            self._bus = None
        elif bus is not None:
            self._notifier = can.Notifier(bus, [_Receiver(self)], timeout=RECEIVE_CYCLE)
        name = getattr(bus, "channel_info", None) or "network"
        self._timer = threading.Thread(target=self._timer_loop, name=f"sim-can-timer {name}", daemon=True)
        self._timer.start()
        self.frames_sent = 0
        self.send_errors = 0
        self.stalls = 0            # host stalls noticed (see the module docstring)
        self.last_stall = 0.0      # length of the latest one, s
        self.last_gap = 0.0        # of it, the time no thread of the port ran at all, s
        self._alive: float | None = None  # monotonic time a port thread last ran
        self._stall_noted = float("-inf")  # when the latest stall was counted
        self.awake = 0.0  # the awake clock (see the module docstring)
        self._frame_stamp = 0.0  # the wall-clock send time of the frame being handled, 0: unknown
        self._in_hand = 0  # frames the receive thread took from the queue and has not handled

    # -- receive -----------------------------------------------------------------------------
    def subscribe(self, cob_id: int, callback: FrameCallback) -> None:
        """Call ``callback(cob_id, data)`` in the receive thread for frames with ``cob_id``."""
        with self.lock:
            callbacks = self._subscribers.setdefault(cob_id, [])
            if callback not in callbacks:
                callbacks.append(callback)
                if self._network is not None:
                    self._network.subscribe(cob_id, self._on_network_frame)

    def unsubscribe(self, cob_id: int, callback: FrameCallback) -> None:
        with self.lock:
            callbacks = self._subscribers.get(cob_id, [])
            if callback in callbacks:
                callbacks.remove(callback)
            if not callbacks:
                self._subscribers.pop(cob_id, None)
                if self._network is not None:
                    try:
                        self._network.unsubscribe(cob_id, self._on_network_frame)
                    except (KeyError, ValueError):
                        pass

    def _on_message(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        self._dispatch(msg.arbitration_id, bytes(msg.data), msg.timestamp or 0.0)

    def _on_network_frame(self, cob_id: int, data: bytearray, timestamp: float) -> None:
        self._dispatch(cob_id, bytes(data))

    @property
    def frame_lag(self) -> float:
        """How long the frame being handled has waited since it was sent, s, read now (a node
        takes its own clock in the same expression: a SYNC is handled as of when it was sent);
        0 where unknown or stamped by another clock. Receive thread, under the lock."""
        stamp = self._frame_stamp
        lag = time.time() - stamp if stamp else 0.0
        return lag if 0.0 < lag < MAX_FRAME_LAG else 0.0

    def _dispatch(self, cob_id: int, data: bytes, stamp: float = 0.0) -> None:
        self._in_hand += 1  # (taken from the queue, not handled yet: receive_backlog)
        try:
            self._dispatch_locked(cob_id, data, stamp)
        finally:
            self._in_hand -= 1

    def _dispatch_locked(self, cob_id: int, data: bytes, stamp: float) -> None:
        with self.lock:
            if self._closed:
                return
            # (the wait is taken inside the lock: a wait for it — another thread of the
            # simulator holding it — is part of how long the frame waited unread)
            self._note_alive(time.time() - stamp if stamp else 0.0)
            self._frame_stamp = stamp
            for callback in list(self._subscribers.get(cob_id, ())):
                try:
                    callback(cob_id, data)
                except Exception:  # a simulator bug must not kill the receive thread
                    log.exception("simulated node failed handling frame 0x%03X", cob_id)

    # -- send --------------------------------------------------------------------------------
    def send(self, cob_id: int, data: bytes | bytearray) -> None:
        """Put one standard frame on the bus (never raises: a full queue is logged)."""
        try:
            if self._network is not None:
                self._network.send_message(cob_id, bytes(data))
            elif self._bus is not None:
                msg = can.Message(arbitration_id=cob_id, data=bytes(data), is_extended_id=False)
                with self._send_lock:
                    self._bus.send(msg)
            self.frames_sent += 1
        except (can.CanError, RuntimeError, OSError) as exc:
            self.send_errors += 1
            log.warning("simulated node could not send 0x%03X: %s", cob_id, exc)

    # -- timers ------------------------------------------------------------------------------
    def add_poller(self, callback: Callable[[], object]) -> None:
        """Run ``callback()`` every :data:`POLL_PERIOD` together with every other poller, or
        every :data:`REST_POLL_PERIOD` while every poller returned a false value."""
        with self.lock:
            self._pollers.append(callback)
            if self._poll_timer is None:
                self._alive = None  # (the time without pollers was no stall)
                self._start_poll()
            else:
                self.hurry()

    def hurry(self) -> None:
        """A node changed: poll at :data:`POLL_PERIOD` again, from its next grid point on
        (nothing when the poll already runs at that rate). Under the lock."""
        if self.poll_period != POLL_PERIOD and self._poll_timer is not None and not self._closed:
            self._poll_timer.cancel()
            self._start_poll()

    def _start_poll(self) -> None:
        self._poll_timer = self.call_every(POLL_PERIOD, self._poll_all)
        self.poll_period = POLL_PERIOD

    def remove_poller(self, callback: Callable[[], None]) -> None:
        with self.lock:
            if callback in self._pollers:
                self._pollers.remove(callback)
            if not self._pollers and self._poll_timer is not None:
                self._poll_timer.cancel()
                self._poll_timer = None

    def _note_alive(self, lag: float = 0.0) -> None:
        """A port thread runs (under the lock): count a host stall if none ran for longer than
        :data:`HOST_STALL`, or the frame in hand waited that long (``lag``)."""
        now = time.monotonic()
        gap = 0.0 if self._alive is None else now - self._alive
        self._alive = now
        self.awake += min(gap, self._awake_step)
        stall = max(gap, lag if lag < 60.0 else 0.0)  # (a frame stamped by another clock)
        if stall > HOST_STALL and now - self._stall_noted > HOST_STALL:
            self._stall_noted = now  # (one stall, not one per frame of the backlog behind it)
            self.stalls += 1
            self.last_stall = stall
            self.last_gap = gap if gap > HOST_STALL else 0.0  # nothing of the port ran
            log.info("simulated CAN nodes: their host stalled for %.2f s (a busy machine?); "
                     "their supervision restarts, no fault", stall)

    def receive_backlog(self) -> int:
        """Frames received but not yet handled: waiting in the bus's queue (0 where the bus
        does not tell) or taken from it and waiting for the lock."""
        q = getattr(self._bus, "queue", None)
        try:
            queued = q.qsize() if q is not None else 0
        except (AttributeError, NotImplementedError):
            queued = 0
        return queued + self._in_hand

    def _poll_all(self) -> None:
        self._note_alive()
        busy = False
        for callback in list(self._pollers):
            try:
                busy = bool(callback()) or busy
            except Exception:
                busy = True
                log.exception("simulated node poll failed")
        period = POLL_PERIOD if busy else REST_POLL_PERIOD
        self._awake_step = AWAKE_STEPS * period
        if period != self.poll_period and self._poll_timer is not None:
            self._poll_timer.period = period  # (the timer thread reschedules it on that grid)
            self.poll_period = period

    def call_later(self, delay: float, callback: Callable[[], None]) -> TimerHandle:
        """Run ``callback()`` once in the timer thread after ``delay`` seconds (real time)."""
        return self._schedule(time.monotonic() + max(0.0, delay), TimerHandle(callback, None))

    def call_every(self, period: float, callback: Callable[[], None]) -> TimerHandle:
        """Run ``callback()`` every ``period`` seconds (real time) until cancelled: at the next
        multiple of ``period`` on the monotonic clock and every one after it (the grid timers
        of one period share)."""
        if period <= 0:
            raise ValueError("timer period must be positive")
        return self._schedule(_next_on_grid(time.monotonic(), period), TimerHandle(callback, period))

    def _schedule(self, when: float, handle: TimerHandle) -> TimerHandle:
        with self._cond:
            heapq.heappush(self._heap, (when, next(self._seq), handle))
            self._cond.notify()
        return handle

    def _timer_loop(self) -> None:
        while True:
            with self._cond:
                while not self._closed:
                    now = time.monotonic()
                    while self._heap and self._heap[0][2].cancelled:
                        heapq.heappop(self._heap)
                    if self._heap and self._heap[0][0] <= now:
                        when, _, handle = heapq.heappop(self._heap)
                        break
                    self._cond.wait(None if not self._heap else self._heap[0][0] - now)
                else:
                    return
            with self.lock:
                if handle.cancelled or self._closed:
                    continue
                try:
                    handle.callback()
                except Exception:
                    log.exception("simulated node timer failed")
            if handle.period is not None and not handle.cancelled:
                # Keep the grid, but never catch up on a backlog of missed periods.
                self._schedule(_next_on_grid(max(when, time.monotonic()), handle.period), handle)

    # -- life cycle --------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the threads; shut down the bus if the port opened it. Idempotent."""
        with self.lock:
            if self._closed:
                return
            self._closed = True
            subscribed = list(self._subscribers)
            self._subscribers.clear()
        with self._cond:
            self._cond.notify_all()
        if threading.current_thread() is not self._timer:
            self._timer.join(5.0)
        if self._network is not None:
            for cob_id in subscribed:
                try:
                    self._network.unsubscribe(cob_id, self._on_network_frame)
                except (KeyError, ValueError):
                    pass
        if self._notifier is not None:
            # (returns once the reader ends, within a RECEIVE_CYCLE; the bus may close only then:
            # a reader still in recv would die on the closed socket, on a slow host too)
            self._notifier.stop(2.0)
        if self._owns_bus and self._bus is not None:
            self._bus.shutdown()
        _forget(self)

    @property
    def closed(self) -> bool:
        return self._closed

    def acquire_user(self) -> None:
        with self.lock:
            self._users += 1

    def release(self) -> None:
        """One user is done with the port; the last one closes it."""
        with self.lock:
            self._users -= 1
            last = self._users <= 0
        if last:
            self.close()


_registry: dict[int, SimCanPort] = {}
_registry_lock = threading.Lock()


def _forget(port: SimCanPort) -> None:
    with _registry_lock:
        for key, value in list(_registry.items()):
            if value is port:
                del _registry[key]


def open_port(bus_or_network: Any) -> SimCanPort:
    """The shared port for a bus; the caller must ``release()`` it when done.

    Parameters
    ----------
    bus_or_network:
        A :class:`SimCanPort`, a ``can.BusABC`` (the port reads it: nobody else may), a
        connected ``canopen.Network`` (the port uses its notifier and send lock), or a mapping
        of ``can.Bus`` keyword arguments (the port opens and later shuts down its own bus).
    """
    if isinstance(bus_or_network, SimCanPort):
        port = bus_or_network
        if port.closed:
            raise ValueError("the simulated CAN port is closed")
    elif isinstance(bus_or_network, Mapping) and not hasattr(bus_or_network, "send_message"):
        port = SimCanPort(bus=open_bus(**dict(bus_or_network)), owns_bus=True)
    else:
        with _registry_lock:
            port = _registry.get(id(bus_or_network))
            if port is None or port.closed:
                if isinstance(bus_or_network, can.BusABC):
                    port = SimCanPort(bus=bus_or_network)
                elif hasattr(bus_or_network, "subscribe") and hasattr(bus_or_network, "send_message"):
                    port = SimCanPort(network=bus_or_network)
                else:
                    raise TypeError(
                        f"simulated drive needs a can.BusABC, canopen.Network, SimCanPort or bus "
                        f"arguments, not {type(bus_or_network).__name__}")
                _registry[id(bus_or_network)] = port
    port.acquire_user()
    return port
