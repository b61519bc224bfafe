"""The ASCOM Alpaca devices, driven by alpyca (the ASCOM Initiative's own Python client) over
real HTTP and UDP against the simulated telescope.

One service (module scope, its own event-loop thread) runs ``tests/hw_alpaca.toml``: the fast
telescope of the OpenTSI tests with the enclosure of the enclosure tests, serving OpenTCI,
OpenTSI and Alpaca on free ports (discovery on a free UDP port). alpyca is synchronous
(``requests``), so the tests are plain functions: the service's loop runs in its own thread.
Sky positions are checked against the telescope's astrometry computed here for the read time.
"""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path

import pytest

alpaca = pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
from alpaca import discovery, management  # noqa: E402
from alpaca.exceptions import (InvalidOperationException, InvalidValueException,  # noqa: E402
                               NotConnectedException, ParkedException)
from alpaca.telescope import GuideDirections, Telescope  # noqa: E402

from support.live import LiveService  # noqa: E402
from support.opentci_client import Client  # noqa: E402

HW = Path(__file__).with_name("hw_alpaca.toml")
WAIT = 60.0
ARCSEC = 1.0 / 3600.0


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    service = LiveService(HW, tmp_path_factory.mktemp("alpaca")).start()
    try:
        yield service
    finally:
        service.stop()


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


def address(live) -> str:
    return f"127.0.0.1:{live.service.alpaca_port}"


def until(condition, what: str, timeout: float = WAIT, period: float = 0.1):
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(period)


def connected_telescope(live) -> Telescope:
    t = Telescope(address(live), 0)
    t.Connect()
    until(lambda: not t.Connecting, "Connecting False")
    assert t.Connected
    return t


def ready(live, t: Telescope) -> None:
    """Unparked, powered and referenced, not tracking."""
    t.Unpark()
    until(lambda: live.telescope.operations.ready_state == 1.0, "READY_STATE 1", timeout=WAIT)
    if t.Tracking:
        t.Tracking = False
    until(lambda: not t.Slewing, "at rest")


def star_up_now(t: Telescope, hours_east: float = 1.5, dec: float = 10.0) -> tuple[float, float]:
    """A star well above the horizon now: 1.5 h east of the meridian at Dec 10°."""
    return (t.SiderealTime + hours_east) % 24.0, dec


def sky_of(live, ra: float, dec: float):
    """The observed place of ICRS ``ra``, ``dec`` now by the telescope's astrometry."""
    p = live.telescope.pointing
    obs = p.astrometry().observed(ra, dec, p.utc())
    return float(obs.az) % 360.0, 90.0 - float(obs.zd)


def test_discovery_finds_the_server_and_its_devices(live, monkeypatch):
    # alpyca broadcasts on every adapter to port 32227: keep it on loopback and on the free port
    monkeypatch.setattr(discovery, "port", live.service.alpaca_server.discovery_port)
    adapters = discovery.ifaddr.get_adapters
    monkeypatch.setattr(discovery.ifaddr, "get_adapters",
                        lambda: [a for a in adapters() if a.name == "lo"])
    found = discovery.search_ipv4(numquery=1, timeout=1)
    assert address(live) in found
    assert management.apiversions(address(live)) == [1]
    description = management.description(address(live))
    assert description["ServerName"] and description["Manufacturer"]
    devices = management.configureddevices(address(live))
    kinds = {(d["DeviceType"], d["DeviceNumber"]) for d in devices}
    assert ("Telescope", 0) in kinds
    assert len({d["UniqueID"] for d in devices}) == len(devices)


def test_a_night_with_alpyca(live):
    t = connected_telescope(live)
    assert t.InterfaceVersion == 4 and t.EquatorialSystem.value == 2
    assert t.CanPark and t.CanUnpark and t.CanSetPark and t.CanSlewAsync and t.CanPulseGuide
    ready(live, t)

    # track a star: the encoders read back through the pipeline give its place
    t.Tracking = True
    ra, dec = star_up_now(t)
    t.SlewToCoordinatesAsync(ra, dec)
    assert t.Slewing
    until(lambda: not t.Slewing, "the slew to end")
    assert t.Tracking
    assert abs(t.RightAscension - ra) * 15.0 < ARCSEC * 1.0
    assert abs(t.Declination - dec) < ARCSEC * 1.0
    assert (t.TargetRightAscension, t.TargetDeclination) == (ra, dec)
    az, alt = sky_of(live, ra, dec)
    assert abs(t.Altitude - alt) < 3 * ARCSEC
    assert abs((t.Azimuth - az + 180.0) % 360.0 - 180.0) * math.cos(math.radians(alt)) < 3 * ARCSEC
    assert t.SideOfPier.value == 0 and t.DestinationSideOfPier(ra, dec) == 0

    # it keeps tracking: a few seconds later the star is still centred (the sky turned)
    time.sleep(2.0)
    assert abs(t.RightAscension - ra) * 15.0 < ARCSEC * 1.0

    # pulse guiding north moves the pointing by the guide rate × duration
    dec_before = t.Declination
    t.PulseGuide(GuideDirections.guideNorth, 1000)
    assert t.IsPulseGuiding
    until(lambda: not t.IsPulseGuiding, "the pulse to end")
    until(lambda: not t.Slewing, "on target after the pulse")
    shift = (t.Declination - dec_before) / t.GuideRateDeclination
    assert 0.95 < shift < 1.05

    # park: the park position of the hardware file, shared with OpenTSI's READY=0
    t.Park()
    until(lambda: t.AtPark, "parked")
    assert not t.Tracking and not t.Slewing
    parks = {a.module: a.park for a in live.telescope.config.axes.values()
             if a.park is not None}
    assert set(parks) == {"AZ", "ZD"}
    for axis in live.telescope.axes:
        if axis.module_name in parks:
            assert abs(axis.real_position - parks[axis.module_name]) < 0.1
    with pytest.raises(ParkedException):
        t.SlewToCoordinatesAsync(ra, dec)
    with pytest.raises(ParkedException):
        t.Tracking = True
    t.Unpark()
    assert not t.AtPark
    t.Disconnect()
    assert not t.Connected


