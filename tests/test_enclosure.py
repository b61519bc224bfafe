"""DOME[], COVER, SENSOR[], SWITCH[] and the weather interlock over TPL2 against the simulated
PLCs: the real service, its PLCs simulated as Modbus TCP servers in the same process, a TPL2
client on a real socket.

Most tests share one service (module scope, on its own event-loop thread) running
``tests/hw_enclosure.toml``: fast dome and covers, quick polls, a quick interlock release.
Each test first brings what it uses into a known state (weather good, faults acknowledged,
power on) and never relies on where an earlier test left things. Faults and weather are
injected into the simulated hardware on the service's loop (``live.call``). A few tests start
their own service: the bundled ``hwconfig/sim.toml`` and the roll-roof example. Nothing here
depends on timing: every wait is for a state or a line, with generous limits.
"""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support.live import live_service
from support.opentci_client import WAIT, Client, done_ok, failed
from support.service import make_config, start_service, tolerant_heartbeats
from support.waits import until_async
from tcs.app import Service
from tcs.config import parse_config
from tcs.config.hwconfig import PACKAGE_ROOT
from tcs.errors import ConfigErrors

HW = Path(__file__).with_name("hw_enclosure.toml")
ROLLROOF = PACKAGE_ROOT / "hwconfig" / "sim-rollroof.toml"
MOVING, TRAJ, BLOCKED, ON_TARGET = 1, 2, 4, 8
HW_MIN, HW_MAX, SW_MIN, SW_MAX = 1, 2, 256, 512
ERROR_BIT, WARNING_BIT = 2, 4


live = live_service(HW)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


def sim(live, plc: str):
    return live.telescope.peripherals.sims.plcs[plc]


@pytest.fixture
async def c(live):
    """A client on the shared service, with the simulated weather and PLCs back to normal."""
    for plc in ("dome", "telescope"):
        s = sim(live, plc)
        await live.call(s.power_on)
        await live.call(s.set_responding, True)
        for point in ("rain", "wind_speed"):
            if point in s.points:
                await live.call(s.release, point)
        for axis in s.axes:
            await live.call(s.stall, axis, False)
    client = await Client.connect(live.port)
    yield client
    await client.close()


async def ready(c: Client, *modules: str) -> None:
    """Main power on; each module: errors acknowledged once their causes are gone (a PLC back,
    the interlock released), power on, at rest."""
    if await c.value("CABINET.POWER_STATE") != "1.0":
        assert done_ok(await c.set("CABINET.POWER=1"), "CABINET.POWER")
    for m in modules:
        deadline = time.monotonic() + WAIT
        while int(await c.num(f"{m}.ERROR_STATE")):
            assert time.monotonic() < deadline, f"{m} keeps an error"
            await c.set(f"{m}.ERROR_STATE=0")
            await asyncio.sleep(0.05)
        if await c.num(f"{m}.POWER_STATE") != 1.0:
            assert done_ok(await c.set(f"{m}.POWER=1"), f"{m}.POWER")
        await c.wait(f"{m}.MOTION_STATE", lambda v: not int(v) & MOVING)
    c.forget()


def has(lines: list[str], text: str) -> bool:
    return any(line.endswith(text) for line in lines)


async def answer(c: Client, obj: str) -> str:
    """The value of a GET, or its error keyword (``UNKNOWN``, ``INVALID`` …)."""
    lines = await c.command(7, f"GET {obj}")
    m = re.match(rf"7 DATA (?:INLINE {re.escape(obj)}=(.*)|ERROR {re.escape(obj)} (.*))$", lines[1])
    assert m, lines
    return m.group(1) if m.group(1) is not None else m.group(2)


async def sample_until_done(c: Client, cmd: int, watcher: Client, *objs: str) -> list[tuple]:
    """Values of ``objs`` read over ``watcher`` until command ``cmd`` ended; each sample ends
    with whether ``cmd``'s DATA line had arrived before it was taken."""
    samples = []
    while not c.seen(rf"^{cmd} COMMAND (COMPLETE|FAILED)"):
        answered = bool(c.seen(rf"^{cmd} DATA "))
        samples.append((*await watcher.nums(*objs), answered))
        try:
            c.lines.append(await c._read(0.01))
        except asyncio.TimeoutError:
            pass
    return samples


async def move(c: Client, m: str, target: float) -> list[str]:
    lines = await c.set(f"{m}.TARGETPOS={target}")
    assert done_ok(lines, f"{m}.TARGETPOS"), lines
    return lines


# ------------------------------------------------------------------------------ the tree


