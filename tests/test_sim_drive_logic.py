"""The simulated drive's pure parts, back to back in memory: motion profiles, the axis
follower, homing plans and the CiA-402 application over its object store (no bus).
"""

from __future__ import annotations

import math

import canopen
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcs.sim import DEFAULT_EDS, SimDriveParams
from tcs.sim.drive_logic import DriveLogic
from tcs.sim.drive_physics import Axis, Threshold, linear_profile, position_profile, velocity_profile
from tcs.sim.homing import Switches, plan
from tcs.sim.object_store import ObjectStore

OD = canopen.import_od(str(DEFAULT_EDS), 5)
IPU = 10000.0


def check_profile(profile, vmax, acc):
    segs = profile.segments
    for a, b in zip(segs, segs[1:]):
        x, v = a.state(a.t1)
        assert b.t0 == pytest.approx(a.t1)
        assert b.x0 == pytest.approx(x, abs=1e-6)
        assert b.v0 == pytest.approx(v, abs=1e-9)
        assert abs(a.a) <= acc * (1 + 1e-9)
        # velocity never reverses inside a segment (crossings are solved in closed form)
        assert a.v0 * v >= -1e-12


@settings(max_examples=300, deadline=None)
@given(x=st.floats(-100, 100), v=st.floats(-3, 3), target=st.floats(-100, 100),
       vmax=st.floats(0.1, 5), acc=st.floats(0.1, 10), dec=st.floats(0.1, 10))
def test_position_profile_reaches_target_within_limits(x, v, target, vmax, acc, dec):
    p = position_profile(0.0, x, v, target, vmax, acc, dec)
    check_profile(p, vmax, max(acc, dec))
    assert p.final_position == target
    end = p.segments[-1]
    assert end.v0 == 0 and end.a == 0
    x_end, v_end = p.segments[-2].state(p.segments[-2].t1) if len(p.segments) > 1 else (x, v)
    assert x_end == pytest.approx(target, abs=1e-6)
    assert abs(v_end) < 1e-9
    assert max(abs(s.v0) for s in p.segments) <= max(vmax, abs(v)) + 1e-9


@settings(max_examples=200, deadline=None)
@given(v=st.floats(-3, 3), target=st.floats(-3, 3), acc=st.floats(0.1, 10), dec=st.floats(0.1, 10))
def test_velocity_profile_ramps_to_target(v, target, acc, dec):
    p = velocity_profile(0.0, 0.0, v, target, acc, dec)
    check_profile(p, 3, max(acc, dec))
    assert p.segments[-1].v0 == target


def test_axis_reports_a_crossing_once_at_the_exact_time():
    ax = Axis(x=0.0, max_velocity=2.0, max_acceleration=1.0)
    ax.set_reference(position_profile(0.0, 0.0, 0.0, 10.0, 2.0, 1.0, 1.0))
    ax.thresholds = [Threshold("switch", 3.0)]
    ev = ax.advance(100.0)
    assert ev.kind == "crossing" and ev.upward and ev.time == pytest.approx(2.5)
    assert ax.advance(100.0) is None and ax.x == 10.0
    ax.set_reference(position_profile(100.0, 10.0, 0.0, 0.0, 2.0, 1.0, 1.0))
    ev = ax.advance(200.0)
    assert ev.threshold.name == "switch" and not ev.upward
    assert ax.advance(200.0) is None and ax.x == 0.0


def test_axis_reports_a_switch_where_a_csp_segment_ends():
    """A CSP line ends a rounding error short of its target: a switch exactly at the target (a
    whole number of increments) is still crossed, by the step onto the next segment."""
    t0, x0, v = 21379.928265003, 0.2950374649032756, 0.49625350967243964   # as logged
    ax = Axis(x=x0, v=v, t=t0, max_velocity=2.0, max_acceleration=1.0)
    ax.set_reference(linear_profile(t0, x0, 0.3, 0.01, extrapolate=0.5, trend=v))
    ax.thresholds = [Threshold("switch", 0.3)]
    line = ax.reference.segments[0]
    assert line.state(line.t1)[0] < 0.3   # the rounding the test is about
    ev = ax.advance(t0 + 0.1)
    assert ev is not None and ev.kind == "crossing" and ev.upward
    assert ev.time == pytest.approx(line.t1) and ax.x == 0.3


def test_axis_following_error_when_the_reference_is_too_fast():
    ax = Axis(x=0.0, max_velocity=1.0, max_acceleration=1.0, fe_window=0.1, fe_timeout=0.05)
    ax.set_reference(velocity_profile(0.0, 0.0, 0.0, 3.0, 100.0, 100.0))   # infeasible
    ev = ax.advance(10.0)
    assert ev.kind == "following_error" and ev.time < 1.0


