"""The OpenTSI tree on its own port: what pyobs-pilar, chimera, UNAM and SONG do
(``docs/opentsi.md``), replayed over real sockets against the simulated telescope.

One service (module scope, its own event-loop thread) runs ``tests/hw_opentsi.toml``: the fast
telescope of the pointing tests with a focus, a filter wheel at port 2, park positions and
filter names, serving OpenTCI and OpenTSI on two free ports. Each test brings the telescope
into the state it needs through the OpenTSI tree itself (READY=1, TRACK=0, errors cleared).
Positions are checked against the telescope's astrometry: the encoders, read back through the
inverse pipeline, within 1″ of the target; a goto within the axes' on-target tolerance.
"""

from __future__ import annotations

import asyncio
import math
import re
import time
from pathlib import Path

import pytest

from support.live import live_service
from support.opentci_client import Client as SharedClient
from support.tpl2 import RawClient
from tcs.pointing.sky_object import precess_from_j2000

HW = Path(__file__).with_name("hw_opentsi.toml")
WAIT = 60.0
ARCSEC = 1.0 / 3600.0
# pyobs-pilar's status GET (PilarTelescope._pilar_variables with the filter wheel)
PYOBS_STATUS = [
    "OBJECT.EQUATORIAL.RA", "OBJECT.EQUATORIAL.DEC", "POSITION.EQUATORIAL.RA_J2000",
    "POSITION.EQUATORIAL.DEC_J2000", "POSITION.HORIZONTAL.ZD", "POSITION.HORIZONTAL.ALT",
    "POSITION.HORIZONTAL.AZ", "POSITION.INSTRUMENTAL.FOCUS.REALPOS",
    "POSITION.INSTRUMENTAL.DEROTATOR[2].REALPOS", "POINTING.SETUP.DEROTATOR.OFFSET",
    "TELESCOPE.READY_STATE", "TELESCOPE.MOTION_STATE", "POSITION.INSTRUMENTAL.AZ.OFFSET",
    "POSITION.INSTRUMENTAL.ZD.OFFSET", "POSITION.INSTRUMENTAL.FILTER[2].CURRPOS",
]
# pyobs-pilar's table of error names (pilarerror.ERRORS): any other name is "unknown" to it
PYOBS_ERRORS = {"ERR_GPS_PositionLost", "ERR_GPS_LeapSecond", "ERR_GPS_TooFewSatellites",
                "ERR_FilterWheel_RefMismatch", "ERR_Elevation_ETELExecError", "ERR_Azimuth_ETELExecError",
                "ERR_Oil_TemperatureLow", "ERR_Oil_NoExtractionTimeout", "ERR_Brake_ClosedFromOther",
                "ERR_Azimuth_ETELError", "ERR_Azimuth_ETELWarning", "ERR_Elevation_ETELError"}


live = live_service(HW)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


class Client(SharedClient):
    patience = WAIT


def complete(lines: list[str]) -> bool:
    return lines[-1].endswith("COMMAND COMPLETE") and not any("COMMAND ERROR" in x for x in lines)


async def tsi(live) -> Client:
    return await Client.connect(live.service.opentsi_port)


async def tci(live) -> Client:
    return await Client.connect(live.port)


async def pyobs_set(c: Client, key: str, value) -> list[str]:
    """pyobs-pilar's ``set``: the value quoted, then wait for COMPLETE or FAILED."""
    return await c.set(f'{key}="{value}"')


async def ready(c: Client) -> None:
    """Operational, errors acknowledged, not tracking, no offsets, the derotator not following
    (a test that sets SETUP.DEROTATOR.SYNCMODE for itself leaves it set)."""
    level = int(await c.num("TELESCOPE.STATUS.GLOBAL"))
    if level:
        await pyobs_set(c, "TELESCOPE.STATUS.CLEAR", level)
    if await c.num("TELESCOPE.READY_STATE") != 1.0:
        assert complete(await pyobs_set(c, "TELESCOPE.READY", 1))
    assert await c.num("TELESCOPE.READY_STATE") == 1.0
    await pyobs_set(c, "POINTING.TRACK", 0)
    await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
    for ax in ("AZ", "ZD"):
        if await c.num(f"POSITION.INSTRUMENTAL.{ax}.OFFSET") != 0.0:
            await pyobs_set(c, f"POSITION.INSTRUMENTAL.{ax}.OFFSET", 0)
    await pyobs_set(c, "POINTING.SETUP.DEROTATOR.SYNCMODE", 0)
    await pyobs_set(c, "POINTING.SETUP.DEROTATOR.OFFSET", 0.0)


def star_near(live, az: float, alt: float, ahead: float = 3.0) -> tuple[float, float]:
    """ICRS (RA hours, Dec degrees) of the star at observed (az, alt) ``ahead`` s from now."""
    p = live.telescope.pointing
    ra, dec = p.astrometry().icrs_from_observed(az, 90.0 - alt, time.time() + ahead)
    return float(ra), float(dec)


def sky_separation(ra1: float, dec1: float, ra2: float, dec2: float) -> float:
    import erfa
    return math.degrees(float(erfa.seps(math.radians(ra1 * 15), math.radians(dec1),
                                        math.radians(ra2 * 15), math.radians(dec2))))


# ------------------------------------------------------------------------------ the listener

async def test_two_trees_two_ports_one_model(live):
    """Both ports log in the same users; each tree answers its own names only; a value written
    through one tree is the model's, seen through the other; OpenTCI's TRACK keeps its meaning."""
    a, b = await tsi(live), await tci(live)
    bad = await RawClient.connect(live.service.opentsi_port, login=None)
    try:
        assert a.greeting.startswith("TPL2 2.1 CONN ") and "AUTH PLAIN" in a.greeting
        await bad.send('AUTH PLAIN "admin" "wrong"')
        assert await bad.readline() == "AUTH FAILED"
        assert await a.value("SERVER.INFO.DEVICE") == '"OpenTSI telescope control system"'
        assert await a.members("TELESCOPE") == [
            "READY", "READY_STATE", "POWER", "STOP", "MOTION_STATE", "STATUS", "CONFIG", "ENVIRONMENT"]
        assert await a.value("CABINET.POWER") == "UNKNOWN"
        assert await b.value("TELESCOPE.READY_STATE") == "UNKNOWN"
        assert "tracking ended" in await b.value("POINTING.TRACK!INFO")
        assert "OBJECT.HORIZONTAL" in await a.value("POINTING.TRACK!INFO")
        assert complete(await a.set("TELESCOPE.CONFIG.LOCAL.UT1-UTC=0.25"))
        assert await b.num("LOCAL.UT1-UTC") == 0.25
        assert complete(await b.set("LOCAL.UT1-UTC=-0.1234"))
        assert await a.num("TELESCOPE.CONFIG.LOCAL.UT1-UTC") == -0.1234
        assert await a.members("POSITION.INSTRUMENTAL.AZ") == await b.members("AZ")
        assert await a.value("TELESCOPE.CONFIG.PORT[2].FILTER") == "4"
    finally:
        for c in (a, b, bad):
            await c.close()


# ------------------------------------------------------------------------------ pyobs-pilar

