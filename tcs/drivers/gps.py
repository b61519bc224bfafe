"""NMEA GPS reader: position, fix and time from GGA, RMC and ZDA sentences on a serial line.

How it works
------------
:class:`GpsReader` runs on the event loop. One task opens the port with pyserial's
``serial_for_url`` (a device path, a pty path, ``socket://host:port``, ``loop://``) — in a
short-lived thread, since opening a socket URL may block — and then only waits; the bytes are
read non-blocking by an ``add_reader`` callback, split into lines and parsed with pynmea2:

* GGA → latitude, longitude, height (above mean sea level), fix quality, satellites, HDOP;
* RMC with status ``A`` and ZDA → UTC date and time (``time``, and ``time_received`` on the
  reader's clock to extrapolate from; NMEA time arrives hundreds of ms late, so the system
  clock stays the time reference and this is a plausibility source);
* anything else valid is counted in ``ignored``; lines that are not NMEA (including truncated
  sentences without a checksum) in ``garbage``; wrong checksums in ``bad_checksums`` — all are
  dropped, none raises.

States: *position good* while the port is open and the last GGA reported a fix (quality > 0)
and is younger than ``position_timeout``; *time good* while the port is open and the last
valid RMC/ZDA is younger than ``time_timeout``. A timer at the next deadline re-evaluates them, so a silent or unplugged
receiver turns *loose* on time without polling. Each change calls the listeners with a
:class:`GpsEvent` carrying the OpenTCI event number: 25 POSITION_GOOD / 24 POSITION_LOOSE,
27 TIME_GOOD / 26 TIME_LOOSE. Both start loose (no event for that).

A read error (device unplugged, socket closed) closes the port and reopens it after a backoff
(``reopen_min`` doubling to ``reopen_max``); nothing propagates to the caller.

The OpenTCI GPS module reads :attr:`GpsReader.status`; nothing here knows OpenTCI.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import pynmea2
import serial

from tcs.config.gps import GpsSection
from tcs.errors import ErrorNumber
from tcs.state_epoch import bump as bump_epoch

__all__ = ["GpsReader", "GpsStatus", "GpsEvent"]

log = logging.getLogger(__name__)
MAX_LINE = 120      # NMEA allows 82 characters; anything much longer is noise
MAX_BUFFER = 4096


def close_port(ser) -> None:
    """Close a pyserial port without blocking. pyserial's ``socket://`` handler sleeps 0.3 s in
    ``close()`` ("give the server some time"), which in the event loop would stall every TPL2
    client and the control loop's event delivery: close its socket here instead."""
    sock = getattr(ser, "_socket", None)
    try:
        if isinstance(sock, socket.socket):
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            sock.close()
            ser._socket = None
            ser.is_open = False
        else:
            ser.close()
    except (OSError, serial.SerialException):
        pass


@dataclass(frozen=True)
class GpsEvent:
    """A change of the position or time state; ``number`` is 24, 25, 26 or 27."""

    number: ErrorNumber
    message: str


@dataclass(frozen=True)
class GpsStatus:
    """What the receiver said, as of one instant of the reader's clock."""

    port_open: bool
    position_good: bool
    time_good: bool
    latitude: float | None
    longitude: float | None
    height: float | None
    fix_quality: int
    satellites: int | None
    hdop: float | None
    time: float | None              # UTC, seconds since 1970, of the last valid time sentence
    time_received: float | None     # reader clock when that sentence arrived
    last_sentence_age: float | None  # seconds since the last valid sentence of any type
    sentences: int
    bad_checksums: int
    garbage: int
    ignored: int
    port_error: str


