"""Judging NMEA sentences the way a timing receiver's user must: what is a fix, what is a time.

How it works
------------
pynmea2 does the syntax (talker, sentence type, checksum, fields); this module judges the
fields, since pynmea2 checks none of them (a latitude of 95.5°, a missing hemisphere, minutes
≥ 60, a date of 1980 all pass it). :func:`judge` turns one parsed sentence into a
:class:`Reading` — what it says about the fix, the position and the time, and *why* when it
says there is none — or ``None`` for a sentence that carries nothing used here.

What is a fix
    Only autonomous, differential, PPS, RTK fixed and RTK float solutions. GGA quality 0
    (invalid), 6 (dead reckoning), 7 (manual input) and 8 (simulator) are not fixes, nor the
    NMEA 2.3 mode indicators N, E, M and S of RMC, GLL and GNS, nor RMC/GLL status ``V``, nor
    ``$PUBX,00`` navigation states NF, DR, RK and TT. Each refusal is named (``GGA quality 8
    (simulator)``). The NMEA 4.1 navigational status of RMC/GNS is not judged: u-blox sends a
    fixed ``V`` ("not provided") there with every valid fix.
Ranges
    Latitude ≤ 90°, longitude ≤ 180°, minutes < 60, a hemisphere letter present, height above
    sea level between :data:`HEIGHT_MIN` and :data:`HEIGHT_MAX`, hours < 24, minutes < 60,
    seconds ≤ 60 (a leap second), a real calendar date. A sentence with any field out of
    range is no fix at all: a receiver that writes one impossible field is not trusted for
    the others.
Dates
    Dates before :data:`PLAUSIBLE_FROM` (2000-01-01) are refused: 1980-01-06 is the GPS epoch
    a receiver without time starts from, 1999-08-22 the first week rollover that old firmware
    resets to. A date exactly 1024 or 2048 weeks before the system clock (within
    :data:`ROLLOVER_MATCH`) is a week-rollover firmware: corrected, with a note saying so.
    This needs a system clock after :data:`SANE_CLOCK_FROM`; any other disagreement with the
    system clock is judged by the reader (``clock_tolerance``), not here.
Time
    RMC carries date and time: a time when its status, mode and date pass. ZDA carries them
    without any validity field: it is returned as ``time_unconfirmed`` and the reader trusts it
    only while a validated fix (RMC/GGA/GNS/GLL/PUBX) is fresh. GGA, GNS and GLL carry only
    the time of day, which is not used.
Constellations
    The talker says which: GP GPS, GL GLONASS, GA Galileo, GB/BD BeiDou, GQ QZSS, GI NavIC,
    and GN the combined solution. :attr:`Reading.talker` keeps it so the reader can keep
    satellites and quality per constellation.

Pure functions, no state; :class:`tcs.drivers.gps.GpsReader` is the only user.
"""

from __future__ import annotations

import calendar
import math
import time
from dataclasses import dataclass, replace

__all__ = ["Reading", "judge", "judge_date", "QUALITY_NAMES", "FIX_QUALITIES", "CONSTELLATIONS",
           "HEIGHT_MIN", "HEIGHT_MAX", "PLAUSIBLE_FROM", "ROLLOVER_MATCH", "WEEKS_1024"]

#: GGA fix quality codes (NMEA 0183 4.x).
QUALITY_NAMES = {0: "invalid", 1: "autonomous", 2: "differential", 3: "PPS", 4: "RTK fixed",
                 5: "RTK float", 6: "dead reckoning", 7: "manual input", 8: "simulator",
                 9: "SBAS"}
#: The qualities that are fixes (9: NovAtel and others' SBAS-corrected fix, outside NMEA).
FIX_QUALITIES = frozenset({1, 2, 3, 4, 5, 9})
#: NMEA 2.3+ mode indicator -> the GGA quality it corresponds to.
MODE_QUALITY = {"A": 1, "D": 2, "P": 3, "R": 4, "F": 5, "E": 6, "M": 7, "S": 8, "N": 0}
#: u-blox ``$PUBX,00`` navigation status -> GGA quality (only G2/G3/D2/D3 are fixes).
PUBX_QUALITY = {"G2": 1, "G3": 1, "D2": 2, "D3": 2, "NF": 0, "TT": 0, "DR": 6, "RK": 6}
PUBX_NAMES = {"NF": "no fix", "TT": "time only", "DR": "dead reckoning", "RK": "GNSS + dead reckoning"}
CONSTELLATIONS = {"GP": "GPS", "GL": "GLONASS", "GA": "Galileo", "GB": "BeiDou", "BD": "BeiDou",
                  "GQ": "QZSS", "GI": "NavIC", "GN": "combined", "PUBX": "u-blox"}

HEIGHT_MIN, HEIGHT_MAX = -500.0, 10000.0     # m above sea level: LOCAL.HEIGHT's range
PLAUSIBLE_FROM = 946684800.0                 # 2000-01-01 UTC
SANE_CLOCK_FROM = 1735689600.0               # 2025-01-01: a system clock before it is not set
WEEKS_1024 = 1024 * 7 * 86400.0              # one GPS week rollover, 19.6 years
ROLLOVER_MATCH = 2 * 86400.0                 # a rollover date is this close to clock - 1024 weeks