async def test_pyobs_init_status_and_filters(live):
    """pyobs init (READY=1 then READY_STATE == 1.0), its status GET (every value a float), its
    filter list (CONFIG.PORT[2].FILTER, then INDEX → NAME) and events with OpenTSI names."""
    c = await tsi(live)
    try:
        if await c.num("TELESCOPE.READY_STATE") == 1.0:  # an earlier test: start from "off"
            assert complete(await pyobs_set(c, "TELESCOPE.READY", 0))
        assert await c.num("TELESCOPE.READY_STATE") == 0.0
        c.forget()
        lines = await pyobs_set(c, "TELESCOPE.READY", 1)
        assert complete(lines)
        assert await c.num("TELESCOPE.READY_STATE") == 1.0
        assert await c.num("TELESCOPE.POWER") == 1
        events = [x for x in lines + c.lines if " EVENT " in x]
        assert any(re.match(r"^\d+ EVENT INFO TELESCOPE:21 ", x) for x in events), events  # POWERCHANGE
        assert any(re.match(r"^\d+ EVENT INFO POSITION\.INSTRUMENTAL\.AZ:\d+ ", x) for x in events)
        assert not [x for x in events if re.search(r"EVENT \w+ (CABINET|AZ|ZD):", x)]
        lines = await c.command(4242, "GET " + ";".join(PYOBS_STATUS))
        values = {}
        for line in lines:
            if "DATA INLINE" in line:
                pos = line.find("=")
                values[line[line.find("DATA INLINE") + 12:pos]] = line[pos + 1:]
        assert set(values) == set(PYOBS_STATUS)
        for key in PYOBS_STATUS:
            float(values[key])                       # pyobs: float() of every value
        assert float(values["TELESCOPE.MOTION_STATE"]) == 0
        count = int(await c.value("TELESCOPE.CONFIG.PORT[2].FILTER"))
        names = []
        for i in range(count):
            await pyobs_set(c, "POINTING.SETUP.FILTER.INDEX", i)
            names.append((await c.value("POINTING.SETUP.FILTER.NAME")).replace('"', ""))
        assert names == ["clear", "V", "R", "Halpha"]
    finally:
        await c.close()


async def test_pyobs_track_radec(live):
    """move_radec: TRACK=0, derotator sync, OBJECT.EQUATORIAL.RA (hours) / DEC, TRACK=1 completes
    once tracking runs; MOTION_STATE is never 0 until it reads 11; the encoders point at the
    target within 1″; a J2025 position is precessed to the same star."""
    c = await tsi(live)
    try:
        await ready(c)
        ra, dec = star_near(live, 120.0, 60.0)
        await pyobs_set(c, "POINTING.TRACK", 0)
        await pyobs_set(c, "POINTING.SETUP.DEROTATOR.SYNCMODE", 3)
        await pyobs_set(c, "POINTING.SETUP.DEROTATOR.OFFSET", 0.0)
        await pyobs_set(c, "OBJECT.EQUATORIAL.RA", ra)
        await pyobs_set(c, "OBJECT.EQUATORIAL.DEC", dec)
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        states = set()
        deadline = time.monotonic() + WAIT
        while (state := int(await c.num("TELESCOPE.MOTION_STATE"))) != 11:
            states.add(state)
            assert time.monotonic() < deadline, states
        assert states <= {3}, states
        await c.wait("CURRENT.TARGETDISTANCE", lambda v: v < 0.5 * ARCSEC)
        r, d = await c.nums("POSITION.EQUATORIAL.RA_J2000", "POSITION.EQUATORIAL.DEC_J2000")
        assert sky_separation(r, d, ra, dec) < ARCSEC
        assert await c.num("CURRENT.TRACK") == 1
        assert await c.num("CURRENT.TRACKTIME") > 0
        assert int(await c.num("POSITION.INSTRUMENTAL.DEROTATOR[2].MOTION_STATE")) & 2   # follows the field

        # the same star given for the equinox J2025 (and its epoch) lands on the same place
        ra2, dec2 = star_near(live, 140.0, 55.0)
        r25, d25 = precess_from_j2000(ra2, dec2, 2025.0)
        assert complete(await c.set(f"OBJECT.EQUATORIAL.RA={r25!r};OBJECT.EQUATORIAL.DEC={d25!r};"
                                    "OBJECT.EQUATORIAL.EQUINOX=2025.0;OBJECT.EQUATORIAL.EPOCH=2025.0"))
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        await c.wait("CURRENT.TARGETDISTANCE", lambda v: v < 0.5 * ARCSEC)
        r, d = await c.nums("POSITION.EQUATORIAL.RA_J2000", "POSITION.EQUATORIAL.DEC_J2000")
        assert sky_separation(r, d, ra2, dec2) < ARCSEC
        assert sky_separation(ra2, dec2, r25, d25) > 0.1      # the precession mattered
        # something that cannot be meant is refused, the target kept
        lines = await c.set("OBJECT.EQUATORIAL.EQUINOX=1950.0;OBJECT.EQUATORIAL.EQUINOX=0")
        assert "DATA ERROR OBJECT.EQUATORIAL.EQUINOX RANGE" in lines[-2], lines
        await pyobs_set(c, "OBJECT.EQUATORIAL.EQUINOX", 2000.0)
        await pyobs_set(c, "POINTING.TRACK", 0)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
    finally:
        await c.close()


async def test_pyobs_goto_altaz_through_the_cable_wrap(live):
    """move_altaz: TRACK=2 moves to OBJECT.HORIZONTAL and stops; the SET completes on arrival,
    MOTION_STATE is then exactly 0 and POSITION.HORIZONTAL reads the demanded alt/az within
    the axes' tolerance; the azimuth turn is the one nearest the axis; OpenTCI does not track."""
    c, o = await tsi(live), await tci(live)
    try:
        await ready(c)
        for az, alt in ((90.0, 45.0), (330.0, 45.0), (200.0, 45.0), (170.0, 50.0)):
            await pyobs_set(c, "POINTING.TRACK", 0)
            await pyobs_set(c, "OBJECT.HORIZONTAL.AZ", az)
            await pyobs_set(c, "OBJECT.HORIZONTAL.ALT", alt)
            before = await c.num("POSITION.INSTRUMENTAL.AZ.REALPOS")
            assert complete(await pyobs_set(c, "POINTING.TRACK", 2))
            assert await c.num("TELESCOPE.MOTION_STATE") == 0
            got_az, got_alt = await c.nums("POSITION.HORIZONTAL.AZ", "POSITION.HORIZONTAL.ALT")
            assert abs(math.remainder(got_az - az, 360.0)) < 0.001 and abs(got_alt - alt) < 0.001
            real = await c.num("POSITION.INSTRUMENTAL.AZ.REALPOS")
            candidates = [az + k * 360.0 for k in (-1, 0, 1) if -270.0 <= az + k * 360.0 <= 270.0]
            assert abs(real - min(candidates, key=lambda t: abs(t - before))) < 0.001
            assert await o.num("POINTING.TRACK") == 0
        assert await c.num("POSITION.INSTRUMENTAL.AZ.REALPOS") < -180.0   # 330° = -30°, 200° = -160°, 170° = -190°
        # UNAM's "unpark": an instrumental position, taken as it is (written last: it is used)
        assert complete(await c.set("OBJECT.INSTRUMENTAL.AZ=-100.0;OBJECT.INSTRUMENTAL.ZD=-30.0"))
        assert complete(await pyobs_set(c, "POINTING.TRACK", 2))
        assert await c.nums("POSITION.INSTRUMENTAL.AZ.REALPOS", "POSITION.INSTRUMENTAL.ZD.REALPOS") == \
            pytest.approx([-100.0, -30.0], abs=0.001)
        got_az, got_alt = await c.nums("POSITION.HORIZONTAL.AZ", "POSITION.HORIZONTAL.ALT")
        assert abs(math.remainder(got_az - 80.0, 360.0)) < 0.001 and abs(got_alt - 60.0) < 0.001  # reverse
        await pyobs_set(c, "OBJECT.HORIZONTAL.AZ", 90.0)
        # below the altitude limit: refused, and visible to a client that ignores SET errors
        await pyobs_set(c, "OBJECT.HORIZONTAL.ALT", 5.0)
        lines = await pyobs_set(c, "POINTING.TRACK", 2)
        assert "DATA ERROR POINTING.TRACK FAILED 9" in lines[-2], lines
        assert await c.num("TELESCOPE.READY_STATE") == -1.0
        assert int(await c.num("TELESCOPE.STATUS.GLOBAL")) & 2
        await pyobs_set(c, "TELESCOPE.STATUS.CLEAR", int(await c.num("TELESCOPE.STATUS.GLOBAL")))
        assert await c.num("TELESCOPE.READY_STATE") == 1.0
    finally:
        await c.close()
        await o.close()


