"""The Modbus PLC driver against the simulated PLC, over Modbus TCP (and RTU framing) on loopback.

The register maps are the simulated telescope's (``hwconfig/sim.toml``). The simulated PLC's
physics runs on a manual clock the tests advance, so a dome "turns" for minutes in no time and
no test waits for motion; the driver polls in real time on free loopback ports.
"""

from __future__ import annotations

import asyncio
import dataclasses

import pytest

from support.waits import until_async
from tcs.config import load_config
from tcs.config.plc import PlcSection
from tcs.config.schema import build
from tcs.drivers.modbus import ModbusExceptionResponse, PlcDriver
from tcs.drivers.plc_axis import PlcAxis
from tcs.errors import (AccessDenied, CommunicationError, ErrorNumber, HardwareError, RangeRefused,
                        UnknownObject)
from tcs.sim.enclosure import VARIANTS, enclosure_points
from tcs.sim.plc import SimPlc

WAIT = 20.0  # generous: a test never fails because the machine was slow


class ManualClock:
    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


def fast(section: PlcSection, **changes) -> PlcSection:
    """The section with test timing: quick polls (no idle rate), quick reconnects."""
    # a request time-out well above a loaded machine's stalls: a slow answer is not a lost PLC
    base = dict(poll_interval=0.02, idle_poll_interval=0.0, timeout=4.0, reconnect_min=0.05,
                reconnect_max=0.3)
    return dataclasses.replace(section, **{**base, **changes})


@pytest.fixture(scope="module")
def plcs():
    return load_config().plcs


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
async def dome(plcs, clock):
    """(simulated dome PLC, driver, connection events) — started and stopped by the test."""
    sim = SimPlc("dome", plcs["dome"], clock=clock, port=0)
    await sim.start()
    driver = PlcDriver("dome", fast(plcs["dome"], port=sim.port))
    events = []
    driver.add_connection_listener(events.append)
    await driver.start()
    await driver.wait_connected(WAIT)
    yield sim, driver, events
    await driver.stop()
    await sim.stop()


async def fresh(driver: PlcDriver, after: int | None = None):
    """A snapshot read entirely after now."""
    n = driver.snapshot.cycle if after is None else after
    return await driver.wait_for(lambda s: True, after=n, timeout=WAIT)


# ------------------------------------------------------------------ reading


async def test_reads_sensors_with_their_types_and_scaling(dome, clock):
    sim, driver, _ = dome
    clock.advance(100_000.0)  # uptime above 65535 s: both words of the little-endian uint32 matter
    snap = await fresh(driver)
    assert snap.valid
    assert snap["plc_uptime"] == 100_000
    for name, resolution in [("temp_outside", 0.1), ("pressure", 0.1), ("humidity", 0.1),
                             ("wind_speed", 0.01), ("wind_direction", 0.1)]:
        assert snap[name] == pytest.approx(sim.read_point(name), abs=resolution / 2 + 1e-9), name
    assert -30 < snap["temp_outside"] < 50 and 700 < snap["pressure"] < 850
    assert 0 <= snap["humidity"] <= 100 and snap["wind_speed"] >= 0
    assert snap["rain"] is False
    assert snap["az_position"] == pytest.approx(180.0)
    assert snap["az_status.at_target"] is True and snap["az_status.moving"] is False
    assert snap["slit_status.closed"] is True
    assert driver.value("az_status.at_target") is True
    with pytest.raises(UnknownObject):
        driver.value("no_such_point")


async def test_sensor_values_change_slowly_with_time(dome, clock):
    sim, driver, _ = dome
    first = (await fresh(driver))["temp_outside"]
    clock.advance(1800.0)
    later = (await fresh(driver))["temp_outside"]
    assert later != first and abs(later - first) < 10.0


async def test_forced_rain_and_wind_reach_the_driver(dome):
    sim, driver, _ = dome
    sim.force("rain", True)
    sim.force("wind_speed", 31.5)
    snap = await fresh(driver)
    assert snap["rain"] is True and snap["wind_speed"] == pytest.approx(31.5)
    sim.release("rain")
    assert (await fresh(driver))["rain"] is False