async def test_dome_and_cover_modules_as_configured(c):
    """A classic dome: CAPABILITIES rotation|slit|flap|seal, four DOME[] generic axes, only
    DOME[0] cyclic with a TRAJECTORY; one cover is the plain module COVER; PLC axes are
    referenced and take no speed limit."""
    assert await c.value("CONFIG.DOME.CAPABILITIES") == "15"
    assert await c.value("CONFIG.DOME.DIAMETER") == "6.5"
    assert await c.value("DOME!COUNT") == "4"
    assert await c.value("DOME[0].CYCLIC") == "360.0"
    assert await c.value("DOME[1].CYCLIC") == "0.0"
    assert await c.value("DOME[0].TRAJECTORY.FREEPOINTS") == "120"
    assert await answer(c, "DOME[1].TRAJECTORY.FREEPOINTS") == "UNKNOWN"
    assert await c.value("DOME[1].REALPOS!MAX") == "100.0"
    assert await c.value("DOME[3].REALPOS!MAX") == "1.0"
    for m in ("DOME[0]", "DOME[1]", "DOME[2]", "DOME[3]", "COVER"):
        assert await c.value(f"{m}.REFERENCED") == "1.0"
        assert int(await c.value(f"{m}.VERSION")) >> 16 == 24
    assert await c.value("COVER.REALPOS!MAX") == "90.0"
    assert await answer(c, "COVER[0].REALPOS") == "INVALID"
    lines = await c.set("DOME[1].CURRSPEED=5")
    assert has(lines, "DATA ERROR DOME[1].CURRSPEED DENIED"), lines  # read-only on a PLC part
    lines = await c.set("DOME[1].REINIT=1")
    assert done_ok(lines, "DOME[1].REINIT") and any(":19 " in x for x in lines), lines


# ------------------------------------------------------------------------------ moves


async def test_slit_opens_and_closes_completing_at_the_end_position(live, c):
    """TARGETPOS of the slit completes only at the end position: while pending the slit is seen
    moving between; at the end REALPOS is there, the end switch and software limit bits are
    set and MOTION_STATE says on target."""
    await ready(c, "DOME[1]")
    await move(c, "DOME[1]", 0)
    watcher = await Client.connect(live.port)
    try:
        cmd = await c.start("DOME[1].TARGETPOS=100")
        seen = await sample_until_done(c, cmd, watcher, "DOME[1].REALPOS", "DOME[1].MOTION_STATE")
        lines = await c.until(cmd)
        assert done_ok(lines, "DOME[1].TARGETPOS"), lines
        assert any(0 < p < 100 and int(st) & MOVING for p, st, _ in seen), seen
        assert all(p == pytest.approx(100.0, abs=0.1) for p, _, answered in seen if answered), seen
        pos, state, limit, dist = await c.nums("DOME[1].REALPOS", "DOME[1].MOTION_STATE",
                                               "DOME[1].LIMIT_STATE", "DOME[1].TARGETDISTANCE")
        assert abs(pos - 100) <= 0.1 and abs(dist) <= 0.1
        assert int(state) & ON_TARGET and not int(state) & MOVING
        assert int(limit) & HW_MAX and int(limit) & SW_MAX and not int(limit) & HW_MIN
        assert abs(await live.call(sim(live, "dome").read_point, "slit_position") - 100) <= 0.1

        await move(c, "DOME[1]", 0)
        pos, limit = await c.nums("DOME[1].REALPOS", "DOME[1].LIMIT_STATE")
        assert abs(pos) <= 0.1 and int(limit) & HW_MIN and int(limit) & SW_MIN
    finally:
        await watcher.close()


async def test_cover_petals_move_together(live, c):
    """COVER drives both petals: it completes when both are open, reads closed only when both
    are closed."""
    await ready(c, "COVER")
    await move(c, "COVER", 90)
    s = sim(live, "telescope")
    for petal in ("cover1", "cover2"):
        assert abs(await live.call(s.read_point, f"{petal}_position") - 90) <= 0.1
    assert int(await c.num("COVER.LIMIT_STATE")) & HW_MAX
    await move(c, "COVER", 0)
    for petal in ("cover1", "cover2"):
        assert abs(await live.call(s.read_point, f"{petal}_position")) <= 0.1
    assert await c.num("COVER.REALPOS") == pytest.approx(0.0, abs=0.1)
    assert int(await c.num("COVER.LIMIT_STATE")) & HW_MIN