async def test_pyobs_focus_and_filter(live):
    """set_focus: SETUP.FOCUS.POSITION then TRACK=4, poll TARGETDISTANCE; set_filter: INDEX then
    TRACK=3, poll FILTER[2].CURRPOS."""
    c = await tsi(live)
    try:
        await ready(c)
        await pyobs_set(c, "POINTING.SETUP.FOCUS.SYNCMODE", 1)
        await pyobs_set(c, "POINTING.SETUP.FOCUS.POSITION", 12.5)
        await pyobs_set(c, "POINTING.TRACK", 4)
        await c.wait("POSITION.INSTRUMENTAL.FOCUS.TARGETDISTANCE", lambda v: abs(v) < 0.01)
        assert abs(await c.num("POSITION.INSTRUMENTAL.FOCUS.REALPOS") - 12.5) < 0.01
        for index in (2, 1):
            await pyobs_set(c, "POINTING.SETUP.FILTER.INDEX", index)
            await pyobs_set(c, "POINTING.TRACK", 3)
            await c.wait("POSITION.INSTRUMENTAL.FILTER[2].CURRPOS", lambda v: v == index)
        assert await c.num("TELESCOPE.MOTION_STATE") == 0
    finally:
        await c.close()


async def test_fault_while_tracking_shows_and_clears(live):
    """A drive fault of AZ while tracking: MOTION_STATE falls to 0, READY_STATE −1,
    STATUS.GLOBAL has ERROR, STATUS.LIST names ERR_Azimuth_ETELError in the OpenTSI grammar
    (pyobs's parser finds only names it knows); STATUS.CLEAR with GLOBAL's value clears it
    and READY=1 makes the telescope operational again."""
    c = await tsi(live)
    try:
        await ready(c)
        ra, dec = star_near(live, 100.0, 50.0)
        await pyobs_set(c, "OBJECT.EQUATORIAL.RA", ra)
        await pyobs_set(c, "OBJECT.EQUATORIAL.DEC", dec)
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        sim = live.telescope.sims[1]
        await live.call(sim.inject_fault, "overcurrent")
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
        assert await c.num("TELESCOPE.READY_STATE") == -1.0
        level = int(await c.num("TELESCOPE.STATUS.GLOBAL"))
        assert level & 2
        text = (await c.value("TELESCOPE.STATUS.LIST")).strip('"')
        assert re.search(r"(^|,)AZIMUTH\|\d+:[^:]*AZ\|\d+[^:]*:[^,]*ERR_Azimuth_ETELError\|[^|,]*\|\d+\|AZ",
                         text), text
        names = []  # pyobs_pilar.PilarDriver.list_errors
        for group in text.split(","):
            for error in group[group.rfind(":") + 1:].split(";"):
                if error.split("|")[0]:
                    names.append(error.split("|")[0])
        assert "ERR_Azimuth_ETELError" in names and set(names) <= PYOBS_ERRORS | {"ERR_DeviceError"}
        # the SET completes when the drive's fault reset has ended (as CABINET.ERROR_STATE=0)
        assert complete(await pyobs_set(c, "TELESCOPE.STATUS.CLEAR", level))
        assert not int(await c.num("TELESCOPE.STATUS.GLOBAL")) & 3
        assert await c.num("TELESCOPE.READY_STATE") < 1.0          # AZ is off after its fault
        assert complete(await pyobs_set(c, "TELESCOPE.READY", 1))
        assert await c.num("TELESCOPE.READY_STATE") == 1.0
    finally:
        await c.close()


async def test_clear_by_severity(live):
    """CLEAR_WARNING leaves an error; CLEAR_ERROR acknowledges it (UNAM, Astra)."""
    c = await tsi(live)
    try:
        await ready(c)
        await pyobs_set(c, "OBJECT.HORIZONTAL.ALT", 1.0)
        await pyobs_set(c, "POINTING.TRACK", 2)                     # refused: a latched error
        level = int(await c.num("TELESCOPE.STATUS.GLOBAL"))
        assert level & 2
        await c.set(f"TELESCOPE.STATUS.CLEAR_WARNING={level}")
        assert int(await c.num("TELESCOPE.STATUS.GLOBAL")) & 2
        await c.set(f"TELESCOPE.STATUS.CLEAR_ERROR={level}")
        assert not int(await c.num("TELESCOPE.STATUS.GLOBAL")) & 2
    finally:
        await c.close()


async def test_pyobs_park(live):
    """park: READY=0 stops tracking, moves to the hardware file's park position, powers off;
    READY_STATE 0.0 and MOTION_STATE 0 afterwards."""
    c = await tsi(live)
    try:
        await ready(c)
        ra, dec = star_near(live, 60.0, 70.0)
        await pyobs_set(c, "OBJECT.EQUATORIAL.RA", ra)
        await pyobs_set(c, "OBJECT.EQUATORIAL.DEC", dec)
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        assert complete(await pyobs_set(c, "TELESCOPE.READY", 0))
        assert await c.num("TELESCOPE.READY_STATE") == 0.0
        assert await c.num("TELESCOPE.MOTION_STATE") == 0
        az, zd = await c.nums("POSITION.INSTRUMENTAL.AZ.REALPOS", "POSITION.INSTRUMENTAL.ZD.REALPOS")
        assert abs(az - 30.0) < 0.001 and abs(zd - 20.0) < 0.001
        assert await c.num("POSITION.INSTRUMENTAL.AZ.POWER_STATE") == 0.0
    finally:
        await c.close()


# ------------------------------------------------------------------------------ ABORT (issue 22)

NODE = {"AZ": 1, "ZD": 2, "FOCUS": 5, "FILTER": 6, "MIRROR": 7}


def drive_sim(live, name: str):
    return live.telescope.sims[NODE[name]]


