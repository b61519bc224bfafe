"""Issue 24 (OpenTCI/TPL2 conformance pass 3), the axis items, over a real TPL2 socket against
the simulated telescope (``hwconfig/sim.toml``, whose filter wheel homes 0.125 deg past its
port, and the fast ``tests/hw_axes_fast.toml``).

1  TARGETPOS before referencing reads where the axis is (TARGETDISTANCE 0 at rest).
2  FREEPOINTS is the whole capacity once a trajectory ended; right after RUN=0 no MOTION_STATE
   bit 1.
3  ADDPOINTS that cannot be done (non-increasing times, more points than fit) is FAILED n,
   not RANGE (RANGE is the !MIN/!MAX check only).
5  MOTION_STATE bit 3 on FILTER[2] at rest after referencing.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from support.live import LiveService
from support.opentci_client import Client, upload
from support.service import start_service

FAST = Path(__file__).with_name("hw_axes_fast.toml")
WAIT = 60.0  # generous: behaviour, not timing
MOVING, TRAJ, ON_TARGET = 1, 2, 8


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    service = LiveService(FAST, tmp_path_factory.mktemp("pass3")).start()
    try:
        yield service.port
    finally:
        service.stop()


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; `live` checks at the end
    yield


def ok(lines: list[str], obj: str) -> bool:
    return any(x.endswith(f"DATA OK {obj}") for x in lines) and lines[-1].endswith("COMMAND COMPLETE")


async def ready(c: Client, *axes: str) -> None:
    if await c.get("CABINET.POWER_STATE") != "1.0":
        assert ok(await c.set("CABINET.POWER=1", WAIT), "CABINET.POWER")
    for ax in axes:
        if await c.num(f"{ax}.POWER_STATE") != 1.0:
            assert ok(await c.set(f"{ax}.POWER=1", WAIT), f"{ax}.POWER")
        if await c.num(f"{ax}.REFERENCED") != 1.0:
            await c.set(f"{ax}.REINIT=1")
    for ax in axes:
        await c.wait(f"{ax}.REFERENCED", lambda v: v == 1.0, WAIT)
        await c.wait(f"{ax}.MOTION_STATE", lambda v: not int(v) & MOVING, WAIT)


# ------------------------------------------------------------------ items 1 and 5


async def test_targetpos_before_referencing_and_filter_on_target_after(tmp_path):
    svc, port = await start_service(tmp_path / "state")  # hwconfig/sim.toml: a fresh server
    c = await Client.connect(port)
    try:
        for ax in ("AZ", "ZD", "FOCUS", "MIRROR"):
            await c.wait(f"{ax}.REALPOS", lambda v: isinstance(v, float), WAIT)  # drive booted
            lines = await c.command(7, f"GET {ax}.REALPOS;{ax}.TARGETPOS;{ax}.TARGETDISTANCE;{ax}.REALPOS!MIN")
            values = [float(x.split("=", 1)[1]) for x in lines[1:-1]]
            real, target, distance, lo = values
            assert real != 0.0, lines  # (the simulated axes do not start at 0)
            assert target == real and distance == 0.0, lines
            assert target >= lo, lines  # MIRROR: 2.0, its !MIN, not 0.0
        # item 5: the filter wheel homes past its port; referenced means on the port, on target
        assert ok(await c.set("CABINET.POWER=1", WAIT), "CABINET.POWER")
        await c.set("FILTER[2].REINIT=1")
        await c.wait("FILTER[2].REFERENCED", lambda v: v == 1.0, WAIT)
        lines = await c.command(8, "GET FILTER[2].MOTION_STATE;FILTER[2].REALPOS;FILTER[2].TARGETPOS;"
                                   "FILTER[2].TARGETDISTANCE")
        assert lines[1:-1] == ["8 DATA INLINE FILTER[2].MOTION_STATE=8", "8 DATA INLINE FILTER[2].REALPOS=0.0",
                               "8 DATA INLINE FILTER[2].TARGETPOS=0.0",
                               "8 DATA INLINE FILTER[2].TARGETDISTANCE=0.0"], lines
        # and it moves between ports as before, on target at each
        assert ok(await c.set("FILTER[2].TARGETPOS=1", WAIT), "FILTER[2].TARGETPOS")
        assert await c.get("FILTER[2].MOTION_STATE") == "8"
    finally:
        await c.close()
        await svc.stop()


# ------------------------------------------------------------------ item 2


async def test_freepoints_full_after_the_end_and_no_trajectory_bit_after_run_0(live):
    c = await Client.connect(live)
    try:
        await ready(c, "AZ")
        free = int(await c.num("AZ.TRAJECTORY.FREEPOINTS"))
        p0 = await c.num("AZ.REALPOS")
        t0 = await c.num("LOCAL.UT1") + 1.0
        assert ok(await upload(c, "AZ", [(t0 + 0.25 * i, p0 + 0.01 * i) for i in range(8)]),
                  "AZ.TRAJECTORY.ADDPOINTS")
        assert ok(await c.set("AZ.TRAJECTORY.RUN=1", WAIT), "AZ.TRAJECTORY.RUN")
        # the trajectory ended by itself: every point is free again, without RUN=0
        assert await c.get("AZ.TRAJECTORY.FREEPOINTS") == str(free)
        # RUN=0 while the axis follows a path: the trajectory is over at the reply
        p1 = await c.num("AZ.REALPOS")
        t1 = await c.num("LOCAL.UT1") + 0.5
        assert ok(await upload(c, "AZ", [(t1 + i, p1 + 2.0 * i) for i in range(20)]), "AZ.TRAJECTORY.ADDPOINTS")
        run = await c.start("AZ.TRAJECTORY.RUN=1")
        await c.wait("AZ.MOTION_STATE", lambda v: int(v) & MOVING and int(v) & TRAJ, WAIT)
        lines = await c.command(5, "SET AZ.TRAJECTORY.RUN=0")
        assert "5 DATA OK AZ.TRAJECTORY.RUN" in lines, lines
        lines = await c.command(6, "GET AZ.MOTION_STATE;AZ.TRAJECTORY.RUN;AZ.TRAJECTORY.FREEPOINTS")
        state = int(lines[1].split("=", 1)[1])
        assert not state & TRAJ, lines
        assert lines[2:4] == ["6 DATA INLINE AZ.TRAJECTORY.RUN=0", f"6 DATA INLINE AZ.TRAJECTORY.FREEPOINTS={free}"]
        await c.until(run, WAIT)
        await c.wait("AZ.MOTION_STATE", lambda v: not int(v) & MOVING, WAIT)
    finally:
        await c.close()


# ------------------------------------------------------------------ item 3


async def test_addpoints_that_cannot_be_done_is_failed_not_range(live):
    c = await Client.connect(live)
    try:
        await ready(c, "AZ")
        free = int(await c.num("AZ.TRAJECTORY.FREEPOINTS"))
        p0 = await c.num("AZ.REALPOS")
        t0 = await c.num("LOCAL.UT1") + 100.0
        # two points with the same time
        lines = await c.set(f"AZ.TRAJECTORY.BUFFER[0].TIME={t0!r};AZ.TRAJECTORY.BUFFER[1].TIME={t0!r};"
                            f"AZ.TRAJECTORY.BUFFER[0-1].TARGETPOS={p0!r},{p0!r}")
        assert all(" DATA OK " in x for x in lines[1:-1]), lines
        lines = await c.command(11, "SET AZ.TRAJECTORY.ADDPOINTS=2")
        assert lines[-2:] == ["11 DATA ERROR AZ.TRAJECTORY.ADDPOINTS FAILED 11", "11 COMMAND COMPLETE"], lines
        # more points than the buffer holds
        lines = await c.command(12, f"SET AZ.TRAJECTORY.ADDPOINTS={free + 1}")
        assert lines[-2:] == ["12 DATA ERROR AZ.TRAJECTORY.ADDPOINTS FAILED 12", "12 COMMAND COMPLETE"], lines
        # more points than are free (the queue holds some already)
        assert ok(await upload(c, "AZ", [(t0 + i, p0) for i in range(free - 1)]), "AZ.TRAJECTORY.ADDPOINTS")
        lines = await upload(c, "AZ", [(t0 + 1000.0, p0), (t0 + 1001.0, p0)])
        assert lines[-2:] == [f"{lines[0].split()[0]} DATA ERROR AZ.TRAJECTORY.ADDPOINTS FAILED 12",
                              f"{lines[0].split()[0]} COMMAND COMPLETE"], lines
        # RANGE is the configured range check only
        lines = await c.command(13, "SET AZ.TRAJECTORY.ADDPOINTS=0")
        assert lines[-2:] == ["13 DATA ERROR AZ.TRAJECTORY.ADDPOINTS RANGE", "13 COMMAND COMPLETE"], lines
        assert ok(await c.set("AZ.TRAJECTORY.RUN=0"), "AZ.TRAJECTORY.RUN")
        assert await c.get("AZ.TRAJECTORY.FREEPOINTS") == str(free)
    finally:
        await c.close()
