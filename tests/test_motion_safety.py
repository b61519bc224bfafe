"""No motion anybody did not ask for (issue 22): direction, horizon, ABORT, OFFSET range, speed
limits on late cycles, settings across front ends — through the real front ends (TPL2 over a
socket, ASCOM Alpaca over HTTP) against the simulated drives of ``tests/hw_alpaca.toml``.

One service for the module (its own event-loop thread, :mod:`support.live`). Each test brings
the axes it uses to the state it needs. Motion is judged by sampling the simulated drives
themselves (``telescope.sims[node]``: the position the motor reports, and the CSP targets the
drive received at each SYNC), never by the TCS's own readbacks, and never by timing: every wait
is for a state with a generous time-out.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import subprocess
import sys
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from support.live import live_service
from support.opentci_client import Client, done_ok, upload

HW = Path(__file__).with_name("hw_alpaca.toml")
NODE = {"AZ": 1, "ZD": 2, "DEROTATOR[2]": 3}
MOVING = 1
WAIT = 60.0
#: A CSP target step against a MoveAxis's direction larger than this fails the randomized test
#: (two drive increments of rounding). Steps back of 0.0008°–0.07° were seen on a loaded machine: a MoveAxis
#: arriving while the axis braked hard towards an earlier goal behind it, whose jerk-limited
#: unwinding of the deceleration reversed the axis first (fixed: MotionPlanner._unwound).
BACKSTEP = 2e-5

live = live_service(HW)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


# ----------------------------------------------------------------------------- helpers

class stream_as_made:
    """Within: the cycle source sends each setpoint as the axis made it, not moved on by its
    SYNC's lateness (``CycleSource.retime``). For the tests that judge the axis's stream step by
    step over the nominal period — a retimed setpoint is the stream's travel over the real
    interval between its SYNC and the one before, which a late SYNC makes longer or shorter
    (judged over real time: tests/vcan/test_stall_recovery.py, the jittery-SYNC test)."""

    def __init__(self, live):
        self.source = live.telescope.control_loop.source

    def __enter__(self):
        self.before, self.source.retime = self.source.retime, False
        return self

    def __exit__(self, *exc):
        self.source.retime = self.before

class Sampler:
    """Samples a simulated drive's reported position every few ms in a thread of its own."""

    def __init__(self, sim, period: float = 0.005):
        self.sim, self.period = sim, period
        self.samples: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="test-sampler", daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.samples.append((time.monotonic(), self.sim.position))
            self._stop.wait(self.period)

    def __enter__(self) -> "Sampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5)

    @property
    def positions(self) -> list[float]:
        return [p for _, p in self.samples]


def sim(live, ax: str):
    return live.telescope.sims[NODE[ax]]


def alpaca(live, member: str, method: str = "PUT", **form) -> dict:
    """One Alpaca request to Telescope 0 over HTTP; the decoded JSON reply."""
    url = f"http://127.0.0.1:{live.service.alpaca_port}/api/v1/telescope/0/{member}"
    data = None
    if method == "PUT":
        data = urllib.parse.urlencode({**form, "ClientID": 7, "ClientTransactionID": 1}).encode()
    elif form:
        url += "?" + urllib.parse.urlencode(form)
    with urllib.request.urlopen(urllib.request.Request(url, data=data, method=method), timeout=40) as r:
        return json.loads(r.read())


async def aput(live, member: str, **form) -> dict:
    return await asyncio.to_thread(alpaca, live, member, "PUT", **form)


async def connect(live) -> Client:
    return await Client.connect(live.port)


async def ready(live, c: Client, *axes: str) -> None:
    """Unparked (Alpaca), main power on, ``axes`` without fault, powered, referenced, at rest,
    not tracking."""
    assert (await aput(live, "connected", Connected="true"))["ErrorNumber"] == 0
    if live.telescope.operations.at_park:
        # (Unpark refuses while a drive fault an earlier test left is latched: acknowledged
        # first, as an operator would)
        await aput(live, "action", Action="AcknowledgeFaults", Parameters="")
        assert (await aput(live, "unpark"))["ErrorNumber"] == 0
    if await c.get("CABINET.POWER_STATE") != "1.0":
        assert done_ok(await c.set("CABINET.POWER=1", 60), "CABINET.POWER")
    if await c.num("POINTING.TRACK"):
        await c.set("POINTING.TRACK=0")
    for ax in axes:
        await make_ready(c, ax)
        if await c.num(f"{ax}.OFFSET") != 0.0:
            assert done_ok(await c.set(f"{ax}.OFFSET=0"), f"{ax}.OFFSET")


async def make_ready(c: Client, ax: str) -> None:
    """``ax`` without a fault, powered, referenced, at rest (the other axis of the mount is
    powered off with it when one faults)."""
    for one in ([ax, "ZD" if ax == "AZ" else "AZ"] if ax in ("AZ", "ZD") else [ax]):
        await c.wait(f"{one}.MOTION_STATE", lambda v: not int(v) & MOVING, WAIT)
        if await c.num(f"{one}.ERROR_STATE"):
            await c.set(f"{one}.ERROR_STATE=0")
            await c.wait(f"{one}.ERROR_STATE", lambda v: not int(v) & 3)
        if await c.num(f"{one}.POWER_STATE") != 1.0:
            assert done_ok(await c.set(f"{one}.POWER=1"), f"{one}.POWER")
        if await c.num(f"{one}.REFERENCED") < 1.0:
            await c.set(f"{one}.REINIT=0")
            await c.wait(f"{one}.REFERENCED", lambda v: v == 1.0, WAIT)
        await c.wait(f"{one}.MOTION_STATE", lambda v: not int(v) & MOVING)


