"""One target model for every kind of object: what the tracker follows, as an observed path.

How it works
------------
Every target answers :meth:`Target.observed` — the observed place (Az/ZD, HA/Dec, PA, LST;
:class:`~tcs.pointing.astrometry.Observed`) at an array of UTC times — which is what the
tracker (:mod:`tcs.pointing.tracker`) samples into the axes' trajectory queues, through the
pointing model (:class:`~tcs.pointing.demand.Pipeline`). The kinds:

* :class:`IcrsTarget` — a catalogue place in ICRS (any Julian equinox, epoch and proper motion
  are brought there by :meth:`tcs.pointing.sky_object.SkyObject.icrs`, IAU 2006 precession with
  pyerfa), plus differential rates. **Rates** are kept as the model's ``POINTING.TARGET.RA_V`` / ``DEC_V``:
  arcsec *of RA* (not × cos Dec) and arcsec of Dec per SI second. Clients use two conventions
  for the RA rate; :func:`ra_rate_to_ra_v` converts both: ``"time"`` — seconds of time of RA
  per second (× 15 = arcsec of RA; ASCOM's ``RightAscensionRate`` is this per *sidereal*
  second) — and ``"sky"`` — arcsec of RA·cos Dec per second, a great-circle rate on the sky
  (JPL Horizons' "dRA*cosD", MPC): divided by cos Dec. The place goes through pyerfa's
  ICRS → observed transformation (:mod:`tcs.pointing.astrometry`).
* :class:`BodyTarget` — the Sun, the Moon and the planets from the JPL ephemeris DE421 that
  the ``skyfield-data`` package ships (1900–2050; opened from the package, nothing is ever
  downloaded): skyfield's *apparent* topocentric place — light time, light deflection and the
  observer's aberration (annual and diurnal) included — then only the Earth's orientation
  and refraction here (:meth:`~tcs.pointing.astrometry.Astrometry.observed_apparent`). The
  planets beyond Mars are their system barycentres (what DE421 has; ≤ 0.05″ from the centre).
* :class:`SatelliteTarget` — an Earth satellite from a two-line element set: SGP4 (skyfield's
  ``EarthSatellite``), topocentric from the site. As skyfield's ``(satellite - site).at(t)``,
  the place is *geometric*: no light time and no aberration (together up to ~5″ for a LEO;
  far below the along-track error of any TLE, and it keeps the path comparable with what
  everyone else computes from the same TLE). :meth:`SatelliteTarget.plan` plans a pass
  (:class:`PassPlan`): when it rises above the altitude limit and sets, the largest axis
  rates, the cable-wrap turn that keeps AZ inside its range for the whole pass, and — for a
  pass through the zenith keyhole of an AZ-ZD mount, where AZ would need more speed or
  acceleration than the axis has — the best-effort path: AZ *leads*: it starts turning before
  the culmination on a quintic bridge inside 90 % of the axis's speed, acceleration and jerk
  and ends on the target's path after it, symmetric about the culmination; ZD stays near its
  minimum: it is put on the leading azimuth's vertical circle at the point nearest the
  satellite (tan ZD' = tan ZD · cos ΔAZ, over the zenith when AZ lags by more than 90°), so the
  error is asin(sin ZD · |sin ΔAZ|) instead of the whole lag (the plan's ``keyhole_error``). The plan is what OpenTSI's
  ``OBJECT.TLE.PASS.*`` reads and what TRACK=1 then follows (the axes wait at the rise point).
* :class:`HorizontalTarget` — a fixed observed azimuth and altitude (through the pointing
  model like any other path).

TLE validation (docs/satellites.md): :func:`check_tle_line` judges one line by itself — line
number, 69 characters, the mod-10 checksum, its fields, and for line 2 a perigee at least
:data:`MIN_PERIGEE` km up (what SGP4 can propagate); :class:`SatelliteTarget` adds one catalogue
number on both lines and SGP4's own initialisation. :meth:`SatelliteTarget.plan` refuses (a
:meth:`PassPlan.refused` plan: FEASIBLE 0, the reason, the figures None) an epoch further than
``max_age`` days from the planning time, SGP4 errors anywhere in the search, no pass, or a pass
an axis cannot follow — naming the axis and what it would need against its limits.

Time: every method takes Unix UTC seconds and the :class:`~tcs.pointing.astrometry.TimeBase`
of the astrometry it is given (TT = UTC + TAI−UTC + 32.184 s, UT1 = UTC + UT1−UTC): skyfield
gets a timescale with that ΔT, so both libraries see the same instants and Earth angle.

What may touch it
-----------------
Targets are immutable after construction (a planned satellite is a new object); every
method is pure apart from the shared, lazily opened ephemeris (guarded by a lock): safe from
any thread. The OpenTSI tree, Alpaca and POINTING build them; the tracker samples them.
"""