async def moved(live, name: str, away: float) -> float:
    """Wait until the simulated drive of ``name`` stands more than ``away`` from where it stood
    when called; returns that start."""
    s = drive_sim(live, name)
    start = s.position
    deadline = time.monotonic() + WAIT
    while abs(s.position - start) <= away:
        assert time.monotonic() < deadline, f"{name} did not move (at {s.position})"
        await asyncio.sleep(0.01)
    return start


async def stands(live, name: str) -> float:
    """Wait until the simulated drive of ``name`` stands still (0.3 s without a change of
    1e-4); returns where."""
    s = drive_sim(live, name)
    deadline = time.monotonic() + WAIT
    last, since = s.position, time.monotonic()
    while time.monotonic() - since < 0.3:
        assert time.monotonic() < deadline, f"{name} did not stop"
        await asyncio.sleep(0.02)
        if abs(s.position - last) > 1e-4:
            last, since = s.position, time.monotonic()
    return last


async def abort(c: Client, cmd: int) -> None:
    await c.send(f"{cmd + 500000} ABORT {cmd}")
    line = await c.event(rf"^{cmd} COMMAND (ABORTEDBY|COMPLETE|FAILED)")
    assert line.endswith(f"ABORTEDBY {cmd + 500000}"), line


async def _aborted_short(live, c: Client, text: str, name: str, goal: float, away: float) -> None:
    """``SET text`` moves ``name`` towards ``goal``; ABORTed once it moved ``away``: the drive
    stops short of the goal and stays there."""
    cmd = await c.start(text)
    await moved(live, name, away)
    await abort(c, cmd)
    stopped = await stands(live, name)
    assert abs(stopped - goal) > away, (name, stopped, goal)
    await asyncio.sleep(0.3)
    assert abs(drive_sim(live, name).position - stopped) < 1e-3, f"{name} moved on after the ABORT"


async def test_abort_of_opentsi_verbs_stops_their_motion(live):
    """ABORT of POINTING.TRACK=1 (before it completed: the tracking), =4 (focus), =3 (filter wheel, a
    profile-position move in the drive), of USE_PORT (M3) and of an OpenTCI FILTER TARGETPOS:
    each motion stops short of its goal with the normal deceleration, the command ends
    ABORTEDBY, nothing moves on (issue 22 item 3); the wheel's STOP stops it too."""
    c, o = await tsi(live), await tci(live)
    try:
        await ready(c)
        for ax, pos in (("AZ", 0.0), ("AZ", -60.0), ("ZD", 40.0)):
            assert complete(await o.set(f"{ax}.TARGETPOS={pos}"))
        ra, dec = star_near(live, 90.0, 60.0, ahead=10.0)   # 150 deg away in azimuth
        await pyobs_set(c, "OBJECT.EQUATORIAL.RA", ra)
        await pyobs_set(c, "OBJECT.EQUATORIAL.DEC", dec)
        # TRACK=1 completes once tracking runs on the new path (the slew goes on after it):
        # an ABORT right behind the SET ends the tracking it started, no slew follows
        cmd = await c.start("POINTING.TRACK=1")
        await abort(c, cmd)
        await c.wait("POINTING.TRACK", lambda v: v == 0)
        stopped = await stands(live, "AZ")
        assert abs(stopped - 90.0) > 5.0, stopped
        await asyncio.sleep(0.5)
        assert abs(drive_sim(live, "AZ").position - stopped) < 1e-3, "it went on tracking"

        focus = drive_sim(live, "FOCUS").position
        goal = 45.0 if focus < 25.0 else 5.0
        await pyobs_set(c, "POINTING.SETUP.FOCUS.POSITION", goal)
        await _aborted_short(live, c, "POINTING.TRACK=4", "FOCUS", goal, 2.0)

        assert complete(await pyobs_set(c, "POINTING.SETUP.USE_PORT", 2))
        for index in (0, 3):
            await pyobs_set(c, "POINTING.SETUP.FILTER.INDEX", index)
            if index == 0:
                assert complete(await pyobs_set(c, "POINTING.TRACK", 3))
        await _aborted_short(live, c, "POINTING.TRACK=3", "FILTER", 135.0, 10.0)
        await _aborted_short(live, o, "FILTER[2].TARGETPOS=3", "FILTER", 135.0, 10.0)
        await _aborted_short(live, c, "POINTING.SETUP.USE_PORT=3", "MIRROR", 180.0, 10.0)
        # axis STOP of a wheel moving in the drive (PP) stops it too; the TARGETPOS fails with 10
        cmd = await o.start("FILTER[2].TARGETPOS=0")
        await moved(live, "FILTER", 10.0)
        assert complete(await o.set("FILTER[2].STOP=1"))
        assert any(line.endswith("DATA ERROR FILTER[2].TARGETPOS FAILED 10") for line in await o.until(cmd))
        stopped = await stands(live, "FILTER")
        assert stopped > 10.0, stopped
        # after a halted move a new one goes where it is asked
        assert complete(await pyobs_set(c, "POINTING.SETUP.USE_PORT", 2))
        assert abs(drive_sim(live, "MIRROR").position) < 0.01
        assert complete(await pyobs_set(c, "POINTING.TRACK", 3))
        assert abs(drive_sim(live, "FILTER").position - 135.0) < 0.01
    finally:
        await c.close()
        await o.close()


async def test_abort_of_ready_stops_the_park_move_and_the_referencing(live):
    """READY=0 aborted during the move to the park position: the axes stop there, the power
    stays on. CABINET.REINIT returns at once (OpenTCI): CABINET.STOP ends its homing run on the
    drive. READY=1 aborted while it references: the homing run stops, nothing is powered off."""
    c, o = await tsi(live), await tci(live)
    try:
        await ready(c)
        for pos in (0.0, -100.0):
            assert complete(await o.set(f"AZ.TARGETPOS={pos}"))
        await _aborted_short(live, c, "TELESCOPE.READY=0", "AZ", 30.0, 2.0)
        assert await o.num("CABINET.POWER_STATE") == 1.0
        assert await o.num("AZ.POWER_STATE") == 1.0
        # homing (method 19: to the home switch at 0) from 10 deg away
        assert complete(await o.set("AZ.TARGETPOS=10"))
        assert complete(await o.set("CABINET.REINIT=1"))
        await moved(live, "AZ", 0.3)
        assert complete(await o.set("CABINET.STOP=1"))
        here = await stands(live, "AZ")
        assert abs(here) > 0.3, here
        await asyncio.sleep(0.3)
        assert abs(drive_sim(live, "AZ").position - here) < 1e-3, "homing went on after STOP"
        await o.wait("AZ.REFERENCED", lambda v: v < 1.0)
        await _aborted_short(live, c, "TELESCOPE.READY=1", "AZ", 0.0, 0.3)
        assert await o.num("AZ.REFERENCED") < 1.0
        assert await o.num("AZ.POWER_STATE") == 1.0
        assert complete(await pyobs_set(c, "TELESCOPE.READY", 1))   # referenced again
        assert await c.num("TELESCOPE.READY_STATE") == 1.0
    finally:
        await c.close()
        await o.close()