async def goto(c: Client, ax: str, position: float) -> None:
    """Set-up move of ``ax`` to exactly ``position`` (not the nearest turn of it: through 0 and
    ±100 on a wrapping axis). A set-up move that a loaded machine spoils (the drives stop by
    themselves when the loop starves: RPDO time-out, following error) is retried after the
    axis is made ready again; the moves under test are never retried."""
    steps = [position]
    if ax in ("AZ", "DEROTATOR[2]", "DEROTATOR[3]"):
        steps = [0.0] + ([100.0 if position > 0 else -100.0] if abs(position) > 150 else []) + [position]
    for step in steps:
        for attempt in range(3):
            lines = await c.set(f"{ax}.TARGETPOS={step}", WAIT)
            if done_ok(lines, f"{ax}.TARGETPOS") or attempt == 2:
                break
            await make_ready(c, ax)
        assert done_ok(lines, f"{ax}.TARGETPOS"), lines


async def at_rest(c: Client, ax: str) -> None:
    await c.wait(f"{ax}.MOTION_STATE", lambda v: not int(v) & MOVING, WAIT)


async def moves_until(live, ax: str, pred, what: str, timeout: float = WAIT) -> None:
    s = sim(live, ax)
    deadline = time.monotonic() + timeout
    while not pred(s.position):
        assert time.monotonic() < deadline, f"{ax}: {what} (at {s.position})"
        await asyncio.sleep(0.01)


def targets(live, ax: str) -> list[float]:
    """The CSP targets the simulated drive of ``ax`` received, one per SYNC (what the TCS
    commanded; the motor's reported position adds its own loop's settling to it)."""
    return [p for _, p, _ in list(sim(live, ax).csp_targets)]  # (a copy: the sim appends)


def bridged(records) -> float:
    """The longest time a drive bridged by itself in its CSP ``records`` (a SYNC that came
    without a setpoint: the host stalled, tcs.drivers.cycle drops a stale one): from the last
    target before such a gap to the first after it, s; 0 without one."""
    records = list(records)
    return max((t1 - t0 for (t0, _, _), (t1, _, cont) in zip(records, records[1:]) if not cont),
               default=0.0)


def against(values: list[float], sign: int) -> list[tuple[float, float]]:
    """Consecutive pairs of ``values`` that step against ``sign``."""
    return [(a, b) for a, b in zip(values, values[1:]) if sign * (b - a) < -1e-9]


# ------------------------------------------------------- 1, 6, 7: Alpaca MoveAxis

async def test_moveaxis_moves_a_wrapping_axis_the_way_asked(live):
    """From AZ 0 a positive rate increases the azimuth, a negative one decreases it (the ±270°
    goal of the cable wrap is no longer folded into ∓90°); the derotator likewise."""
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD", "DEROTATOR[2]")
        for ax, n in (("AZ", 0), ("DEROTATOR[2]", 2)):
            for rate in (20.0, -20.0):
                await goto(c, ax, 0.0)
                start = sim(live, ax).position
                sign = 1 if rate > 0 else -1
                sim(live, ax).csp_targets.clear()
                reply = await aput(live, "moveaxis", Axis=n, Rate=rate)
                assert reply["ErrorNumber"] == 0, reply
                await moves_until(live, ax, lambda p: sign * (p - start) > 10.0,
                                  f"MoveAxis({n}, {rate}) moving 10 deg its way")
                assert (await aput(live, "moveaxis", Axis=n, Rate=0))["ErrorNumber"] == 0
                await at_rest(c, ax)
                commanded = targets(live, ax)
                assert against(commanded, sign) == [], (ax, rate, against(commanded, sign)[:5])
                assert sign * (sim(live, ax).position - start) > 10.0
    finally:
        await c.close()


async def test_a_moveaxis_at_a_guiding_rate_runs(live):
    """MoveAxis of AZ at 0.01°/s (a guiding rate; its end, the software limit, is over 7,600 s
    away, longer than ruckig plans — it answered -101, the control cycle failed and stopped
    the axis): the axis moves at that rate its way, no error, and MoveAxis(0) stops it."""
    c = await connect(live)
    try:
        await ready(live, c, "AZ")
        await goto(c, "AZ", 0.0)
        axis = live.telescope.axis("AZ")
        errors = live.telescope.control_loop.errors
        start = sim(live, "AZ").position
        reply = await aput(live, "moveaxis", Axis=0, Rate=0.01)
        assert reply["ErrorNumber"] == 0, reply
        await moves_until(live, "AZ", lambda p: p - start > 0.005, "MoveAxis(0, 0.01) moving its way")
        assert axis.motion_state & 1 and axis.fault is None
        assert live.telescope.control_loop.errors == errors
        assert (await aput(live, "moveaxis", Axis=0, Rate=0))["ErrorNumber"] == 0
        await at_rest(c, "AZ")
        assert 0.005 < sim(live, "AZ").position - start < 0.1
    finally:
        await c.close()


