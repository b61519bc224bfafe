"""Pointing model (terms, inverse, fit), orientation choice and pointing files.

The physical meaning of the terms is checked against an independent simulation: a mount
whose axes are rotated by a known small angle, with its encoder angles computed from
rotation matrices. Files are real files in a temporary directory; the atomic save is
exercised by killing a real subprocess while it saves.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import erfa
import numpy as np
import pytest

from tcs.errors import ErrorNumber, RequestRefused, TcsError
from tcs.pointing.astrometry import Refraction, Site, TimeBase
from tcs.pointing.model import (ALTAZ_TERMS, EQUATORIAL_TERMS, PointingModel, Sample, fit,
                                fit_samples)
from tcs.pointing.orientation import (AxisRange, choose_path, mount_path, to_normal, to_reverse)
from tcs.pointing.storage import (DumpHeader, ModelStore, append_sample, load_dump,
                                  write_dump_header)

AS = 1.0 / 3600.0
D = np.pi / 180.0


# -- physical meaning of the terms -------------------------------------------------------

def _rot_y(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_x(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _encoders_altaz(rot, az, zd):
    """Encoder (AZ, ZD) of a mount whose frame is ``rot`` × true frame (x N, y E, z up)."""
    e = (90.0 - zd) * D
    v = np.stack([np.cos(e) * np.cos(az * D), np.cos(e) * np.sin(az * D), np.sin(e)])
    vm = rot.T @ v
    return np.degrees(np.arctan2(vm[1], vm[0])) % 360.0, 90.0 - np.degrees(np.arcsin(vm[2]))


def _encoders_hadec(rot, ha, dec):
    """Encoder (HA, Dec) of an equatorial mount (x: h=0,δ=0; y: east, h=−90°; z: pole)."""
    v = np.stack([np.cos(dec * D) * np.cos(ha * D), -np.cos(dec * D) * np.sin(ha * D),
                  np.sin(dec * D)])
    vm = rot.T @ v
    return np.degrees(np.arctan2(-vm[1], vm[0])), np.degrees(np.arcsin(vm[2]))


@pytest.fixture(scope="module")
def altaz_sky():
    rng = np.random.default_rng(7)
    return rng.uniform(0.0, 360.0, 300), rng.uniform(10.0, 80.0, 300)


@pytest.mark.parametrize("term, rot", [
    ("AN", _rot_y(30 * AS * D)),     # azimuth axis tilted 30" towards north
    ("AW", _rot_x(-30 * AS * D)),    # … towards east
])
def test_altaz_tilt_terms_match_a_tilted_mount(altaz_sky, term, rot):
    az, zd = altaz_sky
    enc_az, enc_zd = _encoders_altaz(rot, az, zd)
    dem_az, dem_zd = PointingModel("AZ-ZD", {term: 30 * AS}).apply(az, zd)
    sky_err = np.hypot(((dem_az - enc_az + 180) % 360 - 180) * np.sin(zd * D), dem_zd - enc_zd)
    assert sky_err.max() < 0.1 * AS          # second-order effects of a 30" tilt only
    wrong = PointingModel("AZ-ZD", {term: -30 * AS}).apply(az, zd)
    assert np.abs(wrong[1] - enc_zd).max() > 50 * AS


@pytest.mark.parametrize("term, rot", [
    ("ME", _rot_y(30 * AS * D)),     # polar axis 30" above the pole (towards the zenith)
    ("MA", _rot_x(30 * AS * D)),     # polar axis 30" west of the pole
])
def test_polar_axis_terms_match_a_misaligned_mount(term, rot):
    rng = np.random.default_rng(8)
    ha, dec = rng.uniform(-90.0, 90.0, 300), rng.uniform(-40.0, 80.0, 300)
    enc_ha, enc_dec = _encoders_hadec(rot, ha, dec)
    dem_ha, dem_dec = PointingModel("RA-DEC", {term: 30 * AS}, latitude=40.0).apply(ha, dec)
    sky_err = np.hypot((dem_ha - enc_ha) * np.cos(dec * D), dem_dec - enc_dec)
    assert sky_err.max() < 0.1 * AS


def test_index_terms_and_tube_flexure_directions():
    az, zd = np.array([10.0, 200.0]), np.array([30.0, 60.0])
    assert np.allclose(PointingModel("AZ-ZD", {"IA": 0.01}).apply(az, zd)[0], az + 0.01)
    assert np.allclose(PointingModel("AZ-ZD", {"IE": 0.01}).apply(az, zd)[1], zd - 0.01)
    assert np.allclose(PointingModel("RA-DEC", {"IH": 0.01}).apply(az, zd)[0], az - 0.01)
    assert np.allclose(PointingModel("RA-DEC", {"ID": 0.01}).apply(az, zd)[1], zd - 0.01)
    # TF > 0: demand lower (larger ZD) by TF·sin ZD.
    _, dz = PointingModel("AZ-ZD", {"TF": 0.01}).corrections(az, zd)
    assert np.allclose(dz, 0.01 * np.sin(zd * D))
    # The equatorial TF is the same vertical shift, seen in HA/Dec.
    lat = 35.0
    rng = np.random.default_rng(9)
    ha, dec = rng.uniform(-80, 80, 200), rng.uniform(-30, 85, 200)
    a0, e0 = erfa.hd2ae(ha * D, dec * D, lat * D)
    keep = e0 > 10 * D
    h1, d1 = PointingModel("RA-DEC", {"TF": 20 * AS}, latitude=lat).apply(ha, dec)
    a1, e1 = erfa.hd2ae(h1 * D, d1 * D, lat * D)
    de = (e1 - e0)[keep] / D
    da = (np.angle(np.exp(1j * (a1 - a0))) * np.cos(e0))[keep] / D
    assert np.abs(de - (-20 * AS) * np.cos(e0[keep])).max() < 0.01 * AS
    assert np.abs(da).max() < 0.01 * AS


# -- apply / invert ------------------------------------------------------------------------

ALTAZ_TRUE = {"IA": 120 * AS, "IE": -45 * AS, "NPAE": 15 * AS, "CA": -25 * AS, "AN": 8 * AS,
              "AW": -12 * AS, "TF": -20 * AS, "TX": 3 * AS}
EQ_TRUE = {"IH": 60 * AS, "ID": -30 * AS, "CH": 20 * AS, "NP": -10 * AS, "MA": 40 * AS,
           "ME": -25 * AS, "TF": 15 * AS}


def test_apply_invert_round_trip_both_mounts_and_orientations():
    rng = np.random.default_rng(10)
    az, zd = rng.uniform(0, 360, 500), rng.uniform(0.0, 89.0, 500)
    model = PointingModel("AZ-ZD", ALTAZ_TRUE)
    for a1, a2 in ((az, zd), to_reverse(az, zd, "AZ-ZD")):
        back = model.invert(*model.apply(a1, a2))
        assert np.abs(back[0] - a1).max() < 1e-9 and np.abs(back[1] - a2).max() < 1e-9
    ha, dec = rng.uniform(-180, 180, 500), rng.uniform(-89.9, 89.9, 500)
    model = PointingModel("RA-DEC", EQ_TRUE, latitude=-30.0)
    for a1, a2 in ((ha, dec), to_reverse(ha, dec, "RA-DEC")):
        back = model.invert(*model.apply(a1, a2))
        assert np.abs(back[0] - a1).max() < 1e-9 and np.abs(back[1] - a2).max() < 1e-9
    # Scalars in, floats out; the zenith itself stays finite.
    m = PointingModel("AZ-ZD", ALTAZ_TRUE)
    x = m.apply(123.0, 0.0)
    assert all(isinstance(v, float) and np.isfinite(v) for v in x)
    assert m.invert(*x) == pytest.approx((123.0, 0.0), abs=1e-9)


def test_model_validation():
    with pytest.raises(RequestRefused, match="'IH' is not one of AZ-ZD"):
        PointingModel("AZ-ZD", {"IH": 0.0})
    with pytest.raises(RequestRefused, match="mount 'ALT'"):
        PointingModel("ALT", {})
    with pytest.raises(RequestRefused, match="not plausible"):
        PointingModel("AZ-ZD", {"IA": float("nan")})
    m = PointingModel("AZ-ZD", {"IA": 0.1})
    assert m.replace(CA=0.2).coefficients == {"IA": 0.1, "CA": 0.2} and m.get("TX") == 0.0


# -- fit -----------------------------------------------------------------------------------

def _synthetic(model, a1, a2, noise, rng):
    """Measured axis positions: the model's demand plus on-sky Gaussian noise (degrees)."""
    m1, m2 = model.apply(a1, a2)
    lat = (90.0 - a2) if model.mount == "AZ-ZD" else a2
    w = np.abs(np.cos(lat * D))
    return m1 + rng.normal(0, noise, a1.size) / w, m2 + rng.normal(0, noise, a1.size)