async def test_dome_rotates_the_short_way_with_an_offset(live, c):
    """DOME[0] moves across north the short way, completes on arrival; OFFSET (DOME[0] only)
    shifts CURRPOS against REALPOS; other parts refuse an OFFSET."""
    await ready(c, "DOME[0]")
    if await c.num("DOME[0].OFFSET") != 0.0:
        assert done_ok(await c.set("DOME[0].OFFSET=0"), "DOME[0].OFFSET")
    await move(c, "DOME[0]", 340)
    watcher = await Client.connect(live.port)
    try:
        cmd = await c.start("DOME[0].TARGETPOS=20")
        positions = [p for p, _ in await sample_until_done(c, cmd, watcher, "DOME[0].REALPOS")]
        assert done_ok(await c.until(cmd), "DOME[0].TARGETPOS")
        assert all(p >= 335 or p <= 25 for p in positions), positions  # never the long way round
        assert await c.num("DOME[0].REALPOS") == pytest.approx(20.0, abs=0.1)

        assert done_ok(await c.set("DOME[0].OFFSET=5"), "DOME[0].OFFSET")
        real, curr, target = await c.nums("DOME[0].REALPOS", "DOME[0].CURRPOS", "DOME[0].TARGETPOS")
        assert real == pytest.approx(25.0, abs=0.1)
        assert curr == pytest.approx(20.0, abs=0.1) and target == pytest.approx(20.0, abs=1e-6)
        await move(c, "DOME[0]", 350)
        assert await c.num("DOME[0].REALPOS") == pytest.approx(355.0, abs=0.1)
        assert done_ok(await c.set("DOME[0].OFFSET=0"), "DOME[0].OFFSET")
        assert await c.num("DOME[0].REALPOS") == pytest.approx(350.0, abs=0.1)
    finally:
        await watcher.close()
    lines = await c.set("DOME[1].OFFSET=1")
    assert has(lines, "DATA ERROR DOME[1].OFFSET DENIED"), lines  # read-only: takes no offset
    assert has(await c.set("COVER.OFFSET=1"), "DATA ERROR COVER.OFFSET DENIED")


async def test_stop_in_mid_move_and_a_newer_target(live, c):
    """A newer TARGETPOS fails the older one with 10 (and an event); STOP fails the pending one
    with 10, the dome comes to rest short of the target and TARGETPOS reads where it rests."""
    await ready(c, "DOME[0]")
    start = await c.num("DOME[0].REALPOS")
    first = await c.start(f"DOME[0].TARGETPOS={(start + 170) % 360}")
    await c.wait("DOME[0].MOTION_STATE", lambda v: int(v) & MOVING)
    second = await c.start(f"DOME[0].TARGETPOS={(start + 160) % 360}")
    assert done_ok(await c.set("DOME[0].STOP=1"), "DOME[0].STOP")
    lines = await c.until(first)
    assert failed(lines, "DOME[0].TARGETPOS") == 10, lines
    assert any(re.match(rf"{first} EVENT ERROR DOME\[0\]:10 ", x) for x in lines), lines
    lines = await c.until(second)
    assert failed(lines, "DOME[0].TARGETPOS") == 10, lines
    await c.wait("DOME[0].MOTION_STATE", lambda v: not int(v) & MOVING)
    rest, target, dist = await c.nums("DOME[0].REALPOS", "DOME[0].TARGETPOS", "DOME[0].TARGETDISTANCE")
    travelled = (rest - start) % 360
    assert 0 < travelled < 159, (start, rest)
    assert target == pytest.approx(rest, abs=0.2) and abs(dist) <= 0.2


async def test_power_off_refuses_moves_and_cabinet_stop_stops(live, c):
    """POWER=0 stops and makes TARGETPOS fail with 5; CABINET.STOP stops every part and fails
    their pending SETs with 10; CABINET.POWER=0/1 switches the parts off and on."""
    await ready(c, "DOME[1]", "DOME[2]")
    assert done_ok(await c.set("DOME[1].POWER=0"), "DOME[1].POWER")
    assert await c.value("DOME[1].POWER_STATE") == "0.0"
    assert failed(await c.set("DOME[1].TARGETPOS=10"), "DOME[1].TARGETPOS") == 5
    assert done_ok(await c.set("DOME[1].POWER=1"), "DOME[1].POWER")

    await move(c, "DOME[2]", 0)
    cmd = await c.start("DOME[2].TARGETPOS=100")  # the slow flap
    await c.wait("DOME[2].MOTION_STATE", lambda v: int(v) & MOVING)
    assert done_ok(await c.set("CABINET.STOP=1"), "CABINET.STOP")
    assert failed(await c.until(cmd), "DOME[2].TARGETPOS") == 10
    await c.wait("DOME[2].MOTION_STATE", lambda v: not int(v) & MOVING)
    assert 0 < await c.num("DOME[2].REALPOS") < 100

    assert done_ok(await c.set("CABINET.POWER=0"), "CABINET.POWER")
    for m in ("DOME[0]", "DOME[1]", "DOME[2]", "DOME[3]", "COVER"):
        assert await c.value(f"{m}.POWER_STATE") == "0.0"
    assert done_ok(await c.set("CABINET.POWER=1"), "CABINET.POWER")
    for m in ("DOME[0]", "DOME[1]", "DOME[2]", "DOME[3]", "COVER"):
        assert await c.value(f"{m}.POWER_STATE") == "1.0"


