"""LOCAL: the telescope's time base and geographic position (OpenTCI §8).

Times come from the system clock (kept by chrony/PPS on a real cabinet) and the configured
offsets: ``UTC`` = system time, ``UT1 = UTC + (UT1−UTC)``, ``TAI = UTC + (TAI−UTC)``; every
trajectory and the pointing code read time through :meth:`LocalTime.ut1` so one clock rules.

``UT1-UTC``, ``TAI-UTC``, ``LATITUDE``, ``LONGITUDE`` and ``HEIGHT`` are writable and
persisted. A persisted value is used after a restart only while the hardware file still holds
the value it was written over — editing the file wins. Writing a site coordinate sets
``SYNCPOS`` to 0 (spec §8); with ``SYNCPOS`` ≠ 0 a GPS, when configured, moves the site
(:meth:`follow_gps`). Longitudes are east-positive inside; ``site.longitude_west_positive``
flips only the served value.
"""

from __future__ import annotations

import time
from typing import Callable

from tcs.config import HwConfig
from tcs.model.health import ModuleHealth
from tcs.model.state_store import StateStore

PERSISTED = ("ut1_utc", "tai_utc", "latitude", "longitude", "height", "syncpos")
#: LOCAL's own ranges (its OpenTCI !MIN/!MAX): a GPS fix outside them never becomes the site.
LATITUDE_RANGE, LONGITUDE_RANGE, HEIGHT_RANGE = (-90.0, 90.0), (-360.0, 360.0), (-500.0, 10000.0)


class LocalTime(ModuleHealth):
    """Domain object of the LOCAL module."""

    def __init__(self, config: HwConfig, store: StateStore, events=None,
                 clock: Callable[[], float] = time.time):
        super().__init__("LOCAL", events)
        self._store = store
        self._clock = clock
        self.west_positive = config.site.longitude_west_positive
        self._config_values = {
            "ut1_utc": config.time.ut1_utc, "tai_utc": config.time.tai_utc,
            "latitude": config.site.latitude, "longitude": config.site.longitude,
            "height": config.site.height, "syncpos": 0,
        }
        saved = store.get("local", {}) or {}
        for key, default in self._config_values.items():
            entry = saved.get(key)
            use_saved = isinstance(entry, dict) and entry.get("config") == default and "value" in entry
            setattr(self, "_" + key, entry["value"] if use_saved else default)

    # -- time ------------------------------------------------------------------------------
    def utc(self) -> float:
        return self._clock()

    def ut1(self) -> float:
        return self._clock() + self._ut1_utc

    def tai(self) -> float:
        return self._clock() + self._tai_utc

    @property
    def ut1_utc(self) -> float:
        return self._ut1_utc

    @property
    def tai_utc(self) -> float:
        return self._tai_utc

    # -- site ------------------------------------------------------------------------------
    @property
    def latitude(self) -> float:
        return self._latitude

    @property
    def longitude(self) -> float:
        """East-positive longitude (what the astrometry uses)."""
        return self._longitude

    @property
    def served_longitude(self) -> float:
        return -self._longitude if self.west_positive else self._longitude

    @property
    def height(self) -> float:
        return self._height

    @property
    def syncpos(self) -> int:
        return self._syncpos

    # -- writes from clients ------------------------------------------------------------------
    def set_ut1_utc(self, value: float) -> None:
        self._save(ut1_utc=float(value))

    def set_tai_utc(self, value: float) -> None:
        self._save(tai_utc=float(value))

    def set_latitude(self, value: float) -> None:
        self._save(latitude=float(value), syncpos=0)

    def set_served_longitude(self, value: float) -> None:
        self._save(longitude=-float(value) if self.west_positive else float(value), syncpos=0)

    def set_height(self, value: float) -> None:
        self._save(height=float(value), syncpos=0)

    def set_syncpos(self, value: int) -> None:
        self._save(syncpos=int(value))

    def follow_gps(self, latitude: float, longitude: float, height: float) -> bool:
        """Move the site to a (validated) GPS fix when ``SYNCPOS`` ≠ 0 and it lies within
        LOCAL's own ranges; True when it did."""
        if not self._syncpos:
            return False
        for value, (lo, hi) in ((latitude, LATITUDE_RANGE), (longitude, LONGITUDE_RANGE),
                                (height, HEIGHT_RANGE)):
            if not isinstance(value, (int, float)) or not lo <= value <= hi:  # NaN fails too
                return False
        self._save(latitude=latitude, longitude=longitude, height=height)
        return True

    def _save(self, **values) -> None:
        for key, value in values.items():
            setattr(self, "_" + key, value)
        self._store.update(local={
            key: {"value": getattr(self, "_" + key), "config": self._config_values[key]}
            for key in PERSISTED})
