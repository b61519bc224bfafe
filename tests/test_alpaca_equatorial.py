"""The Alpaca Telescope on an equatorial (RA-DEC) mount: alt/az from HA/Dec, sync as the index
terms IH/ID, pulse guiding east, driven by alpyca against ``tests/hw_pointing_eq.toml``.

The hardware file is the pointing tests' fast equatorial telescope with an ``[alpaca]`` section
and a keep-out zone (a "pier": HA 4-8 h west, Dec 50-89° in the normal orientation) added
(written next to the state directory: the file has no relative paths).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import pytest

pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
from alpaca.telescope import GuideDirections, Telescope  # noqa: E402

from support.live import live_service  # noqa: E402
from support.waits import until as wait_until  # noqa: E402

until = functools.partial(wait_until, timeout=60.0)

ARCSEC = 1.0 / 3600.0


def _equatorial_with_alpaca(base: Path) -> Path:
    hw = base / "hw_alpaca_eq.toml"
    hw.write_text(Path(__file__).with_name("hw_pointing_eq.toml").read_text() + "\n[alpaca]\nport = 0\n"
                  + "\n[[envelope.keepout]]\nname = \"pier\"\naxis1 = [60.0, 120.0]\naxis2 = [50.0, 89.0]\n")
    return hw


live = live_service(_equatorial_with_alpaca)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


def test_equatorial_slew_altaz_sync_and_guiding(live):
    t = Telescope(f"127.0.0.1:{live.service.alpaca_port}", 0)
    t.Connect()
    assert t.AlignmentMode.value == 1   # algPolar
    t.Unpark()   # asynchronous: AtPark until ready
    until(lambda: not t.AtPark, "unparked")
    t.Tracking = True
    until(lambda: not t.Slewing, "tracking where it points")
    ra, dec = (t.SiderealTime + 1.5) % 24.0, 20.0
    t.SlewToCoordinatesAsync(ra, dec)
    until(lambda: not t.Slewing, "on the star")
    until(lambda: abs(t.RightAscension - ra) * 15.0 < ARCSEC and abs(t.Declination - dec) < ARCSEC,
          "the star within 1″", timeout=10.0)
    p = live.telescope.pointing
    obs = p.astrometry().observed(ra, dec, p.utc())
    assert abs(t.Altitude - (90.0 - float(obs.zd))) < 3 * ARCSEC
    assert abs((t.Azimuth - float(obs.az) % 360.0 + 180.0) % 360.0 - 180.0) < 3 * ARCSEC / math.cos(math.radians(t.Altitude))
    params = p.params
    before = {n: params.coefficient(n) for n in ("IH", "ID")}
    try:
        t.SyncToCoordinates(ra + 0.001, dec + 0.01)
        until(lambda: not t.Slewing, "tracking after the sync")
        until(lambda: abs(t.Declination - (dec + 0.01)) < ARCSEC
              and abs(t.RightAscension - (ra + 0.001)) * 15.0 < ARCSEC, "reading the synced place", timeout=10.0)
        assert params.coefficient("IH") != before["IH"] and params.coefficient("ID") != before["ID"]
        ra0 = t.RightAscension
        t.PulseGuide(GuideDirections.guideEast, 2000)
        until(lambda: not t.IsPulseGuiding, "the pulse to end")
        until(lambda: not t.Slewing, "on target after the pulse")
        moved = (t.RightAscension - ra0) * 15.0 * math.cos(math.radians(t.Declination))
        assert abs(moved / (2.0 * t.GuideRateRightAscension) - 1.0) < 0.05
    finally:
        for name, value in before.items():
            params.set_coefficient(name, value)
        t.Tracking = False
        t.Disconnect()


def test_moveaxis_on_an_equatorial_mount_stops_at_the_horizon_limit(live):
    """MoveAxis of HA (west) or Dec (south) from the meridian on the equator would take the
    telescope far below ``[pointing] min_altitude`` (15°) before the software limits: each stops
    with the telescope at the horizon limit; lowering it further is refused, raising it works
    (issue 22 item 6)."""
    import asyncio

    from alpaca.exceptions import InvalidValueException
    from alpaca.telescope import TelescopeAxes

    from support.opentci_client import Client, done_ok

    async def goto(**targets) -> None:
        c = await Client.connect(live.port)
        try:
            for ax, pos in targets.items():
                assert done_ok(await c.set(f"{ax}.TARGETPOS={pos}", 60.0), f"{ax}.TARGETPOS")
        finally:
            await c.close()

    t = Telescope(f"127.0.0.1:{live.service.alpaca_port}", 0)
    t.Connect()
    t.Action("AcknowledgeFaults", "")   # (Unpark refuses while a drive fault is latched)
    t.Unpark()
    until(lambda: live.telescope.operations.ready_state == 1.0, "READY_STATE 1")
    t.Tracking = False
    until(lambda: not t.Slewing, "at rest")
    ha, dec = live.telescope.axis("HA"), live.telescope.axis("DEC")
    floor = live.telescope.pointing.config.min_altitude
    try:
        for axis, rate, lowered in ((TelescopeAxes.axisPrimary, 30.0, ha), (TelescopeAxes.axisSecondary, -30.0, dec)):
            asyncio.run(goto(HA=0.0, DEC=0.0))
            assert t.Altitude > 45.0
            t.MoveAxis(axis, rate)
            until(lambda: abs(lowered.real_position) > 2.0, "moving")
            until(lambda: not t.Slewing and not lowered.motion_state & 1, "stopped")
            assert abs(t.Altitude - floor) < 0.01, (axis, t.Altitude, lowered.real_position)
            assert lowered.section.min + 1.0 < lowered.real_position < lowered.section.max - 1.0
            with pytest.raises(InvalidValueException):
                t.MoveAxis(axis, rate)     # lower still: refused
            t.MoveAxis(axis, -rate)        # up again: allowed
            until(lambda: t.Altitude > floor + 1.0, "rising")
            t.MoveAxis(axis, 0.0)
            until(lambda: not t.Slewing and not lowered.motion_state & 1, "stopped")
    finally:
        t.AbortSlew()
        t.Disconnect()


def test_destination_side_of_pier_is_the_side_the_slew_ends_on(live):
    """The pier side is the TCS's (POINTING.TRACK mode 2: the orientation that stays inside the
    limits longest, normal preferred, and out of the envelope's keep-outs): DestinationSideOfPier
    answers from that same plan and SideOfPier reads it once the slew ended — also for a star
    whose normal orientation would put the tube into the pier keep-out, where the slew goes
    through the pole (pierWest). The old answer (the first orientation inside the axis limits
    and above the horizon) said pierEast there."""
    from alpaca.exceptions import DriverException

    t = Telescope(f"127.0.0.1:{live.service.alpaca_port}", 0)
    t.Connect()
    t.Action("AcknowledgeFaults", "")   # (Unpark refuses while a drive fault is latched)
    t.Unpark()
    until(lambda: live.telescope.operations.ready_state == 1.0, "READY_STATE 1")
    try:
        t.Tracking = True
        until(lambda: not t.Slewing, "tracking where it points")
        sides = []
        for ha_hours, dec in ((-2.0, 10.0), (2.0, 30.0), (5.0, 70.0), (-1.0, 60.0)):
            ra = (t.SiderealTime - ha_hours) % 24.0
            expected = t.DestinationSideOfPier(ra, dec)
            for _attempt in range(3):
                t.SlewToCoordinatesAsync(ra, dec)
                try:
                    until(lambda: not t.Slewing, "on the star")
                    break
                except DriverException as exc:   # a drive fault of a loaded machine: recover
                    assert any(w in str(exc) for w in ("following error", "stale", "faulted")), exc
                    t.Action("AcknowledgeFaults", "")
                    t.Unpark()
                    until(lambda: live.telescope.operations.ready_state == 1.0, "READY_STATE 1")
                    t.Tracking = True
                    until(lambda: not t.Slewing, "tracking where it points")
            assert t.SideOfPier == expected, (ha_hours, dec, t.SideOfPier, expected)
            sides.append(int(getattr(expected, "value", expected)))
        assert sides == [0, 0, 1, 0], sides   # HA 5 h, Dec 70: the normal side is in the pier
    finally:
        t.Tracking = False
        t.Disconnect()