def test_fit_recovers_altaz_model_within_errors():
    rng = np.random.default_rng(11)
    n, noise = 80, 1.0 * AS
    az, zd = rng.uniform(0, 360, n), np.degrees(np.arccos(rng.uniform(0.1, 0.98, n)))
    true = PointingModel("AZ-ZD", ALTAZ_TRUE)
    m1, m2 = _synthetic(true, az, zd, noise, rng)
    res = fit(az, zd, m1, m2, mount="AZ-ZD")
    assert res.fitted == ALTAZ_TERMS and res.n_samples == n
    for name in ALTAZ_TERMS:
        err = res.errors[name]
        assert 0 < err < 20 * AS
        assert abs(res.model.get(name) - ALTAZ_TRUE[name]) < 4 * err, name
    assert 0.7 * noise < res.rms / np.sqrt(2) < 1.3 * noise
    assert np.allclose(res.correlation, res.correlation.T)
    assert np.allclose(np.diag(res.correlation), 1.0)
    assert res.covariance.shape == (8, 8)
    # The fitted model reproduces the measurements to the noise.
    back = res.model.invert(m1, m2)
    assert np.abs(back[1] - zd).max() < 5 * noise
    text = res.report()
    assert "IA" in text and "±" in text and "80 samples" in text


def test_fit_recovers_equatorial_model_with_both_orientations():
    rng = np.random.default_rng(12)
    n, noise, lat = 100, 0.5 * AS, -24.6
    ha, dec = rng.uniform(-75, 75, n), rng.uniform(-85, 60, n)
    flip = rng.random(n) < 0.5
    r1, r2 = to_reverse(ha, dec, "RA-DEC")
    a1, a2 = np.where(flip, r1, ha), np.where(flip, r2, dec)
    true = PointingModel("RA-DEC", EQ_TRUE, latitude=lat)
    m1, m2 = _synthetic(true, a1, a2, noise, rng)
    samples = [Sample(1.7e9 + i, 0.0, 0.0, a1[i], a2[i], m1[i], m2[i]) for i in range(n)]
    res = fit_samples(samples, mount="RA-DEC", latitude=lat)
    for name in EQUATORIAL_TERMS:
        assert abs(res.model.get(name) - EQ_TRUE[name]) < 4 * res.errors[name], name
    assert res.model.latitude == lat


