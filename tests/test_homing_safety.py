"""Homing (referencing) ends and bounds, and the make-ready policy, end to end (issue 39, items 1, 2).

One module-scoped service runs ``tests/hw_pointing.toml`` (AZ homes with method 19 on a home
switch at 0°: upward at 10°/s from below it; ZD references where it stands) with the Sun cone
on (30°), Alpaca and OpenTSI served, at a site whose latitude is the Sun's declination − 40°:
the Sun culminates in the NORTH (azimuth ≈ 0°, the AZ home switch's azimuth), 50° high, when
the tests start — so an AZ homing search from the west of the Sun, at its altitude, heads into
the cone. Every test places its positions relative to where the Sun is when it starts.

Checked over the real protocols (TPL2, OpenTSI, Alpaca HTTP; drives on the simulated CAN bus):

* a STOP during referencing, and a homing time-out, leave AZ where it came to rest — no slew
  back to the position the planner held before the run (``AZ.TARGETPOS=-30``, ``REINIT=1``,
  ``STOP=1`` drove back to −30 with no command) — in the threaded loop and over the control
  process (``sim.toml`` as shipped);
* a homing search that would sweep into the Sun cone is halted at its border (REINIT fails
  with 9 naming the cone), and one that starts at the border is refused before it moves —
  also when Alpaca's Unpark or OpenTSI's READY=1 start it;
* Unpark and READY=1 refuse while a drive fault is latched (an operator acknowledges it), and
  while a control-process crash is latched (``sim.toml``'s control process killed);
* ``[alpaca] read_only = true``: every motion or state change answers InvalidOperation, reads work.
"""

from __future__ import annotations

import asyncio
import dataclasses
import functools
import math
import os
import signal
import time
from pathlib import Path

import erfa
import pytest

from support.sun import sep_from_sun, sun_now
from support.live import LiveService
from support.opentci_client import Client as SharedClient
from support.service import make_config
from support.waits import until as wait_until
from tcs.pointing.envelope import sun_icrs

WAIT = 60.0
until = functools.partial(wait_until, timeout=WAIT)
HOMING = "homing = { method = 19, speed_switch = 4.0, speed_zero = 1.0, acceleration = 50.0, timeout = 20.0 }"
FAST_HOMING = "homing = { method = 19, speed_switch = 10.0, speed_zero = 1.0, acceleration = 50.0, timeout = 8.0 }"


def _site(utc: float) -> tuple[float, float]:
    """(latitude, longitude) where the Sun culminates in the north, 50° high, at ``utc``."""
    ra, dec = sun_icrs(utc)
    jd = 2440587.5 + utc / 86400.0
    gast = math.degrees(erfa.gst06a(jd, 0.0, jd + 69.184 / 86400.0, 0.0))
    lon = math.remainder(ra[0] * 15.0 - gast, 360.0)
    return float(dec[0]) - 40.0, lon


def _hwfile(base: Path, *, alpaca: str = "[alpaca]\nport = 0\n") -> Path:
    lat, lon = _site(time.time() + 20.0)
    text = Path(__file__).with_name("hw_pointing.toml").read_text()
    text = text.replace("latitude = 28.7606", f"latitude = {lat!r}").replace(
        "longitude = -17.8792", f"longitude = {lon!r}")
    text = text.replace("port = 0\n", "port = 0\nopentsi_port = 0\n", 1)   # the OpenTSI tree too
    az = text.index("[drives.az]")
    end = text.index("[drives.zd]")
    assert HOMING in text[az:end]
    text = text[:az] + text[az:end].replace(HOMING, FAST_HOMING) + text[end:]
    hw = base / "hw_homing.toml"
    hw.write_text(text + "\n" + alpaca)
    return hw


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    base = tmp_path_factory.mktemp("homing")
    service = LiveService(_hwfile(base), base / "state",
                          envelope={"sun_avoidance": 30.0, "margin": 0.5}).start()
    try:
        yield service
    finally:
        service.stop()


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


class Client(SharedClient):
    patience = WAIT


def ok(lines, obj):
    return any(line.endswith(f"DATA OK {obj}") for line in lines) and lines[-1].endswith("COMMAND COMPLETE")