from __future__ import annotations

import math
import threading
import warnings
from dataclasses import dataclass, replace

import erfa
import numpy as np

from tcs.errors import ErrorNumber, RangeRefused, TcsError
from tcs.pointing.astrometry import Astrometry, Observed, TimeBase

__all__ = ["Target", "IcrsTarget", "BodyTarget", "SatelliteTarget", "HorizontalTarget",
           "PassPlan", "check_tle", "check_tle_line", "tle_checksum", "tle_epoch", "BODIES", "SOLARSYSTEM_INDEX", "ra_rate_to_ra_v", "body_rates",
           "ephemeris", "skyfield_time"]

_UNIX_JD = 2440587.5
_TT_TAI = 32.184
_D2R = math.pi / 180.0
_R2D = 180.0 / math.pi

#: bodies by name → their DE421 segment name
BODIES = {
    "sun": "sun", "moon": "moon", "mercury": "mercury", "venus": "venus", "mars": "mars",
    "jupiter": "jupiter barycenter", "saturn": "saturn barycenter",
    "uranus": "uranus barycenter", "neptune": "neptune barycenter", "pluto": "pluto barycenter",
}
#: OpenTSI ``OBJECT.SOLARSYSTEM.OBJECT`` index → body (docs/opentsi.md says why this order)
SOLARSYSTEM_INDEX = ("sun", "mercury", "venus", "mars", "jupiter", "saturn", "uranus",
                     "neptune", "pluto")

_lock = threading.Lock()
_kernel = None
_timescales: dict[float, object] = {}


def ephemeris():
    """The DE421 kernel of the ``skyfield-data`` package (opened once; never downloaded)."""
    global _kernel
    with _lock:
        if _kernel is None:
            import os

            import skyfield_data
            from skyfield.jpllib import SpiceKernel
            with warnings.catch_warnings():   # its IERS table's age: not used here (ΔT is ours)
                warnings.simplefilter("ignore")
                path = os.path.join(skyfield_data.get_skyfield_data_path(), "de421.bsp")
            _kernel = SpiceKernel(path)
        return _kernel


def _timescale(timebase: TimeBase):
    delta_t = round(timebase.tai_utc + _TT_TAI - timebase.ut1_utc, 9)
    with _lock:
        ts = _timescales.get(delta_t)
        if ts is None:
            from skyfield.api import load
            ts = load.timescale(delta_t=delta_t, builtin=True)   # bundled files only
            _timescales[delta_t] = ts
        return ts


def skyfield_time(timebase: TimeBase, utc):
    """A skyfield ``Time`` for Unix UTC seconds with this time base's TT and UT1."""
    tt = np.asarray(utc, float) + timebase.tai_utc + _TT_TAI
    days = np.floor(tt / 86400.0)
    return _timescale(timebase).tt_jd(_UNIX_JD + days, (tt - days * 86400.0) / 86400.0)


def _topos(astrometry: Astrometry):
    from skyfield.api import wgs84
    s = astrometry.site
    return wgs84.latlon(s.latitude, s.longitude, elevation_m=s.height)


def ra_rate_to_ra_v(rate: float, dec_deg: float, convention: str = "sky") -> float:
    """An RA rate as clients send it → RA_V (arcsec of RA per second).

    ``convention``: ``"sky"`` — arcsec of RA·cos Dec per second; ``"time"`` — seconds of
    time of RA per second; ``"ra"`` — arcsec of RA per second (RA_V itself).
    """
    rate = float(rate)
    if convention == "ra":
        return rate
    if convention == "time":
        return rate * 15.0
    if convention == "sky":
        c = math.cos(math.radians(dec_deg))
        if abs(c) < 1e-6:
            raise RangeRefused("an RA rate on the sky (RA·cos Dec) cannot be followed at a pole")
        return rate / c
    raise RangeRefused(f"RA rate convention {convention!r} is not 'sky', 'time' or 'ra'")


