"""The NMEA GPS reader against the simulated receiver over a pty and over TCP.

The simulated receiver sends 20 bursts a second here (1 Hz in the telescope) and the reader's
timeouts are short, so losing and regaining the fix takes a fraction of a second; every wait
is on a state with a generous limit, never a fixed sleep.
"""

from __future__ import annotations

import time

import pytest

from tcs.config import parse_config
from tcs.config.gps import GpsSection
from tcs.drivers.gps import GpsReader
from tcs.errors import ConfigErrors, ErrorNumber
from tcs.sim.gps import SimGps, burst, checksum

LAT, LON, HEIGHT = 28.7606, -17.8792, 2326.0
WAIT = 20.0


def section(url: str, **changes) -> GpsSection:
    base = dict(url=url, position_timeout=0.5, time_timeout=0.5, reopen_min=0.05, reopen_max=0.3)
    return GpsSection(**{**base, **changes})


@pytest.fixture(params=["pty", "tcp"])
async def gps(request):
    """(simulated receiver, reader, events) over a pty or TCP."""
    sim = SimGps(LAT, LON, HEIGHT, rate=20.0, mode=request.param)
    await sim.start()
    reader = GpsReader(section(sim.url))
    events = []
    reader.add_listener(events.append)
    await reader.start()
    yield sim, reader, events
    await reader.stop()
    await sim.stop()


def numbers(events) -> list[int]:
    return [e.number for e in events]


def last(events, *kinds):
    """The last event among ``kinds`` (a slow machine may add flaps before it)."""
    return [e for e in events if e.number in kinds][-1]


POSITION = (ErrorNumber.POSITION_GOOD, ErrorNumber.POSITION_LOOSE)
TIME = (ErrorNumber.TIME_GOOD, ErrorNumber.TIME_LOOSE)


async def test_fix_position_and_time(gps):
    sim, reader, events = gps
    st = await reader.wait_for(lambda s: s.position_good and s.time_good, WAIT)
    assert st.latitude == pytest.approx(LAT, abs=1e-6) and st.longitude == pytest.approx(LON, abs=1e-6)
    assert st.height == pytest.approx(HEIGHT) and st.fix_quality == 1 and st.satellites == 9
    assert abs(reader.gps_time() - time.time()) < 2.0
    assert st.port_open and st.last_sentence_age < WAIT and st.sentences > 0
    assert st.bad_checksums == 0 and st.garbage == 0
    assert numbers(events)[0] in (ErrorNumber.POSITION_GOOD, ErrorNumber.TIME_GOOD)
    assert last(events, *POSITION).number == ErrorNumber.POSITION_GOOD
    assert last(events, *TIME).number == ErrorNumber.TIME_GOOD


async def test_silence_makes_position_and_time_loose_and_they_come_back(gps):
    sim, reader, events = gps
    await reader.wait_for(lambda s: s.position_good and s.time_good, WAIT)
    sim.silent = True
    st = await reader.wait_for(lambda s: not s.position_good and not s.time_good, WAIT)
    assert st.port_open and st.last_sentence_age >= 0.5
    assert last(events, *POSITION).number == ErrorNumber.POSITION_LOOSE
    assert last(events, *TIME).number == ErrorNumber.TIME_LOOSE
    assert "silent" in last(events, *POSITION).message
    sim.silent = False
    await reader.wait_for(lambda s: s.position_good and s.time_good, WAIT)
    assert last(events, *POSITION).number == ErrorNumber.POSITION_GOOD
    assert last(events, *TIME).number == ErrorNumber.TIME_GOOD


async def test_garbage_and_bad_checksums_are_counted_and_ignored(gps):
    sim, reader, events = gps
    await reader.wait_for(lambda s: s.position_good, WAIT)
    good = len(events)
    sim.latitude = 10.0          # the bad bursts carry a different position: it must not stick
    sim.garbage = sim.bad_checksums = True
    await reader.wait_for(lambda s: s.garbage >= 10 and s.bad_checksums >= 10, WAIT)
    st = reader.status
    assert st.latitude == pytest.approx(LAT, abs=1e-6)
    sim.bad_checksums = False    # garbage around valid sentences: the valid ones are used
    st = await reader.wait_for(lambda s: s.latitude == pytest.approx(10.0, abs=1e-6), WAIT)
    assert st.position_good and st.garbage > 10
    assert len(events) == good or ErrorNumber.POSITION_GOOD in numbers(events[good:])


async def test_lost_fix_is_position_loose_at_once(gps):
    sim, reader, events = gps
    await reader.wait_for(lambda s: s.position_good, WAIT)
    sim.fix = False
    st = await reader.wait_for(lambda s: not s.position_good, WAIT)
    assert st.fix_quality == 0 and st.latitude == pytest.approx(LAT, abs=1e-6)  # last known kept
    lost = last(events, *POSITION)
    assert lost.number == ErrorNumber.POSITION_LOOSE and "no fix" in lost.message
    sim.fix = True
    await reader.wait_for(lambda s: s.position_good, WAIT)