async def test_a_forced_value_and_its_return_reach_the_driver_each_time(dome):
    """The simulated PLC reuses the register words of a value it stored before (issue 27: its
    idle cost): a value that goes back and forth still reaches the driver every time."""
    sim, driver, _ = dome
    for wind in (31.5, 12.0, 31.5, 12.0):
        sim.force("wind_speed", wind)
        assert (await fresh(driver))["wind_speed"] == pytest.approx(wind)
    sim.release("wind_speed")
    sim.force("rain", True)
    assert (await fresh(driver))["rain"] is True
    sim.force("rain", 0)  # another type, the same register word
    assert (await fresh(driver))["rain"] is False
    sim.force("rain", 1)
    assert (await fresh(driver))["rain"] is True


# ------------------------------------------------------------------ writing


async def test_switch_write_and_delayed_feedback(dome, clock):
    sim, driver, _ = dome
    after = await driver.write("dome_fans", True)
    snap = await fresh(driver, after)
    assert snap["dome_fans"] is True and snap["dome_fans_on"] is False  # contactor delay 2 s
    clock.advance(2.5)
    assert (await fresh(driver))["dome_fans_on"] is True
    await driver.write("dome_lights", 1)
    assert (await fresh(driver))["dome_lights_on"] is True


async def test_bad_writes_are_refused_before_anything_is_sent(dome):
    _, driver, _ = dome
    with pytest.raises(UnknownObject):
        await driver.write("no_such_point", 1)
    with pytest.raises(AccessDenied):
        await driver.write("az_position", 10.0)
    with pytest.raises(RangeRefused, match="outside"):
        await driver.write("az_command", 70000)
    with pytest.raises(RangeRefused):
        await driver.write("dome_lights", 2)
    assert driver.stats.writes == 0 and driver.connected


async def test_plc_refusal_is_an_exception_response_and_the_link_stays(dome):
    _, driver, events = dome
    slit = PlcAxis(driver, "slit")
    with pytest.raises(ModbusExceptionResponse) as info:
        await slit.move(150.0)  # beyond the slit's 0..100
    assert info.value.code == 3 and info.value.number == ErrorNumber.CONFAIL
    assert driver.connected and [e.connected for e in events] == [True]


# ------------------------------------------------------------------ the dome


async def test_dome_azimuth_takes_the_short_way_and_arrives(dome, clock):
    _, driver, _ = dome
    az = PlcAxis(driver, "az")
    after = await az.move(350.0)         # from 180: +170 deg
    clock.advance(10.0)
    mid = az.state(await fresh(driver, after))
    assert mid.moving and not mid.at_target and mid.speed > 0 and 180.0 < mid.position < 350.0
    clock.advance(200.0)
    done = await az.wait_settled(after, timeout=WAIT)
    assert done.at_target and done.position == pytest.approx(350.0)
    after = await az.move(10.0)          # through north: +20 deg, not -340
    clock.advance(3.0)
    mid = az.state(await fresh(driver, after))
    assert mid.speed > 0
    clock.advance(60.0)
    done = await az.wait_settled(after, timeout=WAIT)
    assert done.at_target and done.position == pytest.approx(10.0)


async def test_slit_opens_stops_mid_move_and_reaches_the_end_switch(dome, clock):
    _, driver, _ = dome
    slit = PlcAxis(driver, "slit")
    assert slit.state().closed
    after = await slit.move(100.0)
    clock.advance(5.0)
    moving = slit.state(await fresh(driver, after))
    assert moving.moving and not moving.closed and 0 < moving.position < 100
    after = await slit.stop()
    clock.advance(10.0)
    stopped = await slit.wait_settled(after, timeout=WAIT)
    assert not stopped.moving and not stopped.at_target
    assert moving.position < stopped.position < 100.0 and not stopped.open and not stopped.closed
    clock.advance(10.0)
    assert slit.state(await fresh(driver)).position == pytest.approx(stopped.position)  # stays
    after = await slit.move(100.0)
    clock.advance(60.0)
    opened = await slit.wait_settled(after, timeout=WAIT)
    assert opened.at_target and opened.open and opened.position == pytest.approx(100.0)


