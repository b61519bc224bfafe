"""The telescope's catalogue target: what a client names before it says "track" or "go there".

:class:`SkyObject` keeps a target the way clients of the OpenTSI tree write it — RA (hours)
and Dec (degrees) of a mean equator and equinox, an epoch and proper motions, a name — and a
fixed horizontal position (azimuth, altitude) for a goto. It belongs to the telescope model
(``docs/architecture.md`` rule 0); POINTING.TARGET stays what the tracker follows (ICRS J2000),
and :meth:`SkyObject.icrs` turns the catalogue place into that when a track is started.

Conventions (docs/opentsi.md says why):

* ``EQUINOX`` is a Julian equinox in years (2000 = J2000 = ICRS here); other equinoxes are
  precessed to J2000 with IAU 2006 precession (pyerfa ``pmat06``). Equinoxes outside 1900…2100
  are refused (a B1950/FK4 position needs a conversion the clients never asked for).
* ``EPOCH`` is the epoch of the position for proper motion, in years; unset, it is the equinox.
* ``RA_PM`` (RA·cos Dec) and ``DEC_PM`` are in milliarcseconds per year, applied linearly from
  ``EPOCH`` to the time of the track.
* ``RA_RATE`` / ``DEC_RATE`` are differential rates in arcsec per second: RA_RATE on the sky
  (RA·cos Dec, as ephemeris services give "dRA*cosD"), ``RA_RATE_TIME`` the same rate in the
  other convention clients use, seconds of time of RA per second (×15 = arcsec of RA). The
  last one written counts; both read back converted at the target's Dec. At TRACK they become
  POINTING.TARGET.RA_V (arcsec of RA, not × cos Dec) and DEC_V (:func:`tcs.pointing.targets.ra_rate_to_ra_v`).
* Moving targets: ``SOLARSYSTEM.OBJECT`` (index of :data:`tcs.pointing.targets.SOLARSYSTEM_INDEX`:
  0 Sun, 1 Mercury … 7 Neptune, 8 Pluto), ``SOLARSYSTEM.MOON`` = 1, or a TLE (``TLE.LINE1``,
  ``LINE2``, ``NAME``). ``kind`` says what TRACK=1 follows: the kind written last
  (equatorial RA/DEC, a body, a TLE line).
* Horizontal positions are observed (refracted) azimuth (north 0, east 90) and altitude;
  an instrumental goto target is in the main axes' own frame (their TARGETPOS). A goto uses
  the kind written last.

What may touch it: the event loop (tree setters and the operations that start a track).
"""

from __future__ import annotations

import logging
import math

import erfa
import numpy as np

from tcs.errors import RangeRefused

log = logging.getLogger(__name__)

MAS = math.radians(1.0 / 3.6e6)
EQUINOX_RANGE = (1900.0, 2100.0)