async def test_unplugged_receiver_is_loose_and_reopened_when_back():
    sim = SimGps(LAT, LON, HEIGHT, rate=20.0, mode="tcp")
    await sim.start()
    reader = GpsReader(section(sim.url))
    await reader.start()
    try:
        await reader.wait_for(lambda s: s.position_good, WAIT)
        await sim.unplug()
        st = await reader.wait_for(lambda s: not s.position_good and not s.port_open, WAIT)
        assert not st.time_good
        await sim.replug()
        st = await reader.wait_for(lambda s: s.position_good and s.time_good, WAIT)
        assert st.port_open
    finally:
        await reader.stop()
        await sim.stop()


async def test_pty_pulled_out_is_loose_without_a_crash():
    sim = SimGps(LAT, LON, HEIGHT, rate=20.0, mode="pty")
    await sim.start()
    reader = GpsReader(section(sim.url))
    await reader.start()
    try:
        await reader.wait_for(lambda s: s.position_good, WAIT)
        await sim.unplug()
        st = await reader.wait_for(lambda s: not s.position_good and not s.port_open, WAIT)
        assert st.port_error
    finally:
        await reader.stop()
        await sim.stop()


async def test_missing_device_is_loose_and_named(tmp_path):
    path = tmp_path / "ttyGPS"
    reader = GpsReader(section(str(path)))
    await reader.start()
    try:
        st = await reader.wait_for(lambda s: bool(s.port_error) and "cannot open" in s.port_error, WAIT)
        assert str(path) in st.port_error and not st.position_good and not st.port_open
    finally:
        await reader.stop()


# ------------------------------------------------------------------ the parser, without a port


def sentence(body: str, cs: str | None = None) -> bytes:
    return f"${body}*{cs or checksum(body)}\r\n".encode()


def test_sentences_parsed_and_rejects_counted():
    now = [100.0]
    reader = GpsReader(section("unused"), clock=lambda: now[0], wall=lambda: 1_700_000_000.25)
    gga, rmc, zda = burst(1_700_000_000.25, LAT, LON, HEIGHT)
    reader.feed(sentence(gga) + sentence(rmc) + sentence(zda))
    assert reader.status.latitude is None      # a fix is taken once it stood for a second
    now[0] += 1.0
    reader.feed(sentence(gga) + sentence(rmc) + sentence(zda))
    st = reader.status
    assert st.sentences == 6 and st.latitude == pytest.approx(LAT, abs=1e-6)
    assert st.time == pytest.approx(1_700_000_000.25)
    lines = [
        sentence(gga, "00"),                     # bad checksum
        b"\xff\xfe\x00binary noise\r\n",         # not NMEA
        b"$GPGGA,123519,48\r\n",                 # truncated: no checksum
        b"$" + b"A" * 200 + b"*00\r\n",          # absurdly long
        sentence("GPGSV,1,1,00"),                # valid but not used
        sentence("GPZZZ,1,2"),                   # unknown sentence type
    ]
    reader.feed(b"".join(lines))
    st = reader.status
    assert (st.bad_checksums, st.garbage, st.ignored, st.sentences) == (1, 4, 1, 6)
    reader.feed(sentence(gga)[:10])              # a partial line waits for its end
    reader.feed(sentence(gga)[10:])
    assert reader.status.sentences == 7


async def test_simulated_telescope_gps_from_the_hardware_file():
    from tcs.config import load_config
    config = load_config()
    sim = SimGps.from_config(config.gps, config.site, port=0)
    assert sim.mode == "tcp" and (sim.latitude, sim.longitude) == (config.site.latitude, config.site.longitude)
    sim.rate = 20.0
    async with sim:
        reader = GpsReader(section(sim.url))
        async with reader:
            st = await reader.wait_for(lambda s: s.position_good, WAIT)
            assert st.height == pytest.approx(config.site.height)


def test_gps_section_is_validated():
    with pytest.raises(ConfigErrors) as info:
        parse_config('[gps]\nurl = ""\nreopen_min = 5.0\nreopen_max = 1.0\n', "hw.toml")
    found = [e.message for e in info.value.errors]
    assert "hw.toml: gps.url: must name the serial port or URL of the receiver" in found
    assert any(m.startswith("hw.toml: gps.reopen_min: 5.0 is above reopen_max") for m in found)
    with pytest.raises(ConfigErrors, match="gps.url: missing"):
        parse_config("[gps]\nbaudrate = 9600\n", "hw.toml")
