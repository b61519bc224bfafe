"""Issue 12, OpenTCI behaviour items 9-12, over a real socket on the fast simulated telescope
(``tests/hw_axes_fast.toml``, in-process, one service per test).

9  FREEPOINTS rises again as points are executed and after a run ends.
10 TARGETPOS reads the current position once referenced (TARGETDISTANCE 0 at rest).
11 MOTION_STATE bit 3 (on target) at rest on discrete axes once referenced; RUN reads 0 as
   soon as RUN=0 answered.
12 Every refused request also sends its event (OpenTCI §4).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from support.opentci_client import Client, upload
from support.service import start_service

FAST = Path(__file__).with_name("hw_axes_fast.toml")
WAIT = 30.0  # generous: behaviour, not timing
ON_TARGET, MOVING, TRAJ = 8, 1, 2


@pytest.fixture
async def fast(tmp_path):
    svc, port = await start_service(tmp_path / "state", FAST)
    c = await Client.connect(port)
    try:
        yield c
    finally:
        await c.close()
        await svc.stop()


def ok(lines: list[str], obj: str) -> bool:
    return any(x.endswith(f"DATA OK {obj}") for x in lines) and lines[-1].endswith("COMMAND COMPLETE")


async def ready(c: Client, *axes: str) -> None:
    assert ok(await c.set("CABINET.POWER=1", 60), "CABINET.POWER")
    for ax in axes:
        if await c.num(f"{ax}.POWER_STATE") != 1.0:
            assert ok(await c.set(f"{ax}.POWER=1", WAIT), f"{ax}.POWER")
        await c.set(f"{ax}.REINIT=1")
    for ax in axes:
        await c.wait(f"{ax}.REFERENCED", lambda v: v == 1.0, WAIT)
        await c.wait(f"{ax}.MOTION_STATE", lambda v: not int(v) & MOVING, WAIT)


# ------------------------------------------------------------------ item 9


async def test_freepoints_rise_while_running_and_after_the_end(fast):
    c = fast
    await ready(c, "AZ")
    free = int(await c.num("AZ.TRAJECTORY.FREEPOINTS"))
    p0 = await c.num("AZ.REALPOS")
    t0 = await c.num("LOCAL.UT1") + 1.0
    points = [(t0 + 0.25 * i, p0 + 0.01 * i) for i in range(12)]
    assert ok(await upload(c, "AZ", points), "AZ.TRAJECTORY.ADDPOINTS")
    assert await c.num("AZ.TRAJECTORY.FREEPOINTS") == free - 12
    run = await c.start("AZ.TRAJECTORY.RUN=1")
    await c.wait("AZ.TRAJECTORY.FREEPOINTS", lambda v: free - 12 < v < free - 1, WAIT)  # rising
    assert ok(await c.until(run, WAIT), "AZ.TRAJECTORY.RUN")
    # all executed: every point is free again (issue 24 item 2: the one the path ended on too)
    assert await c.num("AZ.TRAJECTORY.FREEPOINTS") == free
    # a full buffer fits again, without RUN=0 first
    t1 = await c.num("LOCAL.UT1") + 1.0
    p1 = await c.num("AZ.REALPOS")
    lines = await upload(c, "AZ", [(t1 + 0.25 * i, p1) for i in range(free)])
    assert ok(lines, "AZ.TRAJECTORY.ADDPOINTS"), lines
    assert await c.num("AZ.TRAJECTORY.FREEPOINTS") == 0
    assert ok(await c.set("AZ.TRAJECTORY.RUN=0"), "AZ.TRAJECTORY.RUN")
    assert await c.num("AZ.TRAJECTORY.FREEPOINTS") == free


# ------------------------------------------------------------------ items 10, 11


async def test_targetpos_and_on_target_after_referencing(fast):
    c = fast
    axes = ("AZ", "FOCUS", "MIRROR", "FILTER[2]")
    await ready(c, *axes)
    for ax in axes:
        real, target, distance, state = await c.nums(f"{ax}.REALPOS", f"{ax}.TARGETPOS",
                                                     f"{ax}.TARGETDISTANCE", f"{ax}.MOTION_STATE")
        assert target == pytest.approx(real, abs=0.01), (ax, real, target)
        assert abs(distance) <= 0.01, (ax, distance)
        lo = await c.num(f"{ax}.REALPOS!MIN")
        hi = await c.num(f"{ax}.REALPOS!MAX")
        assert lo <= target <= hi, (ax, target, lo, hi)
        assert int(state) & ON_TARGET, (ax, state)


async def test_run_reads_zero_once_run_0_answered(fast):
    c = fast
    await ready(c, "AZ")
    p0 = await c.num("AZ.REALPOS")
    t0 = await c.num("LOCAL.UT1") + 0.5
    assert ok(await upload(c, "AZ", [(t0 + i, p0 + 0.5 * i) for i in range(20)]), "AZ.TRAJECTORY.ADDPOINTS")
    run = await c.start("AZ.TRAJECTORY.RUN=1")
    await c.wait("AZ.MOTION_STATE", lambda v: int(v) & MOVING, WAIT)
    for _ in range(3):
        lines = await c.command(5, "SET AZ.TRAJECTORY.RUN=0")
        assert "5 DATA OK AZ.TRAJECTORY.RUN" in lines, lines
        assert await c.get("AZ.TRAJECTORY.RUN") == "0"
    await c.until(run, WAIT)


# ------------------------------------------------------------------ item 12


def event_before_error(lines: list[str], cmd: int, obj: str, source: str, number: int) -> None:
    error = next(i for i, x in enumerate(lines) if x.startswith(f"{cmd} DATA ERROR {obj} FAILED {number}"))
    assert any(re.match(rf"{cmd} EVENT ERROR {re.escape(source)}:{number}( |$)", x) for x in lines[:error]), lines


async def test_every_refused_request_sends_its_event(fast):
    c = fast
    lines = await c.command(1, "SET AZ.TARGETPOS=10")  # power off: 5 invmode
    event_before_error(lines, 1, "AZ.TARGETPOS", "AZ", 5)
    await ready(c, "AZ")
    lines = await c.command(2, "SET AZ.TRAJECTORY.RUN=1", WAIT)  # no points: 11 nopoints
    event_before_error(lines, 2, "AZ.TRAJECTORY.RUN", "AZ", 11)
    # a full queue: 12 nobuffer
    free = int(await c.num("AZ.TRAJECTORY.FREEPOINTS"))
    t0 = await c.num("LOCAL.UT1") + 1000.0
    p0 = await c.num("AZ.REALPOS")
    assert ok(await upload(c, "AZ", [(t0 + i, p0) for i in range(free)]), "AZ.TRAJECTORY.ADDPOINTS")
    await c.set(f"AZ.TRAJECTORY.BUFFER[0].TIME={t0 + free};AZ.TRAJECTORY.BUFFER[0].TARGETPOS={p0}")
    lines = await c.command(3, "SET AZ.TRAJECTORY.ADDPOINTS=1")
    event_before_error(lines, 3, "AZ.TRAJECTORY.ADDPOINTS", "AZ", 12)
    assert ok(await c.set("AZ.TRAJECTORY.RUN=0"), "AZ.TRAJECTORY.RUN")
    # a TARGETPOS cancelled by STOP
    await c.send(f"4 SET AZ.TARGETPOS={p0 + 90.0}")
    await c.wait("AZ.MOTION_STATE", lambda v: int(v) & MOVING, WAIT)
    assert ok(await c.set("AZ.STOP=1"), "AZ.STOP")
    lines = await c.until(4, WAIT)
    event_before_error(lines, 4, "AZ.TARGETPOS", "AZ", 10)
    # a superseded target is announced once (by the axis), not twice
    await c.send(f"5 SET AZ.TARGETPOS={p0 + 90.0}")
    await c.wait("AZ.MOTION_STATE", lambda v: int(v) & MOVING, WAIT)
    lines6 = await c.command(6, f"SET AZ.TARGETPOS={p0}", WAIT)
    lines = await c.until(5, WAIT)
    assert len([x for x in lines if re.match(r"5 EVENT ERROR AZ:10\b", x)]) == 1, lines
    assert ok(lines6, "AZ.TARGETPOS")