class SkyObject:
    """A target as catalogued (see the module docstring)."""

    def __init__(self, mount: str = "AZ-ZD") -> None:
        self.mount = mount          # names the instrumental axes (AZ/ZD or HA/DEC)
        self.ra: float | None = None
        self.dec: float | None = None
        self.equinox = 2000.0
        self.epoch: float | None = None
        self.ra_pm = 0.0
        self.dec_pm = 0.0
        self.name = ""
        self.az: float | None = None
        self.alt: float | None = None
        #: instrumental goto target (axis 1, axis 2) in the axes' own frame (UNAM's "unpark")
        self.instrumental: list[float | None] = [None, None]
        #: which of the two the next goto uses: the one written last
        self.goto_frame = "horizontal"
        #: differential rates: RA in arcsec/s of RA·cos Dec ("sky") or s of time/s ("time")
        self.ra_rate = 0.0
        self.ra_rate_convention = "sky"
        self.dec_rate = 0.0
        #: what TRACK=1 follows: "equatorial", "body" or "satellite" (the kind written last)
        self.kind = "equatorial"
        self.body = ""
        self.solarsystem_index: int | None = None
        self.moon = 0
        self.tle = ["", "", ""]       # LINE1, LINE2, NAME
        self.tle_error = ""           # why the last LINE1/LINE2 write was refused ("": accepted)

    # -- equatorial --------------------------------------------------------------------------
    @property
    def ra_value(self) -> float:
        """RA as served: 0 until written (as POINTING.TARGET; pyobs reads it with float())."""
        return self.ra if self.ra is not None else 0.0

    @property
    def dec_value(self) -> float:
        return self.dec if self.dec is not None else 0.0

    def set_ra(self, value: float) -> None:
        value = float(value)
        if not 0.0 <= value < 24.0:
            raise RangeRefused(f"RA {value} h is outside 0 <= RA < 24")
        self.ra = value
        self.kind = "equatorial"

    def set_dec(self, value: float) -> None:
        value = float(value)
        if not -90.0 <= value <= 90.0:
            raise RangeRefused(f"Dec {value}° is outside -90…90")
        self.dec = value
        self.kind = "equatorial"

    def set_equinox(self, value: float) -> None:
        self.equinox = _years(value, "EQUINOX")

    def set_epoch(self, value: float) -> None:
        self.epoch = _years(value, "EPOCH")

    def set_ra_pm(self, value: float) -> None:
        self.ra_pm = float(value)

    def set_dec_pm(self, value: float) -> None:
        self.dec_pm = float(value)

    def set_name(self, value: str) -> None:
        self.name = str(value)

    # -- rates -------------------------------------------------------------------------------
    def _cos_dec(self) -> float:
        return max(math.cos(math.radians(self.dec_value)), 1e-6)

    @property
    def ra_rate_sky(self) -> float:
        """RA rate, arcsec of RA·cos Dec per second."""
        if self.ra_rate_convention == "sky":
            return self.ra_rate
        return self.ra_rate * 15.0 * self._cos_dec()

    @property
    def ra_rate_time(self) -> float:
        """RA rate, seconds of time of RA per second."""
        if self.ra_rate_convention == "time":
            return self.ra_rate
        return self.ra_rate / self._cos_dec() / 15.0

    def set_ra_rate(self, value: float) -> None:
        self.ra_rate, self.ra_rate_convention = _finite(value, "RA_RATE"), "sky"

    def set_ra_rate_time(self, value: float) -> None:
        self.ra_rate, self.ra_rate_convention = _finite(value, "RA_RATE_TIME"), "time"

    def set_dec_rate(self, value: float) -> None:
        self.dec_rate = _finite(value, "DEC_RATE")

    def rates_v(self, dec_deg: float) -> tuple[float, float]:
        """(RA_V, DEC_V) of POINTING.TARGET: arcsec of RA and of Dec per second at ``dec_deg``."""
        from tcs.pointing.targets import ra_rate_to_ra_v
        return ra_rate_to_ra_v(self.ra_rate, dec_deg, self.ra_rate_convention), self.dec_rate

    # -- solar system and satellites -------------------------------------------------------------
    def set_solarsystem_object(self, value: int) -> None:
        from tcs.pointing.targets import SOLARSYSTEM_INDEX
        index = int(value)
        if not 0 <= index < len(SOLARSYSTEM_INDEX):
            raise RangeRefused(f"SOLARSYSTEM.OBJECT {index}: 0 Sun, 1 Mercury … 7 Neptune, 8 Pluto")
        self.solarsystem_index = index
        self.body, self.kind, self.moon = SOLARSYSTEM_INDEX[index], "body", 0

    def set_solarsystem_name(self, value: str) -> None:
        """The body by name (sun, moon, mercury … pluto): unambiguous, whatever the index."""
        from tcs.pointing.targets import BODIES, SOLARSYSTEM_INDEX
        name = str(value).strip().strip('"').lower()
        if name not in BODIES:
            raise RangeRefused(f"SOLARSYSTEM.NAME {value!r}: one of {', '.join(BODIES)}")
        if name == "moon":
            self.set_moon(1)
            return
        self.set_solarsystem_object(SOLARSYSTEM_INDEX.index(name))

    @property
    def solarsystem_name(self) -> str:
        return self.body if self.kind == "body" else ""

    def set_moon(self, value: int) -> None:
        value = int(value)
        if value not in (0, 1):
            raise RangeRefused(f"SOLARSYSTEM.MOON {value}: 1 tracks the Moon, 0 does not")
        self.moon = value
        if value:
            self.body, self.kind = "moon", "body"
        elif self.kind == "body" and self.body == "moon":
            self.kind = "equatorial"

    def set_tle(self, index: int, value: str) -> None:
        """TLE line 1 (index 0), line 2 (1) or the name (2); a line must be one
        (:func:`~tcs.pointing.targets.check_tle_line`: line number, 69 characters, checksum,
        fields, a perigee SGP4 can propagate), else RANGE, the last good line kept and the
        reason in :attr:`tle_error` (``OBJECT.TLE.ERROR``)."""
        value = str(value).strip().strip('"')
        if index < 2:
            from tcs.pointing.targets import check_tle_line
            try:
                value = check_tle_line(index + 1, value)
            except RangeRefused as exc:
                self.tle_error = f"LINE{index + 1} refused: {exc.message}"
                log.warning("OBJECT.TLE.%s", self.tle_error)
                raise
            self.tle_error = ""
            self.kind = "satellite"
        self.tle[index] = value

    def satellite(self):
        """The TLE as a :class:`~tcs.pointing.targets.SatelliteTarget` (RANGE if it is not one)."""
        from tcs.pointing.targets import SatelliteTarget
        if not (self.tle[0] and self.tle[1]):
            raise RangeRefused("no satellite: write OBJECT.TLE.LINE1 and LINE2 first")
        return SatelliteTarget(line1=self.tle[0], line2=self.tle[1], name=self.tle[2])

    @property
    def equatorial_complete(self) -> bool:
        return self.ra is not None and self.dec is not None

    def icrs(self, utc: float) -> tuple[float, float]:
        """(RA hours, Dec degrees) in ICRS J2000 at ``utc`` (proper motion applied)."""
        if not self.equatorial_complete:
            raise RangeRefused("no target: write OBJECT.EQUATORIAL.RA and DEC first")
        ra, dec = math.radians(self.ra * 15.0), math.radians(self.dec)
        epoch = self.epoch if self.epoch is not None else self.equinox
        if self.ra_pm or self.dec_pm:
            years = float(erfa.epj(2440587.5, utc / 86400.0)) - epoch
            cosd = max(math.cos(dec), 1e-9)
            ra += self.ra_pm * MAS * years / cosd
            dec = max(-math.pi / 2, min(math.pi / 2, dec + self.dec_pm * MAS * years))
        if abs(self.equinox - 2000.0) > 1e-9:
            d1, d2 = erfa.epj2jd(self.equinox)
            rbp = erfa.pmat06(d1, d2)                 # GCRS -> mean equator and equinox of date
            v = erfa.trxp(rbp, erfa.s2c(ra, dec))     # mean of date -> GCRS
            ra, dec = (float(x) for x in erfa.c2s(v))
        return float(erfa.anp(ra)) * 12.0 / math.pi % 24.0, math.degrees(dec)

    # -- horizontal --------------------------------------------------------------------------
    def set_az(self, value: float) -> None:
        value = float(value)
        if not -360.0 <= value <= 720.0:
            raise RangeRefused(f"azimuth {value}° is not an azimuth")
        self.az = value % 360.0
        self.goto_frame = "horizontal"

    def set_alt(self, value: float) -> None:
        value = float(value)
        if not -90.0 <= value <= 90.0:
            raise RangeRefused(f"altitude {value}° is outside -90…90")
        self.alt = value
        self.goto_frame = "horizontal"

    @property
    def zd(self) -> float | None:
        return None if self.alt is None else 90.0 - self.alt

    def set_zd(self, value: float) -> None:
        self.set_alt(90.0 - float(value))

    # -- instrumental ------------------------------------------------------------------------
    def set_instrumental(self, axis: int, value: float) -> None:
        """Axis position (TARGETPOS frame) of a goto; ``axis`` 0 or 1."""
        self.instrumental[axis] = float(value)
        self.goto_frame = "instrumental"


def precess_from_j2000(ra_h: float, dec_deg: float, equinox: float) -> tuple[float, float]:
    """ICRS → mean place of Julian ``equinox`` (the inverse of :meth:`SkyObject.icrs`; tests)."""
    d1, d2 = erfa.epj2jd(equinox)
    v = erfa.rxp(erfa.pmat06(d1, d2), erfa.s2c(math.radians(ra_h * 15.0), math.radians(dec_deg)))
    ra, dec = erfa.c2s(v)
    return float(erfa.anp(ra)) * 12.0 / math.pi, math.degrees(float(dec))


def _finite(value: float, what: str) -> float:
    value = float(value)
    if not math.isfinite(value) or abs(value) > 36000.0:
        raise RangeRefused(f"{what} {value} is not a rate (arcsec/s, at most 10°/s)")
    return value


def _years(value: float, what: str) -> float:
    value = float(value)
    lo, hi = EQUINOX_RANGE
    if not lo <= value <= hi or not np.isfinite(value):
        raise RangeRefused(f"{what} {value} is not a Julian year in {lo:g}…{hi:g}")
    return value


__all__ = ["SkyObject", "precess_from_j2000"]