async def test_dome_follows_a_trajectory(live, c):
    """DOME[0].TRAJECTORY: points uploaded with ADDPOINTS, RUN=1 runs (MOTION_STATE bit 1) and
    completes after the last point with TRAJ_STOP; the dome ends at the path's end."""
    await ready(c, "DOME[0]")
    start = await c.num("DOME[0].REALPOS")
    now = float(await c.value("LOCAL.UT1"))
    points = [(now + 1.5 + 0.25 * i, (start + 2.0 * i) % 360) for i in range(9)]
    for i, (t, p) in enumerate(points):
        assert done_ok(await c.set(f"DOME[0].TRAJECTORY.BUFFER[{i}].TIME={t!r};"
                                   f"DOME[0].TRAJECTORY.BUFFER[{i}].TARGETPOS={p!r}"),
                       f"DOME[0].TRAJECTORY.BUFFER[{i}].TARGETPOS")
    assert done_ok(await c.set(f"DOME[0].TRAJECTORY.ADDPOINTS={len(points)}"), "DOME[0].TRAJECTORY.ADDPOINTS")
    assert await c.num("DOME[0].TRAJECTORY.FREEPOINTS") < 120
    cmd = await c.start("DOME[0].TRAJECTORY.RUN=1")
    await c.wait("DOME[0].MOTION_STATE", lambda v: int(v) & TRAJ)
    assert await c.value("DOME[0].TRAJECTORY.RUN") == "1"
    lines = await c.until(cmd)
    assert done_ok(lines, "DOME[0].TRAJECTORY.RUN"), lines
    assert any(re.match(rf"{cmd} EVENT INFO DOME\[0\]:32 ", x) for x in lines), lines
    assert not int(await c.num("DOME[0].MOTION_STATE")) & TRAJ
    await c.wait("DOME[0].MOTION_STATE", lambda v: not int(v) & MOVING)
    assert await c.num("DOME[0].REALPOS") == pytest.approx(points[-1][1], abs=0.1)
    assert await c.num("DOME[0].TRAJECTORY.FREEPOINTS") == 120
    lines = await c.set("DOME[0].TRAJECTORY.RUN=1")
    assert failed(lines, "DOME[0].TRAJECTORY.RUN") == 11, lines  # nothing queued: nopoints


async def polled_every(driver, interval: float) -> None:
    """Wait (generously) until the PLC driver polls at ``interval``."""
    await until_async(lambda: driver.stats.interval == interval, f"a poll every {interval} s", WAIT)


async def test_a_dome_trajectory_keeps_the_plc_at_its_full_poll_rate(live, c):
    """The dome's PLC rests at its idle poll rate (hw_enclosure.toml: 0.5 s); a trajectory is
    sampled at every poll, so while one runs the PLC is polled at the full rate (0.05 s) even
    when its path stands still and nothing is written or moves."""
    await ready(c, "DOME[0]")
    driver = live.telescope.peripherals.drivers["dome"]
    await polled_every(driver, 0.5)
    here = await c.num("DOME[0].REALPOS")
    now = float(await c.value("LOCAL.UT1"))
    points = [(now + 0.5 + 0.75 * i, here) for i in range(10)]  # 6.75 s standing still
    for i, (t, p) in enumerate(points):
        assert done_ok(await c.set(f"DOME[0].TRAJECTORY.BUFFER[{i}].TIME={t!r};"
                                   f"DOME[0].TRAJECTORY.BUFFER[{i}].TARGETPOS={p!r}"),
                       f"DOME[0].TRAJECTORY.BUFFER[{i}].TARGETPOS")
    assert done_ok(await c.set(f"DOME[0].TRAJECTORY.ADDPOINTS={len(points)}"), "DOME[0].TRAJECTORY.ADDPOINTS")
    cmd = await c.start("DOME[0].TRAJECTORY.RUN=1")
    await c.wait("DOME[0].MOTION_STATE", lambda v: int(v) & TRAJ)
    # well over 2 s into the run (the idle rate's wait), still 3 s before its end
    await c.wait("DOME[0].TRAJECTORY.RUNTIME", lambda v: v < 3.0)
    running = await c.value("DOME[0].TRAJECTORY.RUN")
    interval = driver.stats.interval
    assert running == "1" and interval == 0.05, (running, interval)
    assert done_ok(await c.until(cmd), "DOME[0].TRAJECTORY.RUN")
    await polled_every(driver, 0.5)  # the hold is released: at rest again


async def test_stalled_motor_fails_the_move_until_acknowledged(live, c):
    """A stalled slit motor: TARGETPOS fails with 7 and an event, ERROR_STATE ERROR, power off;
    POWER=1 is refused until ERROR_STATE=0 (which resets the PLC's fault)."""
    await ready(c, "DOME[1]")
    await move(c, "DOME[1]", 0)
    s = sim(live, "dome")
    await live.call(s.stall, "slit", True)
    lines = await c.set("DOME[1].TARGETPOS=50")
    assert failed(lines, "DOME[1].TARGETPOS") == 7, lines
    await c.event(r"EVENT ERROR DOME\[1\]:7 ")
    assert int(await c.num("DOME[1].ERROR_STATE")) & ERROR_BIT
    assert int(await c.num("DOME[1].MOTION_STATE")) & BLOCKED
    assert await c.value("DOME[1].POWER_STATE") == "0.0"
    assert failed(await c.set("DOME[1].POWER=1"), "DOME[1].POWER") == 7
    await live.call(s.stall, "slit", False)
    await c.set("DOME[1].ERROR_STATE=0")
    await c.wait("DOME[1].ERROR_STATE", lambda v: v == 0)
    assert done_ok(await c.set("DOME[1].POWER=1"), "DOME[1].POWER")
    await move(c, "DOME[1]", 0)


