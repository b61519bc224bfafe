"""The target model (tcs/pointing/targets.py) against skyfield and SGP4, in pure computation.

Bodies: the Moon, the Sun, Mars and Jupiter for the site of hwconfig/sim.toml on dates from
2020 to 2040, against skyfield's own apparent topocentric alt/az (no refraction on either
side), within 1″. A satellite from a TLE against ``(satellite - site).at(t).altaz()``. A LEO
pass followed by the axes' own trajectory queue and follower (simulated 10 ms cycles) within
1″ RMS of the target; a near-zenith pass planned with its keyhole bridge inside the axis
limits; a target with RA/Dec rates evaluated over 10 minutes of (simulated) time.
"""

from __future__ import annotations

import datetime as dt
import math
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from tcs.axes.profile import AxisDynamics
from tcs.errors import RangeRefused
from tcs.pointing.astrometry import Astrometry, Refraction, Site, TimeBase
from tcs.pointing.follow_check import follow, separation_arcsec
from tcs.pointing.sky_object import SkyObject
from tcs.pointing.targets import (BodyTarget, HorizontalTarget, IcrsTarget, SatelliteTarget,
                                  body_rates, ephemeris, ra_rate_to_ra_v)

skyfield_api = pytest.importorskip("skyfield.api")

SIM = tomllib.loads((Path(__file__).parents[1] / "hwconfig" / "sim.toml").read_text())
SITE = Site(SIM["site"]["latitude"], SIM["site"]["longitude"], SIM["site"]["height"])
AXES = SIM["axes"]
AZ = AxisDynamics(AXES["az"]["max_velocity"], AXES["az"]["max_acceleration"], AXES["az"]["max_jerk"])
ZD = AxisDynamics(AXES["zd"]["max_velocity"], AXES["zd"]["max_acceleration"], AXES["zd"]["max_jerk"])
AZ_RANGE = (AXES["az"]["min"], AXES["az"]["max"])

# ISS, the element set of skyfield's documentation (2014-01-20)
ISS = ("1 25544U 98067A   14020.93268519  .00009878  00000-0  18200-3 0  5082",
       "2 25544  51.6498 109.4756 0003572  55.9686 274.8005 15.50377579 39831")
PASS_59 = 1390214651.47        # culmination 59° (2014-01-20 10:44 UTC)
PASS_86 = 1390524930.27        # culmination 86° (2014-01-24 00:55 UTC): the zenith keyhole


def _ts():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return skyfield_api.load.timescale()


def _site_sf():
    return skyfield_api.wgs84.latlon(SITE.latitude, SITE.longitude, elevation_m=SITE.height)


def _astrometry_for(t, refraction=0) -> Astrometry:
    """Our astrometry with the time base skyfield uses at ``t`` (leap seconds, DUT1)."""
    tai_utc = float(np.atleast_1d(t._leap_seconds())[0])
    return Astrometry(SITE, TimeBase(tai_utc, float(np.atleast_1d(t.dut1)[0])), Refraction(mode=refraction))


def _unix(t) -> np.ndarray:
    return np.array([d.timestamp() for d in np.atleast_1d(t.utc_datetime())])


@pytest.mark.parametrize("body", ["moon", "sun", "mars", "jupiter"])
def test_bodies_agree_with_skyfield_within_1_arcsec(body):
    ts, eph, here = _ts(), ephemeris(), _site_sf()
    observer = eph["earth"] + here
    worst = 0.0
    for year in (2020, 2024, 2029, 2033, 2037, 2040):
        for month, hours in ((2, (1.0, 7.5, 13.0, 19.5)), (9, (4.0, 10.5, 16.0, 22.5))):
            t = ts.utc(year, month, 11, hours)
            mine = []
            for i in range(len(hours)):     # each instant with its own DUT1
                ti = t[i]
                mine.append(BodyTarget(body).observed(_astrometry_for(ti), _unix(ti)))
            name = {"jupiter": "jupiter barycenter"}.get(body, body)
            alt, az, _ = observer.at(t).observe(eph[name]).apparent().altaz()
            err = separation_arcsec([m.az[0] for m in mine], [m.zd[0] for m in mine],
                                    az.degrees, 90.0 - alt.degrees)
            worst = max(worst, float(err.max()))
    assert worst < 1.0, worst


