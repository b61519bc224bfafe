"""ICRS (J2000) ↔ observed place for one site, with pyerfa (OpenTCI §14 steps 1 and 2).

How it works
------------
ERFA splits the ICRS → observed transformation into a *star-independent context* (the
``eraASTROM`` record: Earth position and velocity, precession-nutation, site vector,
refraction constants) and a cheap per-star part (``atciq`` ICRS → CIRS, ``atioq`` CIRS →
observed). ``erfa.atco13`` recomputes the whole context for every sample (~50 µs). Here:

* Time is cut into buckets of ``context_interval`` seconds (default 30 s). The context of a
  bucket is computed once, for the bucket's *centre*, and cached; it is never older than
  half an interval for any sample (≤ 15 s → ≤ 0.25 mas, measured against ``atco13``).
  Because the bucket only depends on the time, a result never depends on call history.
* Per sample only the Earth rotation angle is brought up to date (``aper13``), then
  ``atciq`` + ``atioq`` run vectorised over numpy arrays (< 1 µs a sample for 60 samples).
* The context is built like ``erfa.apco13`` but from *our* time base: TT = UTC + (TAI−UTC) +
  32.184 s and UT1 = UTC + (UT1−UTC), both given by the configuration / the LOCAL module,
  never from ERFA's built-in leap-second table. Polar motion is taken as zero.

Units at this API: RA, HA and sidereal time in hours; Dec, Az, ZD and PA in degrees; times
as Unix seconds (POSIX UTC, i.e. without leap seconds). Azimuth is 0 = north, 90 = east;
ZD is the observed (refracted) zenith distance, > 90 below the horizon.

Refraction (§14.3): mode 0 none; mode 1 10 °C and 1010 hPa reduced to the site height with
the isothermal barometric law p = 1010 hPa · exp(−h / (29.3 m/K · 283.15 K)) (scale height
8296 m, the law ERFA's ``refco`` documents); mode 2 the given temperature and pressure (at
the site, no height correction). Relative humidity ``HUMIDITY`` = 0.5 and wavelength
``WAVELENGTH_UM`` = 0.55 µm are fixed. The model is ERFA's A·tan z + B·tan³ z (``refco``).

At a leap second the owner must update TAI−UTC and UT1−UTC together (a new
:class:`Astrometry`); Unix time itself does not show the inserted second.

What may touch it
-----------------
An :class:`Astrometry` is immutable configuration plus a cache: every public method is safe
to call from several threads at once (the cache is guarded by a lock; cached contexts are
never mutated). To change site, time base or refraction, build a new instance with
:meth:`Astrometry.replace` (cheap) and swap the reference. It does no I/O and knows nothing
of axes or the OpenTCI tree.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import erfa
import numpy as np

from tcs.errors import RangeRefused

__all__ = [
    "Site", "TimeBase", "Refraction", "Observed", "Astrometry",
    "HUMIDITY", "WAVELENGTH_UM", "DEFAULT_TEMPERATURE", "DEFAULT_PRESSURE", "SCALE_HEIGHT",
]

#: Relative humidity (0…1) used for refraction in every mode.
HUMIDITY = 0.5
#: Effective wavelength (µm) used for refraction in every mode.
WAVELENGTH_UM = 0.55
#: Refraction mode 1: temperature (°C) and sea-level pressure (hPa).
DEFAULT_TEMPERATURE = 10.0
DEFAULT_PRESSURE = 1010.0
#: Barometric scale height (m) for mode 1: 29.3 m/K × 283.15 K (ERFA ``refco`` note).
SCALE_HEIGHT = 29.3 * (273.15 + DEFAULT_TEMPERATURE)

_D2R = math.pi / 180.0
_R2D = 180.0 / math.pi
_R2H = 12.0 / math.pi
_UNIX_JD = 2440587.5
_TT_TAI = 32.184
_CACHE_SIZE = 32
_INVERSE_STEPS = 8          # fixed-point steps of the exact inverse (2–3 above ZD 85°)
_INVERSE_TOL = 1e-12        # radians (0.2 µas)


def _jd(utc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unix seconds → two-part Julian date (integer days since 1970 + fraction)."""
    days = np.floor(utc / 86400.0)
    return _UNIX_JD + days, (utc - days * 86400.0) / 86400.0