class Target:
    """A target of any kind (see the module docstring)."""

    kind = "target"
    name = ""
    #: UT1 seconds where the path starts / ends (a satellite pass), None: now / open-ended
    start: float | None = None
    end: float | None = None
    #: seconds between the tracker's points (None: ``[pointing] sample_spacing``)
    spacing: float | None = None
    #: the path ending at ``end`` (a pass that set) is a normal end of tracking
    ends_normally = False

    def observed(self, astrometry: Astrometry, utc) -> Observed:
        """Observed place at UTC seconds ``utc`` (array)."""
        raise NotImplementedError

    def radec(self, astrometry: Astrometry, utc: float) -> tuple[float, float]:
        """An ICRS-like (RA hours, Dec degrees) for display (POINTING.TARGET)."""
        obs = self.observed(astrometry, np.atleast_1d(float(utc)))
        ra, dec = astrometry.icrs_from_observed(obs.az, obs.zd, np.atleast_1d(float(utc)))
        return float(ra[0]), float(dec[0])

    def describe(self) -> str:
        return f"{self.kind} {self.name}".strip()


# ------------------------------------------------------------------------------ ICRS

@dataclass(frozen=True)
class IcrsTarget(Target):
    """ICRS J2000 place (hours, degrees) with differential rates RA_V / DEC_V (arcsec of RA
    and of Dec per second, from ``epoch`` = UTC seconds)."""

    ra: float = 0.0
    dec: float = 0.0
    ra_v: float = 0.0
    dec_v: float = 0.0
    epoch: float = 0.0
    name: str = ""
    kind = "icrs"

    def place(self, utc):
        """(RA hours, Dec degrees) at ``utc`` with the rates applied (as TrackRequest.place)."""
        if not (self.ra_v or self.dec_v):
            return self.ra, self.dec
        dt = np.asarray(utc, float) - self.epoch
        return (np.mod(self.ra + self.ra_v / 3600.0 * dt / 15.0, 24.0),
                np.clip(self.dec + self.dec_v / 3600.0 * dt, -90.0, 90.0))

    def observed(self, astrometry, utc):
        utc = np.atleast_1d(np.asarray(utc, float))
        ra, dec = self.place(utc)
        return astrometry.observed(ra, dec, utc)

    def radec(self, astrometry, utc):
        ra, dec = self.place(float(utc))
        return float(ra), float(dec)


# ------------------------------------------------------------------------------ solar system

@dataclass(frozen=True)
class BodyTarget(Target):
    """The Sun, the Moon or a planet (:data:`BODIES`), apparent and topocentric."""

    body: str = "moon"
    kind = "body"

    def __post_init__(self):
        if self.body not in BODIES:
            raise RangeRefused(f"no ephemeris for {self.body!r}: one of {', '.join(BODIES)}")

    @property
    def name(self) -> str:
        return self.body

    def apparent(self, astrometry: Astrometry, utc):
        """Apparent topocentric (RA hours, Dec degrees, distance au), GCRS axes."""
        eph = ephemeris()
        t = skyfield_time(astrometry.timebase, np.atleast_1d(np.asarray(utc, float)))
        observer = eph["earth"] + _topos(astrometry)
        pos = observer.at(t).observe(eph[BODIES[self.body]]).apparent()
        ra, dec, dist = pos.radec()
        return ra.hours, dec.degrees, dist.au

    def observed(self, astrometry, utc):
        utc = np.atleast_1d(np.asarray(utc, float))
        ra, dec, _ = self.apparent(astrometry, utc)
        return astrometry.observed_apparent(ra, dec, utc)

    def astrometric(self, astrometry: Astrometry, utc):
        """Astrometric topocentric (RA hours, Dec degrees): light time, no aberration — the
        ICRS-like place a star catalogue would give (for rates and display)."""
        eph = ephemeris()
        t = skyfield_time(astrometry.timebase, np.atleast_1d(np.asarray(utc, float)))
        pos = (eph["earth"] + _topos(astrometry)).at(t).observe(eph[BODIES[self.body]])
        ra, dec, _ = pos.radec()
        return ra.hours, dec.degrees

    def radec(self, astrometry, utc):
        ra, dec = self.astrometric(astrometry, float(utc))
        return float(ra[0]), float(dec[0])


def body_rates(body: str, astrometry: Astrometry, utc: float, span: float = 600.0):
    """A body's topocentric motion against the stars now: (RA_V arcsec of RA/s, DEC_V
    arcsec/s), a centred difference of its astrometric place over ``span`` seconds (Alpaca's
    lunar and solar tracking rates)."""
    t = np.array([utc - span / 2, utc + span / 2])
    ra, dec = BodyTarget(body).astrometric(astrometry, t)
    dra = math.remainder((ra[1] - ra[0]) * 15.0, 360.0) * 3600.0
    return dra / span, (dec[1] - dec[0]) * 3600.0 / span


# ------------------------------------------------------------------------------ satellites