async def test_a_lost_dome_plc_reads_as_failed_not_the_last_position(live):
    """The dome PLC switched off: POSITION.INSTRUMENTAL.DOME[0].REALPOS (and POWER_STATE,
    MOTION_STATE) answer FAILED 4 instead of the last value polled; readable again once it is
    back (issue 22 item 8)."""
    c = await tsi(live)
    plc = live.telescope.peripherals.sims.plcs["dome"]
    dome = "POSITION.INSTRUMENTAL.DOME[0]"
    try:
        float(await c.value(f"{dome}.REALPOS"))
        await live.call(plc.power_off)
        deadline = time.monotonic() + WAIT
        while await c.value(f"{dome}.REALPOS") != "FAILED 4":
            assert time.monotonic() < deadline, "REALPOS kept a value"
            await asyncio.sleep(0.05)
        for var in ("POWER_STATE", "MOTION_STATE", "CURRPOS"):
            assert await c.value(f"{dome}.{var}") == "FAILED 4", var
    finally:
        await live.call(plc.power_on)
    deadline = time.monotonic() + WAIT
    while (await c.value(f"{dome}.REALPOS")).startswith("FAILED"):
        assert time.monotonic() < deadline, "REALPOS did not come back"
        await asyncio.sleep(0.05)
    await c.close()


# ------------------------------------------------------------------------------ other clients

async def test_chimera_slew_and_park(live):
    """chimera: MOUNTOPTIONS, dome sync off, OBJECT.EQUATORIAL with EPOCH, TRACK=1 then bit 0
    while slewing; abort with TRACK=0; park with READY=0."""
    c = await tsi(live)
    try:
        await ready(c)
        assert await c.value("TELESCOPE.CONFIG.MOUNTOPTIONS") == '"AZ-ZD"'
        await c.set("POINTING.SETUP.DOME.SYNCMODE=0")
        ra, dec = star_near(live, 250.0, 40.0)
        assert complete(await c.set(f"OBJECT.EQUATORIAL.RA={ra!r};OBJECT.EQUATORIAL.DEC={dec!r};"
                                    "OBJECT.EQUATORIAL.EPOCH=2000"))
        cmd = await c.start("POINTING.TRACK=1")
        assert complete(await c.until(cmd, WAIT))
        assert int(await c.num("TELESCOPE.MOTION_STATE")) & 1
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        slewtime = await c.num("POINTING.SLEWTIME")
        axes = live.telescope.pointing._controlled()
        assert slewtime < 1.0, (slewtime, [(a.module_name, a.motion_state, a.target_distance) for a in axes])
        await c.set("POINTING.TRACK=0")
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
        assert complete(await c.set("TELESCOPE.READY=0"))
        assert await c.num("TELESCOPE.READY_STATE") == 0.0
    finally:
        await c.close()


async def test_unam_startup_and_tracking(live):
    """UNAM: AUTH and the first GET back to back, TAI-UTC at start-up, POWER=1 until READY_STATE
    is exactly 1.0, OPTIMIZATION / MIN_TRACKTIME, EQUINOX 2000.000, TRACK=1, wait until
    CURRENT.TRACKTIME is a number, CURRENT.TRACK 1; STOP on the emergency id."""
    raw = await RawClient.connect(live.service.opentsi_port, login=None)
    await raw.send_bytes(b'AUTH PLAIN "admin" "admin"\n1 GET TELESCOPE.READY_STATE\n')
    assert await raw.readline() == "AUTH OK 0 0"
    assert (await raw.until(1))[1].startswith("1 DATA INLINE TELESCOPE.READY_STATE=")
    await raw.close()
    c = await tsi(live)
    try:
        assert complete(await c.set("TELESCOPE.CONFIG.LOCAL.TAI-UTC=37"))
        await c.set("TELESCOPE.POWER=1")
        await c.wait("TELESCOPE.READY_STATE", lambda v: v == 1.0)
        await c.set("POINTING.TRACK=0")
        assert complete(await c.set("POINTING.SETUP.OPTIMIZATION=1;POINTING.SETUP.MIN_TRACKTIME=600"))
        ra, dec = star_near(live, 300.0, 65.0)
        assert complete(await c.set(f"OBJECT.EQUATORIAL.RA={ra:.6f};OBJECT.EQUATORIAL.DEC={dec:.5f};"
                                    "OBJECT.EQUATORIAL.EQUINOX=2000.000"))
        assert complete(await c.set("POINTING.TRACK=1"))
        await c.wait("CURRENT.TRACKTIME", lambda v: v != "NULL")
        assert await c.num("CURRENT.TRACK") == 1
        await c.command(2, "SET TELESCOPE.STOP=1")
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
        assert await c.num("CURRENT.TRACK") == 0
        assert await c.value("CURRENT.TRACKTIME") == "NULL"
    finally:
        await c.close()


async def test_song_status(live):
    """SONG's status poll: every variable it reads answers a value, on fixed ids."""
    c = await tsi(live)
    names = ["TELESCOPE.READY_STATE", "TELESCOPE.MOTION_STATE", "TELESCOPE.STATUS.GLOBAL",
             "TELESCOPE.STATUS.LIST", "POSITION.EQUATORIAL.RA_J2000", "POSITION.EQUATORIAL.DEC_J2000",
             "POSITION.EQUATORIAL.RA_CURRENT", "POSITION.EQUATORIAL.DEC_CURRENT",
             "POSITION.EQUATORIAL.PARALLACTIC_ANGLE", "POSITION.HORIZONTAL.AZ", "POSITION.HORIZONTAL.ALT",
             "POSITION.HORIZONTAL.ZD", "POSITION.HORIZONTAL.DOME", "POSITION.HORIZONTAL.DEROTATOR",
             "POSITION.LOCAL.UTC", "POSITION.LOCAL.SIDEREAL_TIME", "POSITION.INSTRUMENTAL.PORT_SELECT.CURRPOS",
             "POSITION.INSTRUMENTAL.FOCUS.CURRPOS", "POSITION.INSTRUMENTAL.DOME[0].CURRPOS",
             "POINTING.SETUP.DOME.MAX_DEVIATION", "POINTING.SETUP.USE_PORT", "CURRENT.TARGETDISTANCE",
             "TELESCOPE.CONFIG.ENVIRONMENT.TEMPERATURE", "TELESCOPE.CONFIG.ENVIRONMENT.PRESSURE"]
    try:
        for _ in range(2):
            lines = await c.command(100, "GET " + ";".join(names))
            bad = [x for x in lines if re.search(r"=(UNKNOWN|FAILED|DENIED|INVALID)", x)]
            assert not bad and len(lines) == len(names) + 2, bad or lines
        assert await c.num("POSITION.INSTRUMENTAL.PORT_SELECT.CURRPOS") == await c.num("POINTING.SETUP.USE_PORT")
    finally:
        await c.close()


# ------------------------------------------------------------------------------ the whole tree