async def test_stalled_motor_is_reported_and_reset(dome, clock):
    sim, driver, _ = dome
    az = PlcAxis(driver, "az")
    after = await az.move(270.0)
    clock.advance(5.0)
    await fresh(driver, after)
    sim.stall("az")
    clock.advance(5.0)                   # longer than the PLC's standstill detection
    with pytest.raises(HardwareError) as info:
        await az.wait_settled(after, timeout=WAIT)
    assert info.value.number == ErrorNumber.TIMEOUT and "stalled" in info.value.message
    state = az.state(await fresh(driver))
    assert state.fault and state.stalled and not state.moving and state.position < 270.0
    with pytest.raises(ModbusExceptionResponse) as refused:
        await az.move(270.0)             # a PLC in fault refuses motion
    assert refused.value.code == 4
    sim.stall("az", False)
    after = await az.reset()
    assert not az.state(await fresh(driver, after)).fault
    after = await az.move(270.0)
    clock.advance(100.0)
    assert (await az.wait_settled(after, timeout=WAIT)).at_target


# ------------------------------------------------------------------ losing the PLC


async def test_a_move_aborted_while_the_plc_was_away_does_not_resume(dome, clock):
    """The link drops during a move; when it returns, the driver writes stop to every axis of
    the PLC before anything else, so the PLC does not finish the old move by itself."""
    sim, driver, _ = dome
    az = PlcAxis(driver, "az")
    after = await az.move(350.0)          # from 180: +170 deg, tens of seconds
    clock.advance(5.0)
    mid = az.state(await fresh(driver, after))
    assert mid.moving
    await sim.power_off()
    while driver.connected:
        await asyncio.sleep(0.01)
    await sim.power_on()
    await driver.wait_connected(WAIT)     # the stop is written before connected is reported
    clock.advance(300.0)                  # long enough to have arrived, had it gone on
    state = az.state(await fresh(driver))
    assert not state.moving and not state.at_target
    assert state.position < 300.0
    for axis in ("slit", "flap", "seal"):  # at rest: a stop leaves them where they are
        assert not PlcAxis(driver, axis).state().moving


async def test_the_driver_counts_the_watchdog_and_the_simulated_plc_stops_without_it(plcs, clock):
    section = plcs["dome"]
    section = dataclasses.replace(section, sim=dataclasses.replace(section.sim, watchdog_timeout=0.3))
    sim = SimPlc("dome", section, clock=clock, port=0)
    async with sim:
        async with PlcDriver("dome", fast(section, port=sim.port)) as driver:
            await driver.wait_connected(WAIT)
            az = PlcAxis(driver, "az")
            after = await az.move(350.0)
            clock.advance(5.0)
            first = await fresh(driver, after)
            assert az.state(first).moving
            later = await fresh(driver, first.cycle)
            assert later["tcs_watchdog"] != first["tcs_watchdog"]
            await asyncio.sleep(0.6)     # the TCS is alive: the watchdog keeps changing
            assert sim.watchdog_trips == 0
        # the TCS is gone (driver stopped): the PLC program stops the dome on its own
        for _ in range(int(WAIT / 0.02)):
            if sim.watchdog_trips:
                break
            await asyncio.sleep(0.02)
        assert sim.watchdog_trips == 1
        clock.advance(300.0)
        assert sim.read_point("az_position") < 300.0
        assert not sim.read_point("az_status") & 1  # not moving


async def idle_interval(driver: PlcDriver, interval: float) -> None:
    """Wait (generously) until the driver polls at ``interval``."""
    await until_async(lambda: driver.stats.interval == interval, f"a poll every {interval} s",
                      WAIT, 0.02)