@dataclass(frozen=True)
class Site:
    """Geodetic site: latitude (deg, north +), longitude (deg, east +), height (m, WGS84)."""

    latitude: float
    longitude: float
    height: float = 0.0

    def __post_init__(self):
        if not -90.0 <= self.latitude <= 90.0:
            raise RangeRefused(f"site latitude {self.latitude} outside -90…90 degrees")
        if not math.isfinite(self.longitude):
            raise RangeRefused(f"site longitude {self.longitude} is not a number")
        if not -1000.0 <= self.height <= 10000.0:
            raise RangeRefused(f"site height {self.height} m outside -1000…10000")


@dataclass(frozen=True)
class TimeBase:
    """Offsets of the time scales from UTC, seconds: TAI−UTC (leap seconds) and UT1−UTC."""

    tai_utc: float = 37.0
    ut1_utc: float = 0.0

    def __post_init__(self):
        if not 0.0 <= self.tai_utc <= 100.0:
            raise RangeRefused(f"TAI-UTC {self.tai_utc} s outside 0…100")
        if not -1.0 <= self.ut1_utc <= 1.0:
            raise RangeRefused(f"UT1-UTC {self.ut1_utc} s outside -1…1")

    def ut1(self, utc):
        """UT1 as Unix-style seconds (the OpenTCI trajectory time base) for a UTC time."""
        return utc + self.ut1_utc

    def utc_from_ut1(self, ut1):
        """Inverse of :meth:`ut1`."""
        return ut1 - self.ut1_utc

    def tai(self, utc):
        """TAI as Unix-style seconds for a UTC time."""
        return utc + self.tai_utc


@dataclass(frozen=True)
class Refraction:
    """OpenTCI §14.3 refraction settings; ``temperature`` (°C) / ``pressure`` (hPa) for mode 2."""

    mode: int = 1
    temperature: float = DEFAULT_TEMPERATURE
    pressure: float = DEFAULT_PRESSURE

    def __post_init__(self):
        if self.mode not in (0, 1, 2):
            raise RangeRefused(f"refraction mode {self.mode} is not 0, 1 or 2")
        if not -100.0 <= self.temperature <= 100.0:
            raise RangeRefused(f"refraction temperature {self.temperature} °C outside -100…100")
        if not 0.0 <= self.pressure <= 1200.0:
            raise RangeRefused(f"refraction pressure {self.pressure} hPa outside 0…1200")

    def conditions(self, height: float) -> tuple[float, float]:
        """Pressure (hPa, 0 = no refraction) and temperature (°C) used at a site height (m)."""
        if self.mode == 0:
            return 0.0, DEFAULT_TEMPERATURE
        if self.mode == 1:
            return DEFAULT_PRESSURE * math.exp(-height / SCALE_HEIGHT), DEFAULT_TEMPERATURE
        return float(self.pressure), float(self.temperature)


@dataclass(frozen=True)
class Observed:
    """Observed place of a target; floats for scalar input, numpy arrays otherwise.

    Attributes
    ----------
    az : azimuth, degrees 0…360, 0 = north, 90 = east.
    zd : observed (refracted) zenith distance, degrees.
    ha : observed hour angle, hours −12…12 (west positive): the RA-DEC mount's axis frame.
    dec : observed (topocentric, refracted) declination, degrees.
    pa : parallactic angle, degrees −180…180 (positive west of the meridian).
    lst : local apparent sidereal time, hours 0…24.
    """

    az: float | np.ndarray
    zd: float | np.ndarray
    ha: float | np.ndarray
    dec: float | np.ndarray
    pa: float | np.ndarray
    lst: float | np.ndarray


