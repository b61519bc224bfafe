"""Trajectories (tcs.axes.trajectory, tcs.axes.follower): the point queue, its interpolation,
and the follower run cycle by cycle against analytic paths.

Times are UT1 seconds near 1.7e9 (as clients send them), so float resolution is part of
what is tested. Errors are measured in arcseconds on degree axes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from tcs.axes import (
    AxisDynamics,
    FollowerState,
    LimitGuard,
    Setpoint,
    SoftLimits,
    TrajectoryBufferFull,
    TrajectoryFollower,
    TrajectoryQueue,
)
from tcs.axes.profile import ProfileSolver
from tcs.errors import ErrorNumber as E
from tcs.errors import RequestRefused, TcsError

T0 = 1_700_000_000.0
DT = 0.01
ARCSEC = 1.0 / 3600.0
AZ = AxisDynamics(5.0, 2.0, 5.0)
SIDEREAL = 15.041 * ARCSEC          # deg/s


def sinusoid(amplitude=2.0, period=60.0):
    w = 2 * math.pi / period
    return (lambda x: amplitude * np.sin(w * x),
            lambda x: amplitude * w * np.cos(w * x))


def sidereal(x):
    """A sidereal-rate ramp with the slow curvature of a real track."""
    return 120.0 + SIDEREAL * x + 2e-7 * x ** 2 - 1e-10 * x ** 3


def queue_of(f, duration=300.0, spacing=2.0, start=0.0, capacity=1000, cycle=None):
    q = TrajectoryQueue(capacity, cycle=cycle)
    x = np.arange(start, start + duration + spacing / 2, spacing)
    q.add_points(T0 + x, f(x))
    return q


def run(follower: TrajectoryFollower, current: Setpoint, t_from=T0, max_s=2000.0,
        on_step=None):
    """Step the follower (started here if idle) until it ends; returns
    [(t, setpoint, events, state)]."""
    if follower.state is FollowerState.IDLE:
        follower.start(t_from, current)
    out = []
    k = 0
    while follower.state is not FollowerState.ENDED:
        k += 1
        t = t_from + k * DT
        if on_step:
            on_step(k, follower)
        step = follower.step(t, current)
        current = step.setpoint
        out.append((t, current, step.events, follower.state))
        assert k * DT < max_s, "follower did not end"
    return out


def check_stream(out, dyn, start: Setpoint, limits: SoftLimits | None = None):
    prev = start
    for _, sp, _, _ in out:
        assert abs(sp.velocity) <= dyn.max_velocity * (1 + 1e-6), sp
        assert abs(sp.acceleration) <= dyn.max_acceleration * (1 + 1e-6), sp
        # the jerk of the stream: the acceleration change over the cycle. UT1 floats near 1.7e9 s
        # resolve 2.4e-7 s, so a "10 ms" step is 10 ms +- 2.4e-5 relative: that much slack
        assert abs(sp.acceleration - prev.acceleration) / DT <= dyn.max_jerk * (1 + 1e-4), (prev, sp)
        # continuity: no position step larger than the velocity allows
        assert abs(sp.position - prev.position) <= dyn.max_velocity * DT * 1.001
        if limits is not None:
            assert limits.contains(sp.position), sp
        prev = sp


def events_of(out):
    return [(round(t - T0, 2), e) for t, _, evs, _ in out for e in evs]


# -- the queue ----------------------------------------------------------------------------------

def test_add_points_and_sizes():
    q = TrajectoryQueue(10)
    assert q.free_points == 10 and q.start_time is None and q.remaining(T0) == 0.0
    r = q.add_points([T0, T0 + 2], [1.0, 2.0])
    assert r.accepted == 2 and r.dropped == 0
    assert len(q) == 2 and q.free_points == 8 and q.start_time == T0 and q.end_time == T0 + 2
    assert q.remaining(T0 + 0.5) == pytest.approx(1.5)


@pytest.mark.parametrize("times, message", [
    ([T0 + 4, T0 + 4], "point 1: time"),
    ([T0 + 4, T0 + 3], "point 1: time"),
    ([T0 + 2], "point 0: time .* not after the last queued point"),
    ([T0 + 1], "point 0"),
])
def test_non_increasing_times_are_refused_and_nothing_is_added(times, message):
    q = TrajectoryQueue(10)
    q.add_points([T0, T0 + 2], [0.0, 1.0])
    with pytest.raises(RequestRefused, match=message):
        q.add_points(times, [5.0] * len(times))
    assert len(q) == 2 and q.end_time == T0 + 2


def test_bad_batches_are_refused():
    q = TrajectoryQueue(10)
    with pytest.raises(RequestRefused, match="2 times but 1 positions"):
        q.add_points([T0, T0 + 1], [0.0])
    with pytest.raises(RequestRefused, match="not a finite number"):
        q.add_points([T0, T0 + 1], [0.0, float("nan")])
    assert len(q) == 0


def test_overflow_is_nobuffer_and_atomic():
    q = TrajectoryQueue(5)
    q.add_points([T0 + i for i in range(4)], [0.0] * 4)
    with pytest.raises(TrajectoryBufferFull) as info:
        q.add_points([T0 + 10, T0 + 11], [0.0, 0.0])
    assert info.value.number == E.NOBUFFER == 12 and info.value.reply == "FAILED 12"
    assert "1 free" in info.value.message
    assert len(q) == 4
    q.add_points([T0 + 10], [0.0])
    assert q.free_points == 0


def test_points_in_the_past_are_dropped_and_counted():
    q = TrajectoryQueue(5)
    # 10 points, 6 of them wholly in the past: the last one before "now" stays as the segment
    # start, so 5 remain and the batch fits although it is longer than the capacity
    r = q.add_points([T0 + i for i in range(10)], [float(i) for i in range(10)], now=T0 + 5.5)
    assert r == (10, 5)
    assert q.start_time == T0 + 5 and len(q) == 5
    assert q.sample(T0 + 5.5)[0] == pytest.approx(5.5)
    assert q.drop_before(T0 + 7.2) == 2 and q.start_time == T0 + 7
    # everything in the past: nothing stays
    assert q.drop_before(T0 + 100) == 3 and len(q) == 0


def test_empty_queue_sample_is_nopoints():
    with pytest.raises(TcsError) as info:
        TrajectoryQueue(4).sample(T0)
    assert info.value.number == E.NOPOINTS


def test_interpolation_error_on_a_fast_sinusoid():
    f, fv = sinusoid(2.0, 60.0)                 # 0.21 deg/s, points every 2 s
    q = queue_of(f, duration=120.0)
    x = np.linspace(0.0, 120.0, 6001)
    p = np.array([q.sample(T0 + xi) for xi in x])
    err = np.abs(p[:, 0] - f(x)) / ARCSEC
    interior = (x > 6) & (x < 114)
    assert err[interior].max() < 0.02           # arcsec (measured 0.014)
    assert err.max() < 0.15                     # one-sided stencils at both ends
    verr = np.abs(p[:, 1] - fv(x)) / ARCSEC
    assert verr[interior].max() < 0.1           # arcsec/s


def test_interpolation_error_on_a_sidereal_path():
    q = queue_of(sidereal, duration=3600.0, spacing=2.0, capacity=2000)
    x = np.linspace(0.0, 3600.0, 20001)
    err = np.abs(np.array([q.sample(T0 + xi)[0] for xi in x]) - sidereal(x)) / ARCSEC
    # a float UT1 near 1.7e9 s resolves 2.4e-7 s: 3.6e-6 arcsec at the sidereal rate
    assert err.max() < 1e-5


def test_interpolation_is_c2_at_the_knots():
    f, _ = sinusoid(5.0, 40.0)
    q = TrajectoryQueue(100)
    x = np.array([0.0, 1.0, 3.0, 3.5, 6.0, 8.0, 9.0, 12.0])      # uneven spacing
    q.add_points(T0 + x, f(x))
    for knot in x[1:-1]:
        before = q.sample(T0 + knot - 1e-6)
        after = q.sample(T0 + knot + 1e-6)
        assert after[0] == pytest.approx(before[0], abs=1e-5)
        assert after[1] == pytest.approx(before[1], abs=1e-5)
        assert after[2] == pytest.approx(before[2], abs=1e-4)
    assert q.sample(T0 + 3.0)[0] == pytest.approx(f(3.0), abs=1e-12)   # through the points


def test_appending_points_never_moves_a_followed_segment():
    f, _ = sinusoid(2.0, 30.0)
    x = np.arange(0.0, 40.0, 2.0)
    q = TrajectoryQueue(100)
    q.add_points(T0 + x[:4], f(x[:4]))
    seen = q.sample(T0 + 4.3, freeze=True)       # a segment whose knots are not final yet
    q.add_points(T0 + x[4:], f(x[4:]))
    assert q.sample(T0 + 4.3) == seen
    # a segment not followed yet is improved by the new points
    full = queue_of(f, duration=38.0)
    assert q.sample(T0 + 20.3) == full.sample(T0 + 20.3)


def test_batches_or_one_by_one_give_the_same_path():
    f, _ = sinusoid(1.0, 50.0)
    x = np.arange(0.0, 60.0, 2.0)
    whole = TrajectoryQueue(100)
    whole.add_points(T0 + x, f(x))
    single = TrajectoryQueue(100)
    for xi in x:
        single.add_points([T0 + xi], [f(xi)])
    for xi in np.linspace(0, 58, 300):
        assert single.sample(T0 + xi) == pytest.approx(whole.sample(T0 + xi), abs=1e-15)


def test_cyclic_points_are_unwrapped():
    q = TrajectoryQueue(10, cycle=360.0)
    q.add_points([T0, T0 + 1, T0 + 2], [359.0, 359.5, 0.0])
    q.add_points([T0 + 3], [0.5])
    assert q.positions()[1] == [359.0, 359.5, 360.0, 360.5]
    assert q.sample(T0 + 2.5)[0] == pytest.approx(360.25)


def test_usage_reports_the_path_dynamics():
    f, _ = sinusoid(2.0, 60.0)
    q = queue_of(f, duration=120.0, spacing=1.0)
    w = 2 * math.pi / 60
    v, a, j = q.usage(T0, T0 + 120)
    assert v == pytest.approx(2 * w, rel=1e-3)
    assert a == pytest.approx(2 * w * w, rel=1e-2)
    assert j == pytest.approx(2 * w ** 3, rel=0.05)



def test_usage_is_the_true_maximum_of_a_coarse_path():
    # a 5 s sine given at 2 s spacing: the spline's extremes fall between samples; 9 samples
    # a segment missed 2.3 % of the acceleration, more than the follower's 2 % margin
    w = 2 * math.pi / 5.0
    q = queue_of(lambda x: 0.5 * np.sin(w * x), duration=30.0, spacing=2.0)
    t0, t1 = T0 + 2.0, T0 + 8.0
    dense = np.array([q.sample(t) for t in np.linspace(t0, t1, 60001)])
    v, a, _ = q.usage(t0, t1)
    assert v == pytest.approx(np.abs(dense[:, 1]).max(), rel=1e-6)
    assert a == pytest.approx(np.abs(dense[:, 2]).max(), rel=1e-6)


# -- the follower -------------------------------------------------------------------------------

def follower_for(q, limits=SoftLimits(), **kw):
    kw.setdefault("low_points_time", 30.0)
    return TrajectoryFollower(q, AZ, limits, DT, **kw)


def test_sidereal_track_from_elsewhere():
    q = queue_of(sidereal, duration=200.0)
    fo = follower_for(q)
    start = Setpoint(119.0)                    # one degree off the path, at rest
    assert fo.start(T0, start) == 0
    assert fo.state is FollowerState.INTERCEPTING and fo.running
    out = run(fo, start)
    check_stream(out, AZ, start)
    following = [(t, sp) for t, sp, _, s in out if s is FollowerState.FOLLOWING]
    t_on = following[0][0] - T0
    assert t_on < 3.0                          # a 1-degree slew: ~1.8 s
    err = np.array([sp.position - sidereal(t - T0) for t, sp in following]) / ARCSEC
    assert np.abs(err).max() < 1e-5            # arcsec: the path itself (UT1 float resolution)
    evs = events_of(out)
    assert [e for _, e in evs] == [E.TRAJ_LOOSE, E.TRAJ_GOOD, E.TRAJ_LOWPOINTS, E.TRAJ_STOP]
    assert dict((e, t) for t, e in evs)[E.TRAJ_LOWPOINTS] == pytest.approx(170.0, abs=0.02)
    assert dict((e, t) for t, e in evs)[E.TRAJ_STOP] == pytest.approx(200.0, abs=0.02)
    last = out[-1][1]
    assert last.velocity == 0.0 and last.acceleration == 0.0 and fo.end_reason == "end"
    assert not fo.running and fo.runtime(T0 + 300) == 0.0


def test_fast_sinusoid_following_error():
    f, _ = sinusoid(2.0, 60.0)
    q = queue_of(f, duration=300.0)
    fo = follower_for(q)
    out = run(fo, Setpoint(0.0))
    check_stream(out, AZ, Setpoint(0.0))
    err = np.array([sp.position - f(t - T0) for t, sp, _, s in out
                    if s is FollowerState.FOLLOWING]) / ARCSEC
    assert len(err) > 29000
    assert np.sqrt(np.mean(err ** 2)) < 0.02 and np.abs(err).max() < 0.15


def test_intercept_onto_a_fast_moving_path():
    q = queue_of(lambda x: -30.0 + 2.0 * x, duration=60.0)    # 2 deg/s, 30 deg away
    fo = follower_for(q)
    out = run(fo, Setpoint(0.0))
    check_stream(out, AZ, Setpoint(0.0))
    t_on = next(t for t, _, _, s in out if s is FollowerState.FOLLOWING) - T0
    # it has to overtake at up to 5 deg/s: between the pure pursuit bound and twice that
    assert 30.0 / 7.0 < t_on < 2 * (30.0 / 7.0 + 2.5)
    after = [(t, sp) for t, sp, _, s in out if s is FollowerState.FOLLOWING]
    assert max(abs(sp.position - (-30.0 + 2.0 * (t - T0))) for t, sp in after) < 1e-9
    assert not fo.limited


def test_offset_while_following_is_a_smooth_small_move():
    f, _ = sinusoid(2.0, 60.0)
    q = queue_of(f, duration=60.0)
    fo = follower_for(q)

    def on_step(k, follower):
        if k == 3000:
            follower.set_offset(0.01)

    out = run(fo, Setpoint(0.0), on_step=on_step)
    check_stream(out, AZ, Setpoint(0.0))
    after = [(t, sp, s) for t, sp, _, s in out if t - T0 > 30.0]
    # never further from the new reference than the offset itself, back on it within 0.6 s
    dev = [abs(sp.position - (f(t - T0) + 0.01)) for t, sp, s in after if t - T0 <= 60.0]
    assert max(dev) <= 0.01 + 1e-9
    back = next(t for t, sp, s in after if s is FollowerState.FOLLOWING) - T0
    assert back < 30.6
    assert E.TRAJ_LOOSE not in [e for t, e in events_of(out) if t > 29.0]


def test_path_across_a_limit_stops_exactly_at_the_limit():
    q = queue_of(lambda x: 10.0 + 2.0 * x, duration=100.0)
    limits = SoftLimits(-100.0, 100.0)
    fo = follower_for(q, limits)
    out = run(fo, Setpoint(10.0))
    check_stream(out, AZ, Setpoint(10.0), limits)
    assert out[-1][1] == Setpoint(100.0) or out[-1][1].position == pytest.approx(100.0)
    evs = events_of(out)
    assert (E.SOFTLIMIT in [e for _, e in evs]) and evs[-1][1] == E.TRAJ_STOP
    assert fo.end_reason == "softlimit" and fo.softlimit == "max"
    assert evs[-1][0] < 45.0                   # stopped before the path reached +100


def test_nopoints():
    fo = follower_for(TrajectoryQueue(10))
    with pytest.raises(TcsError) as info:
        fo.start(T0, Setpoint(0.0))
    assert info.value.number == E.NOPOINTS
    q = queue_of(lambda x: x * 0.0, duration=10.0)
    with pytest.raises(TcsError):
        follower_for(q).start(T0 + 11.0, Setpoint(0.0))     # all in the past


def test_start_drops_points_in_the_past():
    q = queue_of(sidereal, duration=100.0, spacing=2.0)
    fo = follower_for(q)
    assert fo.start(T0 + 10.5, Setpoint(120.0)) == 5
    assert q.start_time == T0 + 10.0


def test_abort_stops_smoothly_and_frees_the_queue():
    q = queue_of(lambda x: 2.0 * x, duration=100.0)
    fo = follower_for(q)
    fo.start(T0, Setpoint(0.0))
    cur = Setpoint(0.0)
    for k in range(1, 1001):
        cur = fo.step(T0 + k * DT, cur).setpoint
    assert fo.state is FollowerState.FOLLOWING and cur.velocity == pytest.approx(2.0)
    fo.abort()
    assert len(q) == 0
    out = run(fo, cur, t_from=T0 + 10.0)
    check_stream(out, AZ, cur)
    assert out[0][2] == (E.TRAJ_STOP,) and out[-1][1].velocity == 0.0
    assert fo.end_reason == "aborted"


@pytest.mark.parametrize("bridged", ["held", "extrapolated"])
@pytest.mark.parametrize("ending", ["at rest", "moving"])
def test_a_gap_across_the_paths_end_still_ends_where_the_path_does(bridged, ending):
    """A late cycle that steps past the path's end (the control loop stalled 0.4 s; the drive
    held its last setpoint or ran on at its speed, and the axis re-anchored on that demand)
    still brings the axis to rest where the path's own stop from its end lands — its last
    point when it ends at rest, settled on from either side — unless a path that ends moving
    was run past that by the drive: then it stops from there, never moving back (a reversal
    at the end of a 50°/s path broke the deceleration limit in test_motion_safety). Before,
    it stopped where the stale setpoint stood: 77″ off the end of this path that ends at rest
    (16″ in CI's live sinusoid test), 0.3° short of where the ramp's own stop lands."""
    if ending == "at rest":        # one period of a 2° sinusoid over 20 s, ending at rest
        f = lambda x: 2.0 * (1.0 - np.cos(2 * np.pi * np.clip(x, 0.0, 20.0) / 20.0))  # noqa: E731
    else:                          # a 1°/s ramp that ends at speed
        f = lambda x: 1.0 * x      # noqa: E731
    q = queue_of(f, duration=20.0, spacing=1.0)
    end_p, end_v, end_a = q.sample(q.end_time)
    own_stop = ProfileSolver(DT).stop(Setpoint(end_p, end_v, end_a), max_velocity=AZ.max_velocity,
                                      max_acceleration=AZ.max_acceleration,
                                      max_jerk=AZ.max_jerk, discrete=False)
    landing = own_stop.at_time(own_stop.duration)[0][0]
    fo = follower_for(q, low_points_time=1.0)
    cur = Setpoint(0.0)
    fo.start(T0, cur)
    k = 0
    while T0 + (k + 1) * DT <= q.end_time - 0.3:
        k += 1
        cur = fo.step(T0 + k * DT, cur).setpoint
    assert fo.state is FollowerState.FOLLOWING
    gap = 40 * DT                                          # across the end (20 s)
    if bridged == "extrapolated":
        cur = Setpoint(cur.position + cur.velocity * gap, cur.velocity)
    else:
        cur = Setpoint(cur.position, cur.velocity, cur.acceleration)
    t = T0 + k * DT + gap
    first = fo.step(t, cur)
    assert E.TRAJ_STOP in first.events
    after = run(fo, first.setpoint, t_from=t)
    check_stream(after, AZ, first.setpoint)
    last = after[-1][1] if after else first.setpoint
    assert last.velocity == 0.0 and fo.end_reason == "end"
    if ending == "moving":       # never back against the way it ran
        assert min(sp.velocity for _, sp, _, _ in after) >= 0.0
        if bridged == "extrapolated":   # (run on past where the path's own stop lands)
            own = ProfileSolver(DT).stop(cur, max_velocity=AZ.max_velocity,
                                         max_acceleration=AZ.max_acceleration,
                                         max_jerk=AZ.max_jerk, discrete=False)
            landing = own.at_time(own.duration)[0][0]
            assert cur.position > end_p
    assert abs(last.position - landing) < 1e-6, ((last.position - landing) / ARCSEC, landing)
    if ending == "at rest":   # (within the axes' tolerance: the spline's one-sided last knot
        # ends with a little velocity and acceleration, whose own stop runs on ~1″)
        assert abs(last.position - f(20.0)) < 0.0005


def test_path_starting_later_is_met_on_time():
    q = queue_of(sidereal, duration=100.0, start=60.0)
    fo = follower_for(q)
    fo.start(T0, Setpoint(100.0))
    out = run(fo, Setpoint(100.0))
    check_stream(out, AZ, Setpoint(100.0))
    at_start = next((t, sp, s) for t, sp, _, s in out if t - T0 >= 60.0)
    assert at_start[2] is FollowerState.FOLLOWING
    assert at_start[1].position == pytest.approx(sidereal(60.0), abs=1e-9)
    waiting = [sp for t, sp, _, _ in out if 20.0 < t - T0 < 57.0]
    assert all(sp.velocity == 0.0 for sp in waiting)          # parked, not creeping


def test_a_path_too_fast_for_the_axis_is_limited_and_chased():
    q = queue_of(lambda x: 6.0 * x, duration=20.0, spacing=1.0)    # 6 deg/s > 5
    fo = follower_for(q)
    flags = []
    out = run(fo, Setpoint(0.0), on_step=lambda k, f: flags.append(f.limited))
    check_stream(out, AZ, Setpoint(0.0))
    assert sum(flags) > 0.9 * len(flags)
    assert max(sp.velocity for _, sp, _, _ in out) == pytest.approx(5.0, rel=1e-6)
    assert E.TRAJ_LOOSE in [e for _, e in events_of(out)]


def test_cyclic_path_is_placed_inside_the_cable_wrap():
    # the client sends 350 -> 10 deg; the axis sits at -5 with limits -270..270
    x = np.arange(0.0, 101.0, 2.0)
    q = TrajectoryQueue(100, cycle=360.0)
    q.add_points(T0 + x, (350.0 + 0.2 * x) % 360.0)
    limits = SoftLimits(-270.0, 270.0, 360.0)
    fo = follower_for(q, limits)
    fo.start(T0, Setpoint(-5.0))
    assert fo.shift == -360.0
    out = run(fo, Setpoint(-5.0))
    check_stream(out, AZ, Setpoint(-5.0), limits)
    following = [(t, sp) for t, sp, _, s in out if s is FollowerState.FOLLOWING]
    assert max(abs(sp.position - (-10.0 + 0.2 * (t - T0))) for t, sp in following) < 1e-9


def test_fast_path_from_rest_is_met_within_the_limits():
    # the path starts at the axis but at 4.2 deg/s (of 5): the follower first matches the
    # path's velocity with the absolute limits, then closes the position error in the channel
    w = 2 * math.pi / 15.0
    q = queue_of(lambda x: 10.0 * np.sin(w * x), duration=60.0, spacing=0.5)
    fo = follower_for(q, SoftLimits(-50.0, 50.0))
    out = run(fo, Setpoint(0.0))
    check_stream(out, AZ, Setpoint(0.0))
    following = [t - T0 for t, _, _, s in out if s is FollowerState.FOLLOWING]
    assert following and following[0] < 20.0       # ~5 s matching, ~7 s closing 2.9 deg
    assert out[-1][1].velocity == 0.0


# -- property: whatever the path, the stream stays inside limits and dynamics -------------------

@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(amp=st.floats(0.0, 30.0), period=st.floats(5.0, 200.0), rate=st.floats(-3.0, 3.0),
       offset=st.floats(-60.0, 60.0), start=st.floats(-50.0, 50.0), v0=st.floats(-3.0, 3.0),
       spacing=st.sampled_from([0.5, 1.0, 2.0]))
# an axis at rest under a path at 4.2 deg/s of 5: the error channel's budget (0.7 deg/s) is
# below the error's velocity; braking it inside that budget reached 6.8 deg/s (found here)
@example(amp=10.0, period=15.0, rate=0.0, offset=0.0, start=0.0, v0=0.0, spacing=0.5)
@example(amp=11.0, period=16.0, rate=0.0, offset=0.0, start=0.0, v0=0.0, spacing=2.0)
# the path's acceleration under-read by sampling (2.3 % > the 2 % margin): 2.0015 of 2
@example(amp=0.5, period=5.0, rate=0.0, offset=0.0, start=3.0, v0=2.0, spacing=2.0)
def test_property_follower_stays_inside_limits(amp, period, rate, offset, start, v0, spacing):
    limits = SoftLimits(-50.0, 50.0)
    cur = Setpoint(start, v0, 0.0)
    low, high = LimitGuard(limits, AZ, DT).stop_extent(cur)
    assume(-50.0 <= low and high <= 50.0)
    w = 2 * math.pi / period
    q = queue_of(lambda x: offset + rate * x + amp * np.sin(w * x), duration=30.0,
                 spacing=spacing)
    fo = follower_for(q, limits)
    out = run(fo, cur, max_s=200.0)
    check_stream(out, AZ, cur, limits)
    assert out[-1][1].velocity == 0.0