class GpsReader:
    """Reads an NMEA receiver at ``section.url``.

    Parameters
    ----------
    section:
        The ``[gps]`` section.
    clock:
        Monotonic seconds for ages and timeouts (the same clock as the event loop's timers
        should be used in production: the default).
    """

    def __init__(self, section: GpsSection, *, clock: Callable[[], float] = time.monotonic,
                 name: str = "gps"):
        self.section = section
        self.clock = clock
        self.name = name
        self._serial: serial.SerialBase | None = None
        self._closed: asyncio.Future | None = None
        self._task: asyncio.Task | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._buffer = b""
        self._listeners: list[Callable[[GpsEvent], None]] = []
        self._waiters: list[asyncio.Future] = []
        self._port_error = "not started"
        self._lat = self._lon = self._height = self._hdop = None
        self._sats: int | None = None
        self._quality = 0
        self._fix_at: float | None = None
        self._time: float | None = None
        self._time_at: float | None = None
        self._sentence_at: float | None = None
        self.sentences = self.bad_checksums = self.garbage = self.ignored = 0
        self._position_good = self._time_good = False

    # ------------------------------------------------------------- lifecycle

    async def start(self) -> None:
        """Start reading (returns at once; the state is loose until sentences arrive)."""
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run(), name=f"{self.name} reader")

    async def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            while not task.done():  # be sure the cancel is not lost in a coinciding wake-up
                task.cancel()
                await asyncio.wait([task], timeout=0.05)
        self._detach()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    async def __aenter__(self) -> GpsReader:
        await self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()

    def add_listener(self, callback: Callable[[GpsEvent], None]) -> Callable[[], None]:
        """Call ``callback(event)`` on every good/loose change; returns a remover."""
        self._listeners.append(callback)
        return lambda: self._listeners.remove(callback) if callback in self._listeners else None

    # ------------------------------------------------------------- state

    @property
    def position_good(self) -> bool:
        return self._position_good

    @property
    def time_good(self) -> bool:
        return self._time_good

    @property
    def status(self) -> GpsStatus:
        now = self.clock()
        return GpsStatus(
            port_open=self._serial is not None, position_good=self._position_good,
            time_good=self._time_good, latitude=self._lat, longitude=self._lon, height=self._height,
            fix_quality=self._quality, satellites=self._sats, hdop=self._hdop, time=self._time,
            time_received=self._time_at,
            last_sentence_age=None if self._sentence_at is None else now - self._sentence_at,
            sentences=self.sentences, bad_checksums=self.bad_checksums, garbage=self.garbage,
            ignored=self.ignored, port_error=self._port_error)

    def gps_time(self, now: float | None = None) -> float | None:
        """The receiver's UTC at reader-clock ``now``, extrapolated from the last time sentence."""
        if self._time is None or self._time_at is None:
            return None
        return self._time + ((self.clock() if now is None else now) - self._time_at)

    async def wait_for(self, predicate: Callable[[GpsStatus], bool], timeout: float) -> GpsStatus:
        """The first status (checked on every sentence and state change) meeting ``predicate``.

        Raises ``asyncio.TimeoutError`` after ``timeout`` seconds (for tests and tools).
        """
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            st = self.status
            if predicate(st):
                return st
            left = deadline - loop.time()
            if left <= 0:
                raise asyncio.TimeoutError(f"GPS condition not met within {timeout:g} s: {st}")
            fut = loop.create_future()
            self._waiters.append(fut)
            handle = loop.call_later(min(left, 0.5), lambda f=fut: f.done() or f.set_result(None))
            try:
                await fut
            finally:
                handle.cancel()
                if fut in self._waiters:
                    self._waiters.remove(fut)

    # ------------------------------------------------------------- the port

    async def _run(self) -> None:
        s = self.section
        delay = s.reopen_min
        while True:
            try:
                ser = await _in_thread(lambda: serial.serial_for_url(s.url, baudrate=s.baudrate, timeout=0),
                                       cleanup=close_port)
            except (serial.SerialException, OSError, ValueError) as exc:
                self._port_error = f"cannot open {s.url}: {exc}"
                log.debug("%s: %s", self.name, self._port_error)
            else:
                self._attach(ser)
                delay = s.reopen_min
                try:
                    await self._closed
                finally:
                    self._detach()
            self._evaluate()
            await asyncio.sleep(delay)
            delay = min(s.reopen_max, max(2 * delay, 0.05))

    def _attach(self, ser) -> None:
        loop = asyncio.get_running_loop()
        try:
            ser.reset_input_buffer()  # bytes the kernel kept while nobody read are stale
        except (OSError, serial.SerialException):
            pass
        self._serial = ser
        self._buffer = b""
        self._port_error = ""
        self._closed = loop.create_future()
        loop.add_reader(ser.fileno(), self._on_readable)
        log.info("%s: reading %s", self.name, self.section.url)

    def _detach(self) -> None:
        ser, self._serial = self._serial, None
        if ser is None:
            return
        try:
            asyncio.get_running_loop().remove_reader(ser.fileno())
        except (OSError, ValueError, serial.SerialException):
            pass
        close_port(ser)

    def _on_readable(self) -> None:
        ser = self._serial
        if ser is None:
            return
        try:
            data = ser.read(4096)
        except (serial.SerialException, OSError) as exc:
            self._port_error = f"{self.section.url}: {exc}"
            log.warning("%s: port lost: %s", self.name, exc)
            loop = asyncio.get_running_loop()
            loop.remove_reader(ser.fileno())
            if self._closed is not None and not self._closed.done():
                self._closed.set_result(None)
            return
        self.feed(data)

    # ------------------------------------------------------------- parsing

    def feed(self, data: bytes) -> None:
        """Process received bytes (also for replaying a log without a port: values and
        counters update; the good states need an open port)."""
        self._buffer += data
        *lines, self._buffer = self._buffer.split(b"\n")
        if len(self._buffer) > MAX_BUFFER:
            self._buffer = b""
            self.garbage += 1
        for line in lines:
            self._line(line.strip())
        self._evaluate()
        bump_epoch()  # GPS.* and LOCAL.* may have changed (tcs.state_epoch)

    def _line(self, raw: bytes) -> None:
        if not raw:
            return
        if len(raw) > MAX_LINE or not raw.startswith((b"$", b"!")) or b"*" not in raw:
            self.garbage += 1
            return
        try:
            text = raw.decode("ascii")
            msg = pynmea2.parse(text, check=True)
        except pynmea2.ChecksumError:
            self.bad_checksums += 1
            return
        except Exception:  # ParseError, UnicodeDecodeError, anything a mangled line provokes
            self.garbage += 1
            return
        now = self.clock()
        try:
            if isinstance(msg, pynmea2.GGA):
                self._gga(msg, now)
            elif isinstance(msg, pynmea2.RMC):
                if msg.status == "A" and msg.datestamp and msg.timestamp:
                    self._set_time(msg.datetime.timestamp(), now)
            elif isinstance(msg, pynmea2.ZDA):
                if msg.datestamp and msg.timestamp:
                    self._set_time(msg.datetime.timestamp(), now)
            else:
                self.ignored += 1
                self._sentence_at = now
                return
        except (ValueError, TypeError, AttributeError):
            self.garbage += 1
            return
        self.sentences += 1
        self._sentence_at = now

    def _gga(self, msg, now: float) -> None:
        quality = int(msg.gps_qual or 0)
        if quality > 0 and msg.lat and msg.lon:
            lat, lon = float(msg.latitude), float(msg.longitude)
            height = float(msg.altitude) if msg.altitude not in (None, "") else None
            self._lat, self._lon, self._height = lat, lon, height
            self._fix_at = now
        self._quality = quality
        self._sats = int(msg.num_sats) if msg.num_sats not in (None, "") else None
        self._hdop = float(msg.horizontal_dil) if msg.horizontal_dil not in (None, "") else None

    def _set_time(self, t: float, now: float) -> None:
        self._time, self._time_at = t, now

    def _evaluate(self) -> None:
        now = self.clock()
        s = self.section
        port = self._serial is not None
        pos = (port and self._quality > 0 and self._fix_at is not None
               and now - self._fix_at < s.position_timeout)
        tim = port and self._time_at is not None and now - self._time_at < s.time_timeout
        events = []
        if pos != self._position_good:
            self._position_good = pos
            events.append(GpsEvent(ErrorNumber.POSITION_GOOD, "GPS position good") if pos else
                          GpsEvent(ErrorNumber.POSITION_LOOSE, "GPS position uncertain: " + self._why(now)))
        if tim != self._time_good:
            self._time_good = tim
            events.append(GpsEvent(ErrorNumber.TIME_GOOD, "GPS time good") if tim else
                          GpsEvent(ErrorNumber.TIME_LOOSE, "GPS time uncertain: " + self._why(now, time=True)))
        self._schedule(now)
        for ev in events:
            log.info("%s: %s", self.name, ev.message)
            for cb in list(self._listeners):
                try:
                    cb(ev)
                except Exception:
                    log.exception("%s: listener %r failed", self.name, cb)
        for fut in list(self._waiters):
            if not fut.done():
                fut.set_result(None)

    def _why(self, now: float, time: bool = False) -> str:
        if self._serial is None:
            return self._port_error or "port closed"
        if not time and self._quality == 0 and self._sentence_at is not None:
            return "no fix"
        last = self._time_at if time else self._fix_at
        if last is None:
            return "no data"
        return f"silent for {now - last:.1f} s"

    def _schedule(self, now: float) -> None:
        """Arm one timer at the next instant a good state would expire."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        deadlines = []
        if self._position_good and self._fix_at is not None:
            deadlines.append(self._fix_at + self.section.position_timeout)
        if self._time_good and self._time_at is not None:
            deadlines.append(self._time_at + self.section.time_timeout)
        if deadlines:
            try:
                loop = asyncio.get_running_loop()
            except RuntimeError:  # fed outside a loop (replay): no timers
                return
            self._timer = loop.call_later(max(0.0, min(deadlines) - now) + 0.001, self._evaluate)


async def _in_thread(fn, cleanup):
    """Run blocking ``fn`` in a one-shot thread; if the caller is cancelled, ``cleanup`` its result."""
    loop = asyncio.get_running_loop()
    fut = loop.create_future()

    def deliver(result, error):
        if fut.cancelled():
            if error is None:
                cleanup(result)
        elif error is not None:
            fut.set_exception(error)
        else:
            fut.set_result(result)

    def run():
        try:
            result, error = fn(), None
        except BaseException as exc:  # handed to the awaiting task
            result, error = None, exc
        try:
            loop.call_soon_threadsafe(deliver, result, error)
        except RuntimeError:  # loop closed meanwhile
            if error is None:
                cleanup(result)

    threading.Thread(target=run, name="gps-open", daemon=True).start()
    return await fut
