"""The safety envelope (tcs.pointing.envelope) as pure path computation: the Sun's place, the
horizon table, keep-outs, the escape rule, and a seeded randomized test — thousands of slews
and tracks between random places at random times (2020-2040) — that no planned path enters
the Sun cone, goes below the horizon table, into a keep-out or outside the soft limits.

The planned routes are checked by code of their own here: every leg re-simulated with ruckig
(sampled at 0.2° of the faster axis, not the planner's samples), the Sun for every sample from
``erfa.epv00`` + the observed-place astrometry (no interpolation of directions), the horizon table
interpolated with numpy. The live tests (real sockets, simulated telescope) are in
``tests/test_envelope_live.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from ruckig import InputParameter, Ruckig, Trajectory

from tcs.axes.profile import AxisDynamics, Setpoint
from tcs.config.envelope import EnvelopeSection, KeepOutSection
from tcs.errors import ErrorNumber
from tcs.pointing.astrometry import Astrometry, Refraction, Site, TimeBase
from tcs.pointing.envelope import Envelope, EnvelopeError, plan_route, sun_icrs

SITE = Site(28.7606, -17.8792, 2326.0)          # hwconfig/sim.toml
ASTRO = Astrometry(SITE, TimeBase(37.0, 0.0), Refraction(mode=1), context_interval=60.0)
FLOOR = 15.0
HORIZON = ((0.0, 15.0), (80.0, 32.0), (150.0, 18.0), (250.0, 28.0), (320.0, 15.0))
KEEPOUT = KeepOutSection("mast", (100.0, 130.0), (60.0, 85.0))
AZ = AxisDynamics(5.0, 2.0, 4.0)                 # sim.toml AZ and ZD
ZD = AxisDynamics(3.0, 1.5, 3.0)
RANGES = ((-270.0, 270.0), (-85.0, 85.0))
T2020, T2040 = 1577836800.0, 2208988800.0


def envelope(**kw) -> Envelope:
    section = EnvelopeSection(**{"sun_avoidance": 30.0, "horizon": HORIZON, "keepout": (KEEPOUT,),
                                 "margin": 0.5, **kw})
    return Envelope(section, "AZ-ZD", floor=lambda: FLOOR, astrometry=lambda: ASTRO)


# ------------------------------------------------------------------ independent reference

def sun_altaz(utc: np.ndarray):
    """The Sun's observed place at every ``utc`` (its ICRS place taken at the first: it moves
    1°/day against the stars, 0.002° in a slew of minutes; the diurnal motion is exact)."""
    utc = np.atleast_1d(np.asarray(utc, float))
    ra, dec = sun_icrs(utc[0])
    obs = ASTRO.observed(ra[0], dec[0], utc)
    return np.asarray(obs.az), 90.0 - np.asarray(obs.zd)


def separation(az1, alt1, az2, alt2):
    a1, b1, a2, b2 = (np.radians(x) for x in (az1, alt1, az2, alt2))
    c = np.sin(b1) * np.sin(b2) + np.cos(b1) * np.cos(b2) * np.cos(a1 - a2)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def horizon_at(az):
    xs = np.array([h[0] for h in HORIZON])
    ys = np.array([h[1] for h in HORIZON])
    return np.maximum(np.interp(np.mod(az, 360.0), xs, ys, period=360.0), FLOOR)


def sky_of(a1, a2):
    a1, a2 = np.asarray(a1, float), np.asarray(a2, float)
    az = np.mod(np.where(a2 < 0, a1 + 180.0, a1), 360.0)
    return az, 90.0 - np.abs(a2)


def in_keepout(a1, a2):
    az = np.mod(a1, 360.0)
    return (az >= 100.0) & (az <= 130.0) & (a2 >= 60.0) & (a2 <= 85.0)


def violations(a1, a2, utc):
    """Per sample: inside the Sun cone, below the horizon table, in the keep-out."""
    az, alt = sky_of(a1, a2)
    saz, salt = sun_altaz(np.asarray(utc, float))
    return (separation(az, alt, saz, salt) < 30.0, alt < horizon_at(az), in_keepout(a1, a2))


def resimulate(start, goal, t0):
    """One leg with ruckig itself (each axis from rest, at once): times, a1, a2."""
    out = []
    for x0, x1, dyn in ((start[0], goal[0], AZ), (start[1], goal[1], ZD)):
        inp = InputParameter(1)
        inp.current_position, inp.target_position = [x0], [x1]
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = [dyn.max_velocity], [dyn.max_acceleration], [dyn.max_jerk]
        traj = Trajectory(1)
        Ruckig(1, 0.01).calculate(inp, traj)
        out.append(traj)
    duration = max(t.duration for t in out)
    times = np.arange(0.0, duration + 0.05, 0.2 / AZ.max_velocity)
    pos = [np.array([t.at_time(min(x, t.duration))[0][0] for x in times]) for t in out]
    return t0 + times, pos[0], pos[1], duration


def random_place(rng, t, near_sun: bool):
    """A mechanical (AZ, ZD) outside the envelope (by this file's own check)."""
    n = 400
    if near_sun:
        saz, salt = sun_altaz(np.array([t]))
        az = saz[0] + rng.uniform(-80.0, 80.0, n)
        zd = np.clip(90.0 - salt[0] + rng.uniform(-40.0, 40.0, n), 0.0, 74.5)
    else:
        az, zd = rng.uniform(0.0, 360.0, n), rng.uniform(0.0, 74.5, n)
    flip = rng.random(n) < 0.25                  # the reverse orientation now and then
    az, zd = np.where(flip, az + 180.0, az), np.where(flip, -zd, zd)
    a1 = (az + 180.0) % 360.0 - 180.0 + rng.choice([-360.0, 0.0, 360.0], n)
    sun, low, keep = violations(a1, zd, np.full(n, t))
    free = np.flatnonzero(~(sun | low | keep) & (np.abs(a1) <= 270.0))
    assert free.size, "no free place found"
    return float(a1[free[0]]), float(zd[free[0]])


# --------------------------------------------------------------------------------- tests

def test_the_suns_place_agrees_with_astropy_within_a_minute_of_arc():
    astropy = pytest.importorskip("astropy")
    from astropy.utils import iers
    iers.conf.auto_download = False
    iers.conf.auto_max_age = None
    iers.conf.iers_degraded_accuracy = "ignore"
    import astropy.units as u
    from astropy.coordinates import AltAz, EarthLocation, get_sun
    from astropy.time import Time
    assert astropy
    loc = EarthLocation(lon=SITE.longitude * u.deg, lat=SITE.latitude * u.deg, height=SITE.height * u.m)
    astro = Astrometry(SITE, TimeBase(37.0, 0.0), Refraction(mode=0))
    for utc in (1.6e9, 1.65e9 + 5000.0, 1.7e9 + 12345.0, 1.75e9):
        ra, dec = sun_icrs(utc)
        obs = astro.observed(ra[0], dec[0], utc)
        t = Time(utc, format="unix")
        ref = get_sun(t).transform_to(AltAz(obstime=t, location=loc))
        sep = separation(obs.az, 90.0 - obs.zd, ref.az.deg, ref.alt.deg)
        assert sep * 3600.0 < 60.0, (utc, sep * 3600.0)


def test_horizon_table_interpolates_wraps_and_keeps_the_floor():
    env = envelope(horizon=((10.0, 30.0), (350.0, 20.0), (180.0, 5.0)))
    assert env.min_altitude(10.0) == pytest.approx(30.0)
    assert env.min_altitude(0.0) == pytest.approx(25.0)        # between 350 and 10, through 0
    assert env.min_altitude(360.0 + 350.0) == pytest.approx(20.0)
    assert env.min_altitude(180.0) == pytest.approx(FLOOR)     # 5 in the table: the floor wins
    assert envelope(horizon=()).min_altitude(123.0) == pytest.approx(FLOOR)


def test_a_path_starting_inside_may_leave_but_not_go_deeper():
    env = envelope(horizon=(), keepout=())
    t = 1.75e9
    saz, salt = sun_altaz(np.array([t]))
    az0, zd0 = float(saz[0]), 90.0 - float(salt[0])
    # from 10 deg off the Sun straight away from it: allowed (escape)
    away = env.judge(np.full(50, az0), zd0 - np.linspace(10.0, 35.0, 50) * np.sign(zd0 - 45.0), t)
    assert away.ok
    # towards it: refused at once, naming the cone
    path_zd = zd0 + np.linspace(10.0, 0.0, 50) * (1 if zd0 < 45 else -1)
    towards = env.judge(np.full(50, az0), path_zd, t)
    assert not towards.ok and towards.reason == "sun" and "Sun" in towards.text
    # a tracked path (no escape) that starts inside is refused at its first sample
    assert env.judge(np.full(50, az0), path_zd, t, escape=False).good == 0


def test_an_explicit_zero_switches_the_cone_off_and_the_default_is_30():
    assert EnvelopeSection().sun_avoidance == 30.0
    env = envelope(sun_avoidance=0.0, horizon=(), keepout=())
    t = 1.75e9
    saz, salt = sun_altaz(np.array([t]))
    assert env.judge([float(saz[0])], [90.0 - float(salt[0])], t).ok


def test_random_slews_never_plan_a_path_into_the_envelope():
    """Seeded: 1000 slews between random free places at random times, half of them around the
    Sun (so that many direct slews would cross the cone): every planned route, re-simulated,
    stays outside the Sun cone, above the horizon table, out of the keep-out and inside the
    soft limits; direct slews, detours and refusals all occur."""
    rng = np.random.default_rng(20261125)
    env = envelope()
    counts = {"direct": 0, "detour": 0, "refused": 0}
    for i in range(1000):
        t = rng.uniform(T2020, T2040)
        if i % 2:   # daytime for half of them: within 3 h of the site's noon (13:12 UTC)
            t = math.floor(t / 86400.0) * 86400.0 + 13.2 * 3600.0 + rng.uniform(-3.0, 3.0) * 3600.0
        start = random_place(rng, t, near_sun=bool(i % 2))
        end = random_place(rng, t, near_sun=bool(i % 2))
        try:
            route = plan_route(env, t, (Setpoint(start[0]), Setpoint(start[1])), end, (AZ, ZD), RANGES)
        except EnvelopeError as exc:
            assert exc.number == ErrorNumber.SOFTLIMIT and "refused" in exc.message
            counts["refused"] += 1
            continue
        counts["direct" if not route.waypoints else "detour"] += 1
        here, when = start, t
        for goal in route.waypoints + (route.end,):
            assert RANGES[0][0] <= goal[0] <= RANGES[0][1] and RANGES[1][0] <= goal[1] <= RANGES[1][1]
            times, a1, a2, duration = resimulate(here, goal, when)
            assert a1.min() >= RANGES[0][0] - 1e-9 and a1.max() <= RANGES[0][1] + 1e-9
            assert a2.min() >= RANGES[1][0] - 1e-9 and a2.max() <= RANGES[1][1] + 1e-9
            sun, low, keep = violations(a1, a2, times)
            assert not sun.any(), (i, route, "Sun cone", times[sun][:3])
            assert not low.any(), (i, route, "below the horizon table")
            assert not keep.any(), (i, route, "keep-out")
            here, when = goal, when + duration
    assert min(counts.values()) > 20, counts


def test_random_tracks_stop_before_the_envelope():
    """Seeded: 1000 sidereal targets tracked for 1 h from random times: the tracked path (cut
    where :meth:`Envelope.judge` says, as the tracker cuts it) is outside the envelope up to
    the cut, and the first sample past the cut is inside a border (stopped before it, not
    early)."""
    rng = np.random.default_rng(28)
    env = envelope()
    cut = 0
    for _ in range(1000):
        t0 = rng.uniform(T2020, T2040)
        ra, dec = rng.uniform(0.0, 24.0), math.degrees(math.asin(rng.uniform(-1.0, 1.0)))
        times = t0 + np.arange(0.0, 3600.0 + 1.0, 60.0)
        obs = ASTRO.observed(ra, dec, times)
        a1, a2 = np.unwrap(np.asarray(obs.az), period=360.0), np.asarray(obs.zd)
        j = env.judge(a1, a2, times, escape=False)
        sun, low, keep = violations(a1, a2, times)
        bad = sun | low | keep
        assert not bad[:j.good].any()
        if j.good < times.size:
            cut += 1
            m, _why = env.margins(a1[j.good:j.good + 1], a2[j.good:j.good + 1], times[j.good])
            assert bad[j.good] or m[0] < 1e-3   # (the border itself, to rounding)
    assert cut > 50


def test_a_slew_that_cannot_avoid_the_sun_is_refused_with_a_clear_error():
    env = envelope(horizon=(), keepout=())
    t = 1.75e9 + 3600.0 * 2
    saz, salt = sun_altaz(np.array([t]))
    assert salt[0] > 20.0, "a daytime instant"
    target = (float(saz[0]) % 360.0 - 360.0 * (saz[0] > 180.0), 90.0 - float(salt[0]) - 10.0)
    with pytest.raises(EnvelopeError) as err:
        plan_route(env, t, (Setpoint(0.0), Setpoint(0.0)), target, (AZ, ZD), RANGES)
    assert "Sun avoidance cone (30" in err.value.message