def test_a_satellite_agrees_with_sgp4_and_skyfield_within_1_arcsec():
    ts, here = _ts(), _site_sf()
    sat = skyfield_api.EarthSatellite(*ISS)
    utc = PASS_59 + np.arange(-400.0, 400.0, 5.0)
    t = ts.from_datetimes([dt.datetime.fromtimestamp(x, dt.timezone.utc) for x in utc])
    mine = SatelliteTarget(line1=ISS[0], line2=ISS[1]).observed(_astrometry_for(t[0]), utc)
    alt, az, _ = (sat - here).at(t).altaz()
    err = separation_arcsec(mine.az, mine.zd, az.degrees, 90.0 - alt.degrees)
    assert err.max() < 1.0, err.max()
    assert alt.degrees.max() > 55.0             # the pass itself was compared, not the ground


def test_bad_tle_and_bodies_are_refused():
    with pytest.raises(RangeRefused):
        SatelliteTarget(line1="1 hello", line2=ISS[1])
    with pytest.raises(RangeRefused):
        BodyTarget("vulcan")
    obj = SkyObject()
    with pytest.raises(RangeRefused):
        obj.set_tle(1, "1 25544U")
    with pytest.raises(RangeRefused):
        obj.set_solarsystem_object(9)
    with pytest.raises(RangeRefused):
        obj.set_solarsystem_name("vulcan")
    obj.set_solarsystem_name("Jupiter")
    assert (obj.kind, obj.body, obj.solarsystem_index) == ("body", "jupiter", 4)
    obj.set_solarsystem_name("moon")
    assert (obj.kind, obj.body, obj.moon) == ("body", "moon", 1)
    obj.set_ra(1.0)
    assert obj.kind == "equatorial"


def _plan(culm, zd_limit=75.0):
    ast = Astrometry(SITE, TimeBase(35.0, 0.0))
    sat = SatelliteTarget(line1=ISS[0], line2=ISS[1], name="ISS")
    plan = sat.plan(ast, zd_limit=zd_limit, utc=culm - 1500.0, az_range=AZ_RANGE,
                    az_limits=(AZ.max_velocity, AZ.max_acceleration, AZ.max_jerk),
                    zd_limits=(ZD.max_velocity, ZD.max_acceleration, ZD.max_jerk))
    return ast, sat, plan


def test_leo_pass_followed_within_1_arcsec_rms():
    """The fastest minute of a 59° ISS pass (AZ up to 1.7°/s), sampled as the tracker does and
    followed cycle by cycle by the axes' follower within their limits."""
    ast, sat, plan = _plan(PASS_59)
    assert plan.feasible and not plan.keyhole
    assert abs(plan.culmination - PASS_59) < 2.0 and plan.max_altitude > 58.0
    assert AZ_RANGE[0] <= min(plan.az_start, plan.az_end) and max(plan.az_start, plan.az_end) <= AZ_RANGE[1]
    target = sat.planned(plan, 0.0)
    result = follow(target, ast, plan.culmination - 30.0, plan.culmination + 30.0, az=AZ, zd=ZD,
                    az_start=None)
    assert result.rms < 1.0 and result.max < 1.0, result
    assert result.limited_cycles == 0
    assert result.max_az_rate > 1.0                       # it was a fast part of the pass


def test_zenith_keyhole_planned_inside_the_axis_limits():
    """An 86° pass needs more AZ speed than the axis has: the plan leads AZ on a bridge inside
    90 % of its speed, acceleration and jerk (readable before tracking), and the axes follow
    that planned path."""
    ast, sat, plan = _plan(PASS_86)
    assert plan.keyhole and plan.feasible, plan
    assert plan.keyhole_start < plan.culmination < plan.keyhole_end
    assert plan.max_az_rate <= 0.9 * AZ.max_velocity
    assert plan.keyhole_error > 0.0
    # without the bridge AZ would need more than the axis has
    obs = sat.sky(ast, np.arange(plan.culmination - 5, plan.culmination + 5, 0.5))
    assert np.abs(np.diff(np.unwrap(obs.az, period=360.0))).max() / 0.5 > AZ.max_velocity
    target = sat.planned(plan, 0.0)
    result = follow(target, ast, plan.keyhole_start - 5.0, plan.keyhole_end + 5.0, az=AZ, zd=ZD)
    assert result.rms < 1.0 and result.limited_cycles == 0, result


