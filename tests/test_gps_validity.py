"""Issue 43: what a real receiver's sentences are worth, judged over the real pty path.

Two kinds of test, both through a pty into :class:`~tcs.drivers.gps.GpsReader`:

* the simulated receiver (``tcs.sim.gps``) with the failure shapes of real ones switched on
  (cold start, simulator mode, dead reckoning, week rollover, a field out of range, UBX bytes
  before the sentences, no GGA, GGA every few seconds, one GGA per constellation);
* record-like fixtures: sentences as receivers of the 30 recordings write them (written here,
  checksummed here), replayed in a loop on a pty, with the reader's system clock (``wall``)
  set to the fixture's epoch so the comparison with the clock is judged as on the day.

Every wait is on a state with a generous limit; a "never good" is judged after enough
sentences have arrived, from the events the reader sent.
"""

from __future__ import annotations

import asyncio
import calendar
import contextlib
import os
import time
import tty

import pytest

from tcs.config.gps import GpsSection
from tcs.drivers.gps import GpsReader
from tcs.drivers.nmea_judge import WEEKS_1024
from tcs.errors import ErrorNumber
from tcs.sim.gps import UBX_BLOB, SimGps, checksum

LAT, LON, HEIGHT = 28.7606, -17.8792, 2326.0
WAIT = 20.0
GOOD = (ErrorNumber.POSITION_GOOD, ErrorNumber.TIME_GOOD)


def section(url: str, **changes) -> GpsSection:
    base = dict(url=url, position_timeout=0.5, time_timeout=0.5, reopen_min=0.05, reopen_max=0.3)
    return GpsSection(**{**base, **changes})


@contextlib.asynccontextmanager
async def simulated(wall=time.time, timeouts: float = 0.5, **knobs):
    """(receiver, reader, events): the simulated receiver at 20 Hz on a pty with ``knobs`` set;
    ``timeouts``: the reader's position and time timeouts."""
    sim = SimGps(LAT, LON, HEIGHT, rate=20.0, mode="pty")
    for knob, value in knobs.items():
        assert hasattr(sim, knob), knob
        setattr(sim, knob, value)
    await sim.start()
    reader = GpsReader(section(sim.url, position_timeout=timeouts, time_timeout=timeouts), wall=wall)
    events = []
    reader.add_listener(events.append)
    await reader.start()
    try:
        yield sim, reader, events
    finally:
        await reader.stop()
        await sim.stop()


def nmea(*bodies: str, prefix: bytes = b"") -> bytes:
    return b"".join(prefix + f"${b}*{checksum(b)}\r\n".encode() for b in bodies)