async def test_a_resting_plc_is_polled_at_the_idle_rate_until_something_moves(plcs, clock):
    """idle_poll_interval: 2 s after the last write and the last poll that saw an axis moving,
    the driver polls slower — the watchdog still counting; a write brings the full rate back
    before its caller resumes, a moving axis keeps it, and so does a holder (a trajectory)."""
    sim = SimPlc("dome", plcs["dome"], clock=clock, port=0)
    async with sim:
        section = fast(plcs["dome"], port=sim.port, idle_poll_interval=0.25)
        async with PlcDriver("dome", section) as driver:
            await driver.wait_connected(WAIT)
            assert driver.stats.interval == 0.02  # (just connected: the full rate first)
            await idle_interval(driver, 0.25)
            first = await fresh(driver)
            later = await fresh(driver, first.cycle)
            assert later["tcs_watchdog"] != first["tcs_watchdog"]  # written at every idle poll
            az = PlcAxis(driver, "az")
            after = await az.move(250.0)
            assert driver.stats.interval == 0.02   # the write: at once, not at the next idle poll
            clock.advance(1.0)
            assert az.state(await fresh(driver, after)).moving
            await asyncio.sleep(2.5)                # moving (on the manual clock) for longer than 2 s
            assert driver.stats.interval == 0.02
            assert az.state(await fresh(driver)).moving
            clock.advance(600.0)                    # arrived
            assert not az.state(await fresh(driver)).moving
            await idle_interval(driver, 0.25)
            holder = object()
            driver.hold_full_rate(holder)
            await idle_interval(driver, 0.02)
            await asyncio.sleep(2.5)
            assert driver.stats.interval == 0.02    # held, whatever the axes do
            driver.hold_full_rate(holder, False)
            await idle_interval(driver, 0.25)
        assert sim.watchdog_trips == 0


async def test_plc_that_stops_answering_is_lost_and_recovers(dome):
    sim, driver, events = dome
    sim.set_responding(False)
    with pytest.raises(CommunicationError) as info:
        await driver.write("dome_lights", True)
    assert info.value.number == ErrorNumber.CONFAIL
    assert not driver.connected and driver.error == ErrorNumber.CONFAIL
    assert not driver.snapshot.valid
    with pytest.raises(CommunicationError) as later:
        driver.value("rain")
    assert later.value.number in (ErrorNumber.CONFAIL, ErrorNumber.NOCON)
    assert sim.read_point("dome_lights") is False  # a hung PLC applied nothing
    sim.set_responding(True)
    await driver.wait_connected(WAIT)
    assert [(e.connected, e.number) for e in events][:2] == [(True, None), (False, ErrorNumber.CONFAIL)]
    assert events[-1].connected
    await driver.write("dome_lights", True)
    assert (await fresh(driver))["dome_lights_on"] is True


async def test_plc_switched_off_is_nocon_and_comes_back(dome):
    sim, driver, events = dome
    await sim.power_off()
    lost = await _next_event(driver, connected=False)
    assert lost.number == ErrorNumber.NOCON
    with pytest.raises(CommunicationError) as info:
        await driver.write("dome_lights", True)
    assert info.value.number == ErrorNumber.NOCON
    await sim.power_on()
    await driver.wait_connected(WAIT)
    await _until(lambda: driver.snapshot.valid and driver.error is None)  # after the first poll


async def test_dropped_connection_reconnects(dome):
    sim, driver, _ = dome
    connects = driver.stats.connects
    assert sim.drop_connections() == 1
    await _until(lambda: driver.stats.connects > connects and driver.connected)
    await driver.write("dome_lights", True)
    assert (await fresh(driver))["dome_lights"] is True


async def test_unreachable_plc_is_reported_at_start(plcs):
    sim = SimPlc("dome", plcs["dome"], port=0)
    await sim.start()
    port = sim.port
    await sim.stop()                      # a port where nothing listens
    driver = PlcDriver("dome", fast(plcs["dome"], port=port))
    events = []
    driver.add_connection_listener(events.append)
    await driver.start()
    try:
        await _until(lambda: events)
        assert events[0].connected is False and events[0].number == ErrorNumber.NOCON
        assert "cannot connect" in events[0].message
        with pytest.raises(CommunicationError) as info:
            await driver.wait_connected(0.3)
        assert info.value.number == ErrorNumber.NOCON
    finally:
        await driver.stop()


async def test_pending_writes_fail_when_the_plc_goes(dome):
    sim, driver, _ = dome
    sim.set_responding(False)
    first = asyncio.ensure_future(driver.write("dome_lights", True))
    second = asyncio.ensure_future(driver.write("dome_fans", True))
    results = await asyncio.gather(first, second, return_exceptions=True)
    assert all(isinstance(r, CommunicationError) for r in results)
    assert {r.number for r in results} == {ErrorNumber.CONFAIL}
    sim.set_responding(True)
    await driver.wait_connected(WAIT)


# ------------------------------------------------------------------ other PLCs, RTU, variants