def test_cable_wrap_side_keeps_the_whole_pass_in_range():
    """With AZ confined to a narrow range the plan picks the turn that holds the pass or says
    it is not feasible."""
    ast = Astrometry(SITE, TimeBase(35.0, 0.0))
    sat = SatelliteTarget(line1=ISS[0], line2=ISS[1])
    kw = dict(zd_limit=75.0, utc=PASS_59 - 1500.0, az_limits=(5, 2, 4), zd_limits=(3, 1.5, 3))
    ok = sat.plan(ast, az_range=(-200.0, 200.0), az_current=150.0, **kw)
    assert ok.feasible and -200.0 <= min(ok.az_start, ok.az_end) and max(ok.az_start, ok.az_end) <= 200.0
    narrow = sat.plan(ast, az_range=(-60.0, 60.0), **kw)
    assert not narrow.feasible and "AZ would leave" in narrow.reason


def test_rates_stay_on_the_moving_position_for_10_minutes():
    """A target with RA/Dec rates (an asteroid-like 30″/s on the sky): the path the tracker
    samples (every 1 s over 10 minutes) is where the moving position is, within 1″ — both RA
    conventions give the same RA_V."""
    ast = Astrometry(SITE, TimeBase(37.0, 0.0))
    t0 = 1.9e9
    dec0 = 35.0
    sky_rate, dec_rate = 30.0, -12.0                     # arcsec/s: RA·cos Dec, Dec
    ra_v = ra_rate_to_ra_v(sky_rate, dec0, "sky")
    assert ra_v == pytest.approx(ra_rate_to_ra_v(ra_v / 15.0, dec0, "time"))
    target = IcrsTarget(ra=5.0, dec=dec0, ra_v=ra_v, dec_v=dec_rate, epoch=t0)
    utc = t0 + np.arange(0.0, 600.0 + 0.5, 1.0)
    obs = target.observed(ast, utc)
    # the moving position, independently: a great circle rate × time from the start
    ra_true = 5.0 + (sky_rate / math.cos(math.radians(dec0))) * (utc - t0) / 3600.0 / 15.0
    dec_true = dec0 + dec_rate * (utc - t0) / 3600.0
    truth = ast.observed(ra_true, dec_true, utc)
    err = separation_arcsec(obs.az, obs.zd, truth.az, truth.zd)
    assert err.max() < 1.0, err.max()
    moved = separation_arcsec(obs.az[:1], obs.zd[:1], obs.az[-1:], obs.zd[-1:])
    assert moved[0] > 3600.0                              # it did move (and the sky turned)
    # the sampled path interpolated as the axes do stays on it between the samples
    from tcs.axes.trajectory import TrajectoryQueue
    q = TrajectoryQueue(utc.size + 4, cycle=360.0)
    q.add_points(list(utc), list(np.unwrap(obs.az, period=360.0)), None)
    mid = utc[:-1] + 0.5
    exact = target.observed(ast, mid)
    az_mid = np.array([q.sample(float(x))[0] for x in mid])
    err_mid = separation_arcsec(az_mid, exact.zd, exact.az, exact.zd)
    assert err_mid.max() < 1.0, err_mid.max()


def test_catalogue_place_and_horizontal_target():
    """A J2025 place with proper motion is the ICRS place of the same star; a fixed alt/az
    stays where it is."""
    from tcs.pointing.sky_object import precess_from_j2000
    utc = 1.9e9
    r25, d25 = precess_from_j2000(6.0, 20.0, 2025.0)
    obj = SkyObject()
    obj.set_ra(r25)
    obj.set_dec(d25)
    obj.set_equinox(2025.0)
    t = IcrsTarget(*obj.icrs(utc), epoch=utc)
    assert abs(t.ra - 6.0) * 15 * 3600 * math.cos(math.radians(20)) < 0.01
    assert abs(t.dec - 20.0) * 3600 < 0.01
    ast = Astrometry(SITE, TimeBase(37.0, 0.0))
    h = HorizontalTarget(az=123.0, alt=45.0).observed(ast, utc + np.arange(0.0, 100.0, 10.0))
    assert np.allclose(h.az, 123.0) and np.allclose(h.zd, 45.0)


