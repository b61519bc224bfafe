"""The GPS module (spec §11) over TPL2 against the simulated NMEA receiver: the real service
(``tests/hw_enclosure.toml``: a receiver at 10 Hz, loose after 2 s of silence, at a position
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
KNOBS = (("silent", False), ("garbage", False), ("bad_checksums", False), ("fix", True),
         ("kinds", ("GGA", "RMC", "ZDA")), ("quality", 1), ("cold", False), ("date_offset", 0.0),
         ("corrupt", ""), ("mixed_binary", False), ("gga_every", 1), ("talkers", ()))


live = live_service(HW)


def active(live) -> list[str]:
    """The GPS module's active conditions."""
    return [n for n, (bits, on) in live.telescope.peripherals.gps.conditions().items() if on]


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


@pytest.fixture
async def c(live):
    """A client, the receiver talking normally and GPS.ERROR_STATE acknowledged."""
    gps = live.telescope.peripherals.sims.gps
    for knob, value in KNOBS:
        await live.call(setattr, gps, knob, value)
    await live.call(live.telescope.local.set_syncpos, 0)
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


async def test_lost_fix_is_a_warning_and_the_zda_clock_is_not_time(live, c):
    """No fix: POSITION_LOOSE and TIME_LOOSE (the receiver's clock still comes in ZDA, but
    without a validated fix it is no time), WARNING ``no fix (antenna)``, GPS.TIME NULL."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "fix", False)
    await c.event(r"EVENT WARN LOCAL:24 GPS position uncertain: no fix")
    await c.event(r"EVENT WARN LOCAL:26 GPS time uncertain: no fix")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) == WARNING_BIT)
    assert await c.value("GPS.TIME") == "NULL"
    assert "no fix (antenna)" in live.telescope.peripherals.gps.conditions_text()
    await live.call(setattr, gps, "fix", True)
    await c.event(r"EVENT INFO LOCAL:25 ")
    await c.event(r"EVENT INFO LOCAL:27 ")


@pytest.mark.parametrize("kinds", [("GGA", "RMC", "GSV"), ("GSV",)], ids=["gga-rmc-gsv", "gsv-only"])
async def test_talking_without_a_fix_is_a_warning_not_no_data(live, c, kinds):
    """A receiver that talks (GGA 0, RMC V, GSV; or GSV alone) but has no fix and sends no
    ZDA: WARNING ``no GPS fix`` ("no fix (antenna)"), never ERROR ``no GPS data``."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "kinds", kinds)
    await live.call(setattr, gps, "fix", False)
    await c.event(r"EVENT WARN LOCAL:26 ")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) & WARNING_BIT)
    await asyncio.sleep(1.5)   # longer than the timeouts and the module's judging period
    assert active(live) == ["no GPS fix"]   # (a loaded machine's stall may latch an old ERROR)
    assert "no fix (antenna)" in live.telescope.peripherals.gps.conditions_text()


async def test_fix_without_time_is_named(live, c):
    """A GGA-only receiver: position good, GPS.TIME NULL, WARNING ``GPS fix without time``."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "kinds", ("GGA",))
    await c.event(r"EVENT WARN LOCAL:26 ")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) == WARNING_BIT)
    assert await c.value("GPS.TIME") == "NULL"
    assert active(live) == ["GPS fix without time"]
    assert not c.seen(r"LOCAL:24 ")


async def test_time_disagreeing_with_the_clock_is_shown_and_named(live, c):
    """The receiver 30 s off: GPS.TIME shows what it says (LOCAL.UTC the system's), TIME_LOOSE,
    ERROR ``GPS time disagrees with the clock``, GPS.TIME_OFFSET the difference."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "date_offset", 30.0)
    await c.event(r"EVENT WARN LOCAL:26 GPS time uncertain: differs from the system clock")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) & ERROR_BIT)
    gps_time, utc, offset = await c.nums("GPS.TIME", "LOCAL.UTC", "GPS.TIME_OFFSET")
    assert gps_time - utc == pytest.approx(30.0, abs=1.5) and offset == pytest.approx(30.0, abs=1.5)
    assert active(live) == ["GPS time disagrees with the clock"]
    assert "system clock by +" in live.telescope.peripherals.gps.conditions_text()
    await live.call(setattr, gps, "date_offset", 0.0)
    await c.event(r"EVENT INFO LOCAL:27 ")


async def test_simulator_mode_is_no_fix_and_its_quality_is_served(live, c):
    """A Garmin in simulator mode (GGA quality 8, RMC A mode S): no fix, GPS.FIX_QUALITY 8."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "quality", 8)
    await c.event(r"EVENT WARN LOCAL:24 GPS position uncertain: no fix \(RMC mode S \(simulator\)\)")
    await c.wait("GPS.FIX_QUALITY", lambda v: v == 8)
    assert "simulator" in await c.value("GPS.SUMMARY")
    await c.wait("GPS.ERROR_STATE", lambda v: int(v) == WARNING_BIT)


async def test_satellites_per_constellation_are_served(live, c):
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "talkers", (("GP", 11), ("GL", 5)))
    await c.wait("GPS.SATELLITES", lambda v: v == 16)
    assert await c.num("GPS.FIX_QUALITY") == 1
    text = await c.value("GPS.CONSTELLATIONS")
    assert "GP GPS 11/" in text and "GL GLONASS 5/" in text


async def test_ubx_bytes_before_the_sentences_keep_the_time(live, c):
    gps = live.telescope.peripherals.sims.gps
    reader = live.telescope.peripherals.gps_reader
    await live.call(setattr, gps, "mixed_binary", True)
    before = reader.mixed
    deadline = time.monotonic() + WAIT
    while reader.mixed < before + 30:
        assert time.monotonic() < deadline
        float(await c.value("GPS.TIME"))
        assert await c.value("GPS.ERROR_STATE") == "0"
    assert not c.seen(r"LOCAL:2[46] ")


@pytest.mark.parametrize("corrupt", ["latitude", "height"])
async def test_syncpos_never_takes_a_field_out_of_range(live, c, corrupt):
    """A checksummed GGA with latitude 95.5° (or height 99999 m) while LOCAL.SYNCPOS=1: the
    site does not move, the position is no fix."""
    gps = live.telescope.peripherals.sims.gps
    await live.call(setattr, gps, "kinds", ("GGA", "ZDA"))
    await live.call(setattr, gps, "corrupt", corrupt)
    await c.event(r"EVENT WARN LOCAL:24 ")
    assert done_ok(await c.set("LOCAL.SYNCPOS=1"), "LOCAL.SYNCPOS")
    await asyncio.sleep(1.5)  # longer than the SYNCPOS check period; the GPS keeps talking
    assert await c.num("LOCAL.LATITUDE") == pytest.approx(SITE_LAT, abs=1e-9)
    assert await c.num("LOCAL.HEIGHT") == pytest.approx(SITE_HEIGHT, abs=1e-9)
    assert await c.num("GPS.POS.LAT") == pytest.approx(GPS_LAT, abs=1e-6)
    assert "no fix (antenna)" in live.telescope.peripherals.gps.conditions_text()


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