@dataclass(frozen=True)
class PassPlan:
    """A satellite pass planned before tracking (times UTC seconds, angles degrees).

    ``feasible``: the pass (with its keyhole bridge) stays inside the AZ range on one turn and
    within 90 % of both axes' speed and acceleration. ``keyhole``: AZ cannot follow near the
    zenith and leads on a bridge from ``keyhole_start`` to ``keyhole_end``, pointing at most
    ``keyhole_error`` degrees off the target there. ``az_start``/``az_end``: AZ on its chosen
    turn (the mechanical frame, no pointing model) at rise and set.
    """

    rise: float | None
    set: float | None
    culmination: float | None
    max_altitude: float | None
    max_rate: float | None        # largest rate on the sky, °/s
    max_az_rate: float | None     # of the path followed (after a keyhole bridge), °/s
    max_az_acceleration: float | None
    max_zd_rate: float | None
    az_start: float | None
    az_end: float | None
    keyhole: bool | None
    keyhole_start: float | None
    keyhole_end: float | None
    keyhole_error: float | None
    feasible: bool
    reason: str = ""
    bridge: tuple | None = None   # (t0, t1 UTC, quintic coefficients of AZ in τ = (t−t0)/(t1−t0))
    epoch_age: float | None = None   # days from the TLE's epoch to the planning time (< 0: ahead)

    @property
    def duration(self) -> float | None:
        return None if self.rise is None else self.set - self.rise

    @property
    def found(self) -> bool:
        """A pass was found (its times and rates are known), feasible or not."""
        return self.rise is not None

    @classmethod
    def refused(cls, reason: str, epoch_age: float | None = None) -> "PassPlan":
        """No pass to follow: every figure None (NULL), FEASIBLE 0 and the reason."""
        return cls(None, None, None, None, None, None, None, None, None, None, None, None, None,
                   None, False, reason, None, epoch_age)


_PLAN_STEP = 0.5              # s between the samples of a pass plan
_SEARCH_STEP = 10.0           # s between the samples of the pass search
_SEARCH_CHUNK = 3600.0        # s searched at a time
_PLAN_POINTS = 4000           # at most this many samples per planned pass
_SHARE = 0.9                  # of an axis's speed / acceleration a planned path may use