@contextlib.asynccontextmanager
async def replayed(data: bytes, epoch: float, rate: float = 20.0, paced: bool = False):
    """(reader, events): ``data`` written to a pty ``rate`` times a second; the reader's system
    clock stays at ``epoch`` (UTC of the fixture, which repeats one epoch). ``paced``: line by line over the epoch, as
    a receiver at 4800 baud sends them (each line read on its own)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    loop = asyncio.get_running_loop()
    reader = GpsReader(section(os.ttyname(slave)), wall=lambda: epoch)   # the fixture repeats one epoch
    events = []
    reader.add_listener(events.append)
    handle = None

    lines = data.splitlines(keepends=True) if paced else [data]

    def put(chunk: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(master, chunk)

    def write():
        nonlocal handle
        put(lines[0])
        for i, chunk in enumerate(lines[1:], 1):
            loop.call_later(i * 0.6 / rate / len(lines), put, chunk)
        handle = loop.call_later(1.0 / rate, write)

    await reader.start()
    await reader.wait_for(lambda s: s.port_open, WAIT)   # the first epoch is read from its start
    write()
    try:
        yield reader, events
    finally:
        handle.cancel()
        await reader.stop()
        os.close(master)
        os.close(slave)


async def never_good(reader, events, sentences: int = 12):
    """After ``sentences`` more sentences: no good event was ever sent and none is good now."""
    seen = reader.status.sentences + reader.status.ignored
    await reader.wait_for(lambda s: s.sentences + s.ignored >= seen + sentences, WAIT)
    st = reader.status
    assert not st.position_good and not st.time_good and not st.time_valid, st.summary()
    assert not [e for e in events if e.number in GOOD], [e.message for e in events]
    return st


def utc(*ymdhms) -> float:
    return float(calendar.timegm((*ymdhms, 0, 0, 0)[:6]))


# ------------------------------------------------------------------ 1 invalid time reported as good

async def test_cold_start_gives_no_time_and_no_fix():
    """RMC status V, GGA quality 0, ZDA with the receiver's 1999-08-22 clock: nothing is good,
    GPS time is never served, and the reasons are named."""
    async with simulated(cold=True) as (sim, reader, events):
        st = await never_good(reader, events)
        assert reader.gps_time() is None or not st.time_valid
        assert "RMC status V" in st.fix_reason or "quality 0" in st.fix_reason
        assert "1999" in st.time_reason or "without a valid fix" in st.time_reason
        assert st.data_good and "no fix" in st.summary()


async def test_zda_without_a_validated_fix_is_not_time():
    """The receiver loses its fix: RMC V and GGA 0, ZDA still ticking — the time turns loose."""
    async with simulated() as (sim, reader, events):
        await reader.wait_for(lambda s: s.time_good, WAIT)
        sim.fix = False
        await reader.wait_for(lambda s: not s.time_valid and not s.time_good, WAIT)
        assert [e for e in events if e.number == ErrorNumber.TIME_LOOSE]
        del events[:]
        st = await never_good(reader, events)
        assert "without a valid fix" in st.time_reason and reader.status.time is not None


FIXTURE_DAY = utc(2023, 3, 14, 12, 0, 5)
F9P_DAY = utc(2021, 6, 2, 9, 41, 12)

RMC_1980 = nmea("GPGGA,120005.00,4807.0380,N,01131.0000,E,1,08,0.9,545.4,M,46.9,M,,",
                "GPRMC,120005.00,A,4807.0380,N,01131.0000,E,0.0,0.0,050180,,,A")
RMC_MODE_N = nmea("GPRMC,120005.00,A,4807.0380,N,01131.0000,E,0.0,0.0,140323,,,N",
                  "GPZDA,120005.00,14,03,2023,00,00")


async def test_rmc_status_a_with_mode_n_is_no_fix_and_no_time():
    """NMEA 2.3: status A but mode indicator N (data not valid); the ZDA beside it is not time."""
    async with replayed(RMC_MODE_N, FIXTURE_DAY) as (reader, events):
        st = await never_good(reader, events)
        assert "RMC mode N" in st.fix_reason


async def test_rmc_dated_1980_gives_no_time():
    """A fix with an RMC dated 05.01.1980: the position is good, the time is refused."""
    async with replayed(RMC_1980, FIXTURE_DAY) as (reader, events):
        st = await reader.wait_for(lambda s: s.position_good and "1980" in s.time_reason, WAIT)
        assert not st.time_valid and st.time is None
        assert "before 2000" in st.time_reason
        assert not [e for e in events if e.number == ErrorNumber.TIME_GOOD]


# ------------------------------------------------------------------ 2 GPS time against the system clock

async def test_time_disagreeing_with_the_clock_is_served_but_not_good():
    """A receiver 30 s off the system clock: GPS time is served (what the receiver says), the
    time is not good (26), and the offset is named."""
    async with simulated(date_offset=30.0) as (sim, reader, events):
        st = await reader.wait_for(lambda s: s.time_valid and s.position_good, WAIT)
        assert st.clock_offset == pytest.approx(30.0, abs=1.5)
        assert reader.gps_time() - time.time() == pytest.approx(30.0, abs=1.5)
        assert not st.time_good
        assert not [e for e in events if e.number == ErrorNumber.TIME_GOOD]
        sim.date_offset = 0.0
        loose_before = [e for e in events if e.number == ErrorNumber.TIME_LOOSE]
        await reader.wait_for(lambda s: s.time_good, WAIT)
        assert not loose_before or "system clock" in loose_before[-1].message


async def test_week_rollover_is_corrected_and_said():
    """Firmware 1024 weeks behind: the date is corrected and the note says so."""
    async with simulated(date_offset=-WEEKS_1024) as (sim, reader, events):
        st = await reader.wait_for(lambda s: s.time_good, WAIT)
        assert abs(reader.gps_time() - time.time()) < 2.0
        assert "week rollover" in st.time_note and "1024 weeks" in st.time_note


async def test_rollover_date_far_from_the_clock_is_not_good():
    """1024 weeks early but the system clock is elsewhere (no match): never good."""
    day = utc(2006, 8, 1, 12, 0, 5)   # rollover firmware of 2026 sends this
    data = nmea("GPGGA,120005.00,4807.0380,N,01131.0000,E,1,08,0.9,545.4,M,46.9,M,,",
                "GPRMC,120005.00,A,4807.0380,N,01131.0000,E,0.0,0.0,010806,,,A")
    async with replayed(data, day + 5 * 365 * 86400) as (reader, events):
        st = await reader.wait_for(lambda s: s.time_valid, WAIT)
        assert not st.time_good and abs(st.clock_offset) > 365 * 86400
        assert not [e for e in events if e.number == ErrorNumber.TIME_GOOD]


# ------------------------------------------------------------------ 3 only real fixes are fixes

@pytest.mark.parametrize("quality, name", [(6, "dead reckoning"), (7, "manual input"), (8, "simulator")])
async def test_dead_reckoning_manual_and_simulator_are_not_fixes(quality, name):
    """A Garmin in simulator mode (GGA 8, RMC A with mode S), dead reckoning, manual input."""
    async with simulated(quality=quality) as (sim, reader, events):
        st = await never_good(reader, events)
        assert name in st.fix_reason and st.fix_quality == quality and st.quality_name == name


# ------------------------------------------------------------------ 4 ranges

@pytest.mark.parametrize("corrupt, why", [("latitude", "95.5° beyond 90°"), ("hemisphere", "without hemisphere"),
                                          ("minutes", "≥ 60")])
async def test_fields_out_of_range_are_no_fix(corrupt, why):
    async with simulated(corrupt=corrupt) as (sim, reader, events):
        st = await never_good(reader, events)
        assert why in st.fix_reason and st.latitude is None


async def test_impossible_height_is_never_taken():
    """GGA-only receiver with a height of 99999 m: no fix, the height is never served."""
    async with simulated(corrupt="height", kinds=("GGA", "ZDA")) as (sim, reader, events):
        st = await never_good(reader, events)
        assert "height 99999" in st.fix_reason and st.height is None


# ------------------------------------------------------------------ 5 binary before the sentence

async def test_ubx_bytes_before_the_sentences_on_the_same_line():
    """A ZED-F9P sending UBX and NMEA on one port: every sentence is still found."""
    async with simulated(mixed_binary=True) as (sim, reader, events):
        st = await reader.wait_for(lambda s: s.position_good and s.time_good and s.mixed >= 30, WAIT)
        assert st.latitude == pytest.approx(LAT, abs=1e-6) and st.bad_checksums == 0
        assert st.time_source.endswith(("RMC", "ZDA"))


async def test_kilobytes_of_binary_before_a_sentence():
    """UBX RXM-RAWX-sized binary (6 kB without a newline byte) before each RMC: still read."""
    blob = bytes(b for b in range(256) if b not in (0x0A, 0x24)) * 24
    data = blob + nmea("GNRMC,094112.00,A,5231.04821,N,01323.51215,E,0.012,,020621,,,A,V",
                       "GNZDA,094112.00,02,06,2021,00,00")
    async with replayed(data, F9P_DAY, rate=10.0) as (reader, events):
        st = await reader.wait_for(lambda s: s.time_good and s.position_good and s.sentences >= 20, WAIT)
        assert st.latitude == pytest.approx(52.5174702, abs=1e-6)


def test_a_sentence_cut_after_kilobytes_of_binary_is_kept():
    """The bytes up to the middle of a sentence arrive after 6 kB of binary, the rest later."""
    now = [100.0]
    reader = GpsReader(section("unused"), clock=lambda: now[0], wall=lambda: F9P_DAY)
    rmc = nmea("GNRMC,094112.00,A,5231.04821,N,01323.51215,E,0.012,,020621,,,A,V")
    reader.feed(bytes(range(0x30, 0x70)) * 100 + rmc[:30])
    reader.feed(rmc[30:])
    now[0] += 1.0          # a fix is taken once it stood for a second (tcs.drivers.gps.CONFIRM)
    reader.feed(rmc)
    assert reader.status.latitude == pytest.approx(52.5174702, abs=1e-6) and reader.status.garbage == 1


# ------------------------------------------------------------------ 6 position from every sentence

@pytest.mark.parametrize("kinds", [("RMC", "ZDA"), ("GLL",), ("GNS", "ZDA"), ("PUBX", "GSV")],
                         ids=["rmc", "gll", "gns", "pubx"])
async def test_receivers_without_gga_show_a_position(kinds):
    async with simulated(kinds=kinds) as (sim, reader, events):
        st = await reader.wait_for(lambda s: s.position_good, WAIT)
        assert st.latitude == pytest.approx(LAT, abs=1e-6) and st.longitude == pytest.approx(LON, abs=1e-6)
        assert st.fix_source.endswith(kinds[0])


async def test_gga_every_few_seconds_does_not_flip_the_fix():
    """GGA only every 40th burst (2 s, beyond the 1.5 s timeout), RMC in every one: never loose."""
    async with simulated(gga_every=40, timeouts=1.5) as (sim, reader, events):
        await reader.wait_for(lambda s: s.position_good and s.height is not None, WAIT)
        first = sim.bursts
        await reader.wait_for(lambda s: sim.bursts >= first + 60, WAIT)   # a whole gap, 3 s
        assert reader.status.height == pytest.approx(HEIGHT) and reader.position_good
        assert not [e for e in events if e.number == ErrorNumber.POSITION_LOOSE]


# ------------------------------------------------------------------ 7 talking without a fix

async def test_gsv_alone_is_data_but_no_fix():
    async with simulated(kinds=("GSV",)) as (sim, reader, events):
        await reader.wait_for(lambda s: s.ignored >= 10, WAIT)
        st = reader.status
        assert st.data_good and not st.position_good and not st.time_valid
        assert st.constellations and st.constellations[0][2] == 12   # in view


# ------------------------------------------------------------------ 8 satellites per constellation

async def test_glonass_gga_does_not_overwrite_the_gps_count():
    async with simulated(talkers=(("GP", 11), ("GL", 5))) as (sim, reader, events):
        st = await reader.wait_for(lambda s: s.position_good and len(s.constellations) == 2, WAIT)
        assert st.satellites == 16
        assert {c[0]: c[1] for c in st.constellations} == {"GP": 11, "GL": 5}
        assert "GLONASS 5/" in st.constellation_text()


# ------------------------------------------------------------------ record-like fixtures

# (name, data, wall clock, position good?, time valid?, a text the reason holds)
FIXTURES = [
    ("sirf-cold-start",
     nmea("GPGGA,000012.000,0000.0000,N,00000.0000,E,0,00,50.0,0.0,M,0.0,M,,0000",
          "GPRMC,000012.000,V,0000.0000,N,00000.0000,E,0.00,0.00,220899,,,N",
          "GPGSV,1,1,00", "GPZDA,000012.000,22,08,1999,,"),
     FIXTURE_DAY, False, False, "no fix: "),
    ("garmin-simulator",
     nmea("GPRMC,120005,A,4807.038,N,01131.000,E,000.0,000.0,140323,003.1,E,S",
          "GPGGA,120005,4807.038,N,01131.000,E,8,08,0.9,545.4,M,46.9,M,,"),
     FIXTURE_DAY, False, False, "simulator"),
    ("garmin-simulator-nmea20",   # RMC and GLL without a mode field say A; only GGA says 8
     nmea("GPRMC,120005,A,4807.038,N,01131.000,E,000.0,000.0,140323,003.1,E",
          "GPGGA,120005,4807.038,N,01131.000,E,8,08,0.9,545.4,M,46.9,M,,",
          "GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1", "GPGLL,4807.038,N,01131.000,E,120005,A"),
     FIXTURE_DAY, False, False, "simulator"),
    ("f9p-ubx-and-nmea-41",   # NMEA 4.10: navigational status V is a fixed "not provided"
     nmea("GNRMC,094112.00,A,5231.04821,N,01323.51215,E,0.012,,020621,,,A,V",
          "GNGGA,094112.00,5231.04821,N,01323.51215,E,1,12,0.58,41.6,M,44.3,M,,",
          "GNZDA,094112.00,02,06,2021,00,00", prefix=UBX_BLOB),
     F9P_DAY, True, True, ""),
    ("septentrio-gns-zda",
     nmea("GNGNS,094112.00,5231.04821,N,01323.51215,E,RRNN,18,0.6,41.6,44.3,1.0,0000,S",
          "GPZDA,094112.00,02,06,2021,00,00"),
     F9P_DAY, True, True, ""),
    ("telit-gll-rmc-no-gga",
     nmea("GPGLL,5231.0482,N,01323.5121,E,094112.000,A,A",
          "GPRMC,094112.000,A,5231.0482,N,01323.5121,E,0.01,0.00,020621,,,A"),
     F9P_DAY, True, True, ""),
    ("u-blox-pubx-only",
     b"$PUBX,00,094112.00,5231.048210,N,01323.512150,E,85.912,G3,2.1,2.0,0.007,77.52,0.007,,0.92,1.19,0.77,9,0,0*"
     + checksum("PUBX,00,094112.00,5231.048210,N,01323.512150,E,85.912,G3,2.1,2.0,0.007,77.52,0.007,,0.92,"
                "1.19,0.77,9,0,0").encode() + b"\r\n",
     F9P_DAY, True, False, ""),
    ("gga-only",
     nmea("GPGGA,094112.00,5231.04821,N,01323.51215,E,2,09,0.9,41.6,M,44.3,M,1.0,0000"),
     F9P_DAY, True, False, ""),
    ("lat-95",
     nmea("GPGGA,094112.00,9530.00000,N,01323.51215,E,1,09,0.9,41.6,M,44.3,M,,",
          "GPRMC,094112.00,A,9530.00000,N,01323.51215,E,0.01,0.00,020621,,,A"),
     F9P_DAY, False, False, "beyond 90°"),
    ("lon-181",
     nmea("GPGGA,094112.00,5231.04821,N,18100.00000,E,1,09,0.9,41.6,M,44.3,M,,"),
     F9P_DAY, False, False, "longitude 181° beyond 180°"),
]


@pytest.mark.parametrize("name, data, wall, position, time_ok, why", FIXTURES, ids=[f[0] for f in FIXTURES])
async def test_recorded_receivers(name, data, wall, position, time_ok, why):
    async with replayed(data, wall, rate=5.0, paced=True) as (reader, events):
        if position or time_ok:
            st = await reader.wait_for(lambda s: s.position_good == position and s.time_valid == time_ok
                                       and s.sentences >= 10, WAIT)
            if time_ok:
                assert st.time_good and abs(reader.gps_time() - reader.wall()) < 2.0
            assert st.latitude == pytest.approx(52.5174702, abs=1e-6)
            assert st.longitude == pytest.approx(13.3918692, abs=1e-6)
        else:
            st = await never_good(reader, events)
            assert st.data_good
        assert why in st.fix_reason + st.time_reason + st.summary()


# ------------------------------------------------------------------ LOCAL's own ranges

@pytest.mark.parametrize("lat, lon, height", [(95.5, 10.0, 100.0), (45.0, 10.0, 99999.0),
                                              (float("nan"), 10.0, 100.0), (45.0, 400.0, 100.0)])
def test_local_follows_the_gps_only_within_its_own_ranges(tmp_path, lat, lon, height):
    """Behind the reader's own judgement: LOCAL never takes a site outside its !MIN/!MAX."""
    from tcs.config import load_config
    from tcs.model.local import LocalTime
    from tcs.model.state_store import StateStore
    local = LocalTime(load_config(), StateStore(tmp_path))
    site = (local.latitude, local.longitude, local.height)
    local.set_syncpos(1)
    assert not local.follow_gps(lat, lon, height)
    assert (local.latitude, local.longitude, local.height) == site
    assert local.follow_gps(45.0, 10.0, 100.0) and local.latitude == 45.0