async def ready(c: Client) -> None:
    """Errors acknowledged, power on, referenced (ZD up near the zenith first: an AZ homing
    search there stays far from the Sun), at rest."""
    await c.set("CABINET.ERROR_STATE=0")
    if await c.num("CABINET.POWER_STATE") != 1.0:
        await c.set("CABINET.POWER=1")
    for ax in ("AZ", "ZD"):
        if await c.num(f"{ax}.POWER_STATE") != 1.0:
            await c.set(f"{ax}.POWER=1")
    if await c.num("ZD.REFERENCED") < 1.0:
        await c.set("ZD.REINIT=0")
        await c.wait("ZD.REFERENCED", lambda v: v == 1.0)
    if abs(await c.num("ZD.REALPOS")) > 5.5:
        assert ok(await c.set("ZD.TARGETPOS=5"), "ZD.TARGETPOS")
    if await c.num("AZ.REFERENCED") < 1.0:
        await c.set("AZ.REINIT=0")
        await c.wait("AZ.REFERENCED", lambda v: v == 1.0)
    for ax in ("AZ", "ZD"):
        await c.wait(f"{ax}.MOTION_STATE", lambda v: not int(v) & 1)


async def stays(c: Client, obj: str, value: float, seconds: float = 3.0) -> None:
    """``obj`` keeps ``value`` (to 0.01) for ``seconds``: no motion nobody asked for."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        now = await c.num(obj)
        assert abs(now - value) < 0.01, f"{obj} moved from {value} to {now} with no command"
        await asyncio.sleep(0.05)


async def at_rest(c: Client) -> float:
    """AZ at rest (MOTION_STATE bit 0 clear and the speed ~0): its position."""
    await c.wait("AZ.MOTION_STATE", lambda v: not int(v) & 1)
    await c.wait("AZ.CURRSPEED", lambda v: abs(v) < 1e-3)
    return await c.num("AZ.REALPOS")


async def test_stop_during_referencing_leaves_az_where_it_halted(live):
    """``AZ.TARGETPOS=-30``, ``AZ.REINIT=1``, ``AZ.STOP=1`` during the search: AZ halts and
    stays there (TARGETPOS reads where it is); it never drives back to −30."""
    c = await Client.connect(live.port)
    try:
        await ready(c)
        assert ok(await c.set("AZ.TARGETPOS=-30"), "AZ.TARGETPOS")
        c.forget()
        await c.set("AZ.REINIT=1")
        await c.wait("AZ.REALPOS", lambda v: v > -27.0)      # the search runs up to the switch
        await c.set("AZ.STOP=1")
        await c.event(r"EVENT ERROR AZ:20 ")                   # the referencing ended, failed
        halted = await at_rest(c)
        assert halted > -27.0 and await c.num("AZ.REFERENCED") == 0.0
        await stays(c, "AZ.REALPOS", halted)
        assert abs(await c.num("AZ.TARGETPOS") - halted) < 0.01
        assert not c.seen(r"EVENT INFO AZ:23 moving to")
    finally:
        await c.close()


async def test_a_homing_timeout_moves_nothing_afterwards(live):
    """A homing run that times out (8 s here; 10 s needed from −100): the drive stops the search,
    REINIT fails, and AZ stays where it came to rest — no slew back to −100."""
    c = await Client.connect(live.port)
    try:
        await ready(c)
        assert ok(await c.set("AZ.TARGETPOS=-100"), "AZ.TARGETPOS")
        c.forget()
        await c.set("AZ.REINIT=1")
        event = await c.event(r"EVENT ERROR AZ:20 ", timeout=WAIT)
        assert "8 s" in event or "time" in event.lower(), event
        halted = await at_rest(c)
        assert halted > -95.0, halted                           # it searched, then stopped
        await stays(c, "AZ.REALPOS", halted)
        assert abs(await c.num("AZ.TARGETPOS") - halted) < 0.01
    finally:
        await c.close()


async def test_a_homing_search_stops_at_the_sun_cone_and_a_make_ready_there_is_refused(live):
    """AZ 60° west of the Sun at its altitude, the home switch beyond the Sun: ``AZ.REINIT=1``
    starts the search, which is halted before the 30° cone (REINIT fails with 9 naming it, AZ
    at rest outside the cone and staying there). A make-ready from there — Alpaca ``Unpark``,
    OpenTSI ``READY=1`` — would start the same search at the border: refused, nothing moves."""
    pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
    from alpaca.exceptions import DriverException
    from alpaca.telescope import Telescope

    c = await Client.connect(live.port)
    try:
        await ready(c)
        saz, szd = sun_now(live)
        here = await c.num("AZ.REALPOS")
        start = here + math.remainder(saz - 60.0 - here, 360.0)
        assert ok(await c.set(f"AZ.TARGETPOS={start!r}"), "AZ.TARGETPOS")
        assert ok(await c.set(f"ZD.TARGETPOS={szd!r}"), "ZD.TARGETPOS")
        c.forget()
        lines = await c.set("AZ.REINIT=1")
        assert lines[-1].endswith("COMMAND COMPLETE"), lines      # it starts (the cone is 10° off)
        event = await c.event(r"EVENT ERROR AZ:9 ")
        assert "Sun avoidance cone" in event and "homing search" in event, event
        await c.event(r"EVENT ERROR AZ:20 ")
        halted = await at_rest(c)
        zd = await c.num("ZD.REALPOS")
        assert halted > start + 5.0                                   # it searched towards the Sun
        assert sep_from_sun(live, halted, zd) >= 30.0 - 1e-3
        await stays(c, "AZ.REALPOS", halted, 2.0)

        lines = await c.set("AZ.REINIT=1")                            # from the border: refused
        assert any("DATA ERROR AZ.REINIT FAILED 9" in x for x in lines), lines
        assert any("Sun avoidance cone" in x for x in lines), lines

        t = Telescope(f"127.0.0.1:{live.service.alpaca_port}", 0)
        t.Connect()
        try:
            t.Unpark()                                                # READY=1 in the background
            failures = []

            def ended() -> bool:
                try:
                    return not t.Slewing
                except DriverException as exc:
                    failures.append(str(exc))
                    return True
            await asyncio.to_thread(until, ended, "the Unpark to end")
            assert failures and "Sun avoidance cone" in failures[0], failures
        finally:
            t.Disconnect()
        tsi = await Client.connect(live.service.opentsi_port)
        try:
            lines = await tsi.set("TELESCOPE.READY=1")
            assert any("DATA ERROR TELESCOPE.READY" in x for x in lines), lines
        finally:
            await tsi.close()
        assert abs(await c.num("AZ.REALPOS") - halted) < 0.01 and await c.num("AZ.REFERENCED") == 0.0
        assert sep_from_sun(live, await c.num("AZ.REALPOS"), zd) >= 30.0 - 1e-3
    finally:
        # out of the Sun's way as an operator would: the tube down to 18° altitude (up would
        # enter the cone), where the AZ search passes 32° from the Sun; referenced, AZ to the
        # south, the tube up again
        for text in ("ZD.TARGETPOS=72", "AZ.REINIT=0"):
            await c.set(text)
        await c.wait("AZ.REFERENCED", lambda v: v == 1.0)
        await c.wait("AZ.MOTION_STATE", lambda v: not int(v) & 1)
        for text in ("AZ.TARGETPOS=180", "ZD.TARGETPOS=5"):
            await c.set(text)
        await c.close()


async def test_unpark_and_ready_refuse_a_latched_drive_fault(live):
    """A drive fault (overcurrent of the AZ drive) latched: Alpaca ``Unpark`` answers
    InvalidOperation naming the drive fault and the acknowledge, OpenTSI ``READY=1`` fails the
    same way; the fault stays latched. After the operator's acknowledge, READY=1 makes ready."""
    pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
    from alpaca.exceptions import InvalidOperationException
    from alpaca.telescope import Telescope

    c = await Client.connect(live.port)
    try:
        await ready(c)
    finally:
        await c.close()
    await live.call(live.telescope.sims[1].inject_fault, "overcurrent")
    cab = live.telescope.cabinet
    await asyncio.to_thread(until, lambda: cab.error_state & 2, "the fault latched")
    t = Telescope(f"127.0.0.1:{live.service.alpaca_port}", 0)
    t.Connect()
    try:
        with pytest.raises(InvalidOperationException) as refused:
            await asyncio.to_thread(t.Unpark)
        assert "AZ: drive fault" in str(refused.value) and "AcknowledgeFaults" in str(refused.value)
    finally:
        t.Disconnect()
    tsi = await Client.connect(live.service.opentsi_port)
    try:
        lines = await tsi.set("TELESCOPE.READY=1")
        assert any("DATA ERROR TELESCOPE.READY" in x for x in lines), lines
        assert any("drive fault" in x for x in lines), lines
        assert cab.error_state & 2                                  # still latched: not hidden
        assert await tsi.num("TELESCOPE.READY_STATE") == -1.0
        await tsi.set("TELESCOPE.STATUS.CLEAR=2")                   # the operator acknowledges
        lines = await tsi.set("TELESCOPE.READY=1")
        assert lines[-1].endswith("COMMAND COMPLETE"), lines
        assert await tsi.num("TELESCOPE.READY_STATE") == 1.0
    finally:
        await tsi.close()