def test_refusals_below_the_horizon_and_not_connected(live):
    t = Telescope(address(live), 0)
    t.Disconnect()
    with pytest.raises(NotConnectedException):
        t.RightAscension
    with pytest.raises(NotConnectedException):
        t.SlewToCoordinatesAsync(1.0, 10.0)
    t.Connect()
    ready(live, t)
    with pytest.raises(InvalidOperationException):      # V4: slews need Tracking True
        t.SlewToCoordinatesAsync(*star_up_now(t))
    t.Tracking = True
    until(lambda: not t.Slewing, "tracking where it points")
    ra_below, dec_below = (t.SiderealTime + 12.0) % 24.0, -40.0    # under the horizon
    before = (live.telescope.pointing.target.ra, live.telescope.pointing.target.dec)
    with pytest.raises(InvalidValueException):
        t.SlewToCoordinatesAsync(ra_below, dec_below)
    assert (live.telescope.pointing.target.ra, live.telescope.pointing.target.dec) == before
    assert t.Tracking                                     # the refusal changed nothing
    with pytest.raises(InvalidValueException):
        t.SlewToCoordinatesAsync(24.5, 10.0)
    t.Tracking = False
    with pytest.raises(InvalidValueException):
        t.SlewToAltAzAsync(100.0, 5.0)                   # below [pointing] min_altitude
    with pytest.raises(InvalidOperationException):
        t.PulseGuide(GuideDirections.guideEast, 100)    # not tracking
    t.Disconnect()


def test_alt_az_slew_set_park_and_home(live):
    t = connected_telescope(live)
    ready(live, t)
    t.SlewToAltAzAsync(120.0, 50.0)
    until(lambda: not t.Slewing, "the alt-az slew to end")
    assert abs(t.Altitude - 50.0) < 0.01 and abs(t.Azimuth - 120.0) < 0.01
    t.SetPark()
    t.SlewToAltAzAsync(200.0, 70.0)
    until(lambda: not t.Slewing, "the second alt-az slew to end")
    t.Park()
    until(lambda: t.AtPark, "parked at the new park position")
    assert abs(t.Altitude - 50.0) < 0.05 and abs(t.Azimuth - 120.0) < 0.05
    t.Unpark()
    # the hardware file's park positions again (the state directory is the module's)
    live.telescope.store.update(park={})
    t.FindHome()
    until(lambda: t.AtHome, "at home", timeout=WAIT)
    assert not t.Slewing
    t.Disconnect()


def test_sync_is_a_pointing_offset(live):
    t = connected_telescope(live)
    ready(live, t)
    t.Tracking = True
    ra, dec = star_up_now(t, 0.5, 30.0)
    t.SlewToCoordinatesAsync(ra, dec)
    until(lambda: not t.Slewing, "on the star")
    params = live.telescope.pointing.params
    before = {n: params.coefficient(n) for n in ("IA", "IE")}
    try:
        t.SyncToCoordinates(ra, dec + 0.01)   # "the telescope really points 36″ north"
        until(lambda: not t.Slewing, "tracking after the sync")
        assert abs(t.Declination - (dec + 0.01)) < 1.5 * ARCSEC
        assert abs(t.RightAscension - ra) * 15.0 < 1.5 * ARCSEC
        assert params.coefficient("IE") != before["IE"]
    finally:
        for name, value in before.items():
            params.set_coefficient(name, value)
        t.Tracking = False
        t.Disconnect()


def test_command_string_reads_and_sets_either_tree(live):
    t = connected_telescope(live)
    assert float(t.CommandString("TELESCOPE.READY_STATE", False)) == live.telescope.operations.ready_state
    assert float(t.CommandString("OpenTCI:CABINET.POWER_STATE", False)) in (0.0, 1.0)
    assert t.CommandString("SET POINTING.SETUP.FOCUS.POSITION=12.5", False) == "OK"
    assert float(t.CommandString("GET POINTING.SETUP.FOCUS.POSITION", False)) == 12.5
    t.CommandBlind("POINTING.SETUP.FOCUS.POSITION=0", False)
    with pytest.raises(InvalidValueException):
        t.CommandString("NO.SUCH.VARIABLE", False)
    t.Disconnect()


