"""GPS (spec §11): the receiver's time and position, its good/loose events, and SYNCPOS.

How it works
------------
:class:`GpsModule` wraps a running :class:`~tcs.drivers.gps.GpsReader` (NMEA on a serial line).

``TIME``
    The receiver's UTC (seconds since 1970) extrapolated from its last accepted RMC/ZDA with the
    reader's clock, while the receiver's time is *valid* — also while it disagrees with the
    system clock, so an operator sees both (``LOCAL.UTC`` is the system's); ``NULL`` otherwise
    (a stale clock would look like a valid one). Nothing is set from it.
``POS.LAT`` / ``POS.LON`` / ``POS.HEIGHT``
    The last validated fix (degrees north, degrees east, metres above mean sea level); ``NULL``
    before the first fix. A telescope does not move, so the last fix stays served while the
    receiver is silent — ``ERROR_STATE`` tells whether it is current.
Extensions
    ``TIME_OFFSET`` (GPS minus system clock), ``SATELLITES``, ``FIX_QUALITY`` (GGA code),
    ``CONSTELLATIONS`` and ``SUMMARY`` (docs/gps.md).
Events
    The reader's state changes become ``POSITION_GOOD`` 25 / ``POSITION_LOOSE`` 24 and
    ``TIME_GOOD`` 27 / ``TIME_LOOSE`` 26. Appendix B lists them for module ``LOCAL``, and clients
    filter on that, so they are sent as ``EVENT INFO LOCAL:25 …`` (loose ones as ``WARN``):
    they tell whether LOCAL's position and time base are backed by the GPS.
``ERROR_STATE``
    One condition says what is true: ERROR ``no GPS data`` while no valid sentence of any kind
    comes (receiver silent, unplugged, sending garbage or bad checksums); else WARNING ``no GPS
    fix`` ("no fix (antenna): " and the receiver's reason) while it talks without a validated
    fix; else WARNING ``GPS fix without time`` while it has a fix but no valid date and time.
    Besides, ERROR ``GPS time disagrees with the clock`` while a valid GPS time is more than
    ``clock_tolerance`` from the system clock. Conditions are judged every second after a grace
    period of the longer of the two timeouts and the second a fix needs to stand after start,
    and latch until ``ERROR_STATE=0`` like every module's.
``LOCAL.SYNCPOS`` ≠ 0
    The site follows the GPS (:meth:`~tcs.model.local.LocalTime.follow_gps`): at once when the
    position becomes good or SYNCPOS is switched on, then at most once a minute while the fix
    differs from LOCAL's site (the site is persisted: a jittering receiver must not write the
    state file every second). The check runs every second on a timer. Only a validated fix is
    taken, and only within LOCAL's own ranges (:meth:`~tcs.model.local.LocalTime.follow_gps`).
"""

from __future__ import annotations

import asyncio
import logging

from tcs.drivers.gps import CONFIRM, GpsEvent, GpsReader
from tcs.errors import ErrorNumber
from tcs.model.events import INFO, WARN
from tcs.model.health import ERROR, WARNING, ModuleHealth

log = logging.getLogger(__name__)

NO_DATA, NO_FIX, NO_TIME, CLOCK = ("no GPS data", "no GPS fix", "GPS fix without time",
                                  "GPS time disagrees with the clock")
CONDITIONS = (NO_DATA, NO_FIX, NO_TIME, CLOCK)
FOLLOW_EVERY = 60.0     # s between site updates while SYNCPOS is on
CHECK_EVERY = 1.0       # s between checks of the SYNCPOS rule
SAME_ANGLE = 1e-7       # deg: a fix this close to the site is the site
SAME_HEIGHT = 0.01      # m


