"""TLE validation and satellite pass planning over the real protocol (TPL2 on the OpenTSI port
of the simulated telescope).

One service (module scope) runs ``tests/hw_opentsi.toml`` with slower main axes (AZ 10°/s,
5°/s², 20°/s³; ZD 6°/s, 3°/s², 12°/s³: a pass through the zenith needs several times AZ's
speed) and 24-point trajectory buffers (12 s of a satellite's 0.5 s points: a pass outlasts
its queue). The element sets are made for *now* by
:mod:`tcs.pointing.demo_tle` (the docs' example), or edited from one.

What is checked: a line with a wrong checksum, a cut line, two lines of two satellites and an
orbit SGP4 cannot propagate (e = 0.99, 17.5 rev/day) are refused with their reason; a 30-year-old
epoch and a pass that never rises fill ``OBJECT.TLE.PASS.REASON`` and TRACK=1 is refused with it
(FAILED 9, no latched error: READY_STATE stays 1); a pass that reaches the zenith keyhole before
AZ could lead is refused at planning naming AZ and its speeds; a pass longer than the queue is
followed to its set and ends normally; the docs' example TLE is fresh and followable; a star
below the horizon is said to be below it.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support.live import live_service
from support.opentci_client import Client as SharedClient
from tcs.pointing.demo_tle import leo_tle

HW = Path(__file__).with_name("hw_opentsi.toml")
ROOT = Path(__file__).resolve().parent.parent


def _telescope(base: Path) -> Path:
    text = HW.read_text()
    az, zd = text.index("[axes.az]"), text.index("[axes.zd]")
    end = text.index("[axes.", zd + 5)
    text = (text[:az]
            + text[az:zd].replace("max_velocity = 60.0", "max_velocity = 10.0")
            .replace("max_acceleration = 120.0", "max_acceleration = 5.0")
            .replace("max_jerk = 1000.0", "max_jerk = 20.0\ntrajectory_buffer = 24")
            + text[zd:end].replace("max_velocity = 40.0", "max_velocity = 6.0")
            .replace("max_acceleration = 80.0", "max_acceleration = 3.0")
            .replace("max_jerk = 600.0", "max_jerk = 12.0\ntrajectory_buffer = 24")
            + text[end:])
    text = text.replace('channel = "tcs-test-opentsi"', 'channel = "tcs-test-tle"')
    path = base / "hw_tle.toml"
    path.write_text(text)
    return path


live = live_service(_telescope)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


class Client(SharedClient):
    patience = 90.0


def complete(lines: list[str]) -> bool:
    return lines[-1].endswith("COMMAND COMPLETE") and not any("COMMAND ERROR" in x for x in lines)


async def _ready(live) -> Client:
    c = await Client.connect(live.service.opentsi_port)
    level = int(await c.num("TELESCOPE.STATUS.GLOBAL"))
    if level:
        await c.set(f"TELESCOPE.STATUS.CLEAR={level}")
    if await c.num("TELESCOPE.READY_STATE") != 1.0:
        assert complete(await c.set("TELESCOPE.READY=1"))
    await c.set("POINTING.TRACK=0")
    await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0)
    return c


def _site(live) -> tuple[float, float]:
    p = live.telescope.pointing
    return p.latitude, p.local.longitude


def _with_checksum(line: str) -> str:
    """The line with its TLE checksum: digits, 1 per minus sign, mod 10."""
    total = sum(int(ch) if ch.isdigit() else ch == "-" for ch in line[:68])
    return line[:68] + str(total % 10)


def _satrec_tle(epoch_utc: float, inclination: float, mean_motion: float) -> tuple[str, str]:
    """A circular orbit's TLE at this epoch (Unix UTC), sgp4's exporter (valid checksums)."""
    from sgp4.api import WGS72, Satrec
    from sgp4.exporter import export_tle
    sat = Satrec()
    sat.sgp4init(WGS72, "i", 12345, 2440587.5 + epoch_utc / 86400.0 - 2433281.5, 0.0, 0.0, 0.0,
                 0.0001, 0.0, math.radians(inclination), 0.0, mean_motion * 2 * math.pi / 1440.0, 0.0)
    return export_tle(sat)


async def _text(c: Client, name: str) -> str:
    return (await c.value(name)).strip('"')


async def _refused_track(c: Client, *words: str) -> str:
    """TRACK=1 answers FAILED 9 and its event gives the reason; nothing latched."""
    lines = await c.set("POINTING.TRACK=1")
    assert any("DATA ERROR POINTING.TRACK FAILED 9" in x for x in lines), lines
    event = next((x for x in lines if "EVENT ERROR" in x), "")
    for word in words:
        assert word in event, (word, lines)
    assert await c.num("TELESCOPE.READY_STATE") == 1.0     # not latched: -1 blocks everything
    assert int(await c.num("TELESCOPE.STATUS.GLOBAL")) == 0, await c.value("TELESCOPE.STATUS.LIST")
    return event


async def test_bad_lines_are_refused_with_their_reason(live):
    """A changed digit (checksum), a cut line, e = 0.99 or 17.5 rev/day (perigee inside the
    Earth) are refused (RANGE, the last good line kept) and OBJECT.TLE.ERROR says why; two
    lines of two satellites are named in PASS.REASON and TRACK=1 is refused."""
    c = await _ready(live)
    try:
        l1, l2 = leo_tle(*_site(live), time.time() + 3600.0)
        assert complete(await c.set(f'OBJECT.TLE.LINE1="{l1}";OBJECT.TLE.LINE2="{l2}"'))
        changed = l1[:20] + ("1" if l1[20] != "1" else "2") + l1[21:]       # epoch day, checksum kept
        lines = await c.set(f'OBJECT.TLE.LINE1="{changed}"')
        assert "DATA ERROR OBJECT.TLE.LINE1 RANGE" in lines[-2], lines
        assert "checksum" in await _text(c, "OBJECT.TLE.ERROR")
        assert await _text(c, "OBJECT.TLE.LINE1") == l1                    # the good one kept
        assert "RANGE" in (await c.set(f'OBJECT.TLE.LINE2="{l2[:60]}"'))[-2]
        assert "69" in await _text(c, "OBJECT.TLE.ERROR")
        for ecc, motion in (("9900000", l2[52:63]), (l2[26:33], "17.50000000")):
            bad = _with_checksum(l2[:26] + ecc + l2[33:52] + motion + l2[63:])
            assert "RANGE" in (await c.set(f'OBJECT.TLE.LINE2="{bad}"'))[-2], bad
            reason = await _text(c, "OBJECT.TLE.ERROR")
            assert "perigee" in reason and "SGP4" in reason, reason
        assert await _text(c, "OBJECT.TLE.LINE2") == l2
        other = _with_checksum(l2[:2] + "11111" + l2[7:])                   # another satellite
        assert complete(await c.set(f'OBJECT.TLE.LINE2="{other}"'))
        assert await _text(c, "OBJECT.TLE.ERROR") == ""                     # accepted: no reason
        assert "two satellites" in await _text(c, "OBJECT.TLE.PASS.REASON")
        assert await c.num("OBJECT.TLE.PASS.FEASIBLE") == 0
        await _refused_track(c, "two satellites")
    finally:
        await c.close()


async def test_an_old_tle_is_refused_with_its_age(live):
    """A TLE from 30 years ago (valid lines): PASS.REASON names its epoch and age, the figures
    are NULL, EPOCH_AGE reads it; TRACK=1 is refused with that reason and nothing latches."""
    c = await _ready(live)
    try:
        l1, l2 = _satrec_tle(time.time() - 30 * 365.25 * 86400.0, 51.6, 15.5)
        assert l1[18:20] == "96", l1
        assert complete(await c.set(f'OBJECT.TLE.LINE1="{l1}";OBJECT.TLE.LINE2="{l2}"'))
        reason = await _text(c, "OBJECT.TLE.PASS.REASON")
        assert "1996-" in reason and "days old" in reason and "CelesTrak" in reason, reason
        assert await c.num("OBJECT.TLE.PASS.FEASIBLE") == 0
        assert abs(await c.num("OBJECT.TLE.PASS.EPOCH_AGE") - 30 * 365.25) < 1.0
        assert await c.value("OBJECT.TLE.PASS.START") == "NULL"
        await _refused_track(c, "days old")
    finally:
        await c.close()


async def test_a_pass_that_never_rises_is_refused_without_a_fault(live):
    """An equatorial low orbit never rises above 15° at 28.8° N (TPL2 writes ° as "deg"): PASS.REASON says so (not all
    NULL), TRACK=1 is FAILED 9 with that reason, READY_STATE stays 1."""
    c = await _ready(live)
    try:
        l1, l2 = _satrec_tle(time.time() - 3600.0, 0.0, 15.5)
        assert complete(await c.set(f'OBJECT.TLE.LINE1="{l1}";OBJECT.TLE.LINE2="{l2}"'))
        reason = await _text(c, "OBJECT.TLE.PASS.REASON")
        assert "does not rise above 15deg" in reason and "24 h" in reason, reason
        assert await c.num("OBJECT.TLE.PASS.FEASIBLE") == 0
        await _refused_track(c, "does not rise")
    finally:
        await c.close()


async def test_zenith_pass_the_axes_cannot_follow_is_refused_at_planning(live):
    """A pass through the zenith whose culmination is 15 s away: AZ would need far more than
    its 10°/s and there is no time left to lead, so the plan says so (AZ, the speed it needs
    against its limit) and TRACK=1 is refused before anything moves."""
    c = await _ready(live)
    try:
        l1, l2 = leo_tle(*_site(live), time.time() + 15.0, offset=0.0)
        assert complete(await c.set(f'OBJECT.TLE.LINE1="{l1}";OBJECT.TLE.LINE2="{l2}"'))
        reason = await _text(c, "OBJECT.TLE.PASS.REASON")
        assert await c.num("OBJECT.TLE.PASS.FEASIBLE") == 0, reason
        assert reason.startswith("AZ cannot follow") and "zenith" in reason and "10deg/s" in reason, reason
        assert await c.num("OBJECT.TLE.PASS.MAX_ALT") > 85.0
        await _refused_track(c, "AZ cannot follow")
        assert await c.num("TELESCOPE.MOTION_STATE") == 0
    finally:
        await c.close()


async def test_a_pass_longer_than_the_queue_is_followed_to_its_set(live):
    """The last ~30 s of a 60° pass, with 12 s of points in each axis's queue: the tracker keeps
    refilling it (it used to stop refilling a queue it had filled in one go: "trajectory ran out
    of points" once the first batch was used up) and tracking ends at the set, normally."""
    c = await _ready(live)
    try:
        l1, l2 = leo_tle(*_site(live), time.time() - 95.0)
        assert complete(await c.set(f'OBJECT.TLE.LINE1="{l1}";OBJECT.TLE.LINE2="{l2}"'))
        assert await c.num("OBJECT.TLE.PASS.FEASIBLE") == 1, await c.value("OBJECT.TLE.PASS.REASON")
        end = await c.num("OBJECT.TLE.PASS.END")
        assert end - time.time() > 20.0, end - time.time()     # longer than the queue holds
        c.forget()
        assert complete(await c.set("POINTING.TRACK=1"))
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 11)
        await c.wait("TELESCOPE.MOTION_STATE", lambda v: v == 0, timeout=end - time.time() + 60.0)
        assert time.time() > end - 2.0, end - time.time()   # not cut short
        ended = await c.event(r"POINTING:\d+ tracking ended")
        assert "EVENT INFO" in ended, ended
        assert not c.seen("ran out of points"), c.seen("ERROR")
        assert await c.num("TELESCOPE.READY_STATE") == 1.0
    finally:
        await c.close()