# ------------------------------------------------------------------------------ a PLC goes


@pytest.mark.parametrize("how", ["power_off", "not_responding"])
async def test_plc_lost_and_back(live, c, how):
    """The dome PLC switched off (nocon 4) or hung (confail 3): the pending TARGETPOS fails with
    that number, every module of the PLC says so by event and ERROR_STATE, its sensors answer
    FAILED n, moves are refused. When it is back the modules recover by themselves; the
    conditions stay latched (STATUS.LIST keeps them) until acknowledged."""
    number = 4 if how == "power_off" else 3
    await ready(c, "DOME[0]", "DOME[1]")
    start = await c.num("DOME[0].REALPOS")
    cmd = await c.start(f"DOME[0].TARGETPOS={(start + 170) % 360}")
    await c.wait("DOME[0].MOTION_STATE", lambda v: int(v) & MOVING)
    s = sim(live, "dome")
    if how == "power_off":
        await live.call(s.power_off)
    else:
        await live.call(s.set_responding, False)
    lines = await c.until(cmd)
    assert failed(lines, "DOME[0].TARGETPOS") == number, lines
    for m in ("DOME[0]", "DOME[1]", "SENSOR[0]", "SWITCH[0]"):
        await c.event(rf"EVENT ERROR {re.escape(m)}:{number} PLC dome")
    assert int(await c.num("DOME[1].ERROR_STATE")) & ERROR_BIT
    assert int(await c.num("CABINET.ERROR_STATE")) & ERROR_BIT
    # the other PLC's cover works; only the weather interlock (weather unknown) holds it
    assert int(await c.num("COVER.ERROR_STATE")) == WARNING_BIT
    # no fresh readback: status answers the link's error, never the last value (issue 22)
    for m in ("DOME[0]", "DOME[1]"):
        for var in ("REALPOS", "CURRPOS", "POWER_STATE", "POWER", "MOTION_STATE", "LIMIT_STATE"):
            assert await c.value(f"{m}.{var}") == f"FAILED {number}", (m, var)
    assert (await c.value("SENSOR[0].VALUE")).startswith("FAILED ")
    assert failed(await c.set("DOME[1].TARGETPOS=10"), "DOME[1].TARGETPOS") == number
    assert failed(await c.set("SWITCH[0].VALUE=1"), "SWITCH[0].VALUE") == number

    if how == "power_off":
        await live.call(s.power_on)
    else:
        await live.call(s.set_responding, True)
    await c.event(r"EVENT INFO DOME\[1\]:15 PLC dome reachable again")
    await c.wait("DOME[1].POWER_STATE", lambda v: v == 1.0)
    float(await c.value("SENSOR[0].VALUE"))
    assert int(await c.num("DOME[1].ERROR_STATE")) & ERROR_BIT  # latched
    entries = (await c.value("CABINET.STATUS.LIST")).strip('"').split(",")
    entry = [e for e in entries if e.split(":")[1] == "PLC dome unreachable" and e.split(":")[6] == "DOME[1]"]
    assert entry and entry[0].split(":")[5] == "0", entries  # recorded, no longer active
    await ready(c, "DOME[1]")
    assert await c.value("DOME[1].ERROR_STATE") == "0"
    await move(c, "DOME[1]", 0)


async def test_stop_that_cannot_reach_the_plc_fails(live, c):
    """STOP of a module whose PLC is unreachable is not answered DATA OK: it fails with the
    link's number and an event (the driver writes stop when the link returns); CABINET.STOP
    stops everything else and fails the same way."""
    await ready(c, "DOME[0]")
    s = sim(live, "dome")
    await live.call(s.power_off)
    try:
        await c.event(r"EVENT ERROR DOME\[0\]:4 PLC dome")
        lines = await c.set("DOME[0].STOP=1")
        assert failed(lines, "DOME[0].STOP") == 4, lines
        assert any("EVENT ERROR DOME[0]:4 STOP not delivered" in line for line in lines), lines
        assert failed(await c.set("CABINET.STOP=1"), "CABINET.STOP") == 4
        assert done_ok(await c.set("COVER.STOP=1"), "COVER.STOP")  # its PLC is there
    finally:
        await live.call(s.power_on)
    await c.event(r"EVENT INFO DOME\[0\]:15 PLC dome reachable again")
    assert done_ok(await c.set("DOME[0].STOP=1"), "DOME[0].STOP")


# ------------------------------------------------------------------------------ weather