class GpsModule(ModuleHealth):
    """Domain object of the GPS module."""

    def __init__(self, reader: GpsReader, local, events=None, hw_type: int = 1):
        super().__init__("GPS", events, hw_type=hw_type)
        self.reader = reader
        self.local = local
        self._remove = None
        self._timer: asyncio.TimerHandle | None = None
        self._judging = False
        self._grace: asyncio.TimerHandle | None = None
        self._last_follow: float | None = None
        self._texts: dict[str, str] = {}      # condition -> the text it was raised with
        self._syncpos_was = False

    # -- life cycle --------------------------------------------------------------------------
    def start(self) -> None:
        """Follow the reader (which must be started); call on the event loop."""
        loop = asyncio.get_running_loop()
        self._remove = self.reader.add_listener(self._on_event)
        grace = max(self.reader.section.position_timeout, self.reader.section.time_timeout) + CONFIRM
        self._grace = loop.call_later(grace, self._start_judging)
        self._timer = loop.call_later(CHECK_EVERY, self._tick)

    def close(self) -> None:
        if self._remove is not None:
            self._remove()
            self._remove = None
        for handle in (self._timer, self._grace):
            if handle is not None:
                handle.cancel()
        self._timer = self._grace = None

    # -- values --------------------------------------------------------------------------------
    @property
    def time(self) -> float | None:
        """What the receiver says while its time is valid — also while it disagrees with the
        system clock (the condition says so; an operator sees both)."""
        return self.reader.gps_time() if self.reader.time_valid else None

    @property
    def time_offset(self) -> float | None:
        """GPS time minus the system clock at the sentence's arrival, s (NULL without a valid time)."""
        return self.reader.status.clock_offset

    @property
    def satellites(self) -> int | None:
        return self.reader.status.satellites

    @property
    def fix_quality(self) -> int:
        st = self.reader.status
        return st.fix_quality if st.data_good else 0

    @property
    def status_text(self) -> str:
        return self.reader.status.summary()

    @property
    def constellations(self) -> str:
        return self.reader.status.constellation_text()

    @property
    def latitude(self) -> float | None:
        return self.reader.status.latitude

    @property
    def longitude(self) -> float | None:
        return self.reader.status.longitude

    @property
    def height(self) -> float | None:
        return self.reader.status.height

    # -- reactions -----------------------------------------------------------------------------
    def _on_event(self, event: GpsEvent) -> None:
        good = event.number in (ErrorNumber.POSITION_GOOD, ErrorNumber.TIME_GOOD)
        if self._events is not None:
            self._events.emit(INFO if good else WARN, "LOCAL", event.number, event.message)
        if self._judging:
            self._judge()
        if event.number == ErrorNumber.POSITION_GOOD:
            self._follow(force=True)

    def _start_judging(self) -> None:
        self._grace = None
        self._judging = True
        self._judge()

    def _judge(self) -> None:
        """Raise the one condition that says what is true, clear the others (they latch)."""
        st = self.reader.status
        found: dict[str, tuple[int, str]] = {}
        if not st.data_good:
            why = st.port_error or (f"no valid sentence for {st.last_sentence_age:.1f} s"
                                    if st.last_sentence_age is not None else "no valid sentence")
            found[NO_DATA] = (ERROR, f"GPS receiver: {why}")
        elif not st.position_good:
            found[NO_FIX] = (WARNING, "no fix (antenna): " + (st.fix_reason or "no position sentence"))
        elif not st.time_valid:
            found[NO_TIME] = (WARNING, "GPS fix without time: "
                              + (st.time_reason or "no RMC or ZDA sentence with a valid date"))
        tolerance = self.reader.section.clock_tolerance
        if st.time_valid and st.clock_offset is not None and abs(st.clock_offset) > tolerance:
            found[CLOCK] = (ERROR, f"GPS time differs from the system clock by {st.clock_offset:+.3f} s "
                                   f"(tolerance {tolerance:g} s)")
        active = self.conditions()
        for name in CONDITIONS:
            if name in found:
                if not active.get(name, (0, False))[1]:
                    bits, text = found[name]
                    self._texts[name] = text
                    self.raise_condition(name, bits, text)
                    log.warning("GPS: %s", text)
            elif active.get(name, (0, False))[1]:
                self.clear_condition(name)

    def conditions_text(self) -> str:
        """The active conditions with the texts they were raised with (status page, tests)."""
        active = self.conditions()
        return "; ".join(self._texts.get(n, n) for n in CONDITIONS if active.get(n, (0, False))[1])

    def _tick(self) -> None:
        self._timer = asyncio.get_running_loop().call_later(CHECK_EVERY, self._tick)
        try:
            syncpos = bool(self.local.syncpos)
            fresh = syncpos and not self._syncpos_was
            self._syncpos_was = syncpos
            self._follow(force=fresh)
            if self._judging:
                self._judge()
        except Exception:  # a timer must keep running
            log.exception("GPS: following the site failed")

    def _follow(self, force: bool = False) -> None:
        st = self.reader.status
        if not self.local.syncpos or not st.position_good or st.latitude is None:
            return          # only a validated fix (tcs.drivers.nmea_judge) moves the site
        height = st.height if st.height is not None else self.local.height
        if (abs(st.latitude - self.local.latitude) <= SAME_ANGLE
                and abs(st.longitude - self.local.longitude) <= SAME_ANGLE
                and abs(height - self.local.height) <= SAME_HEIGHT):
            return
        now = asyncio.get_running_loop().time()
        if not force and self._last_follow is not None and now - self._last_follow < FOLLOW_EVERY:
            return
        if self.local.follow_gps(st.latitude, st.longitude, height):
            self._last_follow = now
            log.info("LOCAL follows the GPS: %.6f, %.6f, %.1f m", st.latitude, st.longitude, height)
