"""The POINTING pipeline's pure parts: target → demand → back to the target (both mounts, both
orientations, with a pointing model), the field angle convention, the cable-wrap turn choice
and the TRACK value grammar. The served behaviour is tested in test_pointing_module.py."""

from __future__ import annotations

import math

import erfa
import numpy as np
import pytest

from tcs.errors import RequestRefused
from tcs.pointing.astrometry import Astrometry, Refraction, Site, TimeBase
from tcs.pointing.demand import Pipeline, field_angle
from tcs.pointing.model import PointingModel
from tcs.pointing.tracker import choose_turn, parse_track

SITE = Site(28.7606, -17.8792, 2326.0)
ASTRO = Astrometry(SITE, TimeBase(37.0, -0.1234), Refraction(1))
T0 = 1.79e9
MODELS = {
    "AZ-ZD": PointingModel("AZ-ZD", dict(IA=0.05, IE=-0.03, NPAE=0.01, CA=0.02, AN=0.004,
                                         AW=-0.006, TF=0.01, TX=0.001), SITE.latitude),
    "RA-DEC": PointingModel("RA-DEC", dict(IH=0.02, ID=-0.01, CH=0.005, NP=0.003, MA=0.004,
                                           ME=-0.002, TF=0.006), SITE.latitude),
}
MAS = 1.0 / 3.6e6


@pytest.mark.parametrize("mount", ["AZ-ZD", "RA-DEC"])
@pytest.mark.parametrize("reverse", [False, True], ids=["normal", "reverse"])
def test_place_inverts_demand(mount, reverse):
    """CURRENT computed from the demand of a target is the target (model, orientation and
    astrometry all undone), and the corrections are demand − ideal."""
    pipe = Pipeline(ASTRO, MODELS[mount], mount)
    rng = np.random.default_rng(7)
    for _ in range(20):
        utc = T0 + rng.uniform(0, 86400)
        lst = ASTRO.sidereal_time(utc)
        ra = (lst + rng.uniform(-3.0, 3.0)) % 24.0          # within 3 h of the meridian
        dec = rng.uniform(-10.0, 70.0)
        d = pipe.demand(ra, dec, utc, reverse)
        if d.zd[0] > 80.0:
            continue
        place = pipe.place(d.axis1[0], d.axis2[0], utc)
        sep = math.degrees(erfa.seps(ra * math.pi / 12.0, math.radians(dec),
                                     place.ra * math.pi / 12.0, math.radians(place.dec)))
        assert sep < 1 * MAS, sep / MAS
        assert place.reverse is reverse
        assert place.correction1 == pytest.approx(d.axis1[0] - d.ideal1[0], abs=1e-9)
        assert place.correction2 == pytest.approx(d.axis2[0] - d.ideal2[0], abs=1e-9)
        assert place.ha == pytest.approx(float(d.observed.ha[0]), abs=1e-8)


def test_demand_frames():
    """AZ-ZD demand is (AZ, ZD), reverse (AZ+180, -ZD); RA-DEC is (HA·15, Dec), reverse
    (HA·15+180, 180-Dec) — before the model."""
    utc = T0 + np.arange(3) * 10.0
    zero = {m: PointingModel(m, {}, SITE.latitude) for m in ("AZ-ZD", "RA-DEC")}
    altaz = Pipeline(ASTRO, zero["AZ-ZD"], "AZ-ZD")
    d, r = altaz.demand(5.0, 30.0, utc), altaz.demand(5.0, 30.0, utc, True)
    np.testing.assert_allclose(d.axis1, d.observed.az)
    np.testing.assert_allclose(d.axis2, d.observed.zd)
    np.testing.assert_allclose(r.axis1, d.observed.az + 180.0)
    np.testing.assert_allclose(r.axis2, -d.observed.zd)
    eq = Pipeline(ASTRO, zero["RA-DEC"], "RA-DEC")
    d, r = eq.demand(5.0, 30.0, utc), eq.demand(5.0, 30.0, utc, True)
    np.testing.assert_allclose(d.axis1, d.observed.ha * 15.0)
    np.testing.assert_allclose(d.axis2, d.observed.dec)
    np.testing.assert_allclose(r.axis1, d.observed.ha * 15.0 + 180.0)
    np.testing.assert_allclose(r.axis2, 180.0 - d.observed.dec)


def test_pipeline_refuses_other_mounts():
    with pytest.raises(RequestRefused):
        Pipeline(ASTRO, PointingModel("AZ-ZD", {}), "ZD-ZD")
    with pytest.raises(RequestRefused):
        Pipeline(ASTRO, PointingModel("AZ-ZD", {}), "RA-DEC")


def test_field_angle_convention():
    pa, zd = np.array([10.0, -20.0]), np.array([30.0, 50.0])
    np.testing.assert_allclose(field_angle("AZ-ZD", pa, zd, False, 0), pa)
    np.testing.assert_allclose(field_angle("AZ-ZD", pa, zd, False, 2), pa + zd)
    np.testing.assert_allclose(field_angle("AZ-ZD", pa, zd, False, 3), pa - zd)
    np.testing.assert_allclose(field_angle("AZ-ZD", pa, -zd, True, 2), pa - zd + 180.0)
    np.testing.assert_allclose(field_angle("RA-DEC", pa, zd, True, 2), [180.0, 180.0])


def test_choose_turn():
    path = np.linspace(200.0, 300.0, 11)               # a derotator turning past +250
    shifted, n = choose_turn(path, -250.0, 250.0, 360.0, current=220.0)
    assert n == 11 and shifted[0] == pytest.approx(-160.0)   # the turn that stays inside
    path = np.linspace(0.0, 10.0, 5)                    # two turns fit: the nearer one
    shifted, n = choose_turn(path, -400.0, 400.0, 360.0, current=-355.0)
    assert n == 5 and shifted[0] == pytest.approx(-360.0)
    shifted, n = choose_turn(path, -400.0, 400.0, 360.0, current=100.0)
    assert n == 5 and shifted[0] == pytest.approx(0.0)


@pytest.mark.parametrize("value, expected", [(0, (0, 0)), (1, (1, 0)), (4, (4, 0)), (257, (1, 256)),
                                             (131, (3, 128)), (388, (4, 384))])
def test_parse_track(value, expected):
    assert parse_track(value) == expected


@pytest.mark.parametrize("value", [5, 64, 127, 512, -1, 129 + 512])
def test_parse_track_refuses(value):
    with pytest.raises(RequestRefused) as info:
        parse_track(value)
    assert info.value.keyword == "RANGE"