@dataclass(frozen=True)
class SatelliteTarget(Target):
    """An Earth satellite from a TLE (``line1``, ``line2``), geometric topocentric place."""

    line1: str = ""
    line2: str = ""
    name: str = ""
    start: float | None = None     # UT1 of the planned pass (set by :meth:`planned`)
    end: float | None = None
    bridge: tuple | None = None    # keyhole: (t0, t1 UTC, quintic coefficients of AZ in τ)
    kind = "satellite"
    spacing = 0.5                  # s between points (1 s: < 0.06″ off on a 86° pass, 0.5 s: 0.006″)
    ends_normally = True

    def __post_init__(self):
        l1, l2 = check_tle_line(1, self.line1), check_tle_line(2, self.line2)
        if l1[2:7] != l2[2:7]:
            raise RangeRefused(f"the TLE's lines are of two satellites: line 1 is of catalogue number "
                               f"{l1[2:7].strip()}, line 2 of {l2[2:7].strip()} (write both lines of "
                               "one element set)")
        try:
            from skyfield.api import EarthSatellite
            sat = EarthSatellite(l1, l2, self.name or None)
        except Exception as exc:  # sgp4 parses the lines; any complaint is a bad TLE
            raise RangeRefused(f"not a two-line element set: {exc}") from None
        if sat.model.error:
            raise RangeRefused(f"SGP4 cannot propagate this TLE: error {sat.model.error}, "
                               f"{SGP4_ERRORS.get(sat.model.error, 'unknown')}")
        object.__setattr__(self, "_sat", sat)

    @property
    def epoch(self) -> float:
        """The element set's epoch, Unix UTC seconds."""
        return tle_epoch(self.line1)

    def sgp4_trouble(self, utc) -> str:
        """Why SGP4 cannot propagate the elements at some of the UTC times ``utc`` ("" when it
        can at all of them): its error code, its meaning and the first such time."""
        utc = np.atleast_1d(np.asarray(utc, float))
        jd = _UNIX_JD + np.floor(utc / 86400.0)
        fr = (utc - (jd - _UNIX_JD) * 86400.0) / 86400.0
        err, _, _ = self._sat.model.sgp4_array(jd, fr)
        bad = np.flatnonzero(err)
        if not bad.size:
            return ""
        code = int(err[bad[0]])
        return (f"SGP4 cannot propagate this TLE from {_iso(utc[bad[0]])} on (error {code}: "
                f"{SGP4_ERRORS.get(code, 'unknown')})")

    def topocentric(self, astrometry: Astrometry, utc):
        """Geometric topocentric (RA hours, Dec degrees, range km), GCRS axes."""
        t = skyfield_time(astrometry.timebase, np.atleast_1d(np.asarray(utc, float)))
        pos = (self._sat - _topos(astrometry)).at(t)
        ra, dec, dist = pos.radec()
        return ra.hours, dec.degrees, dist.km

    def sky(self, astrometry: Astrometry, utc) -> Observed:
        """The satellite's own observed place (no keyhole bridge)."""
        utc = np.atleast_1d(np.asarray(utc, float))
        ra, dec, _ = self.topocentric(astrometry, utc)
        return astrometry.observed_apparent(ra, dec, utc)

    def observed(self, astrometry, utc):
        """The path to follow: the satellite's place, AZ on the keyhole bridge if planned."""
        obs = self.sky(astrometry, utc)
        if self.bridge is None:
            return obs
        t0, t1, coef = self.bridge
        utc = np.atleast_1d(np.asarray(utc, float))
        inside = (utc > t0) & (utc < t1)
        if not inside.any():
            return obs
        az = np.array(obs.az, float, copy=True)
        zd = np.array(obs.zd, float, copy=True)
        lead = np.polyval(coef, (utc[inside] - t0) / (t1 - t0))
        az[inside] = np.mod(lead, 360.0)
        zd[inside] = _projected_zd(lead, obs.az[inside], obs.zd[inside])
        return replace(obs, az=az, zd=zd)

    def radec(self, astrometry, utc):
        ra, dec, _ = self.topocentric(astrometry, float(utc))
        return float(ra[0]), float(dec[0])

    # -- planning ------------------------------------------------------------------------------
    def _zd(self, astrometry, utc):
        return np.asarray(self.sky(astrometry, utc).zd, float)

    def _crossing(self, astrometry, zd_limit, a, b) -> float:
        """Time in [a, b] where ZD crosses the limit (bisection to 10 ms)."""
        za = self._zd(astrometry, a)[0] <= zd_limit
        while b - a > 0.01:
            m = 0.5 * (a + b)
            if (self._zd(astrometry, m)[0] <= zd_limit) == za:
                a = m
            else:
                b = m
        return b if not za else a

    def next_pass(self, astrometry: Astrometry, zd_limit: float, utc: float,
                  search: float = 86400.0) -> tuple[float, float] | None:
        """(rise, set) UTC of the pass in progress or the next one above the limit (searched
        an hour at a time: a pass soon costs little)."""
        rise = None
        t0 = float(utc)
        while t0 < utc + search:
            t = t0 + np.arange(0.0, _SEARCH_CHUNK + _SEARCH_STEP / 2, _SEARCH_STEP)
            up = self._zd(astrometry, t) <= zd_limit
            if rise is None:
                i = np.flatnonzero(up)
                if i.size:
                    rise = float(utc) if (i[0] == 0 and t0 == utc) else \
                        self._crossing(astrometry, zd_limit, t[i[0] - 1], t[i[0]]) if i[0] else float(t[0])
                    up = up.copy()
                    up[:i[0]] = True          # (before the rise: not the set)
            if rise is not None:
                down = np.flatnonzero(~up)
                if down.size:
                    k = int(down[0])
                    return rise, self._crossing(astrometry, zd_limit, t[k - 1], t[k]) if k else float(t[0])
            t0 = float(t[-1])
        return None if rise is None else (rise, t0)

    def plan(self, astrometry: Astrometry, *, zd_limit: float, utc: float,
             az_range: tuple[float, float], az_limits: tuple[float, float],
             zd_limits: tuple[float, float], az_current: float = 0.0,
             search: float = 86400.0, max_age: float | None = None) -> PassPlan:
        """Plan the pass in progress or the next one (see :class:`PassPlan`).

        ``az_range``: AZ software limits (mechanical degrees); ``az_limits`` /
        ``zd_limits``: (max velocity °/s, max acceleration °/s², max jerk °/s³) of the axes;
        ``max_age``: days the TLE's epoch may be from ``utc`` (None: any). A TLE too old, one
        SGP4 cannot propagate over the search or no pass in it give a refused plan
        (:meth:`PassPlan.refused`: FEASIBLE 0 and the reason).
        """
        age = (float(utc) - self.epoch) / 86400.0
        if max_age is not None and abs(age) > max_age:
            when = "old" if age > 0 else "ahead of now"
            return PassPlan.refused(
                f"TLE epoch {_iso(self.epoch)} is {abs(age):,.1f} days {when} (the limit is "
                f"{max_age:g} days): SGP4 from it is far off the satellite; get a fresh element "
                "set (CelesTrak)", age)
        trouble = self.sgp4_trouble(float(utc) + np.arange(0.0, search + 60.0, 60.0))
        if trouble:
            return PassPlan.refused(trouble, age)
        found = self.next_pass(astrometry, zd_limit, utc, search)
        if found is None:
            return PassPlan.refused(
                f"{self.name or 'the satellite'} does not rise above {90.0 - zd_limit:g}° altitude "
                f"in the {search / 3600.0:g} h from {_iso(utc)}", age)
        rise, set_ = found
        n = max(3, min(int(math.ceil((set_ - rise) / _PLAN_STEP)) + 1, _PLAN_POINTS))   # (a slow
        # satellite that stays up for hours is planned more coarsely: it is slow)
        t = np.linspace(rise, set_, n)
        obs = self.sky(astrometry, t)
        az = np.unwrap(np.asarray(obs.az, float), period=360.0)
        zd = np.asarray(obs.zd, float)
        dt = t[1] - t[0]
        vaz = np.gradient(az, dt)
        vzd = np.gradient(zd, dt)
        sky_rate = np.hypot(vaz * np.sin(zd * _D2R), vzd)
        culm = int(np.argmin(zd))
        vmax, amax, jmax = (x * _SHARE for x in az_limits)
        reason = ""
        bridge = None
        err = 0.0
        path = az
        aaz = np.gradient(vaz, dt)
        if (np.abs(vaz) > vmax).any() or (np.abs(aaz) > amax).any() \
                or (np.abs(np.gradient(aaz, dt)) > jmax).any():
            bridge, path, err = _keyhole_bridge(t, az, zd, culm, vmax, amax, jmax)
            if bridge is None:
                reason = (f"AZ cannot follow the pass through the zenith keyhole "
                          f"({90.0 - zd[culm]:.1f}° high at {_iso(t[culm])}): it needs "
                          f"{np.abs(vaz).max():.3g}°/s and {np.abs(aaz).max():.3g}°/s² against "
                          f"its {az_limits[0]:g}°/s and {az_limits[1]:g}°/s², and a lead inside "
                          f"{_SHARE:.0%} of them does not fit between "
                          f"{'now' if rise <= utc else 'the rise'} and the set")
        if bridge is not None:
            zd_path = np.asarray(replace(self, bridge=bridge).observed(astrometry, t).zd, float)
            vzd = np.gradient(zd_path, dt)                  # ZD on the lead's vertical
        vpath = np.gradient(path, dt)
        apath = np.gradient(vpath, dt)
        # the cable-wrap turn: the one keeping every sample inside the AZ range, nearest
        lo, hi = az_range
        best = None
        for k in range(math.floor((lo - path.max()) / 360.0) - 1, math.ceil((hi - path.min()) / 360.0) + 2):
            c = path + 360.0 * k
            inside = bool(((c >= lo) & (c <= hi)).all())
            key = (not inside, abs(c[0] - az_current))
            if best is None or key < best[0]:
                best = (key, c, inside)
        _, wrapped, inside = best
        if not inside and not reason:
            reason = f"AZ would leave {lo:g}…{hi:g}° on every turn (the pass spans {np.ptp(path):.1f}°)"
        azd = np.gradient(vzd, dt)
        zd_need = (np.abs(vzd).max(), np.abs(azd).max(), np.abs(np.gradient(azd, dt)).max())
        zd_ok = all(need <= lim * _SHARE for need, lim in zip(zd_need, zd_limits))
        if not zd_ok and not reason:
            reason = (f"ZD cannot follow the pass: it needs {zd_need[0]:.3g}°/s, {zd_need[1]:.3g}°/s², "
                      f"{zd_need[2]:.3g}°/s³ against {_SHARE:.0%} of its {zd_limits[0]:g}°/s, "
                      f"{zd_limits[1]:g}°/s², {zd_limits[2]:g}°/s³")
        return PassPlan(
            rise=float(rise), set=float(set_), culmination=float(t[culm]),
            max_altitude=float(90.0 - zd[culm]), max_rate=float(sky_rate.max()),
            max_az_rate=float(np.abs(vpath).max()), max_az_acceleration=float(np.abs(apath).max()),
            max_zd_rate=float(np.abs(vzd).max()),
            az_start=float(wrapped[0]), az_end=float(wrapped[-1]),
            keyhole=bridge is not None or bool(reason.startswith("AZ cannot")),
            keyhole_start=float(bridge[0]) if bridge else None,
            keyhole_end=float(bridge[1]) if bridge else None,
            keyhole_error=float(err), feasible=not reason, reason=reason, bridge=bridge,
            epoch_age=age)

    def planned(self, plan: PassPlan, ut1_utc: float) -> "SatelliteTarget":
        """This satellite bound to a planned pass (start/end as UT1, the keyhole bridge)."""
        return replace(self, start=plan.rise + ut1_utc, end=plan.set + ut1_utc, bridge=plan.bridge)


