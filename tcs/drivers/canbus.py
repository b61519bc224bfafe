"""The CAN bus of the drives: python-can bus, canopen ``Network``, TCS heartbeat, bus health.

:class:`CanBus` opens the python-can interface the hardware file names (``[can]``:
``virtual``, ``socketcand``, ``socketcan``) with the interface's options, puts a canopen
:class:`~canopen.Network` on it (used for SDO, NMT and EDS — not for PDOs, see
:mod:`tcs.drivers.pdo`), and runs

* the TCS's own **heartbeat producer** (COB-ID 0x700 + ``can.node_id``, state 5). Every
  drive watches it (0x1016) and faults when it stops. Until the cyclic phase it is a
  ``send_periodic`` task (boot, commissioning tools); once the control cycle runs
  (:meth:`heartbeat_from_cycle`) the cycle thread itself sends it, through :meth:`beat`, after
  each cycle's work is done — so a stalled control loop, a hung or stopped (SIGSTOP) process
  stops the heartbeat and every drive reacts within its consumer time, which a kernel or
  thread timer independent of the loop would hide. :meth:`stop_heartbeat` stops it in
  either mode (tests, a deliberate safe stop);
* a **bus-health listener** in the notifier: error frames (controller warning / passive,
  bus-off, restarted) and receive failures are counted and kept as :class:`BusHealth`; the
  latest problem is a :class:`~tcs.errors.CommunicationError`; callbacks registered with
  :meth:`add_error_callback` hear each one. Nothing is swallowed: a failed ``send`` raises to
  its caller and is recorded here too;
* the **traffic** (:class:`Traffic`): frames received (the same listener) and sent (every
  ``send`` of the python-can bus is counted, ours and canopen's) and their bits, from which
  :meth:`bus_load` is the share of the bit rate used over the last second or more. Frames
  the kernel sends for us (socketcan ``send_periodic``: SYNC) come back to our socket and are
  counted as received.

**Reconnect.** A bus whose link broke (sends fail: the socketcand peer went away, the
interface is down) is reopened by a thread of its own (``tcs-can-reconnect``) with back-off
(0.2 s doubling to 5 s; a socketcand peer that is not listening fails a try within
:data:`PROBE_TIMEOUT`, see :func:`probe_socketcand`, instead of python-can's 10 s of
retries): the python-can bus and the notifier are replaced under the same
canopen ``Network``, so every subscription stays; callbacks of :meth:`add_reconnect_callback`
then run (the drives are booted again, as after a power blip). Kernel SYNC
(``send_periodic`` on socketcan) is not moved to the new socket: on socketcan the socket
survives an interface down/up and no reopen happens unless sends keep failing.

**Sends from several threads.** The cycle thread (SYNC, RPDOs, heartbeat), the SDO worker
(canopen's ``Network.send_message``) and python-can's periodic-send threads all call the
python-can bus's ``send``. socketcand writes each frame as text to one TCP stream with no lock
of its own, so on that interface (:data:`SERIALIZED_INTERFACES`) the bus's ``send`` is
replaced by one that holds a lock (:func:`serialize_sends`): every caller, ours or the
libraries', goes through it. virtual and socketcan are left as they are (thread-safe: a queue,
one kernel call per frame), so their path costs nothing more.

The SYNC producer is not here but in :class:`tcs.drivers.cycle.CycleSource`, which must know
when each SYNC went out. All receive callbacks run in the one notifier thread and never block.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import can
import canopen

from tcs.config.can import CanSection
from tcs.errors import CommunicationError, ErrorNumber, TcsError
from tcs.virtual_can import open_bus

log = logging.getLogger(__name__)

SYNC_COB_ID = 0x080
#: python-can interfaces whose ``send`` is not safe from several threads (a byte stream).
SERIALIZED_INTERFACES = frozenset({"socketcand"})


#: s a socketcand connection attempt may take before it counts as failed.
PROBE_TIMEOUT = 1.0


def probe_socketcand(host: str, port: int, timeout: float = PROBE_TIMEOUT) -> None:
    """Fail at once (OSError) when no socketcand server accepts a connection at host:port.

    python-can's socketcand client retries a refused connection for 10 s in a busy loop
    before it gives up; a reconnect try (or the service's quick stop after a crash) must not
    block that long on a peer that is simply gone."""
    with socket.create_connection((host, port), timeout=timeout):
        pass


def serialize_sends(bus: can.BusABC) -> can.BusABC:
    """Make ``bus.send`` hold a lock of its own (for every caller: canopen's SDO, python-can's
    periodic tasks and ours call ``bus.send``); returns ``bus``."""
    send = bus.send
    lock = threading.Lock()

    def locked_send(msg: can.Message, timeout: float | None = None) -> None:
        with lock:
            send(msg, timeout)

    bus.send = locked_send  # type: ignore[method-assign]
    return bus
HEARTBEAT_BASE = 0x700
NMT_OPERATIONAL = 0x05

# Linux can/error.h: error class bits in the identifier of an error frame, details in data.
CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40


@dataclass(frozen=True)
class BusHealth:
    """Controller state and error counts; ``last_error`` is the latest problem, if any."""

    state: str = "ok"              # ok | warning | passive | bus-off | failed
    error_frames: int = 0
    bus_off_count: int = 0
    send_failures: int = 0
    receive_failures: int = 0
    last_error: TcsError | None = None


def frame_bits(msg: can.Message) -> int:
    """The bits of a classic data frame on the wire without stuff bits (SOF, identifier, control,
    data, CRC, ACK, EOF and the 3-bit interframe space): 47 + 8·n for an 11-bit identifier, 67 + 8·n
    for a 29-bit one. Bit stuffing adds up to about a fifth more."""
    return (67 if msg.is_extended_id else 47) + 8 * len(msg.data)


class Traffic:
    """Frames and bits counted on one bus (counts of several threads: a lost increment under a
    race only makes a statistic a frame short)."""

    __slots__ = ("rx_frames", "tx_frames", "bits", "_mark", "load")

    def __init__(self) -> None:
        self.rx_frames = 0
        self.tx_frames = 0
        self.bits = 0
        self._mark = (time.monotonic(), 0)
        self.load: float | None = None  # share of the bit rate over the last window (None: not yet)

    def window(self, bitrate: int, now: float, span: float = 1.0) -> float | None:
        """The bus load over the last completed window of at least ``span`` seconds."""
        t0, bits0 = self._mark
        if now - t0 >= span:
            bits = self.bits
            self.load = (bits - bits0) / (bitrate * (now - t0))
            self._mark = (now, bits)
        return self.load


def count_sends(bus: can.BusABC, traffic: Traffic) -> can.BusABC:
    """Make ``bus.send`` count each frame it sent in ``traffic``; returns ``bus``."""
    send = bus.send

    def counted_send(msg: can.Message, timeout: float | None = None) -> None:
        send(msg, timeout)
        traffic.tx_frames += 1
        traffic.bits += frame_bits(msg)

    bus.send = counted_send  # type: ignore[method-assign]
    return bus


class _HealthListener(can.Listener):
    """Notifier listener that turns error frames and receive errors into BusHealth and counts
    the frames received."""

    def __init__(self, bus: CanBus):
        self._bus = bus
        self._traffic = bus.traffic

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self._bus._on_error_frame(msg)
            return
        traffic = self._traffic
        traffic.rx_frames += 1
        traffic.bits += frame_bits(msg)

    def on_error(self, exc: Exception) -> None:
        self._bus._on_receive_error(exc)

    def stop(self) -> None:
        pass


class CanBus:
    """One CAN bus: open with :meth:`open` (blocking, at start), :meth:`close` at the end.

    Parameters
    ----------
    section:
        The ``[can]`` table of the hardware file.
    """

    def __init__(self, section: CanSection):
        self.section = section
        self.name = f"CAN {section.interface}:{section.channel}"
        self.bus: can.BusABC | None = None
        self.network: canopen.Network | None = None
        self._heartbeat_task = None
        self._heartbeat_wanted = False
        self._cycle_beats = False   # the cycle sends the heartbeat (beat())
        self._last_beat = float("-inf")
        self._heartbeat_msg = None
        self._lock = threading.Lock()
        self._health = BusHealth()
        self.traffic = Traffic()
        self._callbacks: list[Callable[[TcsError], None]] = []
        self._reconnect_callbacks: list[Callable[[], None]] = []
        self._last_receive_error = 0.0
        self._broken = threading.Event()   # the link broke: reopen
        self._closing = threading.Event()
        self._reconnector: threading.Thread | None = None
        self._failures_in_row = 0
        #: frames sent from this thread are held in this list instead (CycleSource: the
        #: cycle's RPDOs go out just before the SYNC that latches them, see tcs.drivers.cycle)
        self._held: tuple[int, list] | None = None
        self._reopening = False
        self.reconnects = 0

    # ---------------------------------------------------------------- life cycle
    @property
    def kernel_periodic(self) -> bool:
        """True when ``send_periodic`` is done by the kernel (socketcan broadcast manager)."""
        return self.section.interface == "socketcan"

    def open(self, heartbeat: bool = True) -> CanBus:
        """Open the interface, start the notifier and the TCS heartbeat (blocking).

        ``heartbeat=False`` sends nothing yet (to listen for another master first, see
        :mod:`tcs.drivers.bus_check`); :meth:`start_heartbeat` later.

        Raises
        ------
        CommunicationError
            The interface cannot be opened (names the interface and channel).
        """
        if self.section.interface == "socketcand":
            logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)
        try:
            self.bus = self._new_bus()
        except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
            raise CommunicationError(self.name, f"cannot open the bus: {exc}{open_hint(self.section, exc)}") from exc
        self.network = canopen.Network(self.bus)
        self.network.listeners.append(_HealthListener(self))
        self.network.connect()
        self._closing.clear()
        self._broken.clear()
        if heartbeat:
            self.start_heartbeat()
        self._reconnector = threading.Thread(target=self._reconnect_loop, name="tcs-can-reconnect",
                                             daemon=True)
        self._reconnector.start()
        return self

    def _new_bus(self) -> can.BusABC:
        if self.section.interface == "socketcand":
            probe_socketcand(self.section.host, self.section.port)
        bus = count_sends(open_bus(**self.section.bus_kwargs()), self.traffic)
        return serialize_sends(bus) if self.section.interface in SERIALIZED_INTERFACES else bus

    # ---------------------------------------------------------------- reconnect
    def add_reconnect_callback(self, callback: Callable[[], None]) -> None:
        """``callback()`` after the bus was reopened (in the reconnect thread)."""
        self._reconnect_callbacks.append(callback)

    def _reconnect_loop(self) -> None:
        backoff = 0.2
        while not self._closing.is_set():
            if not self._broken.wait(0.5):
                continue
            if self._closing.is_set():
                return
            try:
                self._reopen()
            except Exception as exc:  # the peer is not back yet
                log.warning("%s: reopening failed (%s); next try in %g s", self.name, exc, backoff)
                if self._closing.wait(backoff):
                    return
                backoff = min(2 * backoff, 5.0)
                continue
            backoff = 0.2
            self._broken.clear()
            self._failures_in_row = 0
            self.reconnects += 1
            self._record(CommunicationError(self.name, "bus reopened", ErrorNumber.CONFAIL), "ok")
            for callback in list(self._reconnect_callbacks):
                try:
                    callback()
                except Exception:
                    log.exception("bus reconnect callback failed")

    def _reopen(self) -> None:
        """Replace the python-can bus and the notifier (same Network, same subscriptions)."""
        network = self.network
        if network is None:
            return
        old_bus, old_notifier = self.bus, network.notifier
        self._reopening = True  # the old notifier's last receive fails: not a new fault
        try:
            if old_notifier is not None:
                try:
                    old_notifier.stop(0.5)
                except Exception:
                    pass
            self._stop_task()  # (bound to the old bus: stopped before its socket closes under it)
            if old_bus is not None:
                try:
                    old_bus.shutdown()
                except Exception:
                    pass
        finally:
            self._reopening = False
        new = self._new_bus()
        network.bus = new
        network.notifier = can.Notifier(new, network.listeners, network.NOTIFIER_CYCLE)
        self.bus = new
        if self._heartbeat_wanted:
            self._start_task()

    def close(self) -> None:
        """Stop the heartbeat and the notifier, shut the bus down (idempotent)."""
        self._closing.set()
        self._broken.set()
        thread, self._reconnector = self._reconnector, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
        self.stop_heartbeat()
        network, self.network = self.network, None
        if network is not None:
            for node_id in list(network.nodes):
                del network[node_id]
            try:
                network.disconnect()
            except Exception as exc:  # the notifier's last error: report, do not hide
                log.warning("%s: notifier ended with %r", self.name, exc)
        self.bus = None

    def __enter__(self) -> CanBus:
        return self.open() if self.bus is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- heartbeat
    def start_heartbeat(self) -> None:
        """Produce the TCS heartbeat (state operational) every ``heartbeat_period``."""
        self._heartbeat_wanted = True
        if not self._broken.is_set():  # (a broken bus: the reconnect starts it on the new one)
            self._start_task()

    def _start_task(self) -> None:
        if self._cycle_beats or self._heartbeat_task is not None or self.bus is None:
            return
        msg = can.Message(arbitration_id=HEARTBEAT_BASE + self.section.node_id,
                          data=[NMT_OPERATIONAL], is_extended_id=False)
        self._heartbeat_task = self.bus.send_periodic(msg, self.section.heartbeat_period)

    def _stop_task(self) -> None:
        task, self._heartbeat_task = self._heartbeat_task, None
        if task is not None:
            task.stop()
            thread = getattr(task, "thread", None)
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=2.0)

    def stop_heartbeat(self) -> None:
        """Stop the TCS heartbeat: every drive faults after its consumer time (0x1016)."""
        self._heartbeat_wanted = False
        self._stop_task()

    def heartbeat_from_cycle(self) -> None:
        """The control cycle starts: from now on it produces the heartbeat with :meth:`beat`."""
        self._stop_task()
        self._cycle_beats = True

    def heartbeat_to_periodic(self) -> None:
        """The control cycle stopped on purpose: back to the periodic task (if wanted)."""
        self._cycle_beats = False
        if self._heartbeat_wanted:
            self.start_heartbeat()

    def beat(self, now: float) -> None:
        """Send the heartbeat if one is due (cycle thread, after the cycle's work)."""
        if not (self._cycle_beats and self._heartbeat_wanted) or \
                now - self._last_beat < 0.95 * self.section.heartbeat_period:
            return
        self._last_beat = now
        try:
            self.send(HEARTBEAT_BASE + self.section.node_id, bytes([NMT_OPERATIONAL]))
        except TcsError:
            pass  # recorded in the health

    @property
    def heartbeat_running(self) -> bool:
        return self._heartbeat_task is not None or (self._cycle_beats and self._heartbeat_wanted)

    # ---------------------------------------------------------------- sending
    def send(self, cob_id: int, data: bytes,
             retime: Callable[[float], bytes] | None = None) -> None:
        """Send one frame (any thread). A failure is recorded and raised as CommunicationError.
        From the thread :meth:`hold_sends` names, the frame is kept for the cycle source, with
        ``retime``: the frame's data again for a SYNC that goes out that many seconds after
        the slot the frame was made for (a setpoint moved on along its stream; None: as is)."""
        held = self._held
        if held is not None and held[0] == threading.get_ident():
            held[1].append((cob_id, bytes(data), retime))
            return
        bus = self.bus
        if bus is None:
            raise CommunicationError(self.name, "bus is closed")
        msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
        try:
            bus.send(msg, timeout=0.005)
        except (can.CanError, OSError) as exc:
            error = CommunicationError(self.name, f"send of 0x{cob_id:03X} failed: {exc}",
                                       ErrorNumber.CONFAIL)
            self._failures_in_row += 1
            broken = self._failures_in_row >= 20 or isinstance(
                exc, (BrokenPipeError, ConnectionError)) or isinstance(exc.__context__, (
                    BrokenPipeError, ConnectionError))
            self._record(error, "failed" if broken else None, send_failures=1)
            if broken:
                self._broken.set()
            raise error from exc
        self._failures_in_row = 0

    def holding(self) -> bool:
        """The calling thread's sends are held for the cycle source (:meth:`hold_sends`)."""
        held = self._held
        return held is not None and held[0] == threading.get_ident()

    def hold_sends(self, frames: list | None) -> None:
        """From now on the calling thread's :meth:`send` appends ``(cob_id, data, retime)`` to
        ``frames`` instead of sending (None: sends go out again). The cycle runner only."""
        self._held = None if frames is None else (threading.get_ident(), frames)

    # ---------------------------------------------------------------- health
    def health(self) -> BusHealth:
        """The bus state now (any thread)."""
        return self._health

    def bus_load(self) -> float | None:
        """The share of the bit rate (``[can] bitrate``) the frames seen used over the last
        second or more (without stuff bits); None before the first second."""
        return self.traffic.window(self.section.bitrate, time.monotonic())

    def add_error_callback(self, callback: Callable[[TcsError], None]) -> None:
        """``callback(error)`` for every bus problem; runs in the thread that saw it."""
        self._callbacks.append(callback)

    def _record(self, error: TcsError, state: str | None = None, **counts: int) -> None:
        with self._lock:
            h = self._health
            values = {k: getattr(h, k) + v for k, v in counts.items()}
            self._health = BusHealth(**{**h.__dict__, **values, "last_error": error,
                                        "state": state or h.state})
        log.warning("%s", error)
        for callback in list(self._callbacks):
            try:
                callback(error)
            except Exception:  # a listener's bug must not stop the notifier
                log.exception("bus error callback failed")

    def _on_error_frame(self, msg: can.Message) -> None:
        cls = msg.arbitration_id
        data = bytes(msg.data).ljust(8, b"\0")
        if cls & CAN_ERR_BUSOFF:
            self._record(CommunicationError(self.name, "bus-off: the controller stopped sending"),
                         "bus-off", error_frames=1, bus_off_count=1)
        elif cls & CAN_ERR_RESTARTED:
            self._record(CommunicationError(self.name, "controller restarted after bus-off",
                                            ErrorNumber.CONFAIL), "ok", error_frames=1)
        elif cls & CAN_ERR_CRTL and data[1] & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
            self._record(CommunicationError(self.name, f"error passive (tx errors {data[6]}, rx "
                                                       f"errors {data[7]})", ErrorNumber.CONFAIL),
                         "passive", error_frames=1)
        elif cls & CAN_ERR_CRTL and data[1] & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING):
            self._record(CommunicationError(self.name, "error warning level reached",
                                            ErrorNumber.CONFAIL), "warning", error_frames=1)
        elif cls & CAN_ERR_CRTL and data[1] & CAN_ERR_CRTL_ACTIVE:
            self._record(CommunicationError(self.name, "back to error active", ErrorNumber.CONFAIL),
                         "ok", error_frames=1)
        else:
            kinds = [n for bit, n in ((CAN_ERR_TX_TIMEOUT, "tx timeout"), (CAN_ERR_LOSTARB, "lost "
                     "arbitration"), (CAN_ERR_PROT, "protocol violation"), (CAN_ERR_TRX,
                     "transceiver"), (CAN_ERR_ACK, "no acknowledge"), (CAN_ERR_BUSERROR,
                     "bus error")) if cls & bit] or [f"class 0x{cls:X}"]
            self._record(CommunicationError(self.name, "error frame: " + ", ".join(kinds),
                                            ErrorNumber.CONFAIL), None, error_frames=1)

    def _from_current_notifier(self) -> bool:
        """False in the thread of a notifier that was replaced or stopped (python-can keeps
        its reader threads in ``Notifier._readers``; True where that is unknown)."""
        notifier = self.network.notifier if self.network is not None else None
        readers = getattr(notifier, "_readers", None)
        if notifier is None or readers is None:
            return notifier is not None
        threads = [r for r in readers if isinstance(r, threading.Thread)]
        return not threads or threading.current_thread() in threads

    def _on_receive_error(self, exc: Exception) -> None:
        if self._closing.is_set() or self._reopening or not self._from_current_notifier():
            # the socket was shut down under its notifier by close() / _reopen(): not a fault
            # of the link (a kernel socket's recv then fails with "Bad file descriptor")
            return
        self._record(CommunicationError(self.name, f"receive failed: {exc}"), "failed",
                     receive_failures=1)
        # canopen's Network.check() would re-raise this on every later send: the error is
        # reported here, so clear it; a dead bus must not spin the notifier thread.
        notifier = self.network.notifier if self.network is not None else None
        if notifier is not None:
            notifier.exception = None
        self._broken.set()  # reopen it (tcs-can-reconnect)
        now = time.monotonic()
        if now - self._last_receive_error < 0.5:
            time.sleep(0.1)
        self._last_receive_error = now


def open_hint(section, exc: BaseException) -> str:
    """What to look at when ``section``'s interface cannot be opened (appended to the error)."""
    import errno

    number = getattr(exc, "errno", None) or getattr(getattr(exc, "__cause__", None), "errno", None)
    channel = section.channel
    if section.interface == "socketcan":
        if number == errno.EAFNOSUPPORT:
            return (": this kernel has no SocketCAN (AF_CAN); load the modules (`modprobe can can_raw`, "
                    "and `vcan` for a virtual bus) or use a kernel that has them (Debian's "
                    "linux-image-amd64 does, the cloud kernel does not)")
        if number == errno.ENODEV:
            return (f": there is no interface {channel!r}; `ip link` lists the CAN interfaces; bring it "
                    f"up with `systemctl start tcs-can@{channel}` (tools/systemd/install.sh installs it) "
                    f"or `ip link set {channel} up type can bitrate ...`")
        if number == errno.ENETDOWN:
            return f": {channel!r} is down; `systemctl start tcs-can@{channel}` brings it up"
    if section.interface == "socketcand" and number == errno.ECONNREFUSED:
        return ": nothing listens there; is the socketcand server (or tcs-sim) running?"
    return ""
