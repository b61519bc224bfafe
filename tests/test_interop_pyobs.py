"""Interoperability: drive the server with pyobs-pilar's own client class.

Optional group (``-m interop``): needs the ``interop`` extra (pyobs-pilar pulls pyobs-core
and an older astropy), so it is skipped when the package is not installed. Run it with::

    python3 -m venv /tmp/interop && /tmp/interop/bin/pip install -e ".[dev,interop]"
    /tmp/interop/bin/python -m pytest -m interop tests/test_interop_pyobs.py
"""

from __future__ import annotations

import asyncio

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
