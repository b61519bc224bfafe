"""The INDI front end (issue 42): the protocol core, JNow against skyfield, the Telescope
device and the equipment (focuser, filter wheel, rotator, dome, dust cap, weather) driven by INDI's own command-line clients (Debian's ``indi-bin``:
``indi_getprop``, ``indi_setprop``, ``indi_eval``, and ``indiserver`` chaining the TCS as a
remote driver), plus a raw-socket client for what those tools do not show (messages, many
clients, a client that vanishes mid-slew).

One service (module scope) runs the simulated telescope with its INDI port on a free loopback
port. The tests that need ``indi-bin`` are skipped, loudly, where it is missing (``.ci/run``
installs it).
"""

from __future__ import annotations

import asyncio
import math
import shutil
import socket
import subprocess
import time
from pathlib import Path

import pytest

from support.live import live_service
from support.opentci_client import Client
from tcs.config import DEFAULT_CONFIG
from tcs.indi.protocol import ProtocolError, StreamParser, Vector, Element, parse_new, parse_number
from tcs.indi.telescope import icrs_to_jnow, jnow_to_icrs

DEVICE = "TCS Telescope"
WAIT = 90.0


def _hw(base: Path) -> Path:
    path = base / "hw.toml"
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    assert "release_after = 600.0" in text
    text = text.replace("release_after = 600.0", "release_after = 1.0")   # (the rain test's end)
    path.write_text(text, encoding="utf-8")   # [indi] port 7624 there: make_config takes a free one
    return path


live = live_service(_hw)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


def need_indi_bin() -> None:
    if shutil.which("indi_getprop") is None:
        pytest.skip("INDI's command-line clients are not installed (Debian: apt-get install "
                    "indi-bin; .ci/run does)")