# ------------------------------------------------------------------ services of their own

@pytest.fixture(scope="module")
def proc_live(tmp_path_factory):
    """The shipped ``sim.toml`` as it is (the loop in a control process; Sun cone off)."""
    from tcs.config import DEFAULT_CONFIG
    base = tmp_path_factory.mktemp("proc")
    service = LiveService(DEFAULT_CONFIG, base / "state").start()
    try:
        yield service
    finally:
        service.stop()


async def test_control_process_stop_during_referencing_leaves_az_where_it_halted(proc_live):
    """The same over the control process (``sim.toml``: AZ homes upward to its switch at 11°
    at 2°/s): ``AZ.TARGETPOS=5``, ``REINIT=1``, ``STOP=1`` during the search — AZ stays where
    it halted, TARGETPOS reads that, no slew back to 5."""
    c = await Client.connect(proc_live.port)
    try:
        await c.set("CABINET.POWER=1")
        await c.set("AZ.REINIT=0")
        await c.wait("AZ.REFERENCED", lambda v: v == 1.0)
        assert ok(await c.set("AZ.TARGETPOS=5"), "AZ.TARGETPOS")
        c.forget()
        await c.set("AZ.REINIT=1")
        await c.wait("AZ.REALPOS", lambda v: v > 6.5)
        await c.set("AZ.STOP=1")
        await c.event(r"EVENT ERROR AZ:20 ")
        halted = await at_rest(c)
        assert halted > 6.5 and await c.num("AZ.REFERENCED") == 0.0
        await stays(c, "AZ.REALPOS", halted)
        assert abs(await c.num("AZ.TARGETPOS") - halted) < 0.01
    finally:
        await c.close()