async def test_a_slower_moveaxis_slows_the_axis_down_without_stepping_back(live):
    """MoveAxis at 20°/s, then MoveAxis at 1°/s the same way (AZ both ways, the altitude
    up): the axis slows down to the new rate and runs on at it — never a CSP target back.
    The planner gave ruckig the new speed as the velocity limit of a move from 20°/s: it
    braked down to it and unwound its deceleration below zero, 10 mdeg back (the randomized
    test saw 1–3 mdeg: ``AZ: MoveAxis(0.8) stepped back``)."""
    c = await connect(live)
    stream = stream_as_made(live).__enter__()  # (each CSP step is judged over one period)
    try:
        await ready(live, c, "AZ", "ZD")
        period = live.telescope.control_loop.source.period
        for ax, n, fast, slow, sign, at in (("AZ", 0, 20.0, 1.0, 1, 0.0), ("AZ", 0, -20.0, -1.0, -1, 0.0),
                                             ("ZD", 1, 20.0, 1.0, -1, 60.0)):
            await goto(c, ax, at)
            s = sim(live, ax)
            start = s.position
            assert (await aput(live, "moveaxis", Axis=n, Rate=fast))["ErrorNumber"] == 0
            await moves_until(live, ax, lambda p: sign * (p - start) > 5.0, f"MoveAxis({n}, {fast}) moving")
            s.csp_targets.clear()
            assert (await aput(live, "moveaxis", Axis=n, Rate=slow))["ErrorNumber"] == 0
            deadline = time.monotonic() + WAIT
            while True:   # until it runs at the slow rate (the last 20 steps)
                steps = [b - a for a, b in zip(targets(live, ax)[-21:], targets(live, ax)[-20:])]
                if len(steps) == 20 and all(abs(x / period - abs(slow) * sign) < 0.01 for x in steps):
                    break
                assert time.monotonic() < deadline, f"{ax}: never ran at {slow}°/s ({steps[-3:]})"
                await asyncio.sleep(0.05)
            assert (await aput(live, "moveaxis", Axis=n, Rate=0))["ErrorNumber"] == 0
            await at_rest(c, ax)
            commanded = targets(live, ax)
            assert against(commanded, sign) == [], (ax, fast, slow, against(commanded, sign)[:5])
    finally:
        stream.__exit__()
        await c.close()


async def test_moveaxis_altitude_raises_and_stops_at_the_horizon(live):
    """Axis 1 of the alt-az mount is altitude: a positive rate decreases ZD (raises the tube)
    up to the zenith; a negative rate lowers it and stops at the altitude limit SlewToAltAz
    keeps (15° here), not at the mechanical ZD limit of 85°.

    A run the host stalled in (a SYNC the drive bridged by itself, running on at the stream's
    speed: it may pass the bound before the TCS is back, which then stops and returns) is
    repeated; a gap while braking at the horizon has its own test below."""
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        for attempt in range(3):
            await goto(c, "ZD", 30.0)
            sim(live, "ZD").csp_targets.clear()
            assert (await aput(live, "moveaxis", Axis=1, Rate=10.0))["ErrorNumber"] == 0
            await moves_until(live, "ZD", lambda p: p < 25.0, "rising")
            await at_rest(c, "ZD")  # runs to the zenith and stops there
            if not bridged(sim(live, "ZD").csp_targets):
                break
        assert against(targets(live, "ZD"), -1) == []
        assert abs(sim(live, "ZD").position) < 0.01
        limit = 90.0 - live.telescope.pointing.config.min_altitude
        for attempt in range(3):
            if attempt:
                await goto(c, "ZD", 0.0)
            sim(live, "ZD").csp_targets.clear()
            with Sampler(sim(live, "ZD")) as s:
                assert (await aput(live, "moveaxis", Axis=1, Rate=-30.0))["ErrorNumber"] == 0
                await moves_until(live, "ZD", lambda p: p > 5.0, "lowering")
                await at_rest(c, "ZD")
            if not bridged(sim(live, "ZD").csp_targets):
                break
        assert against(targets(live, "ZD"), 1) == []
        assert max(targets(live, "ZD")) <= limit + 1e-9, (max(targets(live, "ZD")), limit)
        assert max(s.positions) <= limit + 0.05, (max(s.positions), limit)  # (motor settling)
        assert s.positions[-1] > limit - 0.01
        # at the horizon limit, lower is refused; up is allowed
        reply = await aput(live, "moveaxis", Axis=1, Rate=-5.0)
        assert reply["ErrorNumber"] == 0x401, reply
        assert (await aput(live, "moveaxis", Axis=1, Rate=5.0))["ErrorNumber"] == 0
        await moves_until(live, "ZD", lambda p: p < limit - 1.0, "rising again")
        assert (await aput(live, "moveaxis", Axis=1, Rate=0))["ErrorNumber"] == 0
        await at_rest(c, "ZD")
    finally:
        await c.close()