def test_tpl2_clients_see_no_change(live):
    """A TPL2 client of the same process reads and writes as before while Alpaca is served."""
    async def run():
        c = await Client.connect(live.port)
        try:
            assert float(await c.value("CABINET.POWER_STATE")) in (0.0, 1.0)
        finally:
            await c.close()
    asyncio.run(run())


def test_every_device_connects_and_answers_its_state(live):
    from alpaca.covercalibrator import CoverCalibrator
    from alpaca.dome import Dome
    from alpaca.filterwheel import FilterWheel
    from alpaca.focuser import Focuser
    from alpaca.observingconditions import ObservingConditions
    from alpaca.rotator import Rotator
    from alpaca.safetymonitor import SafetyMonitor
    from alpaca.switch import Switch

    classes = {"Telescope": Telescope, "Dome": Dome, "Focuser": Focuser, "FilterWheel": FilterWheel,
               "Rotator": Rotator, "CoverCalibrator": CoverCalibrator, "Switch": Switch,
               "ObservingConditions": ObservingConditions, "SafetyMonitor": SafetyMonitor}
    devices = management.configureddevices(address(live))
    kinds = sorted({d["DeviceType"] for d in devices})
    assert kinds == sorted(classes)
    assert sum(d["DeviceType"] == "Rotator" for d in devices) == 2      # one per derotator
    for d in devices:
        device = classes[d["DeviceType"]](address(live), d["DeviceNumber"])
        device.Connect()
        assert device.Connected and device.Name == d["DeviceName"]
        assert isinstance(device.DeviceState, list)
        assert device.InterfaceVersion >= 2
        device.Disconnect()


def test_focuser_filter_cover_dome_switch_weather(live):
    from alpaca.covercalibrator import CoverCalibrator, CoverStatus
    from alpaca.dome import Dome, ShutterState
    from alpaca.filterwheel import FilterWheel
    from alpaca.focuser import Focuser
    from alpaca.observingconditions import ObservingConditions
    from alpaca.safetymonitor import SafetyMonitor
    from alpaca.switch import Switch

    t = connected_telescope(live)
    ready(live, t)
    a = address(live)
    focuser = Focuser(a, 0)
    focuser.Connect()
    focuser.Move(12345)
    until(lambda: not focuser.IsMoving and focuser.Position == 12345, "the focuser at 12.345 mm")
    assert abs(live.telescope.axis("FOCUS").real_position - 12.345) < 0.002
    with pytest.raises(InvalidValueException):
        focuser.Move(focuser.MaxStep + 1)

    wheel = FilterWheel(a, 0)
    wheel.Connect()
    names = wheel.Names
    section = next(a for a in live.telescope.config.axes.values() if a.module == "FILTER")
    assert names == [section.names.get(str(k), str(k)) for k in sorted(int(k) for k in section.positions)]
    assert len(wheel.FocusOffsets) == len(names)
    wheel.Position = 3
    until(lambda: wheel.Position == 3, "filter slot 3")
    with pytest.raises(InvalidValueException):
        wheel.Position = len(names)

    weather = SafetyMonitor(a, 0)
    weather.Connect()
    until(lambda: weather.IsSafe, "good weather")
    cover = CoverCalibrator(a, 0)
    cover.Connect()
    cover.OpenCover()
    until(lambda: cover.CoverState == CoverStatus.Open, "the cover open")
    dome = Dome(a, 0)
    dome.Connect()
    dome.OpenShutter()
    until(lambda: dome.ShutterStatus == ShutterState.shutterOpen, "the shutter open", timeout=WAIT)
    dome.SlewToAzimuth(90.0)
    until(lambda: not dome.Slewing and abs(dome.Azimuth - 90.0) < 0.5, "the dome at 90°")

    switch = Switch(a, 0)
    switch.Connect()
    assert switch.MaxSwitch == len(live.telescope.peripherals.switches)
    switch.SetSwitch(0, True)
    until(lambda: switch.GetSwitch(0), "switch 0 on")
    switch.SetSwitch(0, False)
    until(lambda: not switch.GetSwitch(0), "switch 0 off")
    with pytest.raises(InvalidValueException):
        switch.SetSwitchValue(1, 99)

    conditions = ObservingConditions(a, 0)
    conditions.Connect()
    assert -50.0 < conditions.Temperature < 60.0 and conditions.WindSpeed >= 0.0
    assert "pressure" in conditions.SensorDescription("Pressure").lower()

    dome.CloseShutter()
    cover.CloseCover()
    until(lambda: dome.ShutterStatus == ShutterState.shutterClosed, "the shutter closed", timeout=WAIT)
    until(lambda: cover.CoverState == CoverStatus.Closed, "the cover closed")
    for device in (focuser, wheel, weather, cover, dome, switch, conditions, t):
        device.Disconnect()