def _quintic(x0, v0, a0, x1, v1, a1, T):
    """Coefficients (highest first, in τ = t/T ∈ [0, 1]) of the quintic with these end states."""
    v0, v1, a0, a1 = v0 * T, v1 * T, a0 * T * T, a1 * T * T
    c0, c1, c2 = x0, v0, a0 / 2.0
    d = x1 - (c0 + c1 + c2)
    e = v1 - (c1 + 2 * c2)
    f = a1 - 2 * c2
    c3 = 10 * d - 4 * e + f / 2
    c4 = -15 * d + 7 * e - f
    c5 = 6 * d - 3 * e + f / 2
    return np.array([c5, c4, c3, c2, c1, c0])


def _projected_zd(az_axis, az, zd):
    """ZD on the vertical circle of ``az_axis`` nearest the target at (``az``, ``zd``): the
    pointing error is then only asin(sin ZD · |sin ΔAZ|); negative past ΔAZ = 90° (over the
    zenith, the reverse side)."""
    d = np.radians(np.asarray(az_axis, float) - np.asarray(az, float))
    return np.degrees(np.arctan(np.tan(np.radians(zd)) * np.cos(d)))


def _keyhole_bridge(t, az, zd, culm, vmax, amax, jmax):
    """Widen a window about the culmination until a quintic AZ bridge between the target's
    states at its ends stays within ``vmax``/``amax``/``jmax``; returns ((t0, t1, coef),
    path, error°)."""
    dt = t[1] - t[0]
    v = np.gradient(az, dt)
    a = np.gradient(v, dt)
    bad = np.flatnonzero((np.abs(v) > vmax) | (np.abs(a) > amax)
                         | (np.abs(np.gradient(a, dt)) > jmax))
    lo, hi = int(bad.min()), int(bad.max())
    half = max(culm - lo, hi - culm, 1)
    n = t.size
    while culm - half >= 1 and culm + half <= n - 2:
        i0, i1 = culm - half, culm + half
        T = t[i1] - t[i0]
        coef = _quintic(az[i0], v[i0], a[i0], az[i1], v[i1], a[i1], T)
        tau = np.linspace(0.0, 1.0, 401)
        dv = np.polyval(np.polyder(coef), tau) / T
        da = np.polyval(np.polyder(coef, 2), tau) / (T * T)
        dj = np.polyval(np.polyder(coef, 3), tau) / (T * T * T)
        if np.abs(dv).max() <= vmax and np.abs(da).max() <= amax and np.abs(dj).max() <= jmax:
            path = az.copy()
            path[i0:i1 + 1] = np.polyval(coef, (t[i0:i1 + 1] - t[i0]) / T)
            # ZD on the lead azimuth's vertical nearest the target: error sin ZD · |sin ΔAZ|
            d = np.radians(path - az)
            err = float(np.degrees(np.arcsin(np.abs(np.sin(np.radians(zd)) * np.sin(d)))).max())
            return (float(t[i0]), float(t[i1]), coef), path, err
        half = int(half * 1.15) + 1
    return None, az, 0.0