def test_fixed_terms_are_held_and_reported():
    rng = np.random.default_rng(13)
    az, zd = rng.uniform(0, 360, 60), rng.uniform(10, 80, 60)
    true = PointingModel("AZ-ZD", ALTAZ_TRUE)
    m1, m2 = _synthetic(true, az, zd, 0.5 * AS, rng)
    res = fit(az, zd, m1, m2, mount="AZ-ZD", terms=("IA", "IE", "CA", "NPAE", "AN", "AW", "TF"),
              fixed={"TF": ALTAZ_TRUE["TF"], "TX": ALTAZ_TRUE["TX"]})
    assert "TF" not in res.fitted and "TX" not in res.fitted and len(res.fitted) == 6
    assert res.model.get("TF") == ALTAZ_TRUE["TF"] and res.errors["TF"] == 0.0
    assert abs(res.model.get("IA") - ALTAZ_TRUE["IA"]) < 4 * res.errors["IA"]
    assert "(fixed)" in res.report()
    # Holding a term at a wrong value shows up in the residuals.
    bad = fit(az, zd, m1, m2, mount="AZ-ZD", fixed={"TF": 0.0, "TX": ALTAZ_TRUE["TX"]})
    assert bad.rms > 3 * res.rms


def test_fit_refuses_what_it_cannot_determine():
    rng = np.random.default_rng(14)
    az = rng.uniform(0, 360, 30)
    zd = np.full(30, 40.0)       # one elevation: IA, CA and NPAE are the same function
    m1, m2 = PointingModel("AZ-ZD", ALTAZ_TRUE).apply(az, zd)
    with pytest.raises(TcsError, match="cannot separate terms") as e:
        fit(az, zd, m1, m2, mount="AZ-ZD")
    # … and so are IE, TF and TX; AN and AW are not involved.
    named = e.value.message.split("terms ")[1].split(";")[0].split(", ")
    assert sorted(named) == sorted(["IA", "CA", "NPAE", "IE", "TF", "TX"])
    ok = fit(az, zd, m1, m2, mount="AZ-ZD", fixed={"CA": 0.0, "NPAE": 0.0, "TF": 0.0, "TX": 0.0})
    assert ok.model.get("IA") != 0.0
    assert e.value.reply == "FAILED 1013"  # a computation that cannot run, not a refused value
    with pytest.raises(TcsError, match="too few") as e:
        fit(az[:3], zd[:3], m1[:3], m2[:3], mount="AZ-ZD")
    assert e.value.reply == "FAILED 1013"
    with pytest.raises(TcsError, match="no samples"):
        fit_samples([], mount="AZ-ZD")
    with pytest.raises(RequestRefused, match="'ME' is not one of AZ-ZD"):
        fit(az, zd, m1, m2, mount="AZ-ZD", terms=("IA", "ME"))