async def test_rain_closes_and_refuses_opening_until_released(live, c):
    """Rain: the open slit and cover close by themselves (1021), a pending opening fails with
    1021, opening is refused with FAILED 1020 and an event, closing stays allowed, the guarded
    modules carry a WARNING. After the rain (and release_after) opening works again."""
    await ready(c, "DOME[0]", "DOME[1]", "DOME[2]", "COVER")
    await move(c, "DOME[1]", 60)
    await move(c, "COVER", 90)
    await move(c, "DOME[2]", 0)
    cmd = await c.start("DOME[2].TARGETPOS=100")  # the slow flap, still opening
    await c.wait("DOME[2].MOTION_STATE", lambda v: int(v) & MOVING)
    s = sim(live, "dome")
    await live.call(s.force, "rain", True)
    assert failed(await c.until(cmd), "DOME[2].TARGETPOS") == 1021
    for m in ("DOME[1]", "DOME[2]", "COVER"):
        await c.event(rf"EVENT WARN {re.escape(m)}:1020 opening locked: rain detected")
    await c.event(r"EVENT WARN DOME\[1\]:1021 closing: rain detected")
    await c.event(r"EVENT WARN COVER:1021 closing: rain detected")
    for m in ("DOME[1]", "DOME[2]", "COVER"):
        await c.wait(f"{m}.REALPOS", lambda v: v <= 0.1)
        await c.wait(f"{m}.MOTION_STATE", lambda v: not int(v) & MOVING)
        assert int(await c.num(f"{m}.ERROR_STATE")) & WARNING_BIT
    assert await c.value("DOME[0].ERROR_STATE") == "0"  # the rotation is not guarded
    assert await c.value("SENSOR[3].VALUE") == "1.0"
    entries = [e.split(":") for e in (await c.value("CABINET.STATUS.LIST")).strip('"').split(",")]
    closes = {e[6] for e in entries if e[1] == "weather close" and e[5] == "1" and "rain detected" in e[7]}
    assert {"DOME[1]", "COVER"} <= closes, entries  # the close itself is on record

    lines = await c.set("DOME[1].TARGETPOS=50")
    assert failed(lines, "DOME[1].TARGETPOS") == 1020, lines
    assert any(re.search(r"EVENT ERROR DOME\[1\]:1020 opening refused: rain detected", x) for x in lines), lines
    assert failed(await c.set("COVER.TARGETPOS=90"), "COVER.TARGETPOS") == 1020
    await move(c, "DOME[1]", 0)  # closing (or staying closed) is allowed
    await move(c, "DOME[0]", (await c.num("DOME[0].REALPOS") + 10) % 360)  # rotating too

    await live.call(s.release, "rain")
    await c.event(r"EVENT INFO DOME\[1\]:1020 weather good")
    await ready(c, "DOME[1]", "COVER")
    await move(c, "DOME[1]", 30)
    await move(c, "DOME[1]", 0)


async def test_a_weather_close_resumes_after_the_plc_was_away(live, c):
    """Rain closes the cover; its PLC drops out mid-close. At reconnect the driver writes stop
    to every axis (so no aborted move resumes): the interlock then closes the cover again."""
    import dataclasses

    await ready(c, "COVER")
    await move(c, "COVER", 90)
    t = sim(live, "telescope")
    fast = {name: t.axes[name].params for name in ("cover1", "cover2")}

    def set_speed(speed):
        for name, params in fast.items():
            t.axes[name].params = dataclasses.replace(params, speed=speed) if speed else params

    await live.call(set_speed, 10.0)  # a slow close leaves time to cut the PLC during it
    try:
        await live.call(sim(live, "dome").force, "rain", True)
        await c.event(r"EVENT WARN COVER:1021 closing: rain detected")
        await c.wait("COVER.MOTION_STATE", lambda v: int(v) & MOVING)
        await live.call(t.power_off)
        await c.event(r"EVENT ERROR COVER:4 PLC telescope")
        half_open = await live.call(t.read_point, "cover1_position")
        assert half_open > 5.0
        await live.call(t.power_on)
        await c.event(r"EVENT WARN COVER:1021 closing: rain \(again")
        await c.wait("COVER.REALPOS", lambda v: v <= 0.1)
    finally:
        await live.call(set_speed, None)
        await live.call(t.power_on)
        await live.call(sim(live, "dome").release, "rain")
    await c.event(r"EVENT INFO COVER:1020 weather good")


async def test_wind_above_the_limit_refuses_opening_without_closing(live, c):
    await ready(c, "DOME[1]")
    await move(c, "DOME[1]", 20)
    s = sim(live, "dome")
    await live.call(s.force, "wind_speed", 22.0)
    await c.event(r"EVENT WARN DOME\[1\]:1020 opening locked: wind 22.0 above 15")
    lines = await c.set("DOME[1].TARGETPOS=40")
    assert failed(lines, "DOME[1].TARGETPOS") == 1020, lines
    assert await c.num("DOME[1].REALPOS") == pytest.approx(20.0, abs=0.1)  # nothing closed
    assert not c.seen(r":1021 ")
    await move(c, "DOME[1]", 10)  # closing further is allowed
    await live.call(s.release, "wind_speed")
    await c.event(r"EVENT INFO DOME\[1\]:1020 weather good")
    await move(c, "DOME[1]", 40)
    await move(c, "DOME[1]", 0)


