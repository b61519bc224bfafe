"""The simulated telescope on a busy host (issue 25 item 2, issue 27 item 4).

The shipped ``sim.toml`` (control process, seven simulated drives on the virtual bus in that
process), over TPL2: while it tracks, busy-loop processes keep every core busy for a bounded
window and the control process is stopped (SIGSTOP) and continued a few times; the axes stay
powered and tracking, no error is latched, and the simulated drives say they rode out their
own host's stalls. Also ``CABINET.CORE.DRIVE[]`` is served from the control process's
readbacks. The busy loops end by themselves after the window even if the test dies.
Nothing here asserts timing: the test waits for states.
"""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import subprocess
import sys

import pytest

from support.opentci_client import Client
from support.service import make_config
from test_axes import ready
from test_control_process import _children
from tcs.app import Service

HOG_SECONDS = 15.0
STOPS = 3            # SIGSTOP/SIGCONT of the control process during the window
STOP_SECONDS = 1.5   # each: longer than the drives' SYNC loss (0.5 s) and 0x1016 (1 s)


@pytest.fixture
async def sim_service(tmp_path, caplog):
    caplog.set_level(logging.INFO)  # (the control process forwards its log at this level)
    config = make_config(tmp_path / "state")
    assert config.can.control_process
    service = Service(config)
    port = await service.start()
    try:
        yield service, port
    finally:
        await service.stop()


def start_hogs(count: int, seconds: float) -> list[subprocess.Popen]:
    """``count`` processes spinning for ``seconds`` (they end by themselves)."""
    code = f"import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end: pass\n"
    return [subprocess.Popen([sys.executable, "-c", code]) for _ in range(count)]


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for hog in hogs:
        if hog.poll() is None:
            hog.kill()
        hog.wait(10)


async def test_core_drive_is_served_from_the_control_process(sim_service):
    service, port = sim_service
    c = await Client.connect(port)
    try:
        await ready(c, "AZ")
        await c.wait("CABINET.CORE.DRIVE[0].STATE", lambda v: v == '"operation enabled"', 30)
        assert await c.value("CABINET.CORE.DRIVE[0].AXIS") == '"AZ"'
        assert await c.value("CABINET.CORE.DRIVE[0].NAME") == '"az"'
        assert await c.num("CABINET.CORE.DRIVE[0].HEARTBEAT") == 1
        assert int(await c.num("CABINET.CORE.DRIVE[0].STATUSWORD")) & 0x6F == 0x27
        await c.set("AZ.TARGETPOS=12.5")
        await c.wait("CABINET.CORE.DRIVE[0].POSITION", lambda v: abs(v - 12.5) < 1e-3, 30)
        assert await c.num("CABINET.CORE.DRIVE[0].ERRORCODE") == 0
    finally:
        await c.close()


async def test_tracking_survives_a_busy_host_and_stalls_of_the_control_process(sim_service, caplog):
    service, port = sim_service
    c = await Client.connect(port)
    hogs: list[subprocess.Popen] = []
    (child,) = _children(os.getpid())
    try:
        await ready(c, "AZ", "ZD")
        await c.set("AZ.TARGETPOS=30", 180)
        await c.set("ZD.TARGETPOS=35", 180)
        ra, dec = await c.nums("POINTING.CURRENT.RA", "POINTING.CURRENT.DEC")
        await c.set(f"POINTING.TARGET.RA={ra + 0.01!r};POINTING.TARGET.DEC={dec + 0.1!r}")
        cmd = await c.start("POINTING.TRACK=1")
        for ax in ("AZ", "ZD"):
            await c.wait(f"{ax}.MOTION_STATE", lambda v: (int(v) & 10) == 10, 60)  # on the path
        hogs = start_hogs(2 * (os.cpu_count() or 2), HOG_SECONDS)
        for _ in range(STOPS):
            await asyncio.sleep(2.0)
            os.kill(child, signal.SIGSTOP)
            try:
                await asyncio.sleep(STOP_SECONDS)
            finally:
                os.kill(child, signal.SIGCONT)
        await asyncio.to_thread(lambda: [h.wait(HOG_SECONDS + 30) for h in hogs])
        # back on the path after the window (the follower catches up within its limits)
        for ax in ("AZ", "ZD"):
            await c.wait(f"{ax}.MOTION_STATE", lambda v: (int(v) & 10) == 10, 60)
        for ax in ("AZ", "ZD"):
            assert await c.num(f"{ax}.POWER_STATE") == 1.0
            assert await c.num(f"{ax}.ERROR_STATE") == 0
        assert await c.num("POINTING.TRACK") != 0
        listed = await c.value("CABINET.STATUS.LIST")
        assert "drive fault" not in listed, listed
        assert any("their host stalled" in r.getMessage() for r in caplog.records), \
            "the simulated drives never saw their host stall: the test proved nothing"
        lines = await c.set("POINTING.TRACK=0")
        assert lines[-2].endswith("DATA OK POINTING.TRACK"), lines
        await c.until(cmd, 30)
    finally:
        stop_hogs(hogs)
        try:
            os.kill(child, signal.SIGCONT)
        except ProcessLookupError:
            pass
        await c.close()