# -- orientation ---------------------------------------------------------------------------

def test_reverse_and_normal_are_inverse():
    rng = np.random.default_rng(15)
    az, zd = rng.uniform(0, 360, 100), rng.uniform(0.01, 90, 100)
    r = to_reverse(az, zd, "AZ-ZD")
    assert np.all(r[1] < 0)
    n1, n2, rev = to_normal(r[0] + 720.0, r[1], "AZ-ZD")
    assert rev.all() and np.allclose(n1, az) and np.allclose(n2, zd)
    ha, dec = rng.uniform(-180, 180, 100), rng.uniform(-89, 89, 100)
    r = to_reverse(ha, dec, "RA-DEC")
    n1, n2, rev = to_normal(r[0] - 360.0, r[1], "RA-DEC")
    assert rev.all() and np.allclose((n1 - ha + 180) % 360 - 180, 0) and np.allclose(n2, dec)
    assert to_normal(10.0, 20.0, "RA-DEC") == (10.0, 20.0, False)


def test_mount_path_is_continuous_across_north():
    az = np.array([350.0, 355.0, 0.0, 5.0, 10.0])
    p1, p2 = mount_path(az, np.full(5, 30.0), near=-10.0)
    assert np.allclose(p1, [-10, -5, 0, 5, 10])
    p1, p2 = mount_path(az, np.full(5, 30.0), reverse=True, near=170.0)
    assert np.allclose(p1, [170, 175, 180, 185, 190]) and np.all(p2 == -30.0)


AZ_RANGE = AxisRange(-270.0, 270.0)
ZD_BOTH = AxisRange(-90.0, 90.0)


def test_choose_path_modes():
    path_az, path_zd = np.linspace(10.0, 20.0, 30), np.linspace(40.0, 35.0, 30)
    # Mode 1: normal orientation, on the turn nearest the current azimuth.
    near = choose_path(path_az + 90.0, path_zd, mode=1, axis1_range=AZ_RANGE,
                       axis2_range=ZD_BOTH, current=(-200.0, 30.0))
    assert not near.reverse and near.track_mode == 1 and near.in_limits == 30
    assert near.axis1[0] == pytest.approx(-260.0) and near.slew_time == pytest.approx(60.0)
    far = choose_path(path_az + 90.0, path_zd, mode=1, axis1_range=AZ_RANGE,
                      axis2_range=ZD_BOTH, current=(200.0, 30.0))
    assert far.axis1[0] == pytest.approx(100.0)
    # Mode 4: reversing is the shorter slew from azimuth 180.
    p = choose_path(path_az, path_zd, mode=4, axis1_range=AZ_RANGE, axis2_range=ZD_BOTH,
                    current=(180.0, 30.0))
    assert p.reverse and p.track_mode == 3 and p.axis1[0] == pytest.approx(190.0)
    assert p.axis2[0] == pytest.approx(-40.0) and p.slew_time == pytest.approx(70.0)
    # Mode 3: reverse demanded.
    p = choose_path(path_az, path_zd, mode=3, axis1_range=AZ_RANGE, axis2_range=ZD_BOTH)
    assert p.reverse and np.all(p.axis2 < 0)
    # Mode 2: normal unless the normal orientation runs into a limit.
    narrow = AxisRange(0.0, 300.0)
    p = choose_path(path_az, path_zd, mode=2, axis1_range=narrow, axis2_range=ZD_BOTH,
                    current=(180.0, 30.0))
    assert not p.reverse
    runaway = np.linspace(280.0, 320.0, 30)        # leaves 0…300 after half the horizon
    p1 = choose_path(runaway, path_zd, mode=1, axis1_range=narrow, axis2_range=ZD_BOTH)
    assert not p1.reverse and 0 < p1.in_limits < 30
    p2 = choose_path(runaway, path_zd, mode=2, axis1_range=narrow, axis2_range=ZD_BOTH)
    assert p2.reverse and p2.in_limits == 30 and p2.axis1[0] == pytest.approx(100.0)