def indi(*args, timeout: float = 60.0) -> str:
    proc = subprocess.run(list(args), capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, (args, proc.returncode, proc.stdout, proc.stderr)
    return proc.stdout


def getprop(port: int, *props: str) -> dict[str, str]:
    out = indi("indi_getprop", "-h", "127.0.0.1", "-p", str(port), "-t", "5", *props)
    values = {}
    for line in out.splitlines():
        key, _, value = line.partition("=")
        values[key] = value
    return values


def setprop(port: int, spec: str) -> None:
    indi("indi_setprop", "-h", "127.0.0.1", "-p", str(port), spec)


def wait_expr(port: int, expression: str, timeout: float = WAIT) -> None:
    """indi_eval until ``expression`` holds (states: 0 Idle, 1 Ok, 2 Busy, 3 Alert; On = 1)."""
    indi("indi_eval", "-h", "127.0.0.1", "-p", str(port), "-t", str(int(timeout)), "-w",
         expression, timeout=timeout + 10)


class RawClient:
    """An INDI client on a plain socket: what it sent and every element it got back."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT)
        self.parser = StreamParser()
        self.elements: list = []

    def send(self, text: str) -> None:
        self.sock.sendall(text.encode())

    def until(self, predicate, what: str, timeout: float = WAIT):
        deadline = time.monotonic() + timeout
        while True:
            for e in self.elements:
                if predicate(e):
                    return e
            assert time.monotonic() < deadline, f"no {what} in {len(self.elements)} elements"
            self.sock.settimeout(max(0.05, deadline - time.monotonic()))
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                continue
            assert data, f"the server closed the connection before {what}"
            self.elements.extend(self.parser.feed(data))

    def close(self) -> None:
        self.sock.close()


# ------------------------------------------------------------------------------ protocol core
def test_stream_parser_takes_elements_in_any_pieces_and_refuses_entities():
    text = (b"<getProperties version='1.7'/><newNumberVector device='D' name='N'>"
            b"<oneNumber name='A'>1:30:00</oneNumber><oneNumber name='B'> -0.5 </oneNumber></newNumberVector>")
    parser = StreamParser()
    got = []
    for i in range(len(text)):
        got.extend(parser.feed(text[i:i + 1]))
    assert [e.tag for e in got] == ["getProperties", "newNumberVector"]
    assert parse_new(got[1]) == ("Number", "D", "N", {"A": 1.5, "B": -0.5})
    with pytest.raises(ProtocolError):
        StreamParser().feed(b'<!DOCTYPE x [<!ENTITY a "aaaa">]><x>&a;</x>')
    with pytest.raises(ProtocolError):
        StreamParser().feed(b"<newTextVector device='D'><oneText></newTextVector>")
    with pytest.raises(ProtocolError):
        StreamParser(max_element=100).feed(b"<newTextVector device='D' name='T'><oneText name='x'>" + b"a" * 200)


def test_numbers_and_vectors_as_indi_writes_and_reads_them():
    assert parse_number("-10:30:00") == -10.5 and parse_number("12 30") == 12.5
    assert parse_number(" 3.25 ") == 3.25
    for bad in ("", "nan", "1:2:3:4", "x"):
        with pytest.raises(ValueError):
            parse_number(bad)
    v = Vector("Dev <1>", "P", "Number", [Element("X", 'a "b"', 1 / 3, "%.2f", 0, 1)])
    xml = v.define_xml()
    assert 'device="Dev &lt;1&gt;"' in xml and "0.3333333333333333" in xml   # full precision
    element = StreamParser().feed(xml.encode())[0]
    assert element.tag == "defNumberVector" and element[0].get("label") == 'a "b"'
    with pytest.raises(ValueError):
        parse_new(StreamParser().feed(b"<newSwitchVector device='D' name='S'><oneSwitch name='A'>yes</oneSwitch></newSwitchVector>")[0])


def test_jnow_is_skyfields_apparent_place_and_goes_back():
    """EQUATORIAL_EOD_COORD is the apparent place of date (JNow): within 0.5″ of skyfield's
    geocentric apparent RA/Dec of date for stars all over the sky, and the inverse returns
    ICRS within 1 mas."""
    import datetime

    from skyfield.api import Loader, Star
    from skyfield_data import get_skyfield_data_path

    loader = Loader(get_skyfield_data_path(), verbose=False)
    earth = loader("de421.bsp")["earth"]
    ts = loader.timescale(builtin=True)
    utc = 1_800_000_000.0   # 2027-01-15
    t = ts.from_datetime(datetime.datetime.fromtimestamp(utc, datetime.timezone.utc))
    tai_utc = 37.0
    for ra, dec in ((0.5, 10.0), (6.0, -60.0), (12.3, 45.0), (18.7, 85.0), (23.9, -5.0)):
        r, d = icrs_to_jnow(ra, dec, utc, tai_utc)
        app = earth.at(t).observe(Star(ra_hours=ra, dec_degrees=dec)).apparent()
        sra, sdec, _ = app.radec(epoch="date")
        dra = (r - sra.hours) * 15.0 * math.cos(math.radians(dec)) * 3600.0
        ddec = (d - sdec.degrees) * 3600.0
        assert math.hypot(dra, ddec) < 0.5, (ra, dec, dra, ddec)
        back = jnow_to_icrs(r, d, utc, tai_utc)
        assert abs(back[0] - ra) * 15 * 3600 * math.cos(math.radians(dec)) < 1e-3
        assert abs(back[1] - dec) * 3600 < 1e-3


# ------------------------------------------------------------------------------ the device live
def test_every_property_reads_with_indi_getprop(live):
    need_indi_bin()
    port = live.service.indi_port
    values = getprop(port, f"{DEVICE}.*.*")
    for key in ("CONNECTION.CONNECT", "EQUATORIAL_EOD_COORD.RA", "EQUATORIAL_EOD_COORD.DEC",
                "ON_COORD_SET.TRACK", "HORIZONTAL_COORD.ALT", "TELESCOPE_ABORT_MOTION.ABORT",
                "TELESCOPE_PARK.PARK", "TELESCOPE_TRACK_STATE.TRACK_ON", "TELESCOPE_TRACK_MODE.TRACK_SIDEREAL",
                "TELESCOPE_TIMED_GUIDE_NS.TIMED_GUIDE_N", "TELESCOPE_TIMED_GUIDE_WE.TIMED_GUIDE_E",
                "GUIDE_RATE.GUIDE_RATE_WE", "GEOGRAPHIC_COORD.LAT", "TIME_UTC.UTC", "TELESCOPE_INFO.TELESCOPE_APERTURE",
                "DRIVER_INFO.DRIVER_INTERFACE"):
        assert f"{DEVICE}.{key}" in values, (key, sorted(values))
    site = live.telescope.local
    assert float(values[f"{DEVICE}.GEOGRAPHIC_COORD.LAT"]) == pytest.approx(site.latitude)
    assert float(values[f"{DEVICE}.GEOGRAPHIC_COORD.LONG"]) == pytest.approx(site.longitude % 360.0)


@pytest.mark.timeout(360)   # ~30 s alone; a dozen waits of INDI's own clients, each bounded by WAIT
async def test_slew_track_sync_guide_and_abort_with_indis_own_clients(live):
    """Make ready (UNPARK), slew and track JNow coordinates (ending within 10″ of them, as INDI
    reads them back), a guide pulse north moves the target by rate × time, SYNC, ABORT."""
    need_indi_bin()
    port = live.service.indi_port
    c = await Client.connect(live.port)
    try:
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_PARK.UNPARK=On")
        for axis in ("AZ", "ZD"):
            await c.wait(f"{axis}.REFERENCED", lambda v: v == 1.0, WAIT)
        ra_now, dec_now = (float(v) for v in (await asyncio.to_thread(
            getprop, port, f"{DEVICE}.EQUATORIAL_EOD_COORD.*")).values())
        # SYNC: the pointing model's index terms so that the encoders read the given place
        await asyncio.to_thread(setprop, port, f"{DEVICE}.ON_COORD_SET.SYNC=On")
        await asyncio.to_thread(setprop, port, f"{DEVICE}.EQUATORIAL_EOD_COORD.RA;DEC={ra_now!r};{dec_now + 0.01!r}")
        deadline = time.monotonic() + WAIT
        while True:   # the next refresh (every [indi] interval) shows the synced place
            got = await asyncio.to_thread(getprop, port, f"{DEVICE}.EQUATORIAL_EOD_COORD.*")
            synced = float(got[f"{DEVICE}.EQUATORIAL_EOD_COORD.DEC"])
            if abs(synced - (dec_now + 0.01)) < 5 / 3600:
                break
            assert time.monotonic() < deadline, f"after SYNC the Dec reads {synced}, not {dec_now + 0.01}"
            await asyncio.sleep(0.2)
        dec_now = synced
        goal_ra, goal_dec = (ra_now + 0.3) % 24.0, dec_now - 10.0
        await asyncio.to_thread(setprop, port, f"{DEVICE}.ON_COORD_SET.TRACK=On")
        await asyncio.to_thread(setprop, port, f"{DEVICE}.EQUATORIAL_EOD_COORD.RA;DEC={goal_ra!r};{goal_dec!r}")
        await c.wait("POINTING.TRACK", lambda v: v != 0, WAIT)   # (the slew has started)
        await asyncio.to_thread(wait_expr, port, f'"{DEVICE}.EQUATORIAL_EOD_COORD._STATE"==1 && '
                                                 f'"{DEVICE}.TELESCOPE_TRACK_STATE.TRACK_ON"==1')
        got = await asyncio.to_thread(getprop, port, f"{DEVICE}.EQUATORIAL_EOD_COORD.*", f"{DEVICE}.TELESCOPE_TRACK_STATE.*")
        ra, dec = float(got[f"{DEVICE}.EQUATORIAL_EOD_COORD.RA"]), float(got[f"{DEVICE}.EQUATORIAL_EOD_COORD.DEC"])
        off = math.hypot((ra - goal_ra) * 15 * math.cos(math.radians(dec)), dec - goal_dec) * 3600
        assert off < 10.0, (ra, dec, goal_ra, goal_dec, off)
        assert got[f"{DEVICE}.TELESCOPE_TRACK_STATE.TRACK_ON"] == "On"
        # a 2 s pulse north at half the sidereal rate: the target's Dec +15″ (TPL2 reads it)
        dec0 = await c.num("POINTING.TARGET.DEC")
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_TIMED_GUIDE_NS.TIMED_GUIDE_N;TIMED_GUIDE_S=2000;0")
        await c.wait("POINTING.TARGET.DEC", lambda v: v > dec0 + 1e-3, WAIT)
        assert (await c.num("POINTING.TARGET.DEC") - dec0) * 3600 == pytest.approx(0.5 * 15.041 * 2.0, rel=0.02)
        # ABORT: tracking ends, the axes come to rest
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_ABORT_MOTION.ABORT=On")
        await c.wait("POINTING.TRACK", lambda v: v == 0, WAIT)
        await asyncio.to_thread(wait_expr, port, f'"{DEVICE}.TELESCOPE_TRACK_STATE.TRACK_OFF"==1')
        await asyncio.to_thread(setprop, port, f"{DEVICE}.ON_COORD_SET.TRACK=On")
    finally:
        await c.close()


async def test_a_refused_slew_is_alert_with_the_reason_and_other_clients_go_on(live):
    """A target below the horizon: the property goes Alert and a message carries the TCS's
    reason; 20 clients at once each get every property; a client that vanishes mid-slew
    leaves the slew and the others alone."""
    port = live.service.indi_port
    c = await Client.connect(live.port)
    clients = []
    try:
        raw = RawClient(port)
        raw.send("<getProperties version='1.7'/>")
        raw.until(lambda e: e.tag == "defNumberVector" and e.get("name") == "EQUATORIAL_EOD_COORD", "the coordinates")
        lat = live.telescope.local.latitude
        raw.send(f"<newNumberVector device='{DEVICE}' name='EQUATORIAL_EOD_COORD'>"
                 f"<oneNumber name='RA'>3</oneNumber><oneNumber name='DEC'>{-89.0 if lat > 0 else 89.0}</oneNumber>"
                 "</newNumberVector>")
        alert = raw.until(lambda e: e.tag == "setNumberVector" and e.get("state") == "Alert",
                          "an Alert of the refused slew")
        assert "horizon" in (alert.get("message") or "").lower() or "limit" in (alert.get("message") or "").lower(), alert.attrib
        raw.send("<newNumberVector device='nobody' name='X'><oneNumber name='A'>1</oneNumber></newNumberVector>")
        raw.until(lambda e: e.tag == "message" and "no such property" in e.get("message", ""), "the unknown property's message")
        # 20 clients at once, each with every property
        for _ in range(20):
            rc = await asyncio.to_thread(RawClient, port)
            clients.append(rc)
            rc.send(f"<getProperties version='1.7' device='*'/>")
        for rc in clients:
            await asyncio.to_thread(rc.until, lambda e: e.tag == "defTextVector" and e.get("name") == "DRIVER_INFO",
                                    "the last property")
        raw.close()
        # malformed XML closes only that client
        bad = RawClient(port)
        bad.send("<getProperties <<<")
        assert await asyncio.to_thread(bad.sock.recv, 100) == b""
        probe = RawClient(port)
        probe.send(f"<getProperties version='1.7' device='{DEVICE}' name='TIME_UTC'/>")
        await asyncio.to_thread(probe.until, lambda e: e.tag == "defTextVector", "TIME_UTC")
        probe.close()
    finally:
        for rc in clients:
            rc.close()
        await c.close()


def test_through_indiserver_chaining(live, tmp_path):
    """``indiserver @host:port`` chains the TCS as a remote driver: INDI's clients on the
    indiserver's port read the TCS's device."""
    need_indi_bin()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(["indiserver", "-p", str(port), f"@127.0.0.1:{live.service.indi_port}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.monotonic() + WAIT
        while True:
            try:
                values = getprop(port, f"{DEVICE}.GEOGRAPHIC_COORD.*", f"{DEVICE}.EQUATORIAL_EOD_COORD.*",
                                 "TCS Focuser.ABS_FOCUS_POSITION.*", "TCS Filter.FILTER_NAME.*",
                                 "TCS Rotator.ABS_ROTATOR_ANGLE.*", "TCS Dome.DOME_SHUTTER.*",
                                 "TCS Weather.WEATHER_STATUS.*", "TCS Dust Cap.CAP_PARK.*")
                if f"{DEVICE}.EQUATORIAL_EOD_COORD.RA" in values:
                    break
            except AssertionError:
                pass
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "indiserver never showed the TCS's device"
            time.sleep(0.5)
        assert float(values[f"{DEVICE}.GEOGRAPHIC_COORD.LAT"]) == pytest.approx(live.telescope.local.latitude)
    finally:
        proc.terminate()
        proc.wait(10)


# ------------------------------------------------------------------------------ the equipment
def refused(port: int, new_xml: str, device: str, prop: str) -> str:
    """Send ``new_xml`` on a raw connection; the property's Alert message (the reason)."""
    raw = RawClient(port)
    try:
        raw.send(f"<getProperties version='1.7' device='{device}' name='{prop}'/>")
        raw.until(lambda e: e.tag.startswith("def") and e.get("name") == prop, prop)
        raw.send(new_xml)
        alert = raw.until(lambda e: e.tag.startswith("set") and e.get("name") == prop
                          and e.get("state") == "Alert", f"an Alert of {prop}")
        return alert.get("message") or ""
    finally:
        raw.close()


def test_the_focuser_moves_in_microns_and_refuses_outside_its_limits(live):
    """CONNECT powers the focus axis; ABS_FOCUS_POSITION 12345 moves it to 12.345 mm (through
    its referencing on the first move), Busy then Ok; a position beyond FOCUS_MAX is Alert
    with the reason and nothing moves."""
    need_indi_bin()
    port, dev = live.service.indi_port, "TCS Focuser"
    values = getprop(port, f"{dev}.*.*")
    for key in ("CONNECTION.CONNECT", "ABS_FOCUS_POSITION.FOCUS_ABSOLUTE_POSITION",
                "FOCUS_MAX.FOCUS_MAX_VALUE", "FOCUS_ABORT_MOTION.ABORT", "DRIVER_INFO.DRIVER_INTERFACE"):
        assert f"{dev}.{key}" in values, (key, sorted(values))
    assert int(values[f"{dev}.DRIVER_INFO.DRIVER_INTERFACE"]) & 8
    hi = float(values[f"{dev}.FOCUS_MAX.FOCUS_MAX_VALUE"])
    assert hi == pytest.approx(live.telescope.axis("FOCUS").section.max * 1000.0)
    setprop(port, f"{dev}.CONNECTION.CONNECT=On")
    wait_expr(port, f'"{dev}.CONNECTION._STATE"==1')
    setprop(port, f"{dev}.ABS_FOCUS_POSITION.FOCUS_ABSOLUTE_POSITION=12345")
    wait_expr(port, f'"{dev}.ABS_FOCUS_POSITION._STATE"==1 && '
                    f'"{dev}.ABS_FOCUS_POSITION.FOCUS_ABSOLUTE_POSITION"==12345')
    assert abs(live.telescope.axis("FOCUS").real_position - 12.345) < 0.002
    message = refused(port, f"<newNumberVector device='{dev}' name='ABS_FOCUS_POSITION'>"
                            f"<oneNumber name='FOCUS_ABSOLUTE_POSITION'>{hi + 10:.0f}</oneNumber></newNumberVector>",
                      dev, "ABS_FOCUS_POSITION")
    assert "FOCUS_ABSOLUTE_POSITION" in message, message
    assert abs(live.telescope.axis("FOCUS").real_position - 12.345) < 0.002


def test_the_filter_wheel_changes_slot_and_names_its_filters(live):
    """FILTER_SLOT counts from 1 (INDI) over the hardware file's positions; FILTER_NAME has its
    names; a change to slot 4 puts the wheel at its 4th position; slot 0 is Alert."""
    need_indi_bin()
    port, dev = live.service.indi_port, "TCS Filter"
    wheel = next(w for w in live.telescope.axis_array("FILTER") if w is not None)
    keys = sorted(wheel.positions)
    values = getprop(port, f"{dev}.*.*")
    assert int(values[f"{dev}.DRIVER_INFO.DRIVER_INTERFACE"]) & 16
    assert [values[f"{dev}.FILTER_NAME.FILTER_SLOT_NAME_{i + 1}"] for i in range(len(keys))] == \
        [wheel.section.names.get(str(k), str(k)) for k in keys]
    setprop(port, f"{dev}.CONNECTION.CONNECT=On")   # powers the wheel (main power first), references it
    wait_expr(port, f'"{dev}.CONNECTION._STATE"==1')
    setprop(port, f"{dev}.FILTER_SLOT.FILTER_SLOT_VALUE=4")
    wait_expr(port, f'"{dev}.FILTER_SLOT._STATE"==1 && "{dev}.FILTER_SLOT.FILTER_SLOT_VALUE"==4')
    assert abs(wheel.real_position - float(keys[3])) < 1e-6
    message = refused(port, f"<newNumberVector device='{dev}' name='FILTER_SLOT'>"
                            "<oneNumber name='FILTER_SLOT_VALUE'>0</oneNumber></newNumberVector>", dev, "FILTER_SLOT")
    assert "slot" in message, message


def test_the_rotator_moves_to_a_sky_angle_and_syncs(live):
    """ABS_ROTATOR_ANGLE 30 moves the derotator there (sky = mechanical with no sync offset);
    SYNC_ROTATOR_ANGLE makes the angle read 100 without moving; ABORT stops a move."""
    need_indi_bin()
    port, dev = live.service.indi_port, "TCS Rotator"
    rot = next(d for d in live.telescope.axis_array("DEROTATOR") if d is not None)
    values = getprop(port, f"{dev}.*.*")
    assert int(values[f"{dev}.DRIVER_INFO.DRIVER_INTERFACE"]) & 4096
    assert f"{dev}.ROTATOR_ABORT_MOTION.ABORT" in values
    setprop(port, f"{dev}.CONNECTION.CONNECT=On")
    wait_expr(port, f'"{dev}.CONNECTION._STATE"==1')
    setprop(port, f"{dev}.ABS_ROTATOR_ANGLE.ANGLE=30")
    wait_expr(port, f'"{dev}.ABS_ROTATOR_ANGLE._STATE"==1 && abs("{dev}.ABS_ROTATOR_ANGLE.ANGLE"-30)<0.01')
    assert abs(rot.real_position % 360.0 - 30.0) < 0.01
    try:
        setprop(port, f"{dev}.SYNC_ROTATOR_ANGLE.ANGLE=100")
        wait_expr(port, f'abs("{dev}.ABS_ROTATOR_ANGLE.ANGLE"-100)<0.01')
        assert abs(rot.real_position % 360.0 - 30.0) < 0.01          # nothing moved
        setprop(port, f"{dev}.ABS_ROTATOR_ANGLE.ANGLE=160")         # mechanical 90°
        wait_expr(port, f'"{dev}.ABS_ROTATOR_ANGLE._STATE"==2 && "{dev}.ABS_ROTATOR_ANGLE.ANGLE">103')
        setprop(port, f"{dev}.ROTATOR_ABORT_MOTION.ABORT=On")
        wait_expr(port, f'"{dev}.ABS_ROTATOR_ANGLE._STATE"!=2')
        assert not rot.motion_state & 1 and 30.0 < rot.real_position % 360.0 < 89.0
    finally:
        setprop(port, f"{dev}.SYNC_ROTATOR_ANGLE.ANGLE={rot.real_position % 360.0!r}")   # sky = mechanical again


async def test_the_dome_shutter_opens_and_rain_refuses_it_with_the_reason(live):
    """DOME_SHUTTER OPEN moves every opening part (Busy, the parts open); CLOSE closes them
    (Ok); in the rain the weather device's lights say so and OPEN is Alert with the
    interlock's reason; ABS_DOME_POSITION turns the dome; WEATHER_PARAMETERS reads the sensors."""
    need_indi_bin()
    port, dev, weather = live.service.indi_port, "TCS Dome", "TCS Weather"
    dome = live.telescope.peripherals.dome
    shutters = [m for m in dome[1:3]]   # slit and flap (the sim's classic dome)
    values = await asyncio.to_thread(getprop, port, f"{dev}.*.*", f"{weather}.*.*", "TCS Dust Cap.*.*")
    assert int(values["TCS Dust Cap.DRIVER_INFO.DRIVER_INTERFACE"]) & 512
    assert values["TCS Dust Cap.CAP_PARK.PARK"] == "On"
    assert int(values[f"{dev}.DRIVER_INFO.DRIVER_INTERFACE"]) & 32
    assert int(values[f"{weather}.DRIVER_INFO.DRIVER_INTERFACE"]) & 128
    assert -50.0 < float(values[f"{weather}.WEATHER_PARAMETERS.WEATHER_TEMPERATURE"]) < 60.0
    assert f"{weather}.WEATHER_PARAMETERS.WEATHER_WIND_SPEED" in values
    assert values[f"{dev}.DOME_SHUTTER.SHUTTER_CLOSE"] == "On"
    c = await Client.connect(live.port)
    try:
        await c.set("CABINET.POWER=1")
        await asyncio.to_thread(wait_expr, port, f'"{weather}.WEATHER_STATUS.WEATHER_INTERLOCK"==1')
        await asyncio.to_thread(setprop, port, f"{dev}.DOME_SHUTTER.SHUTTER_OPEN=On")
        await asyncio.to_thread(wait_expr, port, f'"{dev}.DOME_SHUTTER._STATE"==2')
        for part in shutters:
            await c.wait(f"{part.module_name}.REALPOS", lambda v: isinstance(v, float) and v > 0.5, WAIT)
        await asyncio.to_thread(setprop, port, f"{dev}.DOME_SHUTTER.SHUTTER_CLOSE=On")
        await asyncio.to_thread(wait_expr, port, f'"{dev}.DOME_SHUTTER._STATE"==1 && '
                                                 f'"{dev}.DOME_SHUTTER.SHUTTER_CLOSE"==1')
        assert all(p.real_position <= p.section.min + 0.01 for p in shutters)
        # the mirror cover as INDI's dust cap: UNPARK opens it, PARK closes it
        cover = live.telescope.peripherals.covers[0]
        await asyncio.to_thread(setprop, port, "TCS Dust Cap.CAP_PARK.UNPARK=On")
        await asyncio.to_thread(wait_expr, port, '"TCS Dust Cap.CAP_PARK._STATE"==2')
        await c.wait(f"{cover.module_name}.REALPOS", lambda v: isinstance(v, float) and v > 2.0, WAIT)
        await asyncio.to_thread(setprop, port, "TCS Dust Cap.CAP_PARK.PARK=On")
        await asyncio.to_thread(wait_expr, port, '"TCS Dust Cap.CAP_PARK._STATE"==1 && "TCS Dust Cap.CAP_PARK.PARK"==1')
        assert cover.real_position <= cover.section.min + 0.01
        await asyncio.to_thread(setprop, port, f"{dev}.ABS_DOME_POSITION.DOME_ABSOLUTE_POSITION=190")
        await asyncio.to_thread(wait_expr, port, f'"{dev}.ABS_DOME_POSITION._STATE"==1 && '
                                                 f'abs("{dev}.ABS_DOME_POSITION.DOME_ABSOLUTE_POSITION"-190)<0.5')
        # DOME_MOTION CW: azimuth grows until Off
        await asyncio.to_thread(setprop, port, f"{dev}.DOME_MOTION.DOME_CW=On")
        await c.wait("DOME[0].REALPOS", lambda v: isinstance(v, float) and 193.0 < v < 260.0, WAIT)
        await asyncio.to_thread(setprop, port, f"{dev}.DOME_MOTION.DOME_CW;DOME_CCW=Off;Off")
        await asyncio.to_thread(wait_expr, port, f'"{dev}.DOME_MOTION._STATE"==0 && "{dev}.ABS_DOME_POSITION._STATE"!=2')
        assert not dome[0].motion_state & 1
        plc = live.telescope.peripherals.sims.plcs["dome"]
        await live.call(plc.force, "rain", True)
        try:
            await asyncio.to_thread(wait_expr, port, f'"{weather}.WEATHER_STATUS.WEATHER_INTERLOCK"==3 && '
                                                     f'"{weather}.WEATHER_STATUS.WEATHER_RAIN"==3')
            message = await asyncio.to_thread(
                refused, port, f"<newSwitchVector device='{dev}' name='DOME_SHUTTER'>"
                               "<oneSwitch name='SHUTTER_OPEN'>On</oneSwitch></newSwitchVector>", dev, "DOME_SHUTTER")
            assert "rain" in message, message
            message = await asyncio.to_thread(
                refused, port, "<newSwitchVector device='TCS Dust Cap' name='CAP_PARK'>"
                               "<oneSwitch name='UNPARK'>On</oneSwitch></newSwitchVector>", "TCS Dust Cap", "CAP_PARK")
            assert "rain" in message, message
            assert all(p.real_position <= p.section.min + 0.01 for p in shutters)
        finally:
            await live.call(plc.release, "rain")
        await asyncio.to_thread(wait_expr, port, f'"{weather}.WEATHER_STATUS.WEATHER_INTERLOCK"==1')
    finally:
        await c.close()


async def test_manual_motion_track_modes_and_the_park_position(live):
    """TELESCOPE_MOTION_NS South (with TELESCOPE_SLEW_RATE Find) moves the altitude axis down
    until Off stops it; TELESCOPE_TRACK_MODE Lunar sets the Moon's rate (TRACK_RATE_RA below
    sidereal, POINTING.TARGET.RA_V the Moon's eastward motion), Custom the given rates,
    Sidereal none; TELESCOPE_PARK_POSITION reads the park positions."""
    need_indi_bin()
    port = live.service.indi_port
    p = live.telescope.pointing
    c = await Client.connect(live.port)
    try:
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_PARK.UNPARK=On")
        for axis in ("AZ", "ZD"):
            await c.wait(f"{axis}.REFERENCED", lambda v: v == 1.0, WAIT)
        await asyncio.to_thread(wait_expr, port, f'"{DEVICE}.TELESCOPE_PARK.UNPARK"==1')
        values = await asyncio.to_thread(getprop, port, f"{DEVICE}.TELESCOPE_PARK_POSITION.*")
        zd_park = dict((a.module_name, park) for a, park in live.telescope.operations.park_positions())["ZD"]
        assert float(values[f"{DEVICE}.TELESCOPE_PARK_POSITION.PARK_ALT"]) == pytest.approx(
            90.0 - abs(zd_park - p.axis2.offset), abs=1e-6)
        # manual motion: down (South on an alt-az mount) at the Find rate, then Off stops it
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_ABORT_MOTION.ABORT=On")
        zd0 = await c.num("ZD.REALPOS")
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_SLEW_RATE.SLEW_FIND=On")
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_MOTION_NS.MOTION_SOUTH=On")
        await asyncio.to_thread(wait_expr, port, f'"{DEVICE}.TELESCOPE_MOTION_NS._STATE"==2')
        await c.wait("ZD.REALPOS", lambda v: isinstance(v, float) and abs(v) > abs(zd0) + 10.0, WAIT)
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_MOTION_NS.MOTION_NORTH;MOTION_SOUTH=Off;Off")
        await c.wait("ZD.MOTION_STATE", lambda v: isinstance(v, float) and not int(v) & 1, WAIT)
        await asyncio.to_thread(wait_expr, port, f'"{DEVICE}.TELESCOPE_MOTION_NS._STATE"==0')
        zd1 = await c.num("ZD.REALPOS")
        assert abs(zd0) + 10.0 < abs(zd1) < p.zd_limit - 5.0, (zd0, zd1)
        # track modes: lunar, custom, sidereal
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_TRACK_STATE.TRACK_ON=On")
        try:
            await c.wait("POINTING.TRACK", lambda v: v != 0, WAIT)
        except AssertionError as exc:   # (say why: the device's Alert, its track switch)
            dev = live.service.indi_server.devices[DEVICE]
            raise AssertionError(f"{exc}; INDI: {dev.eq.state} {dev.eq.message!r}, track vector "
                                 f"{dev.track_state.state}, failure {dev._slew_failed!r}") from None
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_TRACK_MODE.TRACK_LUNAR=On")
        await asyncio.to_thread(wait_expr, port, f'abs("{DEVICE}.TELESCOPE_TRACK_RATE.TRACK_RATE_RA"-15.041067)>0.01')
        # east among the stars: 0.15…1.1″ of RA/s (see the Alpaca test of lunar tracking)
        assert 0.15 < p.target.ra_v < 1.1, p.target.ra_v
        rate = float((await asyncio.to_thread(getprop, port, f"{DEVICE}.TELESCOPE_TRACK_RATE.TRACK_RATE_RA"))[
            f"{DEVICE}.TELESCOPE_TRACK_RATE.TRACK_RATE_RA"])
        assert rate == pytest.approx(15.041067 - p.target.ra_v, abs=1e-3)
        assert p.track != 0
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_TRACK_RATE.TRACK_RATE_RA;TRACK_RATE_DE=15.0;0.5")
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_TRACK_MODE.TRACK_CUSTOM=On")
        await asyncio.to_thread(wait_expr, port, f'abs("{DEVICE}.TELESCOPE_TRACK_RATE.TRACK_RATE_DE"-0.5)<1e-6')
        assert p.target.ra_v == pytest.approx(15.041067 - 15.0, abs=1e-4) and p.target.dec_v == pytest.approx(0.5)
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_TRACK_MODE.TRACK_SIDEREAL=On")
        await asyncio.to_thread(wait_expr, port, f'abs("{DEVICE}.TELESCOPE_TRACK_RATE.TRACK_RATE_RA"-15.041067)<1e-3')
        assert p.target.ra_v == 0.0 and p.target.dec_v == 0.0
    finally:
        await asyncio.to_thread(setprop, port, f"{DEVICE}.TELESCOPE_ABORT_MOTION.ABORT=On")
        await c.close()