async def test_the_docs_example_tle_is_fresh_and_followable(live):
    """docs/satellites.md's command (``python -m tcs.pointing.demo_tle --config
    hwconfig/sim.toml --in 300``) prints a TLE of today: both lines are accepted, the epoch is
    minutes old and the pass over the simulated telescope's site (the same as sim.toml's) rises
    in about 5 minutes and can be followed."""
    page = (ROOT / "docs/satellites.md").read_text(encoding="utf-8")
    command = "python -m tcs.pointing.demo_tle --config hwconfig/sim.toml --in 300"
    assert command in page
    out = subprocess.run([sys.executable, *command.split()[1:]], cwd=ROOT, capture_output=True,
                         text=True, timeout=60, check=True).stdout
    lines = dict(re.findall(r"^(LINE[12])='([^']+)'$", out, flags=re.M))
    c = await _ready(live)
    try:
        assert complete(await c.set(f'OBJECT.TLE.NAME="DEMO";OBJECT.TLE.LINE1="{lines["LINE1"]}";'
                                    f'OBJECT.TLE.LINE2="{lines["LINE2"]}"'))
        assert await _text(c, "OBJECT.TLE.ERROR") == ""
        assert await c.num("OBJECT.TLE.PASS.FEASIBLE") == 1, await c.value("OBJECT.TLE.PASS.REASON")
        assert abs(await c.num("OBJECT.TLE.PASS.EPOCH_AGE")) < 0.01
        assert 60.0 < await c.num("OBJECT.TLE.PASS.START") - time.time() < 300.0
        assert 50.0 < await c.num("OBJECT.TLE.PASS.MAX_ALT") < 75.0
    finally:
        await c.close()


async def test_a_target_below_the_horizon_reads_so(live):
    """TRACK=1 of a star 19.27° below the horizon: the refusal says "19.27° below the horizon",
    not "-19.27° above" it."""
    p = live.telescope.pointing
    ra, dec = p.astrometry().icrs_from_observed(120.0, 90.0 + 19.27, time.time() + 2.0)
    c = await _ready(live)
    try:
        assert complete(await c.set(f"OBJECT.EQUATORIAL.RA={float(ra)!r};OBJECT.EQUATORIAL.DEC={float(dec)!r}"))
        lines = await c.set("POINTING.TRACK=1")
        assert any("DATA ERROR POINTING.TRACK FAILED 9" in x for x in lines), lines
        event = next(x for x in lines if "EVENT ERROR" in x)
        assert "target is 19.2" in event and "deg below the horizon, under the altitude limit 15deg" in event, event
    finally:
        level = int(await c.num("TELESCOPE.STATUS.GLOBAL"))
        if level:
            await c.set(f"TELESCOPE.STATUS.CLEAR={level}")
        await c.close()
