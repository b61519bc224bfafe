"""NMEA GPS reader: fix, position, satellites and time, judged as a timing receiver's user must.

How it works
------------
:class:`GpsReader` runs on the event loop. One task opens the port with pyserial's
``serial_for_url`` (a device path, a pty path, ``socket://host:port``, ``loop://``) — in a
short-lived thread, since opening a socket URL may block — and then only waits; the bytes are
read non-blocking by an ``add_reader`` callback and split into lines. Every sentence found
*anywhere* in a line is used (:data:`SENTENCE`): a u-blox sending UBX and NMEA on one port puts
binary bytes before the ``$`` of the next sentence. pynmea2 checks each one's checksum and
splits its fields; :func:`tcs.drivers.nmea_judge.judge` judges them (status and mode fields,
fix quality, ranges, dates — see that module):

* a position and a fix state from GGA, RMC, GLL, GNS and ``$PUBX,00``. A talker
  (constellation) has a fix while its validated fixes are not contradicted by another sentence
  type of it saying *no fix* within :data:`FIX_MEMORY` (a Garmin in simulator mode: RMC ``A``
  without a mode field, GGA quality 8); a fix that has stood so for :data:`CONFIRM` (one
  epoch's sentences have arrived) is good, and only then becomes latitude and longitude (and
  the height above sea level from GGA/GNS);
* satellites used and fix quality per talker (GP, GL, GA, GB/BD, GQ, GI; GN is the combined
  solution): ``satellites`` is GN's count, else the sum of the others, so ``$GLGGA`` never
  overwrites ``$GPGGA``; satellites in view from GSV;
* the UTC date and time from RMC (status ``A``, a fix mode, a plausible date) and ZDA (trusted
  only while a validated fix is fresh) — ``time``, and ``time_received`` on the reader's clock
  at the *line's arrival*, to extrapolate from. A week-rollover date is corrected (with a note).
  Each accepted time is compared with the system clock (``wall``): ``clock_offset``;
* other valid sentences are counted in ``ignored`` (they are still data: GSV, GSA, VTG);
  lines without any sentence in ``garbage``; wrong checksums in ``bad_checksums`` — all are
  dropped, none raises.

States: *position good* while the port is open and some talker's last validated fix is
younger than ``position_timeout``; *time valid* while the last accepted time is younger than
``time_timeout`` and the last position sentence of some talker was a validated fix no older
than :data:`FIX_MEMORY` (or the timeouts, when longer); *time good* while it is valid and within
``clock_tolerance`` of the system clock; *data good* while any valid sentence came within the
longer timeout. A timer at the next deadline re-evaluates them, so a silent or unplugged
receiver turns *loose* on time without polling. Each change of position or time good calls the
listeners with a :class:`GpsEvent` carrying the OpenTCI event number: 25 POSITION_GOOD / 24
POSITION_LOOSE, 27 TIME_GOOD / 26 TIME_LOOSE. Both start loose (no event for that).

A read error (device unplugged, socket closed) closes the port and reopens it after a backoff
(``reopen_min`` doubling to ``reopen_max``); nothing propagates to the caller.

The OpenTCI GPS module reads :attr:`GpsReader.status`; nothing here knows OpenTCI.
"""

from __future__ import annotations

import asyncio
import logging
import re
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import pynmea2
import serial

from tcs.config.gps import GpsSection
from tcs.drivers.nmea_judge import CONSTELLATIONS, QUALITY_NAMES, judge
from tcs.errors import ErrorNumber
from tcs.state_epoch import bump as bump_epoch

__all__ = ["GpsReader", "GpsStatus", "GpsEvent", "CONFIRM"]