async def test_every_opentsi_variable_reads_on_the_default_telescope(service):
    """hwconfig/sim.toml serves OpenTSI beside OpenTCI; a GET of every variable of the tree
    answers a value or a documented keyword, never an internal failure, and garbage on that
    port is answered as on the OpenTCI port."""
    from tcs.opentci_server.tree import NOBODY, VarNode

    svc, _port = service
    tree = svc.opentsi_server.tree
    paths = [path for path, node in tree.walk() if isinstance(node, VarNode)
             and node.spec.rlevel != NOBODY  # write-only: DENIED on GET (TPL2)
             and ".TRAJECTORY.BUFFER[" not in path and not path.startswith("SERVER.CONNECTION")]
    c = await RawClient.connect(svc.opentsi_port)
    try:
        for i in range(0, len(paths), 40):
            lines = await c.command(7, "GET " + ";".join(paths[i:i + 40]), timeout=30)
            assert lines[-1] == "7 COMMAND COMPLETE"
            bad = [x for x in lines if re.search(r"=(FAILED 13|INVALID|DENIED)$", x)]
            assert not bad, bad
        await c.send_bytes(b"\xff\xfe garbage\n8 SET TELESCOPE.READY=\n9 GET OBJECT.NOPE\n")
        assert (await c.until(9))[1] == "9 DATA INLINE OBJECT.NOPE=UNKNOWN"
        assert (await c.get("TELESCOPE.READY_STATE")) == "0.0"
    finally:
        await c.close()


async def test_position_angle_on_the_sky(live):
    """SETUP.DEROTATOR.OFFSET is a position angle: the derotator follows the field rotation
    turned by it (the same target tracked with 0, 30, then 0 degrees again: the field turns
    meanwhile, so the 30-degree reading is compared with the 0-degree readings interpolated to
    its moment)."""
    c = await tsi(live)
    try:
        await ready(c)
        ra, dec = star_near(live, 160.0, 55.0, ahead=5.0)
        await pyobs_set(c, "POINTING.SETUP.DEROTATOR.SYNCMODE", 3)
        readings = []
        for pa in (0.0, 30.0, 0.0):
            # each tracking starts from rest: a new TRACK while tracking leaves MOTION_STATE 11
            # and the derotator's bit 3 (on its path) set while it still turns to the new angle
            await pyobs_set(c, "POINTING.TRACK", 0)
            await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
            await c.wait("POSITION.INSTRUMENTAL.DEROTATOR[2].MOTION_STATE", lambda v: not int(v) & 3)
            await pyobs_set(c, "POINTING.SETUP.DEROTATOR.OFFSET", pa)
            await c.set(f"OBJECT.EQUATORIAL.RA={ra!r};OBJECT.EQUATORIAL.DEC={dec!r}")
            assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
            await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
            # following its trajectory (bit 1) and on it (bit 3)
            await c.wait("POSITION.INSTRUMENTAL.DEROTATOR[2].MOTION_STATE", lambda v: int(v) & 10 == 10)
            assert await c.num("CURRENT.DEROTATOR_OFFSET") == pa
            readings.append((time.monotonic(), await c.num("POSITION.INSTRUMENTAL.DEROTATOR[2].REALPOS")))
        (t0, r0), (t1, r1), (t2, r2) = readings
        drift = math.remainder(r2 - r0, 360.0)
        at_t1 = r0 + drift * (t1 - t0) / (t2 - t0)
        turned = math.remainder(r1 - at_t1, 360.0)
        assert abs(turned - 30.0) < 1.0, readings
        await pyobs_set(c, "POINTING.SETUP.DEROTATOR.OFFSET", 0.0)
        await pyobs_set(c, "POINTING.SETUP.DEROTATOR.SYNCMODE", 0)
        await pyobs_set(c, "POINTING.TRACK", 0)
    finally:
        await c.close()


async def test_rts2_differential_rates_on_opentci(live):
    """OpenTCI POINTING.TARGET.RA_V / DEC_V (RTS2's setDiffTrack, NTM): the tracked place moves
    at the rate; 0 tracks the fixed star."""
    c, o = await tsi(live), await tci(live)
    try:
        await ready(c)
        ra, dec = star_near(live, 200.0, 60.0, ahead=5.0)
        assert complete(await o.set(f"POINTING.TARGET.RA={ra!r};POINTING.TARGET.DEC={dec!r};"
                                    "POINTING.TARGET.RA_V=0;POINTING.TARGET.DEC_V=36"))
        cmd = await o.start("POINTING.TRACK=1")
        await o.wait("POINTING.TARGETDISTANCE", lambda v: v < ARCSEC and v > 0)
        await o.wait("POINTING.TRACK", lambda v: v == 1)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        t0, d0 = await o.nums("LOCAL.UTC", "POINTING.CURRENT.DEC")   # one GET: one moment
        await asyncio.sleep(3.0)
        await o.wait("POINTING.TARGETDISTANCE", lambda v: v < ARCSEC)
        t1, d1 = await o.nums("LOCAL.UTC", "POINTING.CURRENT.DEC")
        rate = (d1 - d0) * 3600.0 / (t1 - t0)
        assert abs(rate - 36.0) < 1.0, rate          # encoders a control cycle old: < 0.4"
        assert await o.num("POINTING.TARGET.DEC_V") == 36.0
        await o.set("POINTING.TRACK=0")
        await o.until(cmd, WAIT)
        await o.set("POINTING.TARGET.DEC_V=0")
    finally:
        await c.close()
        await o.close()


async def test_rts2_leftovers_on_opentci(live):
    """RTS2's model term names are aliases of ours (AOFF = IA, ZOFF = −IE, AE = −AW, FLEX = TF)
    and CABINET.STATUS.TEXT[n] names error n (rts2-opentpl-errors)."""
    o = await tci(live)
    try:
        assert await o.value("CABINET.STATUS.TEXT[5]") == '"invmode"'
        assert await o.value("CABINET.STATUS.TEXT[10]") == '"targetchange"'
        assert complete(await o.set("POINTING.POINTINGPARAMS.AOFF=0.01;POINTING.POINTINGPARAMS.ZOFF=0.02;"
                                    "POINTING.POINTINGPARAMS.AE=0.003;POINTING.POINTINGPARAMS.FLEX=0.004"))
        assert await o.nums("POINTING.POINTINGPARAMS.IA", "POINTING.POINTINGPARAMS.IE",
                            "POINTING.POINTINGPARAMS.AW", "POINTING.POINTINGPARAMS.TF") == [0.01, -0.02, -0.003, 0.004]
        assert await o.num("POINTING.POINTINGPARAMS.ZOFF") == 0.02
        for term in ("IA", "IE", "AW", "TF"):
            await o.set(f"POINTING.POINTINGPARAMS.{term}=0")
    finally:
        await o.close()


def test_tcs_server_opentsi_port_option(tmp_path):
    """``tcs-server --opentsi-port N`` serves the OpenTSI tree there (like ``--port``)."""
    import os
    import signal
    import socket
    import subprocess
    import sys

    def free_port() -> int:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    def connect(port: int) -> socket.socket:
        deadline = time.monotonic() + 60
        while True:
            try:
                return socket.create_connection(("127.0.0.1", port), timeout=10)
            except OSError:
                assert time.monotonic() < deadline, f"nothing listens on {port}"
                time.sleep(0.1)

    port, tsi_port = free_port(), free_port()
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    proc = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--port", str(port),
                             "--opentsi-port", str(tsi_port), "--alpaca-port", "0", "--alpaca-discovery-port", "-1",
                             "--web-port", "0", "--indi-port", "0"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        for p, query, answer in ((tsi_port, b"TELESCOPE.READY_STATE", b"0.0"),
                                 (port, b"CABINET.POWER_STATE", b"0.0")):
            s = connect(p)
            f = s.makefile("rb")
            assert f.readline().startswith(b"TPL2 2.1 CONN ")
            s.sendall(b'AUTH PLAIN "admin" "admin"\n1 GET ' + query + b"\n")
            assert f.readline() == b"AUTH OK 0 0\n"
            assert [f.readline() for _ in range(3)][1] == b"1 DATA INLINE " + query + b"=" + answer + b"\n"
            f.close()
            s.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()