async def test_telescope_plc_covers_and_settings(plcs, clock):
    sim = SimPlc("telescope", plcs["telescope"], clock=clock, port=0)
    async with sim, PlcDriver("telescope", fast(plcs["telescope"], port=sim.port)) as driver:
        await driver.wait_connected(WAIT)
        cover = PlcAxis(driver, "cover1")
        assert cover.state().closed and cover.unit == "deg"
        after = await cover.move(90.0)
        clock.advance(30.0)
        opened = await cover.wait_settled(after, timeout=WAIT)
        assert opened.open and opened.at_target and not opened.closed
        after = await driver.write_many({"mirror_fans": 2})
        snap = await fresh(driver, after)
        assert snap["mirror_fans"] == 2
        later = await fresh(driver, snap.cycle)  # the driver counts the watchdog at every poll
        assert later["tcs_watchdog"] != snap["tcs_watchdog"]
        assert snap["temp_cabinet"] == pytest.approx(sim.read_point("temp_cabinet"))
        assert snap["oil_pressure"] == pytest.approx(25.0)


async def test_rtu_framing_over_a_serial_url(plcs, clock):
    section = dataclasses.replace(plcs["dome"], transport="rtu", serial_port="socket://127.0.0.1:0")
    sim = SimPlc("dome", section, clock=clock, port=0)
    async with sim:
        rtu = fast(section, serial_port=f"socket://127.0.0.1:{sim.port}")
        async with PlcDriver("dome", rtu) as driver:
            await driver.wait_connected(WAIT)
            assert driver.snapshot["az_position"] == pytest.approx(180.0)
            after = await driver.write("dome_lights", True)
            assert (await fresh(driver, after))["dome_lights_on"] is True


@pytest.mark.parametrize("variant", sorted(VARIANTS))
async def test_every_enclosure_type_opens(variant, clock):
    points, axes = enclosure_points(variant)
    section, errors = build(PlcSection, {"points": points, "sim": {"axes": axes}}, "generated")
    assert not errors, errors
    sim = SimPlc(variant, section, clock=clock, port=0)
    async with sim, PlcDriver(variant, fast(section, port=sim.port)) as driver:
        await driver.wait_connected(WAIT)
        for name, _, _ in VARIANTS[variant]:
            axis = PlcAxis(driver, name)
            if name == "az":
                continue
            top = sim.axes[name].params.max
            after = await axis.move(top)
            clock.advance(400.0)
            state = await axis.wait_settled(after, timeout=WAIT)
            assert state.open and state.position == pytest.approx(top), name


# ------------------------------------------------------------------ helpers


async def _next_event(driver: PlcDriver, connected: bool):
    fut = asyncio.get_running_loop().create_future()
    remove = driver.add_connection_listener(
        lambda ev: ev.connected == connected and not fut.done() and fut.set_result(ev))
    try:
        return await asyncio.wait_for(fut, WAIT)
    finally:
        remove()


async def _until(condition, timeout: float = WAIT) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        assert loop.time() < deadline, "condition not reached"
        await asyncio.sleep(0.01)


# ------------------------------------------------------------------ bad register maps


def map_problems(points: str, extra: str = "") -> list[str]:
    from tcs.config import parse_config
    from tcs.errors import ConfigErrors
    text = f"[plcs.p]\n{extra}\n[plcs.p.points]\n{points}\n"
    with pytest.raises(ConfigErrors) as info:
        parse_config(text, "hw.toml")
    return [e.message for e in info.value.errors]