log = logging.getLogger(__name__)
MAX_LINE = 120      # NMEA allows 82 characters; anything much longer is noise
MAX_BUFFER = 4096
FIX_MEMORY = 10.0   # s a validated fix vouches for a ZDA time (see GpsReader._fix_memory)
CONFIRM = 1.0       # s a fix must stand uncontradicted before it is good (one epoch's sentences)
LINE_END = re.compile(rb"[\r\n]")   # CR LF, and receivers that end lines with CR or LF alone
#: One sentence anywhere in a line: binary bytes (UBX, SBF) before it on the same line are
#: skipped. ``$``, ``!`` and ``*`` cannot occur inside, so a match never spans two sentences.
SENTENCE = re.compile(rb"[$!][A-Z][A-Z0-9]{1,9},[\x20\x22\x23\x25-\x29\x2b-\x7e]*\*[0-9A-Fa-f]{2}")


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
    fix_quality: int                # GGA code of the last position sentence (0-8)
    satellites: int | None          # used: the combined (GN) count, else the sum per constellation
    hdop: float | None
    time: float | None              # UTC, seconds since 1970, of the last valid time sentence
    time_received: float | None     # reader clock when that sentence arrived
    last_sentence_age: float | None  # seconds since the last valid sentence of any type
    sentences: int
    bad_checksums: int
    garbage: int
    ignored: int
    port_error: str
    time_valid: bool = False        # the receiver's time is validated (GPS.TIME is served)
    clock_offset: float | None = None   # receiver UTC minus the system clock at arrival, s
    data_good: bool = False         # valid sentences (of any type) keep coming
    fix_reason: str = ""            # why the last position sentence was no fix
    time_reason: str = ""           # why the last time was refused
    time_note: str = ""             # a week rollover corrected
    fix_source: str = ""            # talker and sentence of the last fix ("GNRMC")
    time_source: str = ""
    constellations: tuple = ()      # (talker, used, in view, quality, fix) per fresh talker
    mixed: int = 0                  # lines with other bytes around a sentence

    @property
    def quality_name(self) -> str:
        return QUALITY_NAMES.get(self.fix_quality, "unknown")

    def summary(self) -> str:
        """One line a person reads: the fix, its satellites, the time."""
        if not self.port_open:
            return f"no receiver: {self.port_error or 'port closed'}"
        if not self.data_good:
            return "no data"
        parts = [f"fix {self.fix_quality} ({self.quality_name}) from {self.fix_source}" if self.position_good
                 else "no fix" + (f": {self.fix_reason}" if self.fix_reason else "")]
        if self.satellites is not None:
            parts.append(f"{self.satellites} satellites used")
        if self.time_valid:
            parts.append(f"time from {self.time_source}, {self.clock_offset:+.3f} s from the system clock"
                         if self.clock_offset is not None else "time valid")
        else:
            parts.append("no valid time" + (f": {self.time_reason}" if self.time_reason else ""))
        if self.time_note:
            parts.append(self.time_note)
        return "; ".join(parts)

    def constellation_text(self) -> str:
        """``GP 9/12 autonomous; GL 5/8 autonomous`` (used/in view, quality), fresh talkers only."""
        out = []
        for talker, used, in_view, quality, fix in self.constellations:
            name = CONSTELLATIONS.get(talker, talker)
            counts = f"{'-' if used is None else used}/{'-' if in_view is None else in_view}"
            out.append(f"{talker} {name} {counts} {QUALITY_NAMES.get(quality, '?') if fix else 'no fix'}")
        return "; ".join(out)


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
                 wall: Callable[[], float] = time.time, name: str = "gps"):
        self.section = section
        self.clock = clock
        self.wall = wall
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
        self._quality = 0
        self._fix_at: float | None = None
        self._time: float | None = None
        self._time_at: float | None = None
        self._sentence_at: float | None = None
        self.sentences = self.bad_checksums = self.garbage = self.ignored = self.mixed = 0
        self._position_good = self._time_good = self._time_valid = False
        self._said: dict[tuple[str, str], tuple[bool, float]] = {}  # (talker, kind) -> (fix?, when)
        self._fix_run: dict[str, float] = {}     # talker -> start of its uncontradicted run of fixes
        self._candidate: tuple | None = None  # (talker, lat, lon, height, source, when): not yet confirmed
        self._constellations: dict[str, dict] = {}
        self._fix_reason = self._time_reason = self._time_note = ""
        self._fix_source = self._time_source = ""
        self._clock_offset: float | None = None

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
        """The receiver's time is valid *and* agrees with the system clock (events 27/26)."""
        return self._time_good

    @property
    def time_valid(self) -> bool:
        """The receiver's time is valid (it may still disagree with the system clock)."""
        return self._time_valid

    def _satellites(self, now: float, fresh: list) -> int | None:
        combined = [e["used"] for t, e in fresh if t == "GN" and e["used"] is not None]
        if combined:
            return combined[0]
        used = [e["used"] for t, e in fresh if t not in ("GN", "PUBX") and e["used"] is not None]
        if used:
            return sum(used)
        pubx = [e["used"] for t, e in fresh if t == "PUBX" and e["used"] is not None]
        return pubx[0] if pubx else None

    @property
    def status(self) -> GpsStatus:
        now = self.clock()
        s = self.section
        age = max(10.0, 3 * s.position_timeout)
        fresh = [(t, e) for t, e in sorted(self._constellations.items()) if now - e["at"] < age]
        data = (self._serial is not None and self._sentence_at is not None
                and now - self._sentence_at < max(s.position_timeout, s.time_timeout))
        return GpsStatus(
            port_open=self._serial is not None, position_good=self._position_good,
            time_good=self._time_good, latitude=self._lat, longitude=self._lon, height=self._height,
            fix_quality=self._quality, satellites=self._satellites(now, fresh), hdop=self._hdop,
            time=self._time, time_received=self._time_at,
            last_sentence_age=None if self._sentence_at is None else now - self._sentence_at,
            sentences=self.sentences, bad_checksums=self.bad_checksums, garbage=self.garbage,
            ignored=self.ignored, port_error=self._port_error, time_valid=self._time_valid,
            clock_offset=self._clock_offset if self._time_valid else None, data_good=data,
            fix_reason=self._fix_reason, time_reason=self._time_reason, time_note=self._time_note,
            fix_source=self._fix_source, time_source=self._time_source,
            constellations=tuple((t, e["used"], e["in_view"], e["quality"], e["fix"]) for t, e in fresh),
            mixed=self.mixed)

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
        now = self.clock()       # the bytes' arrival: every line in them is stamped with it
        wall = self.wall()
        self._buffer += data
        *lines, self._buffer = LINE_END.split(self._buffer)
        if len(self._buffer) > MAX_BUFFER:   # kilobytes of binary without a newline: keep only
            cut = self._buffer.rfind(b"$", len(self._buffer) - MAX_LINE)   # a sentence's start
            self._buffer = self._buffer[cut:] if cut >= 0 else b""
            self.garbage += 1
        for line in lines:
            self._line(line.strip(), now, wall)
        self._evaluate()
        bump_epoch()  # GPS.* and LOCAL.* may have changed (tcs.state_epoch)

    def _line(self, raw: bytes, now: float, wall: float) -> None:
        if not raw:
            return
        found = SENTENCE.findall(raw)
        if not found:
            self.garbage += 1
            return
        if len(found) > 1 or len(found[0]) < len(raw):
            self.mixed += 1      # binary (UBX, SBF …) or a broken sentence before it on the line
        for sentence in found:
            self._sentence(sentence, now, wall)

    def _sentence(self, raw: bytes, now: float, wall: float) -> None:
        if len(raw) > MAX_LINE:
            self.garbage += 1
            return
        try:
            msg = pynmea2.parse(raw.decode("ascii"), check=True)
        except pynmea2.ChecksumError:
            self.bad_checksums += 1
            return
        except Exception:  # ParseError, unknown type, anything a mangled line provokes
            self.garbage += 1
            return
        if isinstance(msg, pynmea2.ProprietarySentence):
            talker = ""
            kind = "PUBX00" if msg.manufacturer == "UBX" and msg.data[1:2] == ["00"] else "P" + msg.manufacturer
        else:
            talker, kind = getattr(msg, "talker", ""), getattr(msg, "sentence_type", "")
        try:
            reading = judge(talker, kind, list(msg.data), wall)
        except (ValueError, TypeError, IndexError) as exc:  # a field judge() did not foresee
            log.debug("%s: %s sentence not judged: %s", self.name, kind, exc)
            reading = None
        self._sentence_at = now
        if reading is None or not (reading.position or reading.time_reason or reading.time
                                   or reading.time_unconfirmed):
            self.ignored += 1
            if reading is not None and reading.in_view is not None:
                self._constellation(reading.talker, now)["in_view"] = reading.in_view
            return
        self.sentences += 1
        if reading.position:
            self._position(reading, now)
        self._take_time(reading, now, wall)

    def _constellation(self, talker: str, now: float) -> dict:
        entry = self._constellations.setdefault(talker or "PUBX", {
            "used": None, "in_view": None, "quality": 0, "fix": False})
        entry["at"] = now
        return entry

    def _position(self, r, now: float) -> None:
        entry = self._constellation(r.talker, now)
        entry["quality"], entry["fix"] = r.quality, r.fix
        if r.satellites is not None:
            entry["used"] = r.satellites
        self._quality = r.quality
        if r.hdop is not None:
            self._hdop = r.hdop
        self._said[(r.talker, r.kind)] = (r.fix, now)
        if len(self._said) > 64:   # talkers made up by noise that passed the checksum
            self._prune(now)
        if r.fix and not self._contradicted(r.talker, now):
            self._fix_run.setdefault(r.talker, now)
            height = r.height
            if height is None and self._candidate is not None and self._candidate[0] == r.talker:
                height = self._candidate[3]   # GGA's height stays with the RMC after it
            self._candidate = (r.talker, r.latitude, r.longitude, height, f"{r.talker}{r.kind}", now)
            self._fix_reason = ""
        else:    # this sentence, or another of this talker lately, says: no fix
            self._fix_run.pop(r.talker, None)
            if not r.fix:
                self._fix_reason = r.reason

    def _prune(self, now: float) -> None:
        old = now - 2 * self._fix_memory
        self._said = {key: v for key, v in self._said.items() if v[1] >= old}
        self._constellations = {t: e for t, e in self._constellations.items() if e["at"] >= old}
        self._fix_run = {t: since for t, since in self._fix_run.items() if any(k[0] == t for k in self._said)}

    def _contradicted(self, talker: str, now: float) -> bool:
        """Another sentence type of ``talker`` said *no fix* within the fix memory and has not
        said otherwise since (a Garmin in simulator mode: RMC ``A`` without a mode field, GGA
        quality 8 — the more telling one wins)."""
        memory = self._fix_memory
        return any(not fix and t == talker and now - at < memory for (t, _k), (fix, at) in self._said.items())

    def _last_fix(self, talker: str) -> float | None:
        return max((at for (t, _k), (fix, at) in self._said.items() if t == talker and fix), default=None)

    def _confirmed(self, talker: str, now: float, timeout: float) -> bool:
        """``talker`` has a fix that has stood uncontradicted for :data:`CONFIRM` (so a sentence
        of the same epoch saying otherwise has had time to arrive) and is younger than ``timeout``."""
        since = self._fix_run.get(talker)
        if since is None or now - since < CONFIRM:
            return False
        last = self._last_fix(talker)
        return last is not None and now - last < timeout

    def _take_time(self, r, now: float, wall: float) -> None:
        if r.time is not None:
            t, source = r.time, f"{r.talker}{r.kind}"
        elif r.time_unconfirmed is not None:
            if not self._fix_fresh(now, self._fix_memory):
                self._time_reason = (f"{r.talker}ZDA not trusted without a valid fix"
                                     + (f" ({self._fix_reason})" if self._fix_reason else ""))
                return
            t, source = r.time_unconfirmed, f"{r.talker}ZDA"
        else:
            if r.time_reason:
                self._time_reason = r.time_reason
            return
        self._time, self._time_at, self._time_source = t, now, source
        self._time_reason = ""
        self._time_note = r.note
        self._clock_offset = t - wall

    @property
    def _fix_memory(self) -> float:
        """How long a validated fix vouches for the time (ZDA) when no position sentence came
        since: receivers sending GGA/RMC every few seconds and ZDA every second exist. A
        sentence saying *no fix* ends it at once."""
        s = self.section
        return max(s.time_timeout, s.position_timeout, FIX_MEMORY)

    def _fix_fresh(self, now: float, timeout: float) -> bool:
        return any(self._confirmed(talker, now, timeout) for talker in self._fix_run)

    def _evaluate(self) -> None:
        now = self.clock()
        s = self.section
        port = self._serial is not None
        pos = port and self._fix_fresh(now, s.position_timeout)
        c = self._candidate
        if c is not None and self._confirmed(c[0], now, s.position_timeout):
            _talker, self._lat, self._lon, height, self._fix_source, self._fix_at = c
            if height is not None:
                self._height = height
            self._candidate = (*c[:3], height, *c[4:])   # kept: the next sentence may lack a height
        valid = (port and self._time_at is not None and now - self._time_at < s.time_timeout
                 and self._fix_fresh(now, self._fix_memory))
        self._time_valid = valid
        tim = valid and self._clock_offset is not None and abs(self._clock_offset) <= s.clock_tolerance
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
        if self._sentence_at is None:
            return "no data"
        if now - self._sentence_at >= max(self.section.position_timeout, self.section.time_timeout):
            return f"silent for {now - self._sentence_at:.1f} s"
        if not self._fix_fresh(now, self._fix_memory if time else self.section.position_timeout):
            return "no fix" + (f" ({self._fix_reason})" if self._fix_reason else "")
        if time:
            if self._time_valid and self._clock_offset is not None:
                return (f"differs from the system clock by {self._clock_offset:+.3f} s "
                        f"(tolerance {self.section.clock_tolerance:g} s)")
            last = self._time_at
            if self._time_reason:
                return self._time_reason
            if last is None:
                return "no time sentence (RMC or ZDA)"
            return f"no valid time for {now - last:.1f} s"
        return f"no fix for {now - self._fix_at:.1f} s" if self._fix_at is not None else "no fix"

    def _schedule(self, now: float) -> None:
        """Arm one timer at the next instant a good state would expire."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        deadlines = []
        s = self.section
        fixes = [at for at in map(self._last_fix, self._fix_run) if at is not None]
        deadlines += [since + CONFIRM for since in self._fix_run.values() if now - since < CONFIRM]
        if self._position_good and fixes:
            deadlines.append(max(fixes) + s.position_timeout)
        if self._time_valid and self._time_at is not None and fixes:
            deadlines.append(min(self._time_at + s.time_timeout, max(fixes) + self._fix_memory))
        if self._sentence_at is not None and now - self._sentence_at < max(s.position_timeout, s.time_timeout):
            deadlines.append(self._sentence_at + max(s.position_timeout, s.time_timeout))  # data_good ends
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