async def test_pyobs_pointing_series(live, tmp_path):
    """start_pointing_series / add_pointing_measure / stop_pointing_series: MODEL.CLEAR, FILE
    (pyobs's absolute path: its name is kept, in the model directory), AUTO_SAVE=0, ADD and
    SAVE while tracking a star, COUNT; LOAD=1 reads FILE back; pyobs sees no COMMAND ERROR."""
    c = await tsi(live)
    try:
        await ready(c)
        for key, value in (("POINTING.MODEL.CLEAR", 1), ("POINTING.MODEL.FILE", tmp_path / "pointing_1.dat"),
                           ("POINTING.MODEL.AUTO_SAVE", 0)):
            assert complete(await pyobs_set(c, key, value))
        assert await c.value("POINTING.MODEL.FILE") == '"pointing_1.dat"'
        assert await c.num("POINTING.MODEL.COUNT") == 0
        for n, (az, alt) in enumerate(((100.0, 50.0), (220.0, 65.0)), start=1):
            ra, dec = star_near(live, az, alt)
            await pyobs_set(c, "OBJECT.EQUATORIAL.RA", ra)
            await pyobs_set(c, "OBJECT.EQUATORIAL.DEC", dec)
            assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
            await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
            lines = await pyobs_set(c, "POINTING.MODEL.ADD", str(n))
            assert complete(lines) and "DATA OK POINTING.MODEL.ADD" in lines[-2], lines
            assert complete(await pyobs_set(c, "POINTING.MODEL.SAVE", 1))
            assert await c.num("POINTING.MODEL.COUNT") == n
        assert complete(await pyobs_set(c, "POINTING.MODEL.CLEAR", 1))
        assert await c.num("POINTING.MODEL.COUNT") == 0
        assert complete(await pyobs_set(c, "POINTING.MODEL.LOAD", 1))
        assert await c.num("POINTING.MODEL.COUNT") == 2
        assert "DATA ERROR POINTING.MODEL.LOAD" in (await c.set("POINTING.MODEL.LOAD=2"))[-2]
        await pyobs_set(c, "POINTING.TRACK", 0)
    finally:
        await c.close()


# ------------------------------------------------------------------------------ fuzz (last: it
# writes harmless variables of the shared service)

_TSI_FRAGMENTS = [b"GET ", b"SET ", b"ABORT ", b"1 ", b"0 ", b"TELESCOPE.READY_STATE", b"TELESCOPE.STATUS.LIST",
                  b"TELESCOPE.STATUS.CLEAR", b"OBJECT.EQUATORIAL.RA", b"OBJECT.EQUATORIAL.EQUINOX",
                  b"OBJECT.HORIZONTAL.ALT", b"POSITION.HORIZONTAL.AZ", b"POSITION.INSTRUMENTAL.FILTER[2].CURRPOS",
                  b"POINTING.SETUP.FILTER.INDEX", b"POINTING.SETUP.FILTER.NAME", b"AUXILIARY.SENSOR",
                  b"TELESCOPE.CONFIG.PORT", b"!MEMBERS", b"!TYPE", b"[0-3]", b"[2]", b"<1>.<2>", b"=", b";",
                  b",", b'"', b"\\", b"1.5", b"-7", b"1e400", b"NULL", b"\n", b"\x00", b"\xff", b" ", b"."]


def test_fuzz_the_opentsi_port(live):
    """Any bytes on the OpenTSI port get well-formed 7-bit replies and the port keeps serving."""
    import socket

    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    port = live.service.opentsi_port

    def login() -> tuple[socket.socket, object]:
        s = socket.create_connection(("127.0.0.1", port), timeout=10)
        f = s.makefile("rb")
        assert f.readline().startswith(b"TPL2 ")
        s.sendall(b'AUTH PLAIN "admin" "admin"\n')
        assert f.readline() == b"AUTH OK 0 0\n"
        return s, f

    def until(f, final: bytes) -> list[bytes]:
        lines = []
        while line := f.readline():
            lines.append(line)
            if line.startswith(final):
                break
        return lines

    @settings(max_examples=80, deadline=None, suppress_health_check=list(HealthCheck))
    @given(st.lists(st.one_of(st.sampled_from(_TSI_FRAGMENTS), st.binary(max_size=12)), max_size=30))
    def check(parts):
        s, f = login()
        try:
            s.sendall(b"".join(parts) + b"\n4000000000 GET TELESCOPE.MOTION_STATE\n")
            lines = until(f, b"4000000000 COMMAND COMPLETE")
        finally:
            f.close()
            s.close()
        for line in lines:
            text = line.decode("ascii")
            assert text.endswith("\n") and (text.split(" ", 1)[0].isdigit() or
                                            text.split(" ", 1)[0] in ("AUTH", "DISCONNECT", "ENC")), text
        s, f = login()
        try:
            s.sendall(b"1 GET TELESCOPE.CONFIG.MOUNT\n")
            data = [x for x in until(f, b"1 COMMAND COMPLETE") if b" EVENT " not in x]  # events may come
            assert data[1] == b'1 DATA INLINE TELESCOPE.CONFIG.MOUNT="AZ-ZD"\n', data
        finally:
            f.close()
            s.close()

    check()


# ------------------------------------------------------------------------------ moving targets

def _leo_tle(lat: float, lon: float, culm_utc: float, offset_deg: float = 2.5) -> tuple[str, str]:
    """A circular 420 km, 51.6° orbit whose ground track passes ``offset_deg`` north of the
    site at ``culm_utc`` (an ISS-like pass at about 60°, happening now)."""
    import erfa
    from sgp4.api import WGS72, Satrec
    from sgp4.exporter import export_tle
    a = 6378.135 + 420.0
    n = math.sqrt(398600.4418 / a ** 3)
    epoch = culm_utc - 120.0
    inc = math.radians(51.6)
    u = math.asin(math.sin(math.radians(lat + offset_deg)) / math.sin(inc))
    gmst = erfa.gmst82(2440587.5 + culm_utc / 86400.0, 0.0)
    node = gmst + math.radians(lon) - math.atan2(math.cos(inc) * math.sin(u), math.cos(u))
    sat = Satrec()
    sat.sgp4init(WGS72, "i", 99999, 2440587.5 + epoch / 86400.0 - 2433281.5, 0.0, 0.0, 0.0, 0.0001,
                 0.0, inc, (u - n * (culm_utc - epoch)) % (2 * math.pi), n * 60.0, node % (2 * math.pi))
    return export_tle(sat)


