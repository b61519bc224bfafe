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
from ruckig import ControlInterface, InputParameter, Ruckig, Trajectory

from tcs.axes.limits import SoftLimits
from tcs.axes.motion import MotionPlanner
from tcs.axes.profile import AxisDynamics, Setpoint
from tcs.config.envelope import EnvelopeSection, KeepOutSection
from tcs.errors import ErrorNumber
from tcs.pointing.astrometry import Astrometry, Refraction, Site, TimeBase
from tcs.pointing.envelope import Envelope, EnvelopeError, offset_path, pair_bound, plan_route, sun_icrs
from tcs.pointing.model import PointingModel

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


# ------------------------------------------- issue 39: the path the axes really take (randomized)

def ruckig_move(x0, x1, dyn, speed=None):
    """One axis from rest at ``x0`` to rest at ``x1``: ruckig's Trajectory."""
    inp = InputParameter(1)
    inp.current_position, inp.target_position = [x0], [x1]
    inp.max_velocity = [speed or dyn.max_velocity]
    inp.max_acceleration, inp.max_jerk = [dyn.max_acceleration], [dyn.max_jerk]
    traj = Trajectory(1)
    Ruckig(1, 0.01).calculate(inp, traj)
    return traj


def one_axis(x0, x1, dyn, speed=None):
    """One axis from rest at ``x0`` to rest at ``x1`` with ruckig itself: a function of time
    from the start (held at the ends) and the duration."""
    traj = ruckig_move(x0, x1, dyn, speed)
    grid = np.linspace(0.0, traj.duration, max(2, int(traj.duration / 0.01) + 1))
    pos = np.array([traj.at_time(x)[0][0] for x in grid])
    return (lambda t: np.interp(t, grid, pos)), traj.duration