def test_homing_plans_depend_on_the_start():
    sw = Switches(negative_limit=-2.0, home_switch=1.0)
    assert [p.signal for p in plan(1, sw, 0.0)] == ["negative limit", "negative limit", "index pulse"]
    assert [p.signal for p in plan(17, sw, -3.0)] == ["negative limit"]      # already on it
    assert [(p.direction, p.fast) for p in plan(19, sw, 0.0)] == [(1, True), (-1, False)]
    assert [(p.direction, p.fast) for p in plan(19, sw, 2.0)] == [(-1, False)]
    assert plan(37, sw, 0.0) == []
    assert sw.next_index(0.0, 1) == 1.0 and sw.next_index(0.0, -1) == -1.0
    assert sw.next_index(0.5, 1) == 1.0 and sw.next_index(0.5, -1) == 0.0


# --------------------------------------------------------------------------- DriveLogic in memory
class Drive:
    def __init__(self, **params):
        self.store = ObjectStore(OD)
        self.emcy: list[int] = []
        self.t = 0.0
        self.logic = DriveLogic(self.store, SimDriveParams(**params), self.t,
                                lambda code, reg: self.emcy.append(code))

    def write(self, index, sub, value):
        self.logic.update(self.t)
        self.store.write_value(self.store.variable(index, sub), value)

    def read(self, index, sub=0):
        self.logic.update(self.t)
        return self.store.value(index, sub)

    def advance(self, dt):
        self.t += dt
        self.logic.update(self.t)

    def enable(self, mode):
        self.write(0x6060, 0, mode)
        for cw in (0x06, 0x07, 0x0F):
            self.write(0x6040, 0, cw)
        assert self.read(0x6041) & 0x6F == 0x27


def test_profile_velocity_reaches_speed_and_halts():
    d = Drive()
    d.write(0x60FF, 0, 20000)                 # 2 units/s, set before enabling
    d.enable(3)
    assert not d.read(0x6041) & 0x0400
    d.advance(5.0)
    assert d.read(0x606C) == 20000 and d.read(0x6041) & 0x0400
    d.write(0x6040, 0, 0x10F)                 # halt
    d.advance(5.0)
    assert d.read(0x606C) == 0 and d.read(0x6041) & 0x1000      # speed 0
    d.write(0x6040, 0, 0x0F)
    d.advance(5.0)
    assert d.read(0x606C) == 20000


def test_profile_position_buffers_one_setpoint():
    d = Drive()
    d.enable(1)
    d.write(0x607A, 0, 10000)
    d.write(0x6040, 0, 0x1F)
    d.write(0x6040, 0, 0x0F)
    d.advance(0.1)
    d.write(0x607A, 0, -5000)                 # queued: bit 5 (change immediately) clear
    d.write(0x6040, 0, 0x1F)
    assert d.read(0x6041) & 0x1000
    d.write(0x6040, 0, 0x0F)
    seen = []
    for _ in range(600):
        d.advance(0.1)
        seen.append(d.read(0x6064))
    assert max(seen) > 9900                   # the first target was reached first ...
    assert seen[-1] == -5000                  # ... then the buffered one


def test_quick_stop_ramps_with_the_quick_stop_deceleration():
    d = Drive(max_velocity=5.0, max_acceleration=5.0)
    d.write(0x6085, 0, 10000)                 # 1 unit/s²
    d.write(0x60FF, 0, 20000)
    d.enable(3)
    d.advance(10.0)
    d.write(0x6040, 0, 0x02)                  # quick stop, option 2 -> switch on disabled at rest
    assert d.read(0x6041) & 0x6F == 0x07
    d.advance(1.9)
    assert d.read(0x6041) & 0x6F == 0x07 and d.read(0x606C) > 0
    d.advance(0.2)
    assert d.read(0x6041) & 0x4F == 0x40 and d.read(0x606C) == 0
    assert d.logic.transitions[-2:] == [11, 12]


def test_fault_reaction_ramps_then_faults_and_reset_emcy():
    d = Drive()
    d.write(0x60FF, 0, 20000)
    d.enable(3)
    d.advance(10.0)
    d.logic.fault(0x8611)
    assert d.read(0x6041) & 0x4F == 0x0F      # fault reaction active while braking
    d.advance(10.0)
    assert d.read(0x6041) & 0x4F == 0x08
    d.write(0x6040, 0, 0x80)
    assert d.emcy == [0x8611, 0x0000]