def test_choose_path_refusals():
    with pytest.raises(TcsError) as e:
        choose_path([10.0], [40.0], mode=1, axis1_range=AxisRange(100.0, 200.0),
                    axis2_range=AxisRange(0.0, 90.0))
    assert e.value.number == ErrorNumber.SOFTLIMIT
    with pytest.raises(TcsError) as e:       # reverse needs negative ZD, not allowed here
        choose_path([150.0], [40.0], mode=3, axis1_range=AZ_RANGE, axis2_range=AxisRange(0.0, 90.0))
    assert e.value.number == ErrorNumber.SOFTLIMIT
    with pytest.raises(RequestRefused, match="track mode 7"):
        choose_path([1.0], [1.0], mode=7, axis1_range=AZ_RANGE, axis2_range=ZD_BOTH)
    with pytest.raises(RequestRefused, match="empty"):
        AxisRange(5.0, 5.0)


# -- dump files ----------------------------------------------------------------------------

HEADER = DumpHeader("AZ-ZD", Site(52.38, 13.06, 40.0), TimeBase(37.0, -0.17),
                    Refraction(2, 7.5, 990.0))


def _samples(n):
    rng = np.random.default_rng(16)
    return [Sample(1.7e9 + 61.3 * i, *rng.uniform(0, 1, 8) * [24, 90, 360, 90, 360, 90, 0.1, 0.1])
            for i in range(n)]


def test_dump_round_trip_exact(tmp_path):
    path = tmp_path / "night.dump"
    write_dump_header(path, HEADER)
    samples = _samples(12)
    for s in samples:
        append_sample(path, s)
    header, back = load_dump(path)
    assert header == HEADER and back == samples


def test_dump_torn_last_line_ignored_but_damage_reported(tmp_path):
    path = tmp_path / "night.dump"
    write_dump_header(path, HEADER)
    for s in _samples(3):
        append_sample(path, s)
    with open(path, "a") as f:
        f.write("1700000000.0 5.1 20.")          # a write cut short by a crash
    _h, back = load_dump(path)
    assert len(back) == 3
    lines = path.read_text().splitlines()
    lines.insert(8, "1 2 3")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(TcsError, match=r"night.dump, line 9: expected 9 numbers"):
        load_dump(path)
    (tmp_path / "nohead.dump").write_text("1 2 3 4 5 6 7 8 9\n")
    with pytest.raises(TcsError, match="format"):
        load_dump(tmp_path / "nohead.dump")
    with pytest.raises(TcsError, match="cannot read"):
        load_dump(tmp_path / "missing.dump")


# -- saved models --------------------------------------------------------------------------