# ------------------------------------------------------------------------------ sensors, switches


async def test_sensors_read_the_plc_points(live, c):
    """SENSOR[] values are the points' engineering values (FLOAT), with NAME, UNIT and
    DESCRIPTION from the file or the register map."""
    d, t = sim(live, "dome"), sim(live, "telescope")
    assert await c.value("SENSOR!COUNT") == "6"
    assert await c.value("SENSOR[0].NAME") == '"T_OUTSIDE"'
    assert await c.value("SENSOR[0].UNIT") == '"degC"'
    assert await c.value("SENSOR[0].DESCRIPTION") == '"outside air temperature"'
    assert await c.value("SENSOR[1].NAME") == '"pressure"'
    assert await c.value("SENSOR[3].UNIT") == '"1 = rain"'
    value = await c.num("SENSOR[0].VALUE")
    assert value == pytest.approx(await live.call(d.read_point, "temp_outside"), abs=0.3)
    assert await c.num("SENSOR[5].VALUE") == pytest.approx(25.0, abs=0.01)
    assert await c.num("SENSOR[4].VALUE") == pytest.approx(await live.call(t.read_point, "temp_m1"), abs=0.3)
    await live.call(d.force, "temp_outside", -3.4)
    await c.wait("SENSOR[0].VALUE", lambda v: v == pytest.approx(-3.4, abs=1e-6))
    await live.call(d.release, "temp_outside")


async def test_switches_write_and_read_back(live, c):
    """SWITCH VALUE writes the point (completing once the PLC took it) and reads the feedback,
    which follows after the contactor's delay; values outside the range are RANGE."""
    d = sim(live, "dome")
    if await c.value("SWITCH[0].VALUE") != "0":
        assert done_ok(await c.set("SWITCH[0].VALUE=0"), "SWITCH[0].VALUE")
        await c.wait("SWITCH[0].VALUE", lambda v: v == 0)
    assert done_ok(await c.set("SWITCH[0].VALUE=1"), "SWITCH[0].VALUE")
    assert await live.call(d.read_point, "dome_lights") is True
    await c.wait("SWITCH[0].VALUE", lambda v: v == 1)
    assert done_ok(await c.set("SWITCH[0].VALUE=0"), "SWITCH[0].VALUE")
    await c.wait("SWITCH[0].VALUE", lambda v: v == 0)
    assert has(await c.set("SWITCH[0].VALUE=2"), "DATA ERROR SWITCH[0].VALUE RANGE")
    assert await c.value("SWITCH[1].VALUE!MAX") == "3"
    assert done_ok(await c.set("SWITCH[1].VALUE=3"), "SWITCH[1].VALUE")
    await c.wait("SWITCH[1].VALUE", lambda v: v == 3)
    assert has(await c.set("SWITCH[1].VALUE=4"), "DATA ERROR SWITCH[1].VALUE RANGE")
    assert await c.value("SWITCH[1].NAME") == '"mirror_fans"'


# ------------------------------------------------------------------------------ other files


async def test_bundled_sim_toml_serves_the_enclosure(tmp_path):
    """hwconfig/sim.toml: a classic dome, one two-petal COVER, sensors, switches, GPS — all
    answering right after start, nothing in error."""
    svc, port = await start_service(tmp_path / "state")
    c = await Client.connect(port)
    try:
        assert await c.value("CONFIG.DOME.CAPABILITIES") == "15"
        assert await c.value("DOME!COUNT") == "4"
        assert await c.value("COVER.REALPOS") == "0.0"
        assert await c.value("SENSOR!COUNT") == "10"
        assert await c.value("SWITCH!COUNT") == "5"
        float(await c.value("SENSOR[0].VALUE"))
        await c.wait("GPS.POS.LAT", lambda v: v == pytest.approx(28.7606, abs=1e-4), timeout=WAIT)
        assert await c.value("CABINET.ERROR_STATE") == "0"
        assert done_ok(await c.set("CABINET.POWER=1", 60), "CABINET.POWER")
        await move(c, "DOME[3]", 1.0)  # the seal, slowest part of the bundled dome: 2-3 s
    finally:
        await c.close()
        await svc.stop()