def _out(x: np.ndarray, scalar: bool):
    return float(x) if scalar else x


def _wrap_hours(h: np.ndarray) -> np.ndarray:
    """Hours into (−12, 12]."""
    return 12.0 - np.mod(12.0 - h, 24.0)


class Astrometry:
    """ICRS ↔ observed transformations for one site, time base and refraction setting.

    Parameters
    ----------
    site, timebase, refraction:
        The configuration (immutable for the life of the instance).
    context_interval:
        Seconds between star-independent contexts, 10…60 (default 30).

    Notes
    -----
    All methods accept scalars or numpy arrays (broadcast together) and return floats for
    scalar input, arrays otherwise. Thread-safe; see the module docstring.
    """

    def __init__(self, site: Site, timebase: TimeBase = TimeBase(),
                 refraction: Refraction = Refraction(), *, context_interval: float = 30.0):
        if not 10.0 <= context_interval <= 60.0:
            raise RangeRefused(f"astrometry context interval {context_interval} s outside 10…60")
        self._site = site
        self._timebase = timebase
        self._refraction = refraction
        self._interval = float(context_interval)
        self._phpa, self._tc = refraction.conditions(site.height)
        self._lock = threading.Lock()
        self._cache: OrderedDict[int, tuple[np.ndarray, float]] = OrderedDict()

    # -- configuration -------------------------------------------------------------------
    @property
    def site(self) -> Site:
        return self._site

    @property
    def timebase(self) -> TimeBase:
        return self._timebase

    @property
    def refraction(self) -> Refraction:
        return self._refraction

    @property
    def context_interval(self) -> float:
        return self._interval

    def replace(self, **changes) -> "Astrometry":
        """A new instance with some of ``site``, ``timebase``, ``refraction``,
        ``context_interval`` changed (the cache starts empty)."""
        kw = dict(site=self._site, timebase=self._timebase, refraction=self._refraction,
                  context_interval=self._interval)
        unknown = set(changes) - set(kw)
        if unknown:
            raise TypeError(f"Astrometry.replace: unknown fields {sorted(unknown)}")
        kw.update(changes)
        interval = kw.pop("context_interval")
        return Astrometry(**kw, context_interval=interval)

    # -- contexts ------------------------------------------------------------------------
    def _build_contexts(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Contexts (``eraASTROM`` array) and equations of the origins for bucket keys."""
        centre = (keys.astype(np.float64) + 0.5) * self._interval
        d1, d2 = _jd(centre)
        tb = self._timebase
        tt2 = d2 + (tb.tai_utc + _TT_TAI) / 86400.0
        ut2 = d2 + tb.ut1_utc / 86400.0
        pvh, pvb = erfa.epv00(d1, tt2)
        rnpb = erfa.pnm06a(d1, tt2)
        x, y = erfa.bpn2xy(rnpb)
        s = erfa.s06(d1, tt2, x, y)
        theta = erfa.era00(d1, ut2)
        sp = erfa.sp00(d1, tt2)
        refa, refb = erfa.refco(self._phpa, self._tc, HUMIDITY, WAVELENGTH_UM)
        site = self._site
        astrom = erfa.apco(d1, tt2, pvb, pvh["p"], x, y, s, theta,
                           site.longitude * _D2R, site.latitude * _D2R, site.height,
                           0.0, 0.0, sp, refa, refb)
        return np.atleast_1d(astrom), np.atleast_1d(erfa.eors(rnpb, s))

    def _lookup(self, keys: list[int]) -> dict[int, tuple[np.ndarray, float]]:
        """Cached contexts for bucket keys, computing (vectorised) the missing ones."""
        found: dict[int, tuple[np.ndarray, float]] = {}
        with self._lock:
            for k in keys:
                hit = self._cache.get(k)
                if hit is not None:
                    self._cache.move_to_end(k)
                    found[k] = hit
        if len(found) < len(keys):
            missing = np.array([k for k in keys if k not in found], dtype=np.int64)
            astroms, eos = self._build_contexts(missing)
            new = {int(k): (astroms[i:i + 1].copy(), float(eos[i])) for i, k in enumerate(missing)}
            found.update(new)
            with self._lock:
                self._cache.update(new)
                while len(self._cache) > _CACHE_SIZE:
                    self._cache.popitem(last=False)
        return found

    def _contexts(self, utc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample contexts (flat ``utc``) with each sample's Earth rotation angle, and EO."""
        keys = np.floor(utc / self._interval).astype(np.int64)
        if keys.size and (keys.size == 1 or (keys == keys[0]).all()):
            k = int(keys[0])
            base, eo = self._lookup([k])[k]
            eo = np.full(keys.shape, eo)
        else:
            ukeys, inverse = np.unique(keys, return_inverse=True)
            klist = ukeys.tolist()
            found = self._lookup(klist)
            inverse = inverse.reshape(-1)
            base = np.concatenate([found[k][0] for k in klist])[inverse]
            eo = np.array([found[k][1] for k in klist])[inverse]
        d1, d2 = _jd(utc)
        astrom = erfa.aper13(d1, d2 + self._timebase.ut1_utc / 86400.0, base)
        return astrom, eo

    # -- forward -------------------------------------------------------------------------
    def _forward(self, ra: np.ndarray, dec: np.ndarray, utc: np.ndarray):
        """Radians in → (az, zd, ha, dec_obs, eral, eo) radians, flat arrays."""
        astrom, eo = self._contexts(utc)
        ri, di = erfa.atciq(ra, dec, 0.0, 0.0, 0.0, 0.0, astrom)
        az, zd, ha, dob, _rob = erfa.atioq(ri, di, astrom)
        return az, zd, ha, dob, astrom["eral"], eo

    def observed(self, ra_h, dec_deg, utc) -> Observed:
        """Observed place of ICRS (J2000) positions.

        Parameters
        ----------
        ra_h : right ascension, hours.
        dec_deg : declination, degrees.
        utc : Unix seconds (UTC).

        Returns
        -------
        Observed
            Az/ZD (degrees), observed HA (hours) and Dec (degrees), parallactic angle
            (degrees) and local apparent sidereal time (hours) per sample.
        """
        ra, dec, t = np.broadcast_arrays(np.asarray(ra_h, float), np.asarray(dec_deg, float),
                                         np.asarray(utc, float))
        shape, scalar = ra.shape, ra.ndim == 0
        az, zd, ha, dob, eral, eo = self._forward(ra.ravel() * (math.pi / 12.0),
                                                  dec.ravel() * _D2R, t.ravel())
        pa = erfa.hd2pa(ha, dob, self._site.latitude * _D2R)
        lst = np.mod(eral - eo, 2.0 * math.pi) * _R2H
        values = (np.mod(az * _R2D, 360.0), zd * _R2D, _wrap_hours(ha * _R2H), dob * _R2D,
                  pa * _R2D, lst)
        if scalar:
            return Observed(*(float(v[0]) for v in values))
        return Observed(*(v.reshape(shape) for v in values))

    def observed_apparent(self, ra_h, dec_deg, utc) -> Observed:
        """Observed place of *apparent topocentric* directions in GCRS axes (RA hours, Dec
        degrees): light time, deflection and aberration already applied (or, for an Earth
        satellite, deliberately not) by the caller (:mod:`tcs.pointing.targets`). Only the
        bias-precession-nutation, the Earth's rotation and refraction are applied here
        (``bpn`` of the context, then ``atioq``); arrays like :meth:`observed`."""
        ra, dec, t = np.broadcast_arrays(np.asarray(ra_h, float), np.asarray(dec_deg, float),
                                         np.asarray(utc, float))
        shape, scalar = ra.shape, ra.ndim == 0
        astrom, eo = self._contexts(t.ravel())
        v = erfa.s2c(ra.ravel() * (math.pi / 12.0), dec.ravel() * _D2R)
        ri, di = erfa.c2s(erfa.rxp(astrom["bpn"], v))
        az, zd, ha, dob, _rob = erfa.atioq(ri, di, astrom)
        pa = erfa.hd2pa(ha, dob, self._site.latitude * _D2R)
        lst = np.mod(astrom["eral"] - eo, 2.0 * math.pi) * _R2H
        values = (np.mod(az * _R2D, 360.0), zd * _R2D, _wrap_hours(ha * _R2H), dob * _R2D,
                  pa * _R2D, lst)
        if scalar:
            return Observed(*(float(v[0]) for v in values))
        return Observed(*(v.reshape(shape) for v in values))

    def sidereal_time(self, utc):
        """Local apparent sidereal time, hours 0…24, for Unix seconds ``utc``."""
        t = np.asarray(utc, float)
        astrom, eo = self._contexts(t.ravel())
        lst = np.mod(astrom["eral"] - eo, 2.0 * math.pi) * _R2H
        return _out(lst.reshape(t.shape), t.ndim == 0)

    # -- inverse -------------------------------------------------------------------------
    def _inverse(self, kind: str, ob1: np.ndarray, ob2: np.ndarray, utc: np.ndarray):
        """Observed (radians, ``kind`` 'A' = Az/ZD, 'H' = HA/Dec) → ICRS radians.

        ``atoiq``/``aticq`` invert ``atioq``/``atciq`` only to the accuracy of the refraction
        model's inversion (0.7 mas at ZD 70°, 0.1" at 85°, arcsec near the horizon);
        fixed-point steps against the forward transformation make it the inverse of
        :meth:`observed` (< 1 µas above the horizon).
        """
        astrom, _eo = self._contexts(utc)
        t1, t2 = ob1.copy(), ob2.copy()
        for _ in range(_INVERSE_STEPS):
            ri, di = erfa.atoiq(kind, t1, t2, astrom)
            rc, dc = erfa.aticq(ri, di, astrom)
            ri, di = erfa.atciq(rc, dc, 0.0, 0.0, 0.0, 0.0, astrom)
            az, zd, ha, dob, _rob = erfa.atioq(ri, di, astrom)
            f1, f2 = (az, zd) if kind == "A" else (ha, dob)
            e1 = np.angle(np.exp(1j * (ob1 - f1)))
            e2 = ob2 - f2
            if max(np.abs(e1).max(initial=0.0), np.abs(e2).max(initial=0.0)) < _INVERSE_TOL:
                break
            t1 = t1 + e1
            t2 = t2 + e2
        return np.mod(rc, 2.0 * math.pi), dc

    def icrs_from_observed(self, az, zd, utc):
        """ICRS place seen at observed Az/ZD (degrees) at ``utc``: ``(ra_h, dec_deg)``.

        The exact inverse of :meth:`observed` (same refraction); for POINTING.CURRENT.
        """
        a, z, t = np.broadcast_arrays(np.asarray(az, float), np.asarray(zd, float),
                                      np.asarray(utc, float))
        rc, dc = self._inverse("A", a.ravel() * _D2R, z.ravel() * _D2R, t.ravel())
        scalar = a.ndim == 0
        return (_out((rc * _R2H).reshape(a.shape), scalar),
                _out((dc * _R2D).reshape(a.shape), scalar))

    def icrs_from_hadec(self, ha_h, dec_deg, utc):
        """ICRS place seen at observed HA (hours) / Dec (degrees): ``(ra_h, dec_deg)``."""
        h, d, t = np.broadcast_arrays(np.asarray(ha_h, float), np.asarray(dec_deg, float),
                                      np.asarray(utc, float))
        rc, dc = self._inverse("H", h.ravel() * (math.pi / 12.0), d.ravel() * _D2R, t.ravel())
        scalar = h.ndim == 0
        return (_out((rc * _R2H).reshape(h.shape), scalar),
                _out((dc * _R2D).reshape(h.shape), scalar))

