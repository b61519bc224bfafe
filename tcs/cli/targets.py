"""What ``tcs-client goto TARGET`` points at: a named bright star, a solar-system body, an
``"RA DEC"`` place or a fixed ``--altaz ALT AZ``.

How it works
------------
* **Stars**: ``data/bright_stars.csv`` (shipped in the package) lists ~110 bright stars with
  their IAU names: Hipparcos J2000.0 ICRS places and proper motions (the file's header says
  where they come from). :func:`star_place` moves a star by its proper motion to the date;
  OpenTCI's ``POINTING.TARGET.RA/DEC`` is an ICRS place, and the TCS's own astrometry makes it
  apparent and observed (precession, nutation, aberration, refraction). Names are matched
  without case, spaces or hyphens, and PyEphem's variant spellings are accepted (``ALIASES``).
* **Bodies** (``moon``, ``mars``, ``jupiter`` … :data:`BODIES`; never the Sun): OpenTCI takes
  only an RA/Dec and rates, so :func:`body_place` gives the body's *astrometric topocentric*
  place now (light time, seen from the site: the Moon's parallax is up to 1°) from the JPL
  ephemeris DE421 that ``skyfield-data`` ships (nothing is downloaded), and its rates against
  the stars (``RA_V`` arcsec of RA per second, ``DEC_V`` arcsec per second, a centred
  difference over 10 min) — what the TCS's own solar-system targets compute
  (:class:`tcs.pointing.targets.BodyTarget`). The TCS then adds aberration and refraction as
  for a star.
* **"RA DEC"**: :func:`parse_radec`: RA in hours (``5.5``, ``5:35:17.3``, ``5h35m17.3s``) or
  in degrees with a ``d`` (``83.8d``); Dec in degrees (``-5.4``, ``-5:23:28``, ``-5d23m28s``).

Pure functions, no connection: :mod:`tcs.cli.client` reads the site and the time from the
TCS and sends the result.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

J2000_UNIX = 946728000.0        # 2000-01-01 12:00 (UTC; TT differs by ~1 min: far below a mas)
JULIAN_YEAR = 365.25 * 86400.0

#: solar-system bodies a goto may name (the Sun is refused: see :func:`resolve`)
BODIES = {"moon": "moon", "mercury": "mercury", "venus": "venus", "mars": "mars",
          "jupiter": "jupiter barycenter", "saturn": "saturn barycenter",
          "uranus": "uranus barycenter", "neptune": "neptune barycenter",
          "pluto": "pluto barycenter"}

#: PyEphem's variant spellings → the IAU name in the list
ALIASES = {"adara": "Adhara", "agena": "Hadar", "albereo": "Albireo", "alcaid": "Alkaid",
           "etamin": "Eltanin", "formalhaut": "Fomalhaut", "gienahcorvi": "Gienah",
           "sirrah": "Alpheratz", "alphacentauri": "Rigil Kentaurus", "northstar": "Polaris"}


class TargetError(ValueError):
    """A TARGET that names nothing known, or a place out of range (message says which)."""


@dataclass(frozen=True)
class Star:
    name: str
    ra: float        # hours, J2000.0 ICRS
    dec: float       # degrees
    pm_ra: float     # mas/yr, mu_alpha * cos(dec)
    pm_dec: float    # mas/yr
    vmag: float


@dataclass(frozen=True)
class Goto:
    """What to point at: ``kind`` "icrs" (ra hours, dec degrees, rates) or "altaz"."""

    kind: str
    label: str
    ra: float = 0.0
    dec: float = 0.0
    ra_v: float = 0.0    # arcsec of RA per second (not × cos Dec)
    dec_v: float = 0.0   # arcsec per second
    alt: float = 0.0
    az: float = 0.0
    body: str = ""


def _key(name: str) -> str:
    return re.sub(r"[\s\-_']", "", name).lower()


@lru_cache(maxsize=1)
def stars() -> dict[str, Star]:
    """The shipped list, by :func:`_key` of the name."""
    text = resources.files("tcs.cli").joinpath("data/bright_stars.csv").read_text("utf-8")
    rows = csv.DictReader(line for line in text.splitlines() if line and not line.startswith("#"))
    out = {}
    for r in rows:
        s = Star(r["name"], float(r["ra_hours"]), float(r["dec_degrees"]),
                 float(r["pm_ra_cosdec_mas_yr"]), float(r["pm_dec_mas_yr"]), float(r["vmag"]))
        out[_key(s.name)] = s
    return out


def find_star(name: str) -> Star | None:
    key = _key(name)
    table = stars()
    if key in ALIASES:
        key = _key(ALIASES[key])
    return table.get(key)


def star_place(star: Star, utc: float) -> tuple[float, float]:
    """(RA hours, Dec degrees) ICRS of ``star`` at ``utc`` (Unix seconds): its J2000.0 place
    moved by its proper motion along the sphere."""
    years = (utc - J2000_UNIX) / JULIAN_YEAR
    ra, dec = math.radians(star.ra * 15.0), math.radians(star.dec)
    # unit vector plus the proper motion's tangent vector (exact on the sphere, linear in time)
    mu_a = math.radians(star.pm_ra / 3.6e6) * years
    mu_d = math.radians(star.pm_dec / 3.6e6) * years
    x = math.cos(dec) * math.cos(ra) - mu_a * math.sin(ra) - mu_d * math.sin(dec) * math.cos(ra)
    y = math.cos(dec) * math.sin(ra) + mu_a * math.cos(ra) - mu_d * math.sin(dec) * math.sin(ra)
    z = math.sin(dec) + mu_d * math.cos(dec)
    ra2 = math.degrees(math.atan2(y, x)) / 15.0 % 24.0
    dec2 = math.degrees(math.atan2(z, math.hypot(x, y)))
    return ra2, dec2


def _sexagesimal(text: str) -> tuple[float, bool]:
    """A number from ``12.5``, ``12:30:00``, ``12 30 00``, ``12h30m00s``, ``-5d23m28s``,
    ``-5°23'28"``; the flag says whether it was written in degrees (``d``/``°``)."""
    t = text.strip().lower()
    degrees = bool(re.search(r"[d°]", t))
    sign = -1.0 if t.startswith("-") else 1.0
    t = t.lstrip("+-")
    parts = [p for p in re.split(r"[:hdms°'\"\s]+", t) if p]
    if not parts or len(parts) > 3:
        raise TargetError(f"not a number or h:m:s / d:m:s: {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise TargetError(f"not a number or h:m:s / d:m:s: {text!r}") from None
    if any(v < 0 for v in values) or any(v >= 60 for v in values[1:]):
        raise TargetError(f"minutes and seconds are 0..60: {text!r}")
    value = values[0] + sum(v / 60.0 ** (i + 1) for i, v in enumerate(values[1:]))
    return sign * value, degrees


def parse_radec(ra_text: str, dec_text: str) -> tuple[float, float]:
    """(RA hours, Dec degrees) of an ``RA DEC`` pair (see the module docstring)."""
    ra, in_degrees = _sexagesimal(ra_text)
    if in_degrees:
        ra /= 15.0
    dec, _ = _sexagesimal(dec_text)
    if not 0.0 <= ra < 24.0:
        raise TargetError(f"RA {ra_text!r} is outside 0..24 h (write degrees as e.g. 83.8d)")
    if not -90.0 <= dec <= 90.0:
        raise TargetError(f"Dec {dec_text!r} is outside -90..90 degrees")
    return ra, dec


def body_place(body: str, utc: float, latitude: float, longitude: float, height: float,
               span: float = 600.0) -> tuple[float, float, float, float]:
    """(RA hours, Dec degrees, RA_V, DEC_V) of a body: astrometric topocentric place at ``utc``
    seen from the site (longitude east positive) and its rates (module docstring)."""
    from skyfield.api import load, wgs84

    from tcs.pointing.targets import ephemeris

    eph = ephemeris()
    ts = load.timescale(builtin=True)
    t = ts.utc(1970, 1, 1, 0, 0, [utc, utc - span / 2, utc + span / 2])
    site = eph["earth"] + wgs84.latlon(latitude, longitude, elevation_m=height)
    ra, dec, _ = site.at(t).observe(eph[BODIES[body]]).radec()
    hours, degs = ra.hours, dec.degrees
    ra_v = math.remainder((hours[2] - hours[1]) * 15.0, 360.0) * 3600.0 / span
    dec_v = (degs[2] - degs[1]) * 3600.0 / span
    return float(hours[0]) % 24.0, float(degs[0]), float(ra_v), float(dec_v)


def gast_hours(utc: float, ut1_utc: float = 0.0) -> float:
    """Greenwich apparent sidereal time at ``utc`` (to find the site's east longitude from
    the TCS's sidereal time, whatever sign convention its LOCAL.LONGITUDE uses)."""
    from skyfield.api import load

    ts = load.timescale(builtin=True)
    return float(ts.utc(1970, 1, 1, 0, 0, utc).gast)


def resolve(words: list[str]) -> Goto:
    """The :class:`Goto` of a TARGET given as one or more words (stars and bodies by name,
    ``RA DEC`` as one quoted word or two). Places that need the time and the site (stars'
    proper motion, bodies) are computed by :func:`star_place` / :func:`body_place` later."""
    text = " ".join(words).strip()
    if not text:
        raise TargetError("no target")
    key = _key(text)
    if key == "sun":
        raise TargetError("the Sun is never a target (the TCS keeps the telescope out of its cone)")
    if key in BODIES:
        return Goto("body", key.capitalize(), body=key)
    star = find_star(text)
    if star is not None:
        return Goto("star", star.name, ra=star.ra, dec=star.dec)
    fields = text.split()
    if len(fields) in (2, 4, 6) and any(c.isdigit() for c in text):
        half = len(fields) // 2
        ra, dec = parse_radec(" ".join(fields[:half]), " ".join(fields[half:]))
        return Goto("icrs", f"RA {ra:.6f} h Dec {dec:+.5f}°", ra=ra, dec=dec)
    near = close_names(text)
    hint = f" (did you mean {', '.join(near)}?)" if near else ""
    raise TargetError(f"{text!r}: no star of the shipped list, body ({', '.join(BODIES)}) or "
                      f"'RA DEC'{hint}; `tcs-client goto --list` shows the stars")


def close_names(text: str) -> list[str]:
    import difflib

    names = {s.name for s in stars().values()}
    return difflib.get_close_matches(text.title(), sorted(names), n=3, cutoff=0.7)