@pytest.mark.parametrize("points, extra, expected", [
    ('a = { kind = "holding", address = 10, type = "float32" }\n'
     'b = { kind = "holding", address = 11, type = "uint16" }', "",
     "hw.toml: plcs.p.points.b.address: a holding register 11 overlaps point 'a' (10..11)"),
    ('a = { kind = "holding", address = 0, type = "float64" }', "",
     "hw.toml: plcs.p.points.a.type: must be one of 'bool', 'int16'"),
    ('a = { kind = "input", address = 0, access = "rw" }', "",
     "hw.toml: plcs.p.points.a.access: an input register is read-only on Modbus"),
    ('a = { kind = "discrete", address = 0, access = "w" }', "",
     "hw.toml: plcs.p.points.a.access: a discrete input is read-only on Modbus"),
    ('a = { kind = "input", address = 0, type = "uint16", bits = { fault = 16 } }', "",
     "hw.toml: plcs.p.points.a.bits.fault: bit 16 is beyond a uint16 (0..15)"),
    ('a = { kind = "input", address = 0, type = "int32", bits = { x = 3, y = 3 } }', "",
     "hw.toml: plcs.p.points.a.bits.y: bit 3 is already 'x'"),
    ('a = { kind = "input", address = 0, type = "float32", bits = { x = 3 } }', "",
     "hw.toml: plcs.p.points.a.bits: bit fields need an integer register type"),
    ('a = { kind = "holding", address = 65535, type = "float32" }', "",
     "hw.toml: plcs.p.points.a.address: a float32 needs 2 registers (65535..65536)"),
    ('a = { kind = "holding", address = 0, type = "bool" }', "",
     "hw.toml: plcs.p.points.a.type: 'bool' is for coils and discrete inputs"),
    ('a = { kind = "coil", address = 0, type = "uint16" }', "",
     "hw.toml: plcs.p.points.a.type: a coil is one bit"),
    ('a = { kind = "holding", address = 0, scale = 0.0 }', "",
     "hw.toml: plcs.p.points.a.scale: must be a finite non-zero number"),
    ('a = { kind = "holdings", address = 0 }', "",
     "hw.toml: plcs.p.points.a.kind: must be one of 'coil'"),
    ('"a b" = { kind = "coil", address = 0 }', "",
     "hw.toml: plcs.p.points.a b: point name must be an identifier"),
    ('a = { kind = "coil", address = 0 }', 'transport = "rtu"',
     "hw.toml: plcs.p.serial_port: transport 'rtu' needs a serial_port"),
    ('a = { kind = "coil", address = 0 }', 'reconnect_min = 10.0\nreconnect_max = 1.0',
     "hw.toml: plcs.p.reconnect_min: 10.0 is above reconnect_max"),
    ('a = { kind = "coil", address = 0 }', 'poll_interval = 0.2\nidle_poll_interval = 0.1',
     "hw.toml: plcs.p.idle_poll_interval: must be 0 (off) or at least poll_interval (0.2 s)"),
    ('tcs_watchdog = { kind = "holding", address = 60 }', 'idle_poll_interval = 1.5\nsim = {}',
     "hw.toml: plcs.p.idle_poll_interval: the simulated PLC's watchdog (sim.watchdog_timeout = 2 s) "
     "needs a write at least every 1 s"),
    ('a_target = { kind = "holding", address = 0, type = "float32" }\n'
     'a_command = { kind = "holding", address = 2 }\n'
     'a_position = { kind = "input", address = 0, type = "float32" }',
     'sim = { axes = { a = {} } }',
     "hw.toml: plcs.p.points.a_status: missing: axis 'a' needs it"),
    ('a = { kind = "coil", address = 0 }', 'sim = { switches = { b = {} } }',
     "hw.toml: plcs.p.sim.switches.b: no point 'b' in the register map"),
])
def test_bad_register_map_is_refused_with_its_key_path(points, extra, expected):
    found = map_problems(points, extra)
    assert any(p.startswith(expected) for p in found), found


def test_plc_axis_on_a_map_without_the_convention_names_the_missing_point(plcs):
    driver = PlcDriver("dome", plcs["dome"])  # never started: construction only
    from tcs.errors import ConfigError
    with pytest.raises(ConfigError, match=r"plcs\.dome\.points\.roof_target: missing"):
        PlcAxis(driver, "roof")


async def test_stop_returns_even_when_it_coincides_with_an_answer(plcs):
    """Regression: Python 3.11's wait_for (in pymodbus) swallows a cancel that meets an answer;
    with continuous polling about one stop in four hit it and never returned."""
    sim = SimPlc("dome", plcs["dome"], port=0)
    async with sim:
        for i in range(20):
            section = dataclasses.replace(plcs["dome"], port=sim.port, poll_interval=0.002)
            driver = PlcDriver("dome", section)
            await driver.start()
            await driver.wait_connected(WAIT)
            await asyncio.sleep(0.01 + 0.002 * (i % 7))
            stopping = asyncio.ensure_future(driver.stop())
            done, _ = await asyncio.wait([stopping], timeout=WAIT)
            assert stopping in done, f"stop() hung (round {i})"
            assert not driver.connected