def test_judge_names_what_is_wrong():
    from tcs.drivers.nmea_judge import judge
    day = utc(2024, 1, 1)
    gga = "120005.00,4807.0380,N,01131.0000,E,{q},08,0.9,545.4,M,46.9,M,,".format
    assert judge("GP", "GGA", gga(q=1).split(","), day).fix
    for q, name in ((0, "invalid"), (6, "dead reckoning"), (7, "manual input"), (8, "simulator"), ("", "empty")):
        r = judge("GP", "GGA", gga(q=q).split(","), day)
        assert not r.fix and name in r.reason
    assert judge("GP", "GGA", "1,4807.0380,N,01131.0000,E,4,08,0.9,545.4,M,,,,".split(","), day).quality == 4
    r = judge("GP", "RMC", "120005,A,4807.038,N,01131.000,E,0,0,140323,,,A".split(","), utc(2023, 3, 14, 12))
    assert r.fix and r.time == utc(2023, 3, 14, 12, 0, 5) and not r.note
    r = judge("GP", "RMC", "235960,A,4807.038,N,01131.000,E,0,0,311216,,,A".split(","), utc(2016, 12, 31, 23))
    assert r.time == utc(2017, 1, 1)                                 # a leap second is a time
    for date, why in (("310223", "not a date"), ("050180", "before 2000"), ("220899", "before 2000"),
                      ("1403", "malformed")):
        r = judge("GP", "RMC", f"120005,A,4807.038,N,01131.000,E,0,0,{date},,,A".split(","), day)
        assert r.fix and r.time is None and why in r.time_reason
    r = judge("GP", "RMC", "120005,A,4807.038,N,01131.000,E,0,0,140323,,,D".split(","), day)
    assert r.fix and r.quality == 2 and r.time is not None            # not a rollover of 2024
    r = judge("GN", "ZDA", "120005.00,32,01,2024,00,00".split(","), day)
    assert r.time_unconfirmed is None and "not a date" in r.time_reason
    r = judge("GN", "GNS", "120005.00,4807.038,N,01131.000,E,NNNN,00,,,,,".split(","), day)
    assert not r.fix and "GNS mode NNNN" in r.reason
    r = judge("GN", "GNS", "120005.00,4807.038,N,01131.000,E,NANN,09,1.0,545.4,46.9,,".split(","), day)
    assert r.fix and r.height == 545.4 and r.satellites == 9
    assert judge("GP", "GLL", "4807.038,N,01131.000,E,120005,V,N".split(","), day).reason == "GLL status V (not valid)"
    assert "unknown" in judge("GP", "GLL", "4807.038,N,01131.000,E,120005,A,X".split(","), day).reason


async def test_gga_every_four_seconds_vouches_for_the_zda_between():
    """GGA (the only position sentence) every 40th burst (2 s, beyond the 1.5 s timeouts), ZDA
    in every one: the time stays valid between the fixes."""
    async with simulated(kinds=("GGA", "ZDA"), gga_every=40, timeouts=1.5) as (sim, reader, events):
        await reader.wait_for(lambda s: s.time_good, WAIT)
        first = sim.bursts
        await reader.wait_for(lambda s: sim.bursts >= first + 60, WAIT)   # a whole gap, 3 s
        assert not [e for e in events if e.number == ErrorNumber.TIME_LOOSE]


async def test_lines_ended_by_cr_alone():
    data = nmea("GPRMC,094112.00,A,5231.04821,N,01323.51215,E,0.01,0.00,020621,,,A").replace(b"\r\n", b"\r")
    async with replayed(data, F9P_DAY) as (reader, events):
        st = await reader.wait_for(lambda s: s.time_good and s.position_good, WAIT)
        assert st.latitude == pytest.approx(52.5174702, abs=1e-6)