def test_model_store_list_load_save_erase(tmp_path):
    store = ModelStore(tmp_path / "models")
    assert store.list() == []
    a = PointingModel("AZ-ZD", ALTAZ_TRUE)
    b = PointingModel("RA-DEC", EQ_TRUE, latitude=-24.6)
    store.save("winter-2024", a, errors={"IA": 0.5 * AS}, report="fit of 80 samples\nrms 1.2\"")
    store.save("eq.test_1", b)
    assert store.list() == ["eq.test_1", "winter-2024"]
    assert store.load("winter-2024") == a and store.load("eq.test_1") == b
    store.save("winter-2024", b)                     # replace
    assert store.load("winter-2024") == b
    store.erase("eq.test_1")
    assert store.list() == ["winter-2024"]
    for bad in ("", ".hidden", "a/b", "x" * 65, "sp ace", "../up"):
        with pytest.raises(RequestRefused, match="pointing model name"):
            store.save(bad, a)
    with pytest.raises(RequestRefused, match="no saved pointing model named 'nope'"):
        store.load("nope")
    with pytest.raises(RequestRefused, match="no saved pointing model"):
        store.erase("nope")


def test_damaged_model_file_is_reported(tmp_path):
    store = ModelStore(tmp_path)
    store.save("good", PointingModel("AZ-ZD", ALTAZ_TRUE))
    text = (tmp_path / "good.model").read_text()
    (tmp_path / "cut.model").write_text(text[: text.index("end")])
    with pytest.raises(TcsError, match="cut.model: damaged"):
        store.load("cut")
    (tmp_path / "junk.model").write_text(text.replace("term IA", "term IA x"))
    with pytest.raises(TcsError, match=r"junk.model, line \d+"):
        store.load("junk")


def test_leftover_temporary_file_is_ignored(tmp_path):
    store = ModelStore(tmp_path)
    old = PointingModel("AZ-ZD", {"IA": 0.01})
    store.save("main", old)
    # What a save killed before its rename leaves behind: a partial temporary file.
    (tmp_path / ".main.model.k3j2h1.tmp").write_text("format tcs-pointing-model 1\nmount AZ")
    assert store.list() == ["main"]
    assert store.load("main") == old


_SAVER = r"""
import sys
from tcs.pointing.model import PointingModel
from tcs.pointing.storage import ModelStore
store = ModelStore(sys.argv[1])
report = "x" * 1_000_000                     # a large report makes each write take a while
models = [PointingModel("AZ-ZD", {"IA": 0.001 * k, "IE": -0.001 * k}) for k in (1, 2)]
store.save("m", models[0], report=report)
print("ready", flush=True)
k = 0
while True:
    k ^= 1
    store.save("m", models[k], report=report)
"""


def test_save_survives_kill(tmp_path):
    """Another process saves the same model over and over: readers always find a whole model,
    and so does everyone after it is killed (SIGKILL) in the middle of its work."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.getcwd(), os.environ.get("PYTHONPATH", "")]))
    valid = {PointingModel("AZ-ZD", {"IA": 0.001 * k, "IE": -0.001 * k}) for k in (1, 2)}
    store = ModelStore(tmp_path)
    for attempt in range(2):
        proc = subprocess.Popen([sys.executable, "-c", _SAVER, str(tmp_path)],
                                stdout=subprocess.PIPE, text=True, env=env)
        seen = set()
        try:
            assert proc.stdout.readline().strip() == "ready"
            deadline = time.monotonic() + 0.4 + 0.2 * attempt
            while time.monotonic() < deadline:
                seen.add(store.load("m"))        # never a torn or mixed file
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=30)
            proc.stdout.close()
        assert proc.returncode == -signal.SIGKILL
        assert seen <= valid
        assert store.list() == ["m"]
        assert store.load("m") in valid


def test_unfinished_saves_do_not_survive_a_restart(tmp_path):
    """A kill during SAVE leaves ``.<name>.model.<random>.tmp``; the next start (a new
    ModelStore on the directory) removes it once it is older than a save can take, and leaves
    saved models and a save in progress alone."""
    import os
    import time

    from tcs.pointing.model import PointingModel
    from tcs.pointing.storage import ORPHAN_AGE, ModelStore

    store = ModelStore(tmp_path)
    store.save("night1", PointingModel())
    orphan = tmp_path / ".night1.model.abc123.tmp"
    orphan.write_text("ia 1.0\n")                      # a save killed half-way
    old = time.time() - 10 * ORPHAN_AGE
    os.utime(orphan, (old, old))
    busy = tmp_path / ".night2.model.def456.tmp"
    busy.write_text("ia 2.0\n")                        # another process saving right now
    ModelStore(tmp_path)                               # the service starts again
    assert not orphan.exists()
    assert busy.exists()
    assert ModelStore(tmp_path).list() == ["night1"]