class Refused(ValueError):
    """A field out of range or a status that is not a fix; the text says which."""


@dataclass(frozen=True)
class Reading:
    """What one sentence says. ``fix`` False with ``reason`` when it says there is no fix."""

    kind: str                        # "GGA", "RMC", "GLL", "GNS", "PUBX", "ZDA", "GSV"
    talker: str                      # "GP", "GN", … ("" for PUBX)
    position: bool = False           # the sentence reports a fix state (and maybe a position)
    fix: bool = False
    reason: str = ""                 # why not a fix (or why the time was refused)
    quality: int = 0                 # GGA-equivalent quality code
    latitude: float | None = None
    longitude: float | None = None
    height: float | None = None      # above mean sea level (GGA, GNS only)
    satellites: int | None = None    # used in the solution
    hdop: float | None = None
    in_view: int | None = None       # GSV: satellites in view
    time: float | None = None        # validated UTC, s since 1970
    time_unconfirmed: float | None = None   # ZDA: UTC without a validity field
    time_reason: str = ""            # why a date/time was refused
    note: str = ""                   # e.g. a week rollover corrected


# ------------------------------------------------------------------ fields

def _num(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise Refused(f"{what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise Refused(f"{what} {text!r} is not a number")
    return value


def angle(value: str, hemi: str, kind: str) -> float:
    """``ddmm.mmmm`` (latitude) or ``dddmm.mmmm`` (longitude) and its hemisphere, in degrees."""
    what, hemis, limit = ("latitude", "NS", 90.0) if kind == "lat" else ("longitude", "EW", 180.0)
    if not value:
        raise Refused(f"{what} missing")
    if hemi not in (hemis[0], hemis[1]):
        raise Refused(f"{what} {value} without hemisphere ({hemi!r})")
    v = _num(value, what)
    if v < 0:
        raise Refused(f"{what} {value} negative")
    deg = math.floor(v / 100.0)
    minutes = v - deg * 100.0
    if minutes >= 60.0:
        raise Refused(f"{what} {value}: minutes {minutes:g} ≥ 60")
    result = deg + minutes / 60.0
    if result > limit:
        raise Refused(f"{what} {result:g}° beyond {limit:g}°")
    return -result if hemi == hemis[1] else result


def time_of_day(text: str) -> float:
    """``hhmmss(.sss)`` in seconds since midnight (a leap second 60 allowed)."""
    if len(text) < 6 or not text[:6].isdigit():
        raise Refused(f"time {text!r} malformed")
    h, m = int(text[0:2]), int(text[2:4])
    s = _num(text[4:], "time")
    if h > 23 or m > 59 or not 0 <= s < 61:
        raise Refused(f"time {text} out of range")
    return h * 3600 + m * 60 + s


def day_start(day: int, month: int, year: int) -> float:
    if not (1 <= month <= 12 and 1 <= day <= calendar.monthrange(year, month)[1]):
        raise Refused(f"date {day:02d}.{month:02d}.{year} is not a date")
    return float(calendar.timegm((year, month, day, 0, 0, 0)))


def _date_text(t: float) -> str:
    y, mo, d = time.gmtime(t)[:3]
    return f"{y:04d}-{mo:02d}-{d:02d}"


def judge_date(t: float, wall: float) -> tuple[float, str]:
    """A receiver's UTC ``t`` judged against the system clock ``wall``: ``(t, note)`` with a
    week rollover corrected (and said in ``note``), or :class:`Refused`."""
    if wall >= SANE_CLOCK_FROM:
        for k in (1, 2):
            fixed = t + k * WEEKS_1024
            if abs(fixed - wall) <= ROLLOVER_MATCH:
                return fixed, (f"week rollover: the receiver's date {_date_text(t)} is {1024 * k} weeks "
                               f"early; corrected to {_date_text(fixed)}")
    if t < PLAUSIBLE_FROM:
        raise Refused(f"date {_date_text(t)} before 2000: the receiver has no valid time "
                      "(1980 is the GPS epoch, 1999-08-22 a week-rollover reset)")
    return t, ""


def _mode_refusal(mode: str, kind: str) -> str:
    """'' when the mode indicator (absent in NMEA < 2.3) allows a fix, else the reason."""
    if not mode:
        return ""
    q = MODE_QUALITY.get(mode[0])
    if q is None:
        return f"{kind} mode {mode!r} unknown"
    if q not in FIX_QUALITIES:
        return f"{kind} mode {mode[0]} ({QUALITY_NAMES[q] if q else 'no fix'})"
    return ""


def _int(text: str) -> int | None:
    return int(text) if text.isdigit() else None


def _float(text: str) -> float | None:
    try:
        v = float(text)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


# ------------------------------------------------------------------ sentences

def judge(talker: str, kind: str, data: list[str], wall: float) -> Reading | None:
    """Judge one sentence: ``talker`` ("GP", "" for proprietary), ``kind`` ("GGA", "PUBX00"),
    its fields, and the system clock ``wall`` at its arrival (for the date)."""
    f = ([x.strip() for x in data] + [""] * 20).__getitem__   # missing trailing fields are empty
    if kind == "GGA":
        return _position(kind, talker, f, lat=1, quality_field=5, sats=6, hdop=7, alt=8, alt_unit=9)
    if kind == "GNS":
        return _position(kind, talker, f, lat=1, mode_field=5, sats=6, hdop=7, alt=8)
    if kind == "GLL":
        return _position(kind, talker, f, lat=0, status=5, mode_field=6)
    if kind == "RMC":
        return _rmc(talker, f, wall)
    if kind == "PUBX00":
        return _position("PUBX", talker, lambda i: f(i + 1), lat=2, pubx=7, sats=17, hdop=14)
    if kind == "ZDA":
        return _zda(talker, f, wall)
    if kind == "GSV":
        return Reading(kind, talker, in_view=_int(f(2)))
    return None


def _position(kind, talker, f, *, lat, quality_field=None, mode_field=None, status=None, sats=None,
              hdop=None, alt=None, alt_unit=None, pubx=None) -> Reading:
    satellites = _int(f(sats)) if sats is not None else None
    dop = _float(f(hdop)) if hdop is not None else None
    quality, why = 1, ""
    if quality_field is not None:
        code = _int(f(quality_field))
        quality = code if code is not None else 0
        if quality not in FIX_QUALITIES:
            why = f"{kind} quality {f(quality_field) or 'empty'} ({QUALITY_NAMES.get(quality, 'unknown')})"
    if pubx is not None:
        nav = f(pubx)
        quality = PUBX_QUALITY.get(nav, 0)
        if quality not in FIX_QUALITIES:
            why = f"PUBX navigation status {nav or 'empty'} ({PUBX_NAMES.get(nav, 'unknown')})"
    if status is not None and f(status) != "A":
        quality, why = 0, f"{kind} status {f(status) or 'empty'} (not valid)"
    if mode_field is not None and not why:
        mode = f(mode_field)
        if kind == "GNS":   # one character per constellation (GPS first): any fix counts
            known = [MODE_QUALITY[c] for c in mode if c in MODE_QUALITY]
            fixes = [q for q in known if q in FIX_QUALITIES]
            quality = fixes[0] if fixes else (max(known) if known else 0)
            if not fixes:
                why = f"GNS mode {mode or 'empty'} ({QUALITY_NAMES[quality] if quality else 'no fix'})"
        else:
            why = _mode_refusal(mode, kind)
            if mode:
                quality = MODE_QUALITY.get(mode[0], 0)
    if why:
        return Reading(kind, talker, position=True, reason=why, quality=quality, satellites=satellites,
                       hdop=dop)
    try:
        latitude = angle(f(lat), f(lat + 1), "lat")
        longitude = angle(f(lat + 2), f(lat + 3), "lon")
        height = None
        if alt is not None and f(alt):
            if alt_unit is not None and f(alt_unit) not in ("M", ""):
                raise Refused(f"height unit {f(alt_unit)!r}")
            height = _num(f(alt), "height")
            if not HEIGHT_MIN <= height <= HEIGHT_MAX:
                raise Refused(f"height {height:g} m outside {HEIGHT_MIN:g}…{HEIGHT_MAX:g} m")
    except Refused as exc:
        return Reading(kind, talker, position=True, reason=f"{kind} {exc}", quality=quality,
                       satellites=satellites, hdop=dop)
    return Reading(kind, talker, position=True, fix=True, quality=quality, latitude=latitude,
                   longitude=longitude, height=height, satellites=satellites, hdop=dop)


def _rmc(talker, f, wall) -> Reading:
    pos = _position("RMC", talker, f, lat=2, status=1, mode_field=11)
    if not pos.fix:
        return pos
    try:
        date = f(8)
        if len(date) != 6 or not date.isdigit():
            raise Refused(f"date {date!r} malformed")
        yy = int(date[4:6])
        day = day_start(int(date[0:2]), int(date[2:4]), (2000 if yy < 80 else 1900) + yy)
        t, note = judge_date(day + time_of_day(f(0)), wall)
    except Refused as exc:
        return _replace(pos, time_reason=f"RMC {exc}")
    return _replace(pos, time=t, note=note)


def _zda(talker, f, wall) -> Reading:
    try:
        year = _int(f(3))
        if year is None or _int(f(1)) is None or _int(f(2)) is None:
            raise Refused("date missing")
        day = day_start(int(f(1)), int(f(2)), year)
        t, note = judge_date(day + time_of_day(f(0)), wall)
    except Refused as exc:
        return Reading("ZDA", talker, time_reason=f"ZDA {exc}")
    return Reading("ZDA", talker, time_unconfirmed=t, note=note)


def _replace(r: Reading, **changes) -> Reading:
    return replace(r, **changes)
