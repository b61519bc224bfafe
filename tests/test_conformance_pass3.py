"""Issue 24 (OpenTCI/TPL2 conformance pass 3), the axis items, over a real TPL2 socket against
the simulated telescope (``hwconfig/sim.toml``, whose filter wheel homes 0.125 deg past its
port, and the fast ``tests/hw_axes_fast.toml``).

1  TARGETPOS before referencing reads where the axis is (TARGETDISTANCE 0 at rest).
2  FREEPOINTS is the whole capacity once a trajectory ended; right after RUN=0 no MOTION_STATE
   bit 1.
3  ADDPOINTS that cannot be done (non-increasing times, more points than fit) is FAILED n,
   not RANGE (RANGE is the !MIN/!MAX check only).
5  MOTION_STATE bit 3 on FILTER[2] at rest after referencing.
9  SERVER (TPL2 §9): ACCOUNTS.USERNAMES/BLOCKED/UNBLOCKED and the MODIFY form, CLIENT[] read at
   level 0 only, LOG.CLEAR/EVENTMASK written at level 0, INFO.FLAGS a string, "no restriction"
   readable by any login (levels 10 10 too).
11 A ZD-ZD telescope ships (``hwconfig/sim-zdzd.toml``): ZD[2] and the azimuth rotator
   DEROTATOR[0] served and moving, POINTING absent (README: why).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from support.live import LiveService
from support.opentci_client import Client, upload
from support.service import start_service
from support.tpl2 import RawClient

FAST = Path(__file__).with_name("hw_axes_fast.toml")
ZDZD = Path(__file__).resolve().parent.parent / "hwconfig" / "sim-zdzd.toml"
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


# ------------------------------------------------------------------ item 9


async def auth(port: int, user: str, password: str, levels: str = "") -> tuple[RawClient, str]:
    c = await RawClient.connect(port, login=None)
    await c.send(f'AUTH PLAIN "{user}" "{password}"{" " + levels if levels else ""}')
    return c, await c.readline()


async def test_server_levels_flags_client_and_log(live):
    port = live
    anyone, reply = await auth(port, "admin", "admin", "10 10")
    assert reply == "AUTH OK 10 10"
    lines = await anyone.command(1, "GET SERVER.CONNECTION.RLEVEL;SERVER.CONNECTION.WLEVEL;SERVER.INFO.FLAGS;"
                                    "SERVER.CONNECTION.RLEVEL!RLEVEL")
    assert lines[1:-1] == ["1 DATA INLINE SERVER.CONNECTION.RLEVEL=10", "1 DATA INLINE SERVER.CONNECTION.WLEVEL=10",
                           '1 DATA INLINE SERVER.INFO.FLAGS=""', "1 DATA INLINE SERVER.CONNECTION.RLEVEL!RLEVEL=9"]
    assert await anyone.get("SERVER.INFO.FLAGS!TYPE") == "3"
    # its own per-connection settings have no restriction either; operating has
    assert (await anyone.command(2, "SET SERVER.CONNECTION.EVENTMASK=0"))[1] == \
        "2 DATA OK SERVER.CONNECTION.EVENTMASK"
    assert (await anyone.command(3, "SET AZ.STOP=1"))[1] == "3 DATA ERROR AZ.STOP DENIED"
    config, reply = await auth(port, "admin", "admin", "1 1")
    assert reply == "AUTH OK 1 1"
    admin = await RawClient.connect(port)
    for c, ok in ((anyone, False), (config, False), (admin, True)):
        lines = await c.command(4, "GET SERVER.CLIENT[0].ID;SERVER.CLIENT[0].USERNAME;SERVER.ACCOUNTS.USERNAMES")
        if ok:
            assert all("DENIED" not in x for x in lines), lines
        else:
            assert lines[1:-1] == ["4 DATA INLINE SERVER.CLIENT[0].ID=DENIED",
                                   "4 DATA INLINE SERVER.CLIENT[0].USERNAME=DENIED",
                                   "4 DATA INLINE SERVER.ACCOUNTS.USERNAMES=DENIED"], lines
        for n, obj in ((5, "SERVER.LOG.CLEAR=1"), (6, "SERVER.LOG.EVENTMASK=15")):
            lines = await c.command(n, f"SET {obj}")
            name = obj.split("=")[0]
            assert lines[1] == (f"{n} DATA OK {name}" if ok else f"{n} DATA ERROR {name} DENIED"), lines
    assert await admin.get("SERVER.LOG.CLEAR!WLEVEL") == "0"
    assert await admin.get("SERVER.CLIENT[0].ID!RLEVEL") == "0"
    for c in (anyone, config, admin):
        await c.close()


async def test_accounts_modify_form(live):
    port = live
    c = await RawClient.connect(port)
    m = "SERVER.ACCOUNTS.MODIFY"
    try:
        assert await c.get("SERVER.ACCOUNTS.USERNAMES") == '"admin"'
        assert await c.get("SERVER.ACCOUNTS.MODIFY!MEMBERS") == "12"
        # a new account through the form
        lines = await c.command(1, f'SET {m}.USERNAME="obs9";{m}.NAME="Night observer";{m}.PASSWORD="pw9";'
                                   f'{m}.MIN_RLEVEL=3;{m}.MIN_WLEVEL=3;{m}.DEFAULT_RLEVEL=5;{m}.DEFAULT_WLEVEL=6;'
                                   f'{m}.TYPE=0;{m}.ADD=1', timeout=30)
        assert lines[-2:] == [f"1 DATA OK {m}.ADD", "1 COMMAND COMPLETE"], lines
        assert await c.get(f"{m}.PASSWORD") == "DENIED"  # write-only
        assert await c.get("SERVER.ACCOUNTS.USERNAMES") == '"admin,obs9"'
        assert await c.get("SERVER.ACCOUNTS.UNBLOCKED") == '"admin,obs9"'
        assert await c.get("SERVER.ACCOUNTS.BLOCKED") == '""'
        # a login asking for no levels gets the defaults, never more than the minimum
        for levels, expect in (("", "AUTH OK 5 6"), ("4 4", "AUTH OK 4 4"), ("0 0", "AUTH OK 3 3")):
            o, reply = await auth(port, "obs9", "pw9", levels)
            assert reply == expect, (levels, reply)
            await o.close()
        # it exists now: ADD is an action that cannot be done (FAILED), not a value out of range
        lines = await c.command(2, f"SET {m}.ADD=1")
        assert lines[-2:] == [f"2 DATA ERROR {m}.ADD FAILED 5", "2 COMMAND COMPLETE"], lines
        assert (await c.command(3, f"SET {m}.TYPE=1"))[1] == f"3 DATA ERROR {m}.TYPE RANGE"
        # another connection's form is its own; writing USERNAME loads the account
        other = await RawClient.connect(port)
        assert await other.get(f"{m}.USERNAME") == '""'
        assert (await other.command(4, f'SET {m}.USERNAME="obs9"'))[1] == f"4 DATA OK {m}.USERNAME"
        lines = await other.command(5, f"GET {m}.NAME;{m}.MIN_RLEVEL;{m}.MIN_WLEVEL;{m}.DEFAULT_RLEVEL;"
                                       f"{m}.DEFAULT_WLEVEL;{m}.BLOCKED")
        assert [x.split("=", 1)[1] for x in lines[1:-1]] == ['"Night observer"', "3", "3", "5", "6", "0"], lines
        # UPDATE: block it and change its password
        lines = await other.command(6, f'SET {m}.BLOCKED=1;{m}.PASSWORD="pw10";{m}.UPDATE=1', timeout=30)
        assert lines[-2:] == [f"6 DATA OK {m}.UPDATE", "6 COMMAND COMPLETE"], lines
        assert (await auth(port, "obs9", "pw10"))[1] == "AUTH FAILED"
        assert await c.get("SERVER.ACCOUNTS.BLOCKED") == '"obs9"'
        assert (await c.command(7, 'SET SERVER.ACCOUNTS.UNBLOCKED="obs9"'))[1] == \
            "7 DATA OK SERVER.ACCOUNTS.UNBLOCKED"
        o, reply = await auth(port, "obs9", "pw10")
        assert reply == "AUTH OK 5 6"
        await o.close()
        # the hardware file's user: not removed, never more privilege than the file gives
        assert (await other.command(8, f'SET {m}.USERNAME="admin";{m}.REMOVE=1'))[-2] == \
            f"8 DATA ERROR {m}.REMOVE FAILED 5"
        # REMOVE of the TPL2 account
        lines = await other.command(9, f'SET {m}.USERNAME="obs9";{m}.REMOVE=1')
        assert lines[-2:] == [f"9 DATA OK {m}.REMOVE", "9 COMMAND COMPLETE"], lines
        assert await c.get("SERVER.ACCOUNTS.USERNAMES") == '"admin"'
        assert (await auth(port, "obs9", "pw10"))[1] == "AUTH FAILED"
        await other.close()
        # the string shortcuts that do not collide with §9 stay
        assert await c.get("SERVER.ACCOUNTS.LIST") == '"admin:0:0:0:file"'
    finally:
        await c.close()


# ------------------------------------------------------------------ item 11


async def test_zd_zd_telescope_serves_its_axes_and_no_pointing(tmp_path):
    svc, port = await start_service(tmp_path / "state", ZDZD)
    c = await Client.connect(port)
    try:
        lines = await c.command(1, "GET CONFIG.MOUNT;CONFIG.MOUNTOPTIONS;CONFIG.ORIENTATION;ZD!COUNT;ZD!CLASS;"
                                   "DEROTATOR!COUNT;AZ.VERSION;POINTING.TRACK;HA.VERSION")
        assert lines[1:-1] == ['1 DATA INLINE CONFIG.MOUNT="ZD-ZD"', '1 DATA INLINE CONFIG.MOUNTOPTIONS="ZD-ZD"',
                               "1 DATA INLINE CONFIG.ORIENTATION=0.0", "1 DATA INLINE ZD!COUNT=2",
                               "1 DATA INLINE ZD!CLASS=1003", "1 DATA INLINE DEROTATOR!COUNT=1",
                               "1 DATA INLINE AZ.VERSION=UNKNOWN", "1 DATA INLINE POINTING.TRACK=UNKNOWN",
                               "1 DATA INLINE HA.VERSION=UNKNOWN"], lines
        # the two ZD axes and the rotator are whole generic axes (same members as AZ-ZD's ZD)
        assert await c.get("ZD[0]!MEMBERS") == await c.get("ZD[1]!MEMBERS") == await c.get("DEROTATOR[0]!MEMBERS")
        for ax in ("ZD[0]", "ZD[1]", "DEROTATOR[0]"):
            assert int(await c.num(f"{ax}.TYPE")) >= 1
            await c.wait(f"{ax}.REALPOS", lambda v: isinstance(v, float), WAIT)
            real, target = await c.nums(f"{ax}.REALPOS", f"{ax}.TARGETPOS")
            assert target == real, (ax, real, target)
        assert await c.nums("ZD[0].REALPOS", "ZD[1].REALPOS") == [10.0, -5.0]
        await ready(c, "ZD[0]", "ZD[1]")
        assert await c.nums("ZD[0].REALPOS", "ZD[1].REALPOS") == [pytest.approx(10.0, abs=0.01),
                                                                  pytest.approx(-5.0, abs=0.01)]
        lines = await c.set("ZD[0].TARGETPOS=10.5;ZD[1].TARGETPOS=-5.5", WAIT)
        assert ok(lines, "ZD[0].TARGETPOS") and ok(lines, "ZD[1].TARGETPOS"), lines
        assert await c.nums("ZD[0].REALPOS", "ZD[1].REALPOS") == [pytest.approx(10.5, abs=0.01),
                                                                  pytest.approx(-5.5, abs=0.01)]
        lines = await c.command(2, "SET ZD[1].TARGETPOS=86")
        assert lines[-2:] == ["2 DATA ERROR ZD[1].TARGETPOS RANGE", "2 COMMAND COMPLETE"], lines
        assert int(await c.num("ZD[1].TRAJECTORY.FREEPOINTS")) > 0
    finally:
        await c.close()
        await svc.stop()
