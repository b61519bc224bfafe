"""The GPS module (spec §11) over TPL2 against the simulated NMEA receiver: the real service
(``tests/hw_enclosure.toml``: a receiver at 10 Hz, loose after 0.5 s of silence, at a position
that is not the configured site) shared by the tests of this module, the receiver's faults
injected on the service's loop. Every wait is for a value or an event line.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest

from support.live import live_service
from support.opentci_client import WAIT, Client, done_ok

HW = Path(__file__).with_name("hw_enclosure.toml")
GPS_LAT, GPS_LON, GPS_HEIGHT = 28.75, -17.89, 2330.5   # [gps.sim]
SITE_LAT, SITE_LON, SITE_HEIGHT = 28.7606, -17.8792, 2326.0
ERROR_BIT, WARNING_BIT = 2, 4


live = live_service(HW)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


@pytest.fixture
async def c(live):
    """A client, the receiver talking normally and GPS.ERROR_STATE acknowledged."""
    gps = live.telescope.peripherals.sims.gps
    for knob, value in (("silent", False), ("garbage", False), ("bad_checksums", False), ("fix", True)):
        await live.call(setattr, gps, knob, value)
    await live.call(gps.replug)
    client = await Client.connect(live.port)
    deadline = time.monotonic() + WAIT
    while await client.value("GPS.TIME") == "NULL" or await client.num("GPS.ERROR_STATE"):
        assert time.monotonic() < deadline, "the GPS does not recover"
        await client.set("GPS.ERROR_STATE=0")
        await asyncio.sleep(0.05)
    client.forget()
    yield client
    await client.close()


async def test_fix_gives_position_and_time(c):
    assert int(await c.value("GPS.VERSION")) >> 16 == 24
    lat, lon, height = await c.nums("GPS.POS.LAT", "GPS.POS.LON", "GPS.POS.HEIGHT")
    assert lat == pytest.approx(GPS_LAT, abs=1e-6) and lon == pytest.approx(GPS_LON, abs=1e-6)
    assert height == pytest.approx(GPS_HEIGHT, abs=0.05)
    gps_time, utc = await c.nums("GPS.TIME", "LOCAL.UTC")
    assert abs(gps_time - utc) < 1.0
    assert await c.value("GPS.ERROR_STATE") == "0"


async def test_unplugged_receiver_is_loose_and_comes_back(live, c):
    """Unplugged: POSITION_LOOSE and TIME_LOOSE as LOCAL events, ERROR_STATE ERROR with a
    STATUS.LIST entry, TIME NULL, the last fix still served. Plugged back: GOOD events, the
    condition stays latched until acknowledged."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(gps.unplug)
    await c.event(r"^0 EVENT WARN LOCAL:24 GPS position uncertain")
    await c.event(r"^0 EVENT WARN LOCAL:26 GPS time uncertain")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) & ERROR_BIT)
    assert await c.value("GPS.TIME") == "NULL"
    assert await c.num("GPS.POS.LAT") == pytest.approx(GPS_LAT, abs=1e-6)
    assert int(await c.num("CABINET.ERROR_STATE")) & ERROR_BIT
    assert "no GPS data" in await c.value("CABINET.STATUS.LIST")
    await live.call(gps.replug)
    await c.event(r"^0 EVENT INFO LOCAL:25 GPS position good")
    await c.event(r"^0 EVENT INFO LOCAL:27 GPS time good")
    assert int(await c.num("GPS.ERROR_STATE")) & ERROR_BIT  # latched until acknowledged
    assert done_ok(await c.set("GPS.ERROR_STATE=0"), "GPS.ERROR_STATE")
    await c.wait("GPS.ERROR_STATE", lambda v: v == 0)
    float(await c.value("GPS.TIME"))


async def test_silent_receiver_turns_loose(live, c):
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "silent", True)
    await c.event(r"EVENT WARN LOCAL:26 ")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) & ERROR_BIT)
    await live.call(setattr, gps, "silent", False)
    await c.event(r"EVENT INFO LOCAL:27 ")


async def test_lost_fix_is_a_warning_with_time_still_good(live, c):
    """No fix: POSITION_LOOSE only (the receiver's clock still comes in ZDA), WARNING."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "fix", False)
    await c.event(r"EVENT WARN LOCAL:24 GPS position uncertain: no fix")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) == WARNING_BIT)
    float(await c.value("GPS.TIME"))
    assert not c.seen(r"LOCAL:26 ")
    await live.call(setattr, gps, "fix", True)
    await c.event(r"EVENT INFO LOCAL:25 ")


async def test_nmea_garbage_is_ignored_bad_checksums_are_not_data(live, c):
    """Noise and truncated sentences around good ones change nothing; sentences whose checksum
    is wrong are dropped, so the receiver turns loose."""
    gps = live.telescope.peripherals.sims.gps
    reader = live.telescope.peripherals.gps_reader
    garbage_before = reader.garbage
    await live.call(setattr, gps, "garbage", True)
    deadline = time.monotonic() + WAIT
    while reader.garbage < garbage_before + 10:
        assert time.monotonic() < deadline
        assert await c.value("GPS.ERROR_STATE") == "0"
        assert await c.num("GPS.POS.LAT") == pytest.approx(GPS_LAT, abs=1e-6)
    assert not c.seen(r"LOCAL:2[46] ")
    await live.call(setattr, gps, "garbage", False)
    await live.call(setattr, gps, "bad_checksums", True)
    await c.event(r"EVENT WARN LOCAL:24 ")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) & ERROR_BIT)
    assert reader.bad_checksums > 0
    await live.call(setattr, gps, "bad_checksums", False)
    await c.event(r"EVENT INFO LOCAL:25 ")


async def test_syncpos_makes_the_site_follow_the_gps(c):
    """LOCAL.SYNCPOS=1: the site becomes the GPS fix; writing a coordinate sets SYNCPOS=0 and
    the site stays where it was put."""
    assert done_ok(await c.set("LOCAL.SYNCPOS=1"), "LOCAL.SYNCPOS")
    await c.wait("LOCAL.LATITUDE", lambda v: v == pytest.approx(GPS_LAT, abs=1e-6))
    assert await c.num("LOCAL.LONGITUDE") == pytest.approx(GPS_LON, abs=1e-6)
    assert await c.num("LOCAL.HEIGHT") == pytest.approx(GPS_HEIGHT, abs=0.05)
    assert done_ok(await c.set(f"LOCAL.LATITUDE={SITE_LAT};LOCAL.LONGITUDE={SITE_LON};"
                               f"LOCAL.HEIGHT={SITE_HEIGHT}"), "LOCAL.HEIGHT")
    assert await c.value("LOCAL.SYNCPOS") == "0"
    await asyncio.sleep(1.5)  # longer than the SYNCPOS check period; the GPS keeps talking
    assert await c.num("LOCAL.LATITUDE") == pytest.approx(SITE_LAT, abs=1e-9)