async def test_opentsi_satellite_pass_planned_then_followed(live):
    """OBJECT.TLE.LINE1/LINE2/NAME as SONG sends them; OBJECT.TLE.PASS.* is the plan before
    tracking (start, duration, rates, cable-wrap turn, feasible); TRACK=1 follows the pass in
    progress: on target within 1″ of the planned path, where SGP4 puts the satellite."""
    from tcs.pointing.targets import SatelliteTarget
    c = await tsi(live)
    try:
        await ready(c)
        p = live.telescope.pointing
        l1, l2 = _leo_tle(p.latitude, p.local.longitude, time.time() + 80.0)
        assert complete(await c.set(f'OBJECT.TLE.NAME="TESTSAT";OBJECT.TLE.LINE1="{l1}";'
                                    f'OBJECT.TLE.LINE2="{l2}"'))
        assert "RANGE" in (await c.set('OBJECT.TLE.LINE2="2 garbage"'))[-2]   # kept the good one
        now = time.time()
        start, duration, feasible, rate, alt = await c.nums(
            "OBJECT.TLE.PASS.START", "OBJECT.TLE.PASS.DURATION", "OBJECT.TLE.PASS.FEASIBLE",
            "OBJECT.TLE.PASS.MAX_RATE", "OBJECT.TLE.PASS.MAX_ALT")
        assert feasible == 1 and start <= now + 5.0 and duration > 100.0, (start - now, duration)
        assert 0.5 < rate < 2.0 and 40.0 < alt < 80.0, (rate, alt)
        assert -270.0 <= await c.num("OBJECT.TLE.PASS.AZ_START") <= 270.0
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        await c.wait("CURRENT.TARGETDISTANCE", lambda v: v < ARCSEC)
        sat = SatelliteTarget(line1=l1, line2=l2)
        utc, az, zd = await c.nums("POSITION.LOCAL.UTC", "POSITION.HORIZONTAL.AZ", "POSITION.HORIZONTAL.ZD")
        sky = sat.sky(p.astrometry(), [utc])
        off = sky_separation(az / 15.0, 90.0 - zd, float(sky.az[0]) / 15.0, 90.0 - float(sky.zd[0]))
        assert off < 0.05, off        # encoders a cycle and a GET old at ~1°/s
        assert await c.num("CURRENT.TRACK") == 1
        await pyobs_set(c, "POINTING.TRACK", 0)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
    finally:
        await c.close()


async def test_opentsi_rates_and_a_solar_system_body(live):
    """OBJECT.EQUATORIAL.RA_RATE (on the sky, RA·cos Dec) and DEC_RATE become POINTING.TARGET.
    RA_V / DEC_V (arcsec of RA, of Dec per second) at TRACK=1, RA_RATE_TIME reads the same rate
    in seconds of time; then a body that is up (the Moon or a planet) is tracked on its
    apparent topocentric place within 1″."""
    from tcs.pointing.targets import SOLARSYSTEM_INDEX, BodyTarget
    c, o = await tsi(live), await tci(live)
    try:
        await ready(c)
        ra, dec = star_near(live, 200.0, 60.0, ahead=5.0)
        assert complete(await c.set(f"OBJECT.EQUATORIAL.RA={ra!r};OBJECT.EQUATORIAL.DEC={dec!r};"
                                    "OBJECT.EQUATORIAL.RA_RATE=15;OBJECT.EQUATORIAL.DEC_RATE=20"))
        cosd = math.cos(math.radians(dec))
        assert abs(await c.num("OBJECT.EQUATORIAL.RA_RATE_TIME") - 1.0 / cosd) < 1e-6
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        ra_v, dec_v = await o.nums("POINTING.TARGET.RA_V", "POINTING.TARGET.DEC_V")
        assert abs(ra_v - 15.0 / cosd) < 1e-6 and dec_v == 20.0, (ra_v, dec_v)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        await c.wait("CURRENT.TARGETDISTANCE", lambda v: v < ARCSEC)
        t0, d0 = await o.nums("LOCAL.UTC", "POINTING.CURRENT.DEC")
        await asyncio.sleep(3.0)
        await c.wait("CURRENT.TARGETDISTANCE", lambda v: v < ARCSEC)
        t1, d1 = await o.nums("LOCAL.UTC", "POINTING.CURRENT.DEC")
        assert abs((d1 - d0) * 3600.0 / (t1 - t0) - 20.0) < 1.0
        await c.set("OBJECT.EQUATORIAL.RA_RATE=0;OBJECT.EQUATORIAL.DEC_RATE=0")

        p = live.telescope.pointing
        ast = p.astrometry()
        now = time.time() + 10.0
        sun = BodyTarget("sun").observed(ast, [now])
        up = []
        for body in ("moon", *SOLARSYSTEM_INDEX[1:]):
            obs = BodyTarget(body).observed(ast, [now])
            elong = sky_separation(obs.az[0] / 15, 90 - obs.zd[0], sun.az[0] / 15, 90 - sun.zd[0])
            if obs.zd[0] < 60.0 and elong > 45.0:
                up.append(body)
        if not up:
            pytest.skip("neither the Moon nor a planet is up, away from the Sun, now")
        body = up[0]
        key = ("OBJECT.SOLARSYSTEM.MOON" if body == "moon" else "OBJECT.SOLARSYSTEM.OBJECT")
        value = 1 if body == "moon" else SOLARSYSTEM_INDEX.index(body)
        assert complete(await pyobs_set(c, key, value))
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        await c.wait("CURRENT.TARGETDISTANCE", lambda v: v < ARCSEC)
        utc, az, zd = await c.nums("POSITION.LOCAL.UTC", "POSITION.HORIZONTAL.AZ", "POSITION.HORIZONTAL.ZD")
        place = BodyTarget(body).observed(ast, [utc])
        off = sky_separation(az / 15.0, 90.0 - zd, float(place.az[0]) / 15.0, 90.0 - float(place.zd[0]))
        assert off < 3.0 * ARCSEC, (body, off * 3600)   # sidereal rate × a cycle and a GET
        await pyobs_set(c, "POINTING.TRACK", 0)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
        await pyobs_set(c, "OBJECT.SOLARSYSTEM.MOON", 0)
    finally:
        await c.close()
        await o.close()


async def test_opentsi_satellite_not_yet_risen_is_waited_for(live):
    """A pass that rises in a few seconds: TRACK=1 completes at once (the axes go to where the
    path starts and wait), MOTION_STATE is not 11 before the rise; after it the axes follow
    the satellite on target."""
    c = await tsi(live)
    try:
        await ready(c)
        p = live.telescope.pointing
        l1, l2 = _leo_tle(p.latitude, p.local.longitude, time.time() + 200.0)   # rises in ~12 s
        assert complete(await c.set(f'OBJECT.TLE.LINE1="{l1}";OBJECT.TLE.LINE2="{l2}"'))
        start = await c.num("OBJECT.TLE.PASS.START")
        assert start > time.time() + 3.0, start - time.time()
        assert complete(await pyobs_set(c, "POINTING.TRACK", 1))
        while time.time() < start - 1.0:
            assert int(await c.num("TELESCOPE.MOTION_STATE")) != 11     # nothing to be on yet
            await asyncio.sleep(0.5)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        await c.wait("CURRENT.TARGETDISTANCE", lambda v: v < ARCSEC)
        assert time.time() >= start
        await pyobs_set(c, "POINTING.TRACK", 0)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
    finally:
        await c.close()