async def test_unpark_and_ready_refuse_a_latched_control_process_crash(proc_live):
    """``sim.toml`` (the loop in a control process): kill -9 of the control process, a new one
    is started; the crash stays latched, and Alpaca ``Unpark`` / OpenTSI ``READY=1`` refuse,
    naming it, until it is acknowledged — then Unpark starts the make-ready."""
    pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
    from alpaca.exceptions import InvalidOperationException
    from alpaca.telescope import Telescope
    from test_control_process import _children

    service = proc_live.service
    (child,) = _children(os.getpid())
    os.kill(child, signal.SIGKILL)
    process = service.telescope.can
    deadline = time.monotonic() + 120
    while _children(os.getpid()) in ([], [child]) or process.respawning or \
            process._gone is not None or not service.telescope.control_loop.healthy():
        assert time.monotonic() < deadline and not process.given_up, "not restarted"
        await asyncio.sleep(0.1)
    t = Telescope(f"127.0.0.1:{service.alpaca_port}", 0)
    await asyncio.to_thread(t.Connect)
    try:
        with pytest.raises(InvalidOperationException) as refused:
            await asyncio.to_thread(t.Unpark)
        assert "control process crashed" in str(refused.value), refused.value
        tsi = await Client.connect(service.opentsi_port)
        try:
            lines = await tsi.set("TELESCOPE.READY=1")
            assert any("DATA ERROR TELESCOPE.READY" in x for x in lines), lines
            assert any("control process" in x for x in lines), lines
        finally:
            await tsi.close()
        assert service.telescope.cabinet.error_state & 2
        assert await asyncio.to_thread(t.Action, "AcknowledgeFaults", "") == "acknowledged"
        await asyncio.to_thread(t.Unpark)                  # accepted now (runs in the background)
        await asyncio.to_thread(t.AbortSlew)
    finally:
        await asyncio.to_thread(t.Disconnect)


async def test_read_only_alpaca_refuses_motion_and_answers_reads(tmp_path):
    """``[alpaca] read_only = true``: Unpark, Tracking, MoveAxis, the focuser's Move and the
    AcknowledgeFaults action answer InvalidOperation naming the setting; nothing powers or
    moves; Connect, Connected and the reads work."""
    pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
    from alpaca.exceptions import InvalidOperationException
    from alpaca.telescope import Telescope, TelescopeAxes
    from tcs.app import Service

    base = make_config(tmp_path / "state", _hwfile(tmp_path))
    config = dataclasses.replace(base, alpaca=dataclasses.replace(base.alpaca, read_only=True))
    object.__setattr__(config, "source", base.source)
    service = Service(config)
    await service.start()
    try:
        t = Telescope(f"127.0.0.1:{service.alpaca_port}", 0)
        await asyncio.to_thread(t.Connect)
        assert await asyncio.to_thread(lambda: t.Connected)
        calls = (lambda: t.Unpark(), lambda: setattr(t, "Tracking", True),
                 lambda: t.MoveAxis(TelescopeAxes.axisPrimary, 1.0), lambda: t.FindHome(),
                 lambda: t.Action("AcknowledgeFaults", ""), lambda: t.SetPark())
        for call in calls:
            with pytest.raises(InvalidOperationException) as refused:
                await asyncio.to_thread(call)
            assert "read_only" in str(refused.value), refused.value
        assert await asyncio.to_thread(lambda: t.AtPark)            # reads work
        assert isinstance(await asyncio.to_thread(lambda: t.Azimuth), float)
        await asyncio.sleep(0.5)
        assert service.telescope.cabinet.power_state == 0.0          # nothing was switched on
        assert all(a.power_state == 0.0 and not a.motion_state & 1 for a in service.telescope.axes)
        await asyncio.to_thread(t.Disconnect)
    finally:
        await service.stop()