async def test_a_stall_while_moveaxis_brakes_at_the_horizon_never_passes_it(live):
    """Issue 39 item 6 with the horizon bound: while a MoveAxis lowering ZD at 30°/s brakes to
    the altitude limit, the control loop is held once for 33 ms (a cycle callback that sleeps:
    no SYNC, no setpoint; the drive runs on at the stream's speed). The axis re-anchors where
    the drive is and brakes to the bound with up to the stop deceleration: no CSP target past
    it, none back (re-planned with the normal deceleration from zero acceleration it ran to
    76.5–77.7° and came back). A hold the host stretched past what the stop deceleration can
    still meet (the drive itself then passes the bound: 90 ms and more here) is repeated, up to
    eight times (never held so: skipped, with each try's figures)."""
    c = await connect(live)
    t = live.telescope
    zd = t.axis("ZD")
    source = t.control_loop.source
    limit = 90.0 - t.pointing.config.min_altitude
    state = {"armed": False}

    def hold(cycle) -> None:
        sp = zd.planner.setpoint
        if state["armed"] and sp.position > 60.0 and 0.0 < sp.velocity < 28.0:
            state["armed"] = False
            time.sleep(0.033)   # (three SYNC slots: the held setpoint is dropped; a loaded
            # host stretches it: 30 ms asked came back as 50+, then the attempt is repeated)
    try:
        await ready(live, c, "AZ", "ZD")
        tries = []
        for attempt in range(8):
            await goto(c, "ZD", 30.0)
            resumes = zd.resumes
            sim(live, "ZD").csp_targets.clear()
            source.add_callback(hold)
            state["armed"] = True
            try:
                assert (await aput(live, "moveaxis", Axis=1, Rate=-30.0))["ErrorNumber"] == 0
                await moves_until(live, "ZD", lambda p: p > 35.0, "lowering")
                await at_rest(c, "ZD")
            finally:
                source.remove_callback(hold)
            gap = bridged(sim(live, "ZD").csp_targets)
            tries.append((not state["armed"], zd.resumes - resumes, round(gap, 3)))
            # (the drive bridged under 75 ms: 28 deg/s run on from 5 deg before the bound can still
            # be stopped there with the stop deceleration — 70 ms was, 90 ms ran 0.36 deg past)
            if not state["armed"] and zd.resumes > resumes and gap < 0.075:
                break
        else:   # (held, resumes, the drive's longest bridged gap) of every try
            pytest.skip(f"the host never held the loop for 30-75 ms while ZD braked: {tries}")
        commanded = targets(live, "ZD")
        assert max(commanded) <= limit + 1e-9, (max(commanded), limit)
        assert against(commanded, 1) == [], against(commanded, 1)[:5]
        assert sim(live, "ZD").position == pytest.approx(limit, abs=0.01)
    finally:
        await c.close()


async def test_moveaxis_keeps_the_operators_currspeed(live):
    """An operator's CURRSPEED (set over OpenTCI) still holds after an Alpaca MoveAxis and its
    stop: the next TARGETPOS move runs at most at that speed."""
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        await goto(c, "AZ", 100.0)
        assert done_ok(await c.set("AZ.CURRSPEED=5"), "AZ.CURRSPEED")
        assert (await aput(live, "moveaxis", Axis=0, Rate=30.0))["ErrorNumber"] == 0
        await moves_until(live, "AZ", lambda p: p > 105.0, "MoveAxis moving")
        assert (await aput(live, "moveaxis", Axis=0, Rate=0))["ErrorNumber"] == 0
        await at_rest(c, "AZ")
        here = sim(live, "AZ").position
        sim(live, "AZ").csp_targets.clear()
        # a direct 10° move (goto() would go by 0 first: 230° at the 5°/s under test, 46 s)
        with stream_as_made(live):  # (the axis's own steps are under test)
            assert done_ok(await c.set(f"AZ.TARGETPOS={round(here + 10.0, 3)}", WAIT), "AZ.TARGETPOS")
        recs = list(sim(live, "AZ").csp_targets)  # (steps between consecutive SYNCs' targets)
        steps = [b - a for (_, a, _), (_, b, cont) in zip(recs, recs[1:]) if cont]
        period = live.telescope.control_loop.source.period
        assert max(steps) / period <= 5.0 * (1 + 1e-6), max(steps) / period  # (full speed: 60)
    finally:
        try:
            await c.set("AZ.CURRSPEED=60")
        finally:
            await c.close()


# ------------------------------------------------------------------------- 3: ABORT

async def _abort_and_check(live, c: Client, ax: str, start_text: str, far: float) -> None:
    """Start ``SET start_text``; once ``ax`` moves, ABORT it: the command ends ABORTEDBY, the
    drive stops well short of ``far`` and does not move on."""
    cmd = await c.start(start_text)
    s = sim(live, ax)
    start = s.position
    await moves_until(live, ax, lambda p: abs(p - start) > 1.0, "moving before the ABORT")
    await c.send(f"{cmd + 500000} ABORT {cmd}")
    line = await c.event(rf"^{cmd} COMMAND (ABORTEDBY|COMPLETE|FAILED)")
    assert line.endswith(f"ABORTEDBY {cmd + 500000}"), line
    await at_rest(c, ax)
    stopped = s.position
    assert abs(stopped - far) > 5.0, (ax, stopped, far)
    await asyncio.sleep(0.3)
    assert abs(s.position - stopped) < 1e-3, "it moved on after the ABORT"


async def test_abort_of_a_targetpos_stops_the_axis(live):
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        await goto(c, "AZ", -100.0)
        await _abort_and_check(live, c, "AZ", "AZ.TARGETPOS=200", 200.0)
        # a SET of two targets runs them in order: aborted during the first, neither goes on
        await goto(c, "ZD", 0.0)
        await _abort_and_check(live, c, "AZ", "AZ.TARGETPOS=-200;ZD.TARGETPOS=80", -200.0)
        await at_rest(c, "ZD")
        assert abs(sim(live, "ZD").position) < 1e-3
    finally:
        await c.close()