# ------------------------------------------------------------------------------ horizontal

@dataclass(frozen=True)
class HorizontalTarget(Target):
    """A fixed observed (refracted) azimuth and altitude, degrees."""

    az: float = 0.0
    alt: float = 90.0
    kind = "horizontal"

    def observed(self, astrometry, utc):
        utc = np.atleast_1d(np.asarray(utc, float))
        phi = astrometry.site.latitude * _D2R
        ha, dec = erfa.ae2hd(self.az * _D2R, self.alt * _D2R, phi)
        pa = erfa.hd2pa(ha, dec, phi)
        lst = np.asarray(astrometry.sidereal_time(utc), float)
        shape = utc.shape
        return Observed(np.full(shape, self.az % 360.0), np.full(shape, 90.0 - self.alt),
                        np.full(shape, 12.0 - (12.0 - ha * 12.0 / math.pi) % 24.0),
                        np.full(shape, dec * _R2D), np.full(shape, pa * _R2D), lst)


#: SGP4's error codes (sgp4 ``Satrec.error``)
SGP4_ERRORS = {
    1: "mean eccentricity out of range (0 <= e < 1)",
    2: "mean motion below zero",
    3: "perturbed eccentricity out of range",
    4: "semi-latus rectum below zero",
    6: "the orbit has decayed (the satellite is below the Earth's surface)",
}
_MU = 398600.8                # km³/s², WGS-72 (as SGP4)
_EARTH_RADIUS = 6378.135      # km, WGS-72
#: lowest perigee SGP4 is asked to propagate: nothing orbits below ~100 km for long
MIN_PERIGEE = 80.0


