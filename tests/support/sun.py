"""The real Sun as the envelope tests place and judge it: where it stands now for a running
service (observed az/zd at its site and clock) and how far a mechanical AZ/ZD position is from it."""

from __future__ import annotations

import math

from tcs.pointing.envelope import sun_icrs


def sun_now(live) -> tuple[float, float]:
    """The Sun's observed (az, zd) now, for the service's site and time."""
    p = live.telescope.pointing
    utc = p.utc()
    ra, dec = sun_icrs(utc)
    obs = p.astrometry().observed(ra[0], dec[0], utc)
    return float(obs.az), float(obs.zd)


def sep_from_sun(live, az, zd) -> float:
    """Degrees between the Sun now and the AZ-ZD position (az, zd) (negative ZD: reverse)."""
    saz, szd = sun_now(live)
    a1, b1, a2, b2 = (math.radians(x) for x in (az, 90.0 - abs(zd), saz, 90.0 - szd))
    if zd < 0:
        a1 += math.pi
    c = math.sin(b1) * math.sin(b2) + math.cos(b1) * math.cos(b2) * math.cos(a1 - a2)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))