async def test_roll_roof_example_runs(tmp_path):
    """hwconfig/sim-rollroof.toml: DOME[1] is the roof, DOME[0] is absent; it opens and closes;
    the GPS on a pty gives a fix. (Heartbeats as the other tests of shipped files have them:
    the drives' 0.5 s wait for the TCS heartbeat was seen to run out on a loaded machine.)"""
    svc = Service(tolerant_heartbeats(make_config(tmp_path / "state", ROLLROOF)))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        assert int(await c.value("CONFIG.DOME.CAPABILITIES")) == 2 | 16  # opening part, roll-roof
        assert await c.value("DOME!COUNT") == "2"
        assert await answer(c, "DOME[0].REALPOS") == "FAILED 4"  # no hardware at index 0
        assert await answer(c, "DOME[0].VERSION") == "0"
        assert await c.value("DOME[1].CYCLIC") == "0.0"
        assert done_ok(await c.set("CABINET.POWER=1", 60), "CABINET.POWER")
        await move(c, "DOME[1]", 5.0)
        await move(c, "DOME[1]", 0.0)
        assert int(await c.num("DOME[1].LIMIT_STATE")) & HW_MIN
        await c.wait("GPS.POS.LAT", lambda v: v == pytest.approx(37.2236, abs=1e-4))
    finally:
        await c.close()
        await svc.stop()


# ------------------------------------------------------------------------------ bad files

BASE = HW.read_text()


@pytest.mark.parametrize("change, key, words", [
    (('axis = "dome.slit"', 'axis = "dome.nope"'), "dome.slit.axis", "points.nope_status: missing"),
    (('axis = "dome.slit"', 'axis = "roof.slit"'), "dome.slit.axis", "no PLC 'roof' in [plcs]"),
    (('axis = "dome.slit"', 'axis = "slit"'), "dome.slit.axis", "must be '<plc>.<name>'"),
    (('axis = "dome.flap"', 'axis = "dome.slit"'), "dome.flap.axis", "already moves dome.slit.axis"),
    (('type = "classic"', 'type = "roll-roof"'), "dome.rotation", "a roll-roof dome has no rotation"),
    (('point = "dome.pressure"', 'point = "dome.pressur"'), "sensors[1].point", "no point 'pressur'"),
    (('point = "dome.dome_lights"', 'point = "dome.rain"'), "switches[0].point", "'rain' is not writable"),
    (('rain = "dome.rain"', 'rain = "dome.rain.wet"'), "interlocks.rain", "has no bit 'wet'"),
    (('max = 90.0\nmax_velocity = 180.0', 'max_velocity = 180.0'), "covers[0].max", "missing"),
    (('slit_status    = { kind = "input",   address = 14, type = "uint16", bits = { moving = 0, at_target = 1,',
      'slit_status    = { kind = "input",   address = 14, type = "uint16", bits = { moving = 0, at_targe = 1,'),
     "plcs.dome.points.slit_status.bits", "needs bits ['at_target']"),
])
def test_bad_module_mapping_is_refused_naming_the_key(change, key, words):
    old, new = change
    assert old in BASE
    with pytest.raises(ConfigErrors) as info:
        parse_config(BASE.replace(old, new, 1), "hw.toml")
    text = str(info.value)
    assert f"hw.toml: {key}: " in text and words in text, text


def _dome_variant(kind: str, parts: dict[str, str]) -> str:
    """hw_enclosure.toml with its [dome] replaced by a ``kind`` dome of ``parts`` (part -> axis)."""
    head, rest = BASE.split("[dome]\n", 1)
    tail = rest[rest.index("[[covers]]"):]
    body = f'[dome]\ntype = "{kind}"\n\n'
    for part, axis in parts.items():
        top = "" if part == "rotation" else "max = 100.0\n"
        body += f'[dome.{part}]\naxis = "dome.{axis}"\n{top}max_velocity = 1.0\n\n'
    return head + body + tail


@pytest.mark.parametrize("kind, parts, indices, capabilities", [
    ("classic", {"rotation": "az", "slit": "slit"}, [0, 1], 1 | 2),
    ("classic", {"rotation": "az", "slit": "slit", "flap": "flap", "seal": "seal"}, [0, 1, 2, 3], 15),
    ("roll-roof", {"roof": "slit", "seal": "seal"}, [1, 3], 2 | 8 | 16),
    ("fold", {"fold": "slit"}, [1], 2),
    ("clamshell", {"shell1": "slit", "shell2": "flap"}, [1, 2], 2 | 4 | 32),
])
def test_dome_types_give_their_indices_and_capabilities(kind, parts, indices, capabilities):
    from tcs.model.enclosure import DomeInfo

    config = parse_config(_dome_variant(kind, parts), "hw.toml")
    assert sorted(config.dome.parts()) == indices
    assert DomeInfo.from_section(config.dome).capabilities == capabilities


def test_a_dome_type_needs_its_parts():
    with pytest.raises(ConfigErrors) as info:
        parse_config(_dome_variant("clamshell", {"shell1": "slit"}), "hw.toml")
    assert "hw.toml: dome.shell2: missing: a clamshell dome needs [dome.shell2]" in str(info.value)


def test_tcs_server_refuses_a_bad_mapping_at_start(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(BASE.replace('axis = "dome.slit"', 'axis = "dome.nope"'))
    proc = subprocess.run([sys.executable, "-m", "tcs.cli.server", "--config", str(bad)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "dome.slit.axis" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