async def test_abort_of_an_offset_and_of_a_trajectory_run_stops_the_axis(live):
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        await goto(c, "AZ", -100.0)
        await _abort_and_check(live, c, "AZ", "AZ.OFFSET=150", 50.0)
        assert done_ok(await c.set("AZ.OFFSET=0"), "AZ.OFFSET")
        await goto(c, "AZ", 0.0)
        ut1 = await c.num("LOCAL.UT1")
        points = [(ut1 + 1.0 + i, 30.0 * i) for i in range(8)]   # 30 deg/s for 7 s
        assert done_ok(await upload(c, "AZ", points), "AZ.TRAJECTORY.ADDPOINTS")
        await _abort_and_check(live, c, "AZ", "AZ.TRAJECTORY.RUN=1", 210.0)
    finally:
        await c.close()


async def test_abort_of_tracking_and_of_a_dome_move_stops_them(live):
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        # POINTING.TRACK: a goto far away, aborted during the slew
        p = live.telescope.pointing
        await goto(c, "AZ", -60.0)
        await goto(c, "ZD", 40.0)
        ra, dec = p.current.ra, p.current.dec  # where it points: then 120 deg east of it
        assert done_ok(await c.set(f"POINTING.TARGET.RA={(ra + 8.0) % 24.0};POINTING.TARGET.DEC={dec}"),
                       "POINTING.TARGET.DEC")
        cmd = await c.start("POINTING.TRACK=1")
        start = sim(live, "AZ").position
        await moves_until(live, "AZ", lambda x: abs(x - start) > 2.0, "slewing")
        await c.send(f"{cmd + 500000} ABORT {cmd}")
        line = await c.event(rf"^{cmd} COMMAND (ABORTEDBY|COMPLETE|FAILED)")
        assert "ABORTEDBY" in line, line
        await c.wait("POINTING.TRACK", lambda v: v == 0, WAIT)
        await at_rest(c, "AZ")
        await at_rest(c, "ZD")
        here = sim(live, "AZ").position
        await asyncio.sleep(0.5)
        assert abs(sim(live, "AZ").position - here) < 1e-3, "it went on tracking"
        # DOME[0].TARGETPOS: the PLC rotation stops
        if await c.num("DOME[0].POWER_STATE") != 1.0:
            assert done_ok(await c.set("DOME[0].POWER=1"), "DOME[0].POWER")
        dome = live.telescope.dome[0]
        here = dome.real_position
        cmd = await c.start(f"DOME[0].TARGETPOS={(here + 170.0) % 360.0}")
        deadline = time.monotonic() + WAIT
        while abs((dome.real_position - here + 180.0) % 360.0 - 180.0) < 2.0:
            assert time.monotonic() < deadline, "the dome did not move"
            await asyncio.sleep(0.02)
        await c.send(f"{cmd + 500000} ABORT {cmd}")
        line = await c.event(rf"^{cmd} COMMAND (ABORTEDBY|COMPLETE|FAILED)")
        assert "ABORTEDBY" in line, line
        await c.wait("DOME[0].MOTION_STATE", lambda v: not int(v) & MOVING, WAIT)
        stopped = dome.real_position
        assert abs((stopped - here - 170.0 + 180.0) % 360.0 - 180.0) > 5.0, (here, stopped)
    finally:
        await c.close()


async def test_abort_of_an_opentsi_goto_stops_the_slew(live):
    """OpenTSI ``POINTING.TRACK=2`` (a horizontal goto), aborted during the slew: the axes stop
    short of the goal instead of slewing on."""
    c = await connect(live)
    tsi = await Client.connect(live.service.opentsi_port)
    try:
        await ready(live, c, "AZ", "ZD")
        await goto(c, "AZ", 0.0)
        await goto(c, "AZ", -100.0)
        await goto(c, "ZD", 30.0)
        lines = await tsi.set("OBJECT.HORIZONTAL.AZ=170;OBJECT.HORIZONTAL.ALT=60")
        assert lines[-1].endswith("COMMAND COMPLETE"), lines
        cmd = await tsi.start("POINTING.TRACK=2")
        start = sim(live, "AZ").position
        await moves_until(live, "AZ", lambda p: abs(p - start) > 2.0, "slewing")
        await tsi.send(f"{cmd + 500000} ABORT {cmd}")
        line = await tsi.event(rf"^{cmd} COMMAND (ABORTEDBY|COMPLETE|FAILED)")
        assert "ABORTEDBY" in line, line
        await at_rest(c, "AZ")
        stopped = sim(live, "AZ").position
        assert abs(stopped - 170.0) > 5.0 and abs(stopped + 190.0) > 5.0, stopped
        await asyncio.sleep(0.3)
        assert abs(sim(live, "AZ").position - stopped) < 1e-3
    finally:
        await c.close()
        await tsi.close()