def test_lunar_and_solar_rates_come_from_the_ephemeris():
    """The Moon moves east among the stars by about 0.55″ of RA a second, more or less with its
    distance, declination and parallax; the Sun by about 0.04″/s: measured, not constants."""
    ast = Astrometry(SITE, TimeBase(37.0, 0.0))
    moons = [body_rates("moon", ast, u)[0] for u in (1.7e9, 1.7e9 + 7 * 86400, 1.7e9 + 14 * 86400)]
    assert all(0.3 < m < 0.9 for m in moons), moons
    assert max(moons) - min(moons) > 0.02, moons             # not a constant
    sun_ra, sun_dec = body_rates("sun", ast, 1.7e9)
    assert 0.035 < sun_ra < 0.05 and abs(sun_dec) < 0.02, (sun_ra, sun_dec)


def test_tle_lines_and_elements_sgp4_cannot_propagate_are_refused():
    """Each line by itself (checksum, length, perigee above the atmosphere), then at planning:
    an epoch beyond ``max_age`` days, SGP4 failing during the 24 h searched (a decaying orbit),
    a pass that never rises — each a refused plan (FEASIBLE 0, figures None) whose reason says
    which."""
    from sgp4.api import WGS72, Satrec
    from sgp4.exporter import export_tle

    from tcs.pointing.targets import check_tle_line, tle_checksum
    fixed = ISS[1][:68] + str(tle_checksum(ISS[1]))
    assert check_tle_line(2, fixed) == ISS[1]
    with pytest.raises(RangeRefused, match="checksum"):
        check_tle_line(2, ISS[1][:68] + str((int(ISS[1][68]) + 1) % 10))
    with pytest.raises(RangeRefused, match="69"):
        check_tle_line(1, ISS[0][:-2])
    low = ISS[1][:52] + "17.50000000" + ISS[1][63:68]
    with pytest.raises(RangeRefused, match="perigee .* below the Earth's surface"):
        check_tle_line(2, low + str(tle_checksum(low)))
    ast = Astrometry(SITE, TimeBase(35.0, 0.0))
    kw = dict(zd_limit=75.0, az_range=AZ_RANGE, az_limits=(5, 2, 4), zd_limits=(3, 1.5, 3), max_age=30.0)
    old = SatelliteTarget(line1=ISS[0], line2=ISS[1], name="ISS").plan(ast, utc=PASS_59 + 40 * 86400.0, **kw)
    assert not old.feasible and old.rise is None and old.duration is None
    assert "2014-01-20 22:23 UTC is 39.5 days old" in old.reason, old.reason
    now = 1.8e9
    sat = Satrec()   # 160 km with a huge drag term: SGP4 gives up within hours
    sat.sgp4init(WGS72, "i", 4242, 2440587.5 + now / 86400 - 2433281.5, 0.2, 0.0, 0.0, 0.0001, 0.0,
                 math.radians(51.6), 0.0, math.sqrt(398600.4418 / 6538.135 ** 3) * 60.0, 0.0)
    decaying = SatelliteTarget(*export_tle(sat)).plan(ast, utc=now, **kw)
    assert not decaying.feasible and decaying.reason.startswith("SGP4 cannot propagate this TLE from")
    sat = Satrec()   # equatorial: never above 15° at 28.8° N
    sat.sgp4init(WGS72, "i", 4243, 2440587.5 + now / 86400 - 2433281.5, 0.0, 0.0, 0.0, 0.0001, 0.0,
                 0.0, 0.0, 15.5 * 2 * math.pi / 1440.0, 0.0)
    never = SatelliteTarget(*export_tle(sat), name="EQ").plan(ast, utc=now, **kw)
    assert not never.feasible and never.reason.startswith("EQ does not rise above 15° altitude in the 24 h")
