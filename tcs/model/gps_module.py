"""GPS (spec §11): the receiver's time and position, its good/loose events, and SYNCPOS.

How it works
------------
:class:`GpsModule` wraps a running :class:`~tcs.drivers.gps.GpsReader` (NMEA on a serial line).

``TIME``
    The receiver's UTC (seconds since 1970) extrapolated from its last valid RMC/ZDA with the
    reader's clock, while the time is *good*; ``NULL`` while it is loose (a stale clock would
    look like a valid one).
``POS.LAT`` / ``POS.LON`` / ``POS.HEIGHT``
    The last fix (degrees north, degrees east, metres above mean sea level); ``NULL`` before the
    first fix. A telescope does not move, so the last fix stays served while the receiver is
    silent — ``ERROR_STATE`` tells whether it is current.
Events
    The reader's state changes become ``POSITION_GOOD`` 25 / ``POSITION_LOOSE`` 24 and
    ``TIME_GOOD`` 27 / ``TIME_LOOSE`` 26. Appendix B lists them for module ``LOCAL``, and clients
    filter on that, so they are sent as ``EVENT INFO LOCAL:25 …`` (loose ones as ``WARN``):
    they tell whether LOCAL's position and time base are backed by the GPS.
``ERROR_STATE``
    ERROR ``no GPS data`` while neither time nor position is good (receiver silent, unplugged,
    sending garbage or bad checksums), with the reader's reason; WARNING ``no GPS fix`` while
    the time is good but there is no position fix. Conditions are judged only after a grace
    period of the longer of the two timeouts after start (the receiver needs a burst or two),
    and latch until ``ERROR_STATE=0`` like every module's.
``LOCAL.SYNCPOS`` ≠ 0
    The site follows the GPS (:meth:`~tcs.model.local.LocalTime.follow_gps`): at once when the
    position becomes good or SYNCPOS is switched on, then at most once a minute while the fix
    differs from LOCAL's site (the site is persisted: a jittering receiver must not write the
    state file every second). The check runs every second on a timer.
"""

from __future__ import annotations

import asyncio
import logging

from tcs.drivers.gps import GpsEvent, GpsReader
from tcs.errors import ErrorNumber
from tcs.model.events import INFO, WARN
from tcs.model.health import ERROR, WARNING, ModuleHealth

log = logging.getLogger(__name__)

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
        self._syncpos_was = False

    # -- life cycle --------------------------------------------------------------------------
    def start(self) -> None:
        """Follow the reader (which must be started); call on the event loop."""
        loop = asyncio.get_running_loop()
        self._remove = self.reader.add_listener(self._on_event)
        grace = max(self.reader.section.position_timeout, self.reader.section.time_timeout)
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
        return self.reader.gps_time() if self.reader.time_good else None

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
        st = self.reader.status
        if not st.time_good and not st.position_good:
            why = st.port_error or (f"no valid sentence for {st.last_sentence_age:.1f} s"
                                    if st.last_sentence_age is not None else "no valid sentence")
            self.raise_condition("no GPS data", ERROR, f"GPS receiver: {why}")
        elif self.conditions().get("no GPS data", (0, False))[1]:
            self.clear_condition("no GPS data")
        if st.time_good and not st.position_good:
            self.raise_condition("no GPS fix", WARNING, "GPS receiver has no position fix")
        elif self.conditions().get("no GPS fix", (0, False))[1]:
            self.clear_condition("no GPS fix")

    def _tick(self) -> None:
        self._timer = asyncio.get_running_loop().call_later(CHECK_EVERY, self._tick)
        try:
            syncpos = bool(self.local.syncpos)
            fresh = syncpos and not self._syncpos_was
            self._syncpos_was = syncpos
            self._follow(force=fresh)
        except Exception:  # a timer must keep running
            log.exception("GPS: following the site failed")

    def _follow(self, force: bool = False) -> None:
        st = self.reader.status
        if not self.local.syncpos or not st.position_good or st.latitude is None:
            return
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
