"""A made-up satellite that passes over a site *now*: a valid two-line element set for trying
satellite tracking on the simulated telescope (and for the tests).

How it works
------------
:func:`leo_tle` puts a circular low orbit (420 km, 51.6° like the ISS by default) so that its
ground track passes ``offset`` degrees of latitude north of the site at the chosen UTC: the
argument of latitude and the node follow from the site's latitude and longitude and the
Greenwich mean sidereal time then. The elements are set with sgp4's ``sgp4init`` at an epoch
two minutes before the culmination and written out with sgp4's exporter, so the lines carry
correct checksums and a fresh epoch — what the TCS asks of any TLE (docs/satellites.md).
``offset`` 2.5° gives a pass about 60° high; 0 passes through the zenith.

Run ``python -m tcs.pointing.demo_tle --config hwconfig/sim.toml [--in 300] [--offset 2.5]``:
it prints ``LINE1='…'`` and ``LINE2='…'`` for the shell's ``eval`` (``--plain``: the two lines).
A real satellite's element set comes from CelesTrak or Space-Track, not from here.

What may touch it: anything; pure computation.
"""

from __future__ import annotations

import argparse
import math
import time

__all__ = ["leo_tle"]

_MU = 398600.4418          # km³/s²
_EARTH_RADIUS = 6378.135   # km (WGS-72)


def leo_tle(latitude: float, longitude: float, culmination: float, offset: float = 2.5,
            height: float = 420.0, inclination: float = 51.6,
            number: int = 99999) -> tuple[str, str]:
    """(line 1, line 2) of a circular orbit ``height`` km up at ``inclination`` degrees whose
    ground track passes ``offset`` degrees north of (``latitude``, ``longitude``) at UTC
    ``culmination`` (Unix seconds); the epoch is two minutes before that."""
    import erfa
    from sgp4.api import WGS72, Satrec
    from sgp4.exporter import export_tle
    inc = math.radians(inclination)
    ratio = math.sin(math.radians(latitude + offset)) / math.sin(inc)
    if abs(ratio) > 1.0:
        raise ValueError(f"an orbit inclined {inclination:g}° never passes over latitude "
                         f"{latitude + offset:g}°")
    a = _EARTH_RADIUS + height
    n = math.sqrt(_MU / a ** 3)                       # rad/s
    epoch = culmination - 120.0
    u = math.asin(ratio)                               # argument of latitude at the culmination
    gmst = erfa.gmst82(2440587.5 + culmination / 86400.0, 0.0)
    node = gmst + math.radians(longitude) - math.atan2(math.cos(inc) * math.sin(u), math.cos(u))
    sat = Satrec()
    sat.sgp4init(WGS72, "i", number, 2440587.5 + epoch / 86400.0 - 2433281.5, 0.0, 0.0, 0.0,
                 0.0001, 0.0, inc, (u - n * (culmination - epoch)) % (2 * math.pi), n * 60.0,
                 node % (2 * math.pi))
    return export_tle(sat)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", help="hardware file whose [site] is used")
    ap.add_argument("--latitude", type=float, help="degrees north (instead of --config)")
    ap.add_argument("--longitude", type=float, help="degrees east (instead of --config)")
    ap.add_argument("--in", dest="delay", type=float, default=300.0,
                    help="seconds from now to the culmination (default 300)")
    ap.add_argument("--offset", type=float, default=2.5,
                    help="degrees of latitude north of the site the track passes (2.5: ~60° high)")
    ap.add_argument("--plain", action="store_true", help="print the two lines only")
    args = ap.parse_args(argv)
    lat, lon = args.latitude, args.longitude
    if args.config:
        import tomllib
        with open(args.config, "rb") as f:
            site = tomllib.load(f).get("site", {})
        lat = site.get("latitude", lat) if lat is None else lat
        lon = site.get("longitude", lon) if lon is None else lon
    if lat is None or lon is None:
        ap.error("give --config or --latitude and --longitude")
    line1, line2 = leo_tle(lat, lon, time.time() + args.delay, args.offset)
    if args.plain:
        print(line1)
        print(line2)
    else:
        print(f"LINE1='{line1}'")
        print(f"LINE2='{line2}'")


if __name__ == "__main__":   # pragma: no cover - a command
    main()