async def test_tcs_client_timeout_aborts_and_the_axis_stops(live, tmp_path):
    """``tcs-client set AZ.TARGETPOS=… --timeout 1`` sends ABORT when the time is up: the exit
    status says so and the axis stops short of the target instead of slewing on."""
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        await goto(c, "AZ", 0.0)
        await goto(c, "AZ", -100.0)
        password = tmp_path / "password"
        password.write_text("admin\n")
        env = {**os.environ, "TCS_HOST": "127.0.0.1", "TCS_PORT": str(live.port), "TCS_USER": "admin",
               "TCS_PASSWORD_FILE": str(password)}
        done = await asyncio.to_thread(
            subprocess.run, [sys.executable, "-m", "tcs.cli.client", "set", "AZ.TARGETPOS=200",
                             "--timeout", "1"], env=env, capture_output=True, text=True, timeout=120)
        assert done.returncode != 0 and "aborted" in done.stderr, (done.returncode, done.stderr)
        await at_rest(c, "AZ")
        stopped = sim(live, "AZ").position
        assert abs(stopped - 200.0) > 5.0, stopped
        await asyncio.sleep(0.3)
        assert abs(sim(live, "AZ").position - stopped) < 1e-3
    finally:
        await c.close()


# ----------------------------------------------------------------- 4: OFFSET while tracking

async def test_offset_on_a_running_trajectory_is_range_checked(live):
    """AZ.OFFSET=600 on a running path is RANGE before DATA OK, and so is an offset that puts
    the queued path outside the limits; the offset keeps its value, the path goes on."""
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        await goto(c, "AZ", 100.0)
        await goto(c, "AZ", 200.0)   # (the turn nearest 100: the path runs on +200 ... +258)
        ut1 = await c.num("LOCAL.UT1")
        points = [(ut1 + 0.5 + i, 200.0 + 0.004 * i) for i in range(30)]   # slow, as tracking
        assert done_ok(await upload(c, "AZ", points), "AZ.TRAJECTORY.ADDPOINTS")
        run = await c.start("AZ.TRAJECTORY.RUN=1")
        await c.wait("AZ.MOTION_STATE", lambda v: int(v) & 2, WAIT)
        for value in (600, 80):     # half a turn and more; 80 puts the path at 280 > 270
            lines = await c.set(f"AZ.OFFSET={value}")
            assert any(f"DATA ERROR AZ.OFFSET RANGE" in x for x in lines), lines
            assert await c.num("AZ.OFFSET") == 0.0
        lines = await c.set("AZ.OFFSET=0.01")   # a small one inside is taken
        assert done_ok(lines, "AZ.OFFSET"), lines
        assert int(await c.num("AZ.MOTION_STATE")) & 2, "the path was given up"
        assert sim(live, "AZ").position < 270.0
        await c.set("AZ.TRAJECTORY.RUN=0")
        await c.event(rf"^{run} COMMAND ")
        await at_rest(c, "AZ")
        assert done_ok(await c.set("AZ.OFFSET=0"), "AZ.OFFSET")
    finally:
        await c.close()


# ---------------------------------------------------------------- 5: late cycles

async def test_late_cycles_never_send_more_than_the_speed_and_acceleration_limits(live):
    """Every few cycles the loop is made late (a cycle callback that sleeps 1.5–2.5 periods)
    while AZ follows a 50°/s path (limit 60): no step between two CSP targets the drive
    received exceeds 60°/s × T (the drive runs each step within one period), and no step
    differs from the one before by more than the acceleration limit × T² (120°/s² speeding
    up, 240 slowing down: without the cut a skipped slot doubled the speed for one period)."""
    c = await connect(live)
    try:
        await ready(live, c, "AZ", "ZD")
        await goto(c, "AZ", 0.0)
        await goto(c, "AZ", -150.0)   # (the turn nearest 0)
        loop = live.telescope.control_loop
        period = loop.source.period
        rng = random.Random(22)

        def late(cycle) -> None:
            if rng.random() < 0.15:
                time.sleep(period * rng.uniform(1.5, 2.5))

        ut1 = await c.num("LOCAL.UT1")
        points = [(ut1 + 1.5 + 0.5 * i, -150.0 + 25.0 * i) for i in range(13)]   # 50 deg/s for 6 s
        assert done_ok(await upload(c, "AZ", points), "AZ.TRAJECTORY.ADDPOINTS")
        drive = sim(live, "AZ")
        drive.csp_targets.clear()
        loop.source.add_callback(late)
        try:
            with stream_as_made(live):  # (the axis's own steps under late cycles are under test)
                lines = await c.set("AZ.TRAJECTORY.RUN=1", WAIT)
        finally:
            loop.source.remove_callback(late)
        assert lines[-1].endswith("COMMAND COMPLETE"), lines
        await at_rest(c, "AZ")
        records = list(drive.csp_targets)
        targets = [p for _, p, _ in records]
        assert len(targets) > 300
        # (steps between targets latched at consecutive SYNCs: a SYNC a late cycle's setpoint
        # missed — dropped, tcs.drivers.cycle — goes without one, the drive bridges it, and the
        # next target is no step of the stream: its own re-anchored start, tests/vcan/
        # test_stall_recovery.py)
        steps = [b - a if cont else None for (_, a, _), (_, b, cont) in zip(records, records[1:])]
        vmax = 60.0
        assert max(abs(s) for s in steps if s is not None) <= vmax * period * (1 + 1e-5) + 1e-5, \
            max(abs(s) for s in steps if s is not None)
        section = live.telescope.axis("AZ").section
        for a, b in zip(steps, steps[1:]):
            if a is None or b is None:
                continue
            speeding_up = abs(b) > abs(a) and a * b >= 0
            limit = section.max_acceleration if speeding_up else section.stop_deceleration
            # (+ 2 increments: the drive receives whole increments)
            assert abs(b - a) <= limit * period ** 2 * (1 + 1e-4) + 2.0 / drive.params.increments_per_unit, \
                (a / period, b / period)
        assert max(targets) > 100.0   # it did run the path at speed
    finally:
        await c.close()


