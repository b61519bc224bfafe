"""Pure pieces of the PLC stack: the register codec, the read plan, the simulated motion profile."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcs.config.plc import RegisterPoint
from tcs.drivers.modbus import plan_reads
from tcs.sim.plc_axis import plan_move, plan_stop


def point(name="p", kind="holding", address=0, type="uint16", word_order="big", scale=1.0,
          offset=0.0, access="rw", bits=()):
    return RegisterPoint(name, kind, address, type, word_order, scale, offset, access, bits, "", "")


@pytest.mark.parametrize("type, word_order, scale, offset, value, words", [
    ("uint16", "big", 1.0, 0.0, 65535, [0xFFFF]),
    ("int16", "big", 1.0, 0.0, -2, [0xFFFE]),
    ("int16", "big", 0.1, 0.0, -12.3, [0xFF85]),
    ("uint16", "big", 0.5, 100.0, 101.0, [2]),
    ("int32", "big", 1.0, 0.0, -65536, [0xFFFF, 0x0000]),
    ("uint32", "big", 1.0, 0.0, 0x12345678, [0x1234, 0x5678]),
    ("uint32", "little", 1.0, 0.0, 0x12345678, [0x5678, 0x1234]),
    ("float32", "big", 1.0, 0.0, 1.0, [0x3F80, 0x0000]),
    ("float32", "little", 1.0, 0.0, -2.5, [0x0000, 0xC020]),
])
def test_codec_both_ways(type, word_order, scale, offset, value, words):
    p = point(type=type, word_order=word_order, scale=scale, offset=offset)
    assert p.encode(value) == words
    assert p.decode(words) == pytest.approx(value)


def test_unscaled_integers_stay_integers_and_bools_stay_bools():
    assert isinstance(point(type="int32").decode([0, 5]), int)
    assert point(kind="coil", type="bool").decode([True]) is True
    assert point(kind="coil", type="bool").encode(1) == [True]


@pytest.mark.parametrize("type, value, reason", [
    ("uint16", -1, "outside 0 … 65535"),
    ("int16", 40000, "outside -32768 … 32767"),
    ("uint16", "3", "needs a number"),
    ("float32", math.inf, "not a finite number"),
    ("bool", 2, "is a bool"),
])
def test_codec_refuses_what_does_not_fit(type, value, reason):
    kind = "coil" if type == "bool" else "holding"
    with pytest.raises(ValueError, match=reason):
        point(kind=kind, type=type).encode(value)


def test_named_bits_of_a_32_bit_register():
    p = point(name="st", type="uint32", bits=(("low", 0), ("high", 31)))
    assert p.decode_bits([0x8000, 0x0001]) == {"st.low": True, "st.high": True}
    assert p.decode_bits([0x0000, 0x0002]) == {"st.low": False, "st.high": False}


def test_read_plan_groups_within_gap_and_size_limits():
    pts = {p.name: p for p in [
        point("a", address=0, type="float32"), point("b", address=2), point("c", address=20),
        point("d", kind="input", address=5, access="r"), point("e", kind="coil", type="bool", address=3),
        point("w", address=10, access="w"),      # write-only: never polled
    ]}
    plan = [(b.kind, b.address, b.count, [p.name for p in b.points])
            for b in plan_reads(pts, max_gap=8, max_registers=125)]
    assert plan == [("coil", 3, 1, ["e"]), ("holding", 0, 3, ["a", "b"]), ("holding", 20, 1, ["c"]),
                    ("input", 5, 1, ["d"])]
    wide = plan_reads(pts, max_gap=100, max_registers=4)
    assert [(b.address, b.count) for b in wide if b.kind == "holding"] == [(0, 3), (20, 1)]


@settings(max_examples=300, deadline=None)
@given(p=st.floats(-500, 500), v=st.floats(-5, 5), target=st.floats(-500, 500),
       vmax=st.floats(0.5, 5), amax=st.floats(0.2, 10))
def test_trapezoid_arrives_at_rest_within_its_limits(p, v, target, vmax, amax):
    prof = plan_move(10.0, p, v, target, vmax, amax)
    assert prof.at(prof.end + 1.0) == (target, 0.0)
    pos, vel = prof.at(10.0)
    assert pos == pytest.approx(p, abs=1e-9) and vel == pytest.approx(v, abs=1e-9)
    t, last = 10.0, (p, v)
    speed_cap = max(vmax, abs(v)) + 1e-9
    step = (prof.end - 10.0) / 200 + 1e-6
    while t < prof.end:
        t = min(prof.end, t + step)
        pos, vel = prof.at(t)
        assert abs(vel) <= speed_cap
        assert abs(pos - last[0]) <= speed_cap * step + 1e-9  # continuous, no jumps
        last = (pos, vel)
    end = prof.at(prof.end - 1e-9)[0]
    assert end == pytest.approx(target, abs=1e-6)


def test_stop_decelerates_to_standstill():
    prof = plan_stop(0.0, 10.0, 4.0, 2.0)
    assert prof.end == pytest.approx(2.0)
    assert prof.at(5.0) == (pytest.approx(14.0), 0.0)
