"""Interoperability: drive the server with pyobs-pilar's own client classes (its PilarDriver
on the OpenTCI port; its PilarTelescope module, unchanged, on the OpenTSI port).

Optional group (``-m interop``): needs the ``interop`` extra (pyobs-pilar pulls pyobs-core
and an older astropy), so it is skipped when the package is not installed. Run it with::

    python3 -m venv /tmp/interop && /tmp/interop/bin/pip install -e ".[dev,interop]"
    /tmp/interop/bin/python -m pytest -m interop tests/test_interop_pyobs.py
"""

from __future__ import annotations

import asyncio
import logging

import pytest

pytestmark = pytest.mark.interop
pilar = pytest.importorskip("pyobs_pilar.pilardriver", reason="needs the 'interop' extra (pyobs-pilar)")


async def test_pilar_driver_reads_and_writes(service):
    _, port = service
    loop = asyncio.get_running_loop()
    driver = pilar.PilarDriver("127.0.0.1", port, "admin", "admin")
    # Use the driver's own protocol class, as PilarDriver.open() does, without pyobs' module
    # machinery and its OpenTSI background poller.
    await loop.create_connection(lambda: pilar.PilarClientProtocol(driver, loop, "admin", "admin"),
                                 "127.0.0.1", port)
    for _ in range(100):
        if driver.protocol.logged_in:
            break
        await asyncio.sleep(0.05)
    assert driver.protocol.logged_in
    assert await driver.get("LOCAL.HEIGHT") == "2326.0"
    values = await driver.get_multi(["LOCAL.LATITUDE", "CONFIG.MOUNT", "LOCAL.UT1-UTC!TYPE"])
    assert values == {"LOCAL.LATITUDE": "28.7606", "CONFIG.MOUNT": "AZ-ZD", "LOCAL.UT1-UTC!TYPE": "2"}
    assert await driver.set("LOCAL.UT1-UTC", 0.3) is True      # sent quoted: SET X="0.3"
    assert await driver.get("LOCAL.UT1-UTC") == "0.3"
    assert await driver.set("LOCAL.UT1-UTC", 3) is True        # RANGE arrives as DATA ERROR, not COMMAND ERROR
    assert await driver.get("LOCAL.UT1-UTC") == "0.3"
    await driver.protocol.stop()                               # bare "disconnect", then close
    await asyncio.sleep(0.1)


# ------------------------------------------------------------------------------ OpenTSI

@pytest.fixture
def opentsi_live(tmp_path):
    from pathlib import Path

    from support.live import LiveService

    service = LiveService(Path(__file__).with_name("hw_opentsi.toml"), tmp_path / "state").start()
    try:
        yield service
    finally:
        service.stop()


class _Errors(logging.Handler):
    """Every record of pyobs / pyobs-pilar at ERROR or with an exception."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.bad: list[str] = []

    def emit(self, record):
        if record.levelno >= logging.ERROR or record.exc_info:
            self.bad.append(f"{record.name}: {record.getMessage()}")


async def test_pilar_telescope_runs_a_night_on_the_opentsi_port(opentsi_live):
    """pyobs-pilar's own PilarTelescope, unchanged, with its status and error loops running:
    open → init → move_radec → set_offsets_altaz → set_focus → set_filter → move_altaz →
    stop → park, and no error or exception in its log."""
    from astropy.utils import iers

    iers.conf.auto_download = False        # offline: no IERS download, old predictions are fine
    iers.conf.auto_max_age = None
    iers.conf.iers_degraded_accuracy = "warn"
    from pyobs.comm.dummy import DummyComm
    from pyobs.utils.enums import MotionStatus
    from pyobs_pilar.pilartelescope import PilarTelescope

    errors = _Errors()
    for name in ("pyobs", "pyobs_pilar"):
        logging.getLogger(name).addHandler(errors)
    live = opentsi_live
    port = live.service.opentsi_port
    tel = PilarTelescope("127.0.0.1", port, "admin", "admin", has_filterwheel=True,
                         comm=DummyComm(),
                         location={"longitude": -17.8792, "latitude": 28.7606, "elevation": 2326.0})
    try:
        await tel.open()
        assert await tel.list_filters() == ["clear", "V", "R", "Halpha"]
        await tel.init()
        assert await tel.get_filter() == "clear"

        p = live.telescope.pointing
        import time as _time
        ra, dec = p.astrometry().icrs_from_observed(120.0, 30.0, _time.time() + 5.0)
        await tel.move_radec(float(ra) * 15.0, float(dec))
        assert await tel.get_motion_status() == MotionStatus.TRACKING
        await asyncio.sleep(2.0)                                   # its status loop: 1 s
        got_ra, got_dec = await tel.get_radec()
        assert abs(got_dec - float(dec)) < 1 / 3600 and abs(got_ra - float(ra) * 15.0) < 2 / 3600

        await tel.set_offsets_altaz(10 / 3600, 20 / 3600)
        offsets = await tel.get_offsets_altaz()
        assert offsets == pytest.approx((10 / 3600, 20 / 3600), abs=2e-5), offsets  # its own cos(alt)
        await tel.set_focus(12.5)
        assert await tel.get_focus() == pytest.approx(12.5, abs=0.01)
        await tel.set_filter("V")
        assert await tel.get_filter() == "V"
        await tel.move_altaz(45.0, 200.0)
        await asyncio.sleep(2.0)
        alt, az = await tel.get_altaz()
        assert alt == pytest.approx(45.0, abs=0.001) and az == pytest.approx(200.0, abs=0.001)
        await tel.stop_motion()
        await tel.park()
        assert await tel.get_motion_status() == MotionStatus.PARKED
        assert not errors.bad, errors.bad
    finally:
        await tel.close()
        # pyobs's PilarDriver.close() calls Object.open() and so restarts its background tasks,
        # and PilarTelescope's status task returns when cancelled, which its supervisor takes
        # for a crash and restarts (pyobs-pilar 1.7.0): stop them without a restart
        for obj in (tel, tel._pilar):
            for task, _autostart in obj._background_tasks:
                task._restart = False
        pyobs_tasks = [t for t in asyncio.all_tasks() if t.get_coro().__qualname__ in
                       ("BackgroundTask._func_wrapper", "Event.wait")]   # also those started twice
        for task in pyobs_tasks:
            task.cancel()
        await asyncio.wait(pyobs_tasks, timeout=10)
        for name in ("pyobs", "pyobs_pilar"):
            logging.getLogger(name).removeHandler(errors)