# ------------------------------------------------------------ the seeded randomized test

SEED = int(os.environ.get("TCS_FUZZ_SEED", "22"))   # another seed: TCS_FUZZ_SEED=n
COMMANDS = 2000


async def test_random_commands_from_every_front_end_never_move_unasked(live):
    """Seeded fuzz (``SEED``): ``COMMANDS`` random commands from OpenTCI (TARGETPOS in and out of
    range, OFFSET, CURRSPEED, STOP, trajectories, RUN=0, ABORT of earlier commands, TRACK=0),
    OpenTSI (horizontal gotos above and below the horizon, TELESCOPE.STOP, TRACK=0) and Alpaca
    (MoveAxis at random rates, AbortSlew, SlewToAltAzAsync), with drive faults injected and
    acknowledged, while the simulated drives are sampled. Never: a CSP target or a reported
    position outside the software limits, a step between two CSP targets above the speed
    limit, and while a MoveAxis is the last word on its axis, a commanded step against its
    direction or (ZD) towards the horizon beyond the altitude limit."""
    rng = random.Random(SEED)
    t = live.telescope
    c = await connect(live)
    tsi = await Client.connect(live.service.opentsi_port)
    stream = stream_as_made(live).__enter__()  # (each CSP step is judged over one period)
    try:
        await ready(live, c, "AZ", "ZD")
        rotator, port = t.pointing.active_derotator()
        rot = rotator.module_name
        await ready(live, c, rot)
        names = {"AZ": "AZ", "ZD": "ZD", rot: rot}
        sims = {"AZ": sim(live, "AZ"), "ZD": sim(live, "ZD"), rot: t.sims[rotator.drive.node_id]}
        axes = {"AZ": t.axis("AZ"), "ZD": t.axis("ZD"), rot: rotator}
        moveaxis = {0: "AZ", 1: "ZD", 2: rot}
        for s in sims.values():
            s.csp_targets.clear()
        log: list[tuple[float, tuple, str, object]] = []   # (time, axes touched, kind, detail)
        started: list[int] = []
        every = tuple(names)

        def note(touched, kind, detail=None):
            log.append((time.monotonic(), tuple(touched), kind, detail))

        faults = 0
        for i in range(COMMANDS):
            r = rng.random()
            ax = rng.choice(every)
            if r < 0.22:
                lo, hi = axes[ax].section.min, axes[ax].section.max
                value = round(rng.uniform(lo - 20, hi + 20), 3)
                note([ax], "targetpos")
                started.append(await c.start(f"{ax}.TARGETPOS={value}"))
            elif r < 0.30:
                note([ax], "offset")
                started.append(await c.start(f"{ax}.OFFSET={round(rng.choice([rng.uniform(-1, 1), rng.uniform(-700, 700)]), 3)}"))
            elif r < 0.34:
                note([], "currspeed")
                await c.start(f"{ax}.CURRSPEED={round(rng.uniform(0.5, axes[ax].section.max_velocity), 2)}")
            elif r < 0.38:
                note([ax], "stop")
                await c.start(f"{ax}.STOP=1")
            elif r < 0.43 and started:
                note(every, "abort")   # (which axis it stops is the aborted command's business)
                await c.send(f"{rng.randrange(600000, 900000)} ABORT {rng.choice(started[-20:])}")
            elif r < 0.47:
                ut1 = await c.num("LOCAL.UT1")
                p0 = axes[ax].real_position
                pts = [(ut1 + 0.3 + 0.5 * k, p0 + rng.uniform(-5, 5) * k) for k in range(6)]
                parts = []
                for k, (tt, pp) in enumerate(pts):
                    parts += [f"{ax}.TRAJECTORY.BUFFER[{k}].TIME={tt!r}", f"{ax}.TRAJECTORY.BUFFER[{k}].TARGETPOS={pp!r}"]
                await c.start(";".join(parts))
                await c.start(f"{ax}.TRAJECTORY.ADDPOINTS=6")
                note([ax], "run")
                started.append(await c.start(f"{ax}.TRAJECTORY.RUN=1"))
            elif r < 0.49:
                note([ax], "run0")
                await c.start(f"{ax}.TRAJECTORY.RUN=0")
            elif r < 0.66:
                n = rng.choice((0, 1, 2))
                # the TPL2 commands sent before are applied before this one (a connection's
                # commands run in order: its reply to a GET comes after them)
                await c.value("AZ.REALPOS")
                await tsi.value("TELESCOPE.READY_STATE")
                top = axes[moveaxis[n]].section.max_velocity
                rate = rng.choice([0.0, round(rng.uniform(-top, top), 2)])
                note([moveaxis[n]], "moveaxis-sent")
                moved = axes[moveaxis[n]]
                before = moved.real_position - moved.offset
                reply = await aput(live, "moveaxis", Axis=n, Rate=rate)
                if reply["ErrorNumber"] == 0 and rate != 0.0:
                    note([], "moveaxis", (moveaxis[n], rate, moved.real_position,
                                          (before, moved.real_position - moved.offset)))
            elif r < 0.70:
                note(every, "abortslew")
                await aput(live, "abortslew")
            elif r < 0.74:
                note(every, "slewaltaz")
                await aput(live, "slewtoaltazasync", Azimuth=round(rng.uniform(0, 360), 2),
                           Altitude=round(rng.uniform(-10, 89), 2))
            elif r < 0.78:
                note(every, "tsi-goto")
                await tsi.start(f"OBJECT.HORIZONTAL.AZ={round(rng.uniform(0, 360), 2)};"
                                f"OBJECT.HORIZONTAL.ALT={round(rng.uniform(-10, 89), 2)}")
                await tsi.start("POINTING.TRACK=2")
            elif r < 0.80:
                note(every, "tsi-stop")
                await tsi.start(rng.choice(["TELESCOPE.STOP=1", "POINTING.TRACK=0"]))
            elif r < 0.81 and faults < 6:
                faults += 1
                note([ax], "fault")
                await live.call(sims[ax].inject_fault, "following_error")
            elif r < 0.86:
                note([ax], "ack")
                await c.start(f"{ax}.ERROR_STATE=0")
                await c.start(f"{ax}.POWER=1")
            else:
                await asyncio.sleep(rng.uniform(0.0, 0.03))
            if i % 50 == 0:   # read what piled up (and give the loop a breath)
                await c.value("AZ.REALPOS")
                await tsi.value("TELESCOPE.READY_STATE")
                c.lines.clear()
                tsi.lines.clear()
        note(every, "end")
        await c.set("CABINET.STOP=1")
        for ax in every:
            await c.wait(f"{ax}.MOTION_STATE", lambda v: not int(v) & MOVING, WAIT)
        end = time.monotonic()

        problems = []
        period = t.control_loop.source.period
        for ax in every:
            sec = axes[ax].section
            records = list(sims[ax].csp_targets)
            vmax_step = sec.max_velocity * period * (1 + 1e-6) + 1e-9
            for (t0, p0, _), (t1, p1, cont) in zip(records, records[1:]):
                if not sec.min - 1e-9 <= p1 <= sec.max + 1e-9:
                    problems.append(f"{ax}: CSP target {p1} outside [{sec.min}, {sec.max}]")
                if cont and abs(p1 - p0) > vmax_step:
                    problems.append(f"{ax}: step {p1 - p0:.5f} > {vmax_step:.5f} at {t1:.3f}")
            # MoveAxis windows: from the reply to the next command that touches the axis
            for k, (t0, _, kind, detail) in enumerate(log):
                if kind != "moveaxis" or detail[0] != ax:
                    continue
                _, rate, z0, (zd0, zd1) = detail
                t_end = next((tt for tt, touched, _, _ in log[k + 1:] if ax in touched), end)
                sign = 1 if rate > 0 else -1
                if ax == "ZD" and t.pointing.mount == "AZ-ZD":
                    # altitude: up is towards CURRPOS 0 (REALPOS − OFFSET, the ZD the front end
                    # judges the side of the zenith by); which side is unknown when the axis
                    # crossed it while the request was under way
                    sign = -1 if (zd0 >= 0) == (rate > 0) else 1
                    if (zd0 >= 0) != (zd1 >= 0):
                        sign = 0   # (no direction judged; the horizon still is)
                window = [(tt, p, cont) for tt, p, cont in records if t0 <= tt < t_end]
                # (judged up to a SYNC the drive bridged by itself, the host stalled: running
                # on at the stream's speed it may pass the move's end before the TCS is back,
                # which then stops there and returns — the stall tests judge that case:
                # test_a_stall_while_moveaxis_brakes_at_the_horizon_never_passes_it,
                # tests/vcan/test_stall_recovery.py)
                gap = next((k for k, (_, _, cont) in enumerate(window) if k and not cont), None)
                window = window[:gap]
                went = False
                for (ta, pa, _), (tb, pb, _) in (zip(window, window[1:]) if sign else ()):
                    if sign * (pb - pa) > 1e-9:
                        went = True
                    elif went and sign * (pb - pa) < -BACKSTEP:
                        problems.append(f"{ax}: MoveAxis({rate}) stepped back {pb - pa:.6f} at {tb:.3f}")
                        break
                if ax == "ZD" and t.pointing.mount == "AZ-ZD":
                    allowed = max(t.pointing.zd_limit, abs(z0)) + 1e-6
                    over = [p for _, p, _ in window if abs(p) > allowed]
                    if over:
                        problems.append(f"ZD: MoveAxis({rate}) below the horizon: {max(map(abs, over))}")
        assert not problems, problems[:10]
        kinds = {kind for _, _, kind, _ in log}
        assert {"moveaxis", "targetpos", "run", "abort", "fault"} <= kinds, kinds
        assert sum(1 for _, _, kind, _ in log if kind == "moveaxis") > 50
    finally:
        stream.__exit__()
        for ax in ("AZ", "ZD"):
            try:
                await c.set(f"{ax}.CURRSPEED={t.axis(ax).section.max_velocity}")
            except Exception:
                pass
        await c.close()
        await tsi.close()