def _iso(utc: float) -> str:
    import datetime as _dt
    return _dt.datetime.fromtimestamp(float(utc), _dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def tle_checksum(line: str) -> int:
    """The TLE checksum of a line's first 68 characters: digits, and 1 for each minus sign, mod 10."""
    return sum(int(c) if c.isdigit() else 1 if c == "-" else 0 for c in line[:68]) % 10


def tle_epoch(line1: str) -> float:
    """Epoch of a TLE line 1 (columns 19–32, YYDDD.DDDDDDDD; 57–99 → 19xx), Unix UTC seconds."""
    field = line1[18:32]
    year = int(field[:2])
    year += 1900 if year >= 57 else 2000
    import calendar
    return calendar.timegm((year, 1, 1, 0, 0, 0)) + (float(field[2:]) - 1.0) * 86400.0


def _field(line: str, index: int, a: int, b: int, name: str, lo: float, hi: float,
           implied_point: bool = False) -> float:
    text = line[a:b]
    try:
        value = float("0." + text.strip()) if implied_point else float(text)
        if implied_point and not text.strip().isdigit():
            raise ValueError(text)
    except ValueError:
        raise RangeRefused(f"TLE line {index}: {name} (columns {a + 1}–{b}) is {text.strip()!r}, "
                           "not a number") from None
    if not lo <= value <= hi:
        raise RangeRefused(f"TLE line {index}: {name} {value:g} is outside {lo:g}…{hi:g}")
    return value


def check_tle_line(index: int, line: str) -> str:
    """One TLE line (``index`` 1 or 2), stripped, if it is one; RANGE with what is wrong
    otherwise: its line number, its length (69 characters), its checksum (the last column),
    its fields (line 1: the epoch; line 2: inclination, node, eccentricity, argument of
    perigee, mean anomaly, mean motion) and, for line 2, a perigee above the atmosphere
    (:data:`MIN_PERIGEE`): eccentricity and mean motion SGP4 can propagate."""
    line = str(line).strip()
    if line[:2] != f"{index} ":
        raise RangeRefused(f"TLE line {index} must start with '{index} ' (it starts {line[:2]!r})")
    if len(line) != 69:
        raise RangeRefused(f"TLE line {index} has {len(line)} characters, not 69 (a line cut or "
                           "joined? quote the whole line)")
    if not line[68].isdigit() or int(line[68]) != tle_checksum(line):
        raise RangeRefused(f"TLE line {index}: checksum {line[68]!r} in column 69 does not match the "
                           f"line's {tle_checksum(line)} (a character changed in transfer?)")
    if not line[2:7].strip():
        raise RangeRefused(f"TLE line {index}: no catalogue number in columns 3–7")
    if index == 1:
        _field(line, 1, 18, 20, "epoch year", 0, 99)
        _field(line, 1, 20, 32, "epoch day", 1.0, 367.0)
        return line
    _field(line, 2, 8, 16, "inclination", 0.0, 180.0)
    _field(line, 2, 17, 25, "right ascension of the node", 0.0, 360.0)
    e = _field(line, 2, 26, 33, "eccentricity", 0.0, 0.9999999, implied_point=True)
    _field(line, 2, 34, 42, "argument of perigee", 0.0, 360.0)
    _field(line, 2, 43, 51, "mean anomaly", 0.0, 360.0)
    n = _field(line, 2, 52, 63, "mean motion", 0.0, 1e3)
    if n <= 0.0:
        raise RangeRefused("TLE line 2: mean motion 0 rev/day is not an orbit")
    a = (_MU / (n * 2.0 * math.pi / 86400.0) ** 2) ** (1.0 / 3.0)
    perigee = a * (1.0 - e) - _EARTH_RADIUS
    if perigee < MIN_PERIGEE:
        where = (f"{-perigee:,.0f} km below the Earth's surface" if perigee < 0 else
                 f"{perigee:,.0f} km above the surface, inside the atmosphere")
        raise RangeRefused(
            f"TLE line 2: eccentricity {e:g} and mean motion {n:g} rev/day put the perigee "
            f"{where} (at least {MIN_PERIGEE:g} km above it): not an orbit SGP4 can propagate")
    return line


def check_tle(line1: str, line2: str) -> None:
    """RANGE unless the two lines are one valid TLE (:func:`check_tle_line`, one satellite,
    SGP4 accepts them)."""
    SatelliteTarget(line1=line1, line2=line2)