def test_scaling_follows_encoder_resolution_and_gear():
    d = Drive(increments_per_unit=4096.0, position=2.0)
    assert (d.read(0x608F, 1), d.read(0x608F, 2)) == (4096, 1)
    assert d.read(0x6064) == 8192
    d.write(0x6091, 1, 3)                     # 3 motor turns per shaft turn
    assert d.read(0x6064) == 3 * 8192


def test_csp_interpolates_linearly_over_the_period():
    d = Drive()
    d.enable(8)
    d.write(0x607A, 0, 100)                   # 0.01 unit in one 10 ms period: 1 unit/s
    d.logic.on_sync(True)
    d.advance(0.005)
    assert d.read(0x6062) == 50               # demand halfway
    d.advance(0.005)
    assert d.read(0x6062) == 100
    assert math.isclose(d.logic.axis.demand()[1], 0.0)


@pytest.mark.parametrize("option, state, transitions, emcy", [
    (0, 0x27, [], []),                       # no reaction: still enabled
    (1, 0x08, [13], [0x8250]),               # fault (reaction per 0x605E)
    (2, 0x40, [9], [0x8250]),                # disable voltage
    (3, 0x40, [11, 12], [0x8250]),           # quick stop, then 0x605A = 2 disables at rest
])
def test_lost_master_reaction_follows_0x6007(option, state, transitions, emcy):
    d = Drive()
    d.write(0x6007, 0, option)
    d.write(0x60FF, 0, 20000)
    d.enable(3)
    d.advance(2.0)
    before = len(d.logic.transitions)
    d.logic.connection_lost(0x8250)
    d.advance(10.0)
    assert d.read(0x6041) & (0x4F if state != 0x27 else 0x6F) == state
    assert d.logic.transitions[before:before + len(transitions)] == transitions
    assert d.emcy == emcy


@pytest.mark.parametrize("option, moving", [(0, False), (1, True)])
def test_disable_operation_follows_0x605C(option, moving):
    d = Drive(max_velocity=5.0, max_acceleration=5.0)  # brake: 2/s stops in 0.4 s; profile
    d.write(0x60FF, 0, 20000)                          # deceleration (2.5/s²) takes 0.8 s
    d.enable(3)
    d.advance(10.0)
    d.write(0x605C, 0, option)
    d.write(0x6040, 0, 0x07)                  # disable operation (5)
    d.advance(0.5)
    assert (d.read(0x606C) > 0) is moving
    d.advance(10.0)
    assert d.read(0x606C) == 0


# --------------------------------------------------------------------------- IP and CSV (issue 21)
def test_ip_follows_the_record_only_with_enable_ip():
    """Interpolated position: the record 0x60C1:1 is interpolated like a CSP target only while
    controlword bit 4 is set (statusword bit 12 = IP active); without it it is ignored."""
    d = Drive()
    d.enable(7)
    d.write(0x60C1, 1, 100)
    d.logic.on_sync(True)                     # bit 4 clear: ignored, the drive stays
    d.advance(0.01)
    assert d.read(0x6064) == 0 and d.logic.ip_ignored == 1
    assert not d.read(0x6041) & 0x1000
    d.write(0x6040, 0, 0x1F)                  # enable IP
    assert d.read(0x6041) & 0x1000
    d.logic.on_sync(True)
    d.advance(0.005)
    assert d.read(0x6062) == 50               # linear over the period, as CSP
    d.advance(0.005)
    assert d.read(0x6062) == 100


def test_csv_follows_the_target_velocity_and_clamps_it_at_0x607f():
    d = Drive(max_velocity=5.0, max_acceleration=50.0)
    d.enable(9)
    d.write(0x607F, 0, 20000)                 # 2 units/s
    d.write(0x60FF, 0, 10000)                 # 1 unit/s
    for _ in range(50):
        d.logic.on_sync(True)
        d.advance(0.01)
    assert d.read(0x606C) == 10000 and not d.read(0x6041) & 0x0800
    d.write(0x60FF, 0, 40000)                 # 4 units/s: above 0x607F
    for _ in range(50):
        d.logic.on_sync(True)
        d.advance(0.01)
    assert d.read(0x606C) == 20000 and d.read(0x6041) & 0x0800  # clamped, internal limit
    assert d.emcy == []                       # a clamp, not a fault


def test_streaming_modes_react_to_missing_rpdos():
    for mode in (7, 9):
        d = Drive()
        d.enable(mode)
        if mode == 7:
            d.write(0x6040, 0, 0x1F)
        for _ in range(3):
            d.logic.on_sync(False)
        assert d.emcy == [0x8250], mode       # 0x6007 default 1: fault "RPDO time-out"