def braking(traj, t, dyn):
    """The axis on ``traj`` braking from ``t`` (s from its start) with its normal deceleration:
    a function of the time from ``t`` (held at rest after)."""
    p, v, a = (x[0] for x in traj.at_time(min(t, traj.duration)))
    if t >= traj.duration:
        return lambda s: np.full(np.shape(s), p)
    inp = InputParameter(1)
    inp.control_interface = ControlInterface.Velocity
    inp.current_position, inp.current_velocity, inp.current_acceleration = [p], [v], [a]
    inp.target_velocity, inp.target_acceleration = [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration = [dyn.max_velocity], [dyn.max_acceleration]
    inp.max_jerk = [dyn.max_jerk]
    stop = Trajectory(1)
    Ruckig(1, 0.01).calculate(inp, stop)
    return lambda s: np.array([stop.at_time(min(max(float(x), 0.0), stop.duration))[0][0]
                               for x in np.atleast_1d(s)])


def daytime(rng):
    t = rng.uniform(T2020, T2040)
    return math.floor(t / 86400.0) * 86400.0 + 13.2 * 3600.0 + rng.uniform(-3.0, 3.0) * 3600.0


def random_model(rng) -> PointingModel:
    """Operator-level terms: IA and IE up to ±9° (writable up to ±10°, syncs add to them),
    the others of a badly aligned mount (NPAE/CA 3′, AN/AW 6′, TF 12′)."""
    terms = {"IA": rng.uniform(-9.0, 9.0), "IE": rng.uniform(-9.0, 9.0)}
    for name, size in (("NPAE", 0.05), ("CA", 0.05), ("AN", 0.1), ("AW", 0.1), ("TF", 0.2)):
        terms[name] = rng.uniform(-size, size)
    return PointingModel("AZ-ZD", terms, SITE.latitude)


def violations_model(model, a1, a2, utc):
    """:func:`violations` of the bare axis angles or of the sky the model says (either)."""
    a1, a2 = np.asarray(a1, float), np.asarray(a2, float)
    sun, low, keep = violations(a1, a2, utc)
    i1, i2 = a1.copy(), a2.copy()
    far = np.abs(a2 - model.corrections(a1, a2)[1]) >= 3.0   # (within 3° of the mount's pole
    # the fixed-point inverse may not converge; the azimuth means little there: first order)
    if far.any():
        i1[far], i2[far] = model.invert(a1[far], a2[far])
    if (~far).any():
        d1, d2 = model.corrections(a1[~far], a2[~far])
        i1[~far], i2[~far] = a1[~far] - d1, a2[~far] - d2
    sun_m, low_m, _keep = violations(i1, i2, utc)
    return sun | sun_m, low | low_m, keep


def test_random_slews_with_a_pointing_model_stay_out_in_both_readings():
    """Seeded: 150 slews around the Sun, each with a random pointing model of operator size
    (IA/IE up to 9°): every planned route, re-simulated, is outside the Sun cone and above the
    horizon both as the axis angles say and as the model says (the sky through its inverse)."""
    rng = np.random.default_rng(39007)
    counts = {"done": 0, "refused": 0}
    for _ in range(150):
        model = random_model(rng)
        env = envelope()
        env._model = lambda m=model: m
        t = daytime(rng)
        start = random_place(rng, t, True)
        for _try in range(20):   # a start clear in both readings (a path may leave one that is not)
            if not any(v[0] for v in violations_model(model, np.array([start[0]]), np.array([start[1]]),
                                                      np.array([t]))):
                break
            start = random_place(rng, t, True)
        else:
            continue
        end = random_place(rng, t, True)
        try:
            route = plan_route(env, t, (Setpoint(start[0]), Setpoint(start[1])), end, (AZ, ZD), RANGES)
        except EnvelopeError as exc:
            assert exc.number == ErrorNumber.SOFTLIMIT
            counts["refused"] += 1
            continue
        counts["done"] += 1
        here, when = start, t
        for goal in route.waypoints + (route.end,):
            times, a1, a2, duration = resimulate(here, goal, when)
            sun, low, keep = violations_model(model, a1, a2, times)
            assert not sun.any() and not low.any() and not keep.any(), (model, route)
            here, when = goal, when + duration
    assert min(counts.values()) > 15, counts


def test_random_targetpos_is_judged_on_the_turn_the_planner_drives():
    """Seeded: 300 engineering AZ.TARGETPOS at the Sun's zenith distance from random azimuths
    of the ±270° wrap to random written targets. The envelope judges the turn
    ``MotionPlanner.resolve_target`` gives (what the axis does); when it accepts, the real
    planner, stepped from the start with the written value, drives exactly there and never
    comes within the cone; written-as-is judgements that would have passed a driven path
    through the cone occur (the bug of issue 39 item 3)."""
    rng = np.random.default_rng(39003)
    env = envelope(horizon=(), keepout=())
    counts = {"accepted": 0, "refused": 0, "turn would have lied": 0}
    for i in range(300):
        t = daytime(rng)
        saz, salt = sun_altaz(np.array([t]))
        zd = float(np.clip(90.0 - salt[0] + rng.uniform(-15.0, 15.0), 0.0, 74.0))
        start = rng.uniform(-270.0, 270.0)
        written = rng.uniform(-270.0, 270.0)
        if i % 2:   # the short way through the Sun's azimuth, written on the other turn
            side = rng.choice([-1.0, 1.0])
            sun1 = float(saz[0]) + 360.0 * rng.integers(-1, 1)
            start, short = sun1 + side * rng.uniform(65.0, 90.0), sun1 - side * rng.uniform(65.0, 90.0)
            written = short + 360.0 if short + 360.0 <= 270.0 else short - 360.0
            if not (-270.0 <= start <= 270.0 and -270.0 <= short <= 270.0 and -270.0 <= written <= 270.0):
                continue
        if violations(np.array([start]), np.array([zd]), np.array([t]))[0][0]:
            continue
        planner = MotionPlanner(AZ, SoftLimits(-270.0, 270.0, 360.0), 0.05, position=start)
        resolved = planner.resolve_target(written, 0.0, start)
        starts = (Setpoint(start), Setpoint(zd))
        j = env.check_move(t, starts, (resolved, zd), (AZ, ZD), margin=0.0, horizon=False)
        as_written = env.check_move(t, starts, (written, zd), (AZ, ZD), margin=0.0, horizon=False)
        if not j.ok:
            counts["refused"] += 1
            counts["turn would have lied"] += as_written.ok
            continue
        counts["accepted"] += 1
        planner.set_target(written)
        path = [start]
        while planner.moving:
            path.append(planner.step().position)
        assert path[-1] == pytest.approx(resolved, abs=1e-9)
        a1 = np.array(path)
        sun, _low, _keep = violations(a1, np.full(a1.shape, zd), t + 0.05 * np.arange(a1.size))
        assert not sun.any(), (start, written, resolved)
    assert min(counts.values()) > 10, counts


def test_random_moveaxis_pairs_never_enter_the_envelope():
    """Seeded: 120 pairs of MoveAxis near the Sun: one axis moves (a path clear on its own),
    the other starts a move of its own; :func:`pair_bound` bounds the second on the pair's
    simultaneous path. Re-simulated with ruckig — the second starting on time or 0.1 s late —
    the two axes together never enter the cone, go below the horizon table or into the
    keep-out; bounded and free second moves both occur. And both axes braking from random
    points of the pair's path (a client stops one, the other is bounded again; a stall; a lost
    link), either one up to 0.25 s after the other, stay out too."""
    rng = np.random.default_rng(39004)
    env = envelope()
    which = dict(horizon=True, sun=True, keepouts=True)
    counts = {"free": 0, "bounded": 0, "refused": 0, "braked": 0}
    dyn = (AZ, ZD)
    for _ in range(120):
        t = daytime(rng)
        start = random_place(rng, t, True)
        a = int(rng.integers(2))          # the axis that moves first
        b = 1 - a
        goal_a = float(np.clip(start[a] + rng.choice([-1.0, 1.0]) * rng.uniform(10.0, 70.0), *RANGES[a]))
        speed_a = rng.uniform(0.3, 1.0) * dyn[a].max_velocity
        path_a, dur_a = one_axis(start[a], goal_a, dyn[a], speed_a)
        grid = t + np.linspace(0.0, dur_a, max(2, int(dur_a * 20)))
        alone = (path_a(grid - t), np.full(grid.shape, start[b]))[:: 1 if a == 0 else -1]
        if any(v.any() for v in violations(*alone, grid)):
            continue                      # (the first move's own bound would have cut it)
        direction = int(rng.choice([-1, 1]))
        end_b = float(np.clip(start[b] + direction * rng.uniform(15.0, 60.0), *RANGES[b]))
        speed_b = rng.uniform(0.3, 1.0) * dyn[b].max_velocity
        try:
            g = pair_bound(env, t, Setpoint(start[b]), dyn[b], direction, end_b, speed_b,
                           lambda x: path_a(np.asarray(x) - t), t + dur_a, b == 0, which,
                           other_dyn=dyn[a])
        except EnvelopeError:
            counts["refused"] += 1
            continue
        counts["free" if g is None else "bounded"] += 1
        goal_b = end_b if g is None else g
        path_b, dur_b = one_axis(start[b], goal_b, dyn[b], speed_b)
        for late in (0.0, 0.1):
            times = np.arange(0.0, max(dur_a, dur_b + late) + 0.02, 0.02)
            pa, pb = path_a(times), path_b(times - late)
            a1, a2 = (pa, pb) if a == 0 else (pb, pa)
            sun, low, keep = violations(a1, a2, t + times)
            assert not (sun.any() or low.any() or keep.any()), (start, a, goal_a, goal_b, late)
        traj_a = ruckig_move(start[a], goal_a, dyn[a], speed_a)
        traj_b = ruckig_move(start[b], goal_b, dyn[b], speed_b)
        for _brake in range(6):
            when = rng.uniform(0.0, max(dur_a, traj_b.duration))
            late = rng.uniform(0.0, 0.25)
            d_a, d_b = (late, 0.0) if rng.random() < 0.5 else (0.0, late)
            stop_a, stop_b = braking(traj_a, when + d_a, dyn[a]), braking(traj_b, when + d_b, dyn[b])
            s = np.arange(0.0, late + 4.0, 0.02)
            pa = np.where(s < d_a, path_a(when + s), stop_a(s - d_a))
            pb_path = np.array([traj_b.at_time(min(when + x, traj_b.duration))[0][0] for x in s])
            pb = np.where(s < d_b, pb_path, stop_b(s - d_b))
            a1, a2 = (pa, pb) if a == 0 else (pb, pa)
            sun, low, keep = violations(a1, a2, t + when + s)
            counts["braked"] += 1
            assert not (sun.any() or low.any() or keep.any()), (start, a, goal_a, goal_b, when, d_a, d_b)
    assert counts["free"] > 10 and counts["bounded"] > 10, counts


def test_random_offsets_while_tracking_are_judged_on_their_path():
    """Seeded: 300 OFFSETs of up to ±40° on one axis of a sidereal target tracked for 10 min
    (half of them by day): when the envelope accepts the offset path (:func:`offset_path`,
    the change as a rest-to-rest profile on the tracked path), the path re-simulated with
    ruckig every 0.1 s stays outside every border; accepted and refused offsets both occur."""
    rng = np.random.default_rng(39005)
    env = envelope()
    counts = {"accepted": 0, "refused": 0}
    for i in range(300):
        t0 = daytime(rng) if i % 2 else rng.uniform(T2020, T2040)
        ra, dec = rng.uniform(0.0, 24.0), math.degrees(math.asin(rng.uniform(-1.0, 1.0)))
        grid = t0 + np.arange(0.0, 600.0 + 1.0, 5.0)
        obs = ASTRO.observed(ra, dec, grid)
        track = [np.unwrap(np.asarray(obs.az), period=360.0), np.asarray(obs.zd)]
        if any(v.any() for v in violations(*track, grid)):
            continue
        axis = int(rng.integers(2))
        offset = rng.uniform(-40.0, 40.0)
        dyn = (AZ, ZD)[axis]
        times, own = offset_path(lambda x: np.interp(x, grid, track[axis]), t0, grid[-1], 0.0,
                                 offset, dyn)
        other = np.interp(times, grid, track[1 - axis])
        j = env.judge(*((own, other) if axis == 0 else (other, own)), times, margin=0.0,
                      horizon=True, sun=True, keepouts=True)
        if not j.ok:
            counts["refused"] += 1
            continue
        counts["accepted"] += 1
        blend, _d = one_axis(0.0, offset, dyn)
        fine = np.arange(0.0, 600.0, 0.1)
        mine = np.interp(t0 + fine, grid, track[axis]) + blend(fine)
        rest = np.interp(t0 + fine, grid, track[1 - axis])
        sun, low, keep = violations(*((mine, rest) if axis == 0 else (rest, mine)), t0 + fine)
        assert not (sun.any() or low.any() or keep.any()), (ra, dec, t0, axis, offset)
    assert min(counts.values()) > 10, counts
