"""The control process (``[can] control_process = true``, the shipped files' setting): the
drivers' cycle and the axes' step run in a child process; the service keeps the asyncio side.

Over TPL2 against the simulated telescope: the whole axis life (power, referencing, a move,
a refused move, a trajectory with its refusals, STOP at speed) behaves as in one process;
the loop's counters come from the child; a crashed child leaves the service serving with
stale axes and a withheld watchdog; a crashed service leaves no child behind, and the child
stops the axis it was moving.
"""

from __future__ import annotations

import asyncio
import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support.opentci_client import Client, upload
from support.service import make_config
from test_axes import ready
from tcs.app import Service


def _is_control_process(pid: int) -> bool:
    try:
        return b"tcs.axes.control_core" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


def _children(pid: int) -> list[int]:
    """Process ids of the control processes started by ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and _is_control_process(int(entry.name)):
            found.append(int(entry.name))
    return found


@pytest.fixture
async def proc_service(tmp_path):
    config = make_config(tmp_path / "state")
    assert config.can.control_process, "the shipped sim.toml runs the loop in a control process"
    service = Service(config)
    port = await service.start()
    try:
        yield service, port
    finally:
        await service.stop()


async def test_axis_life_in_the_control_process(proc_service):
    service, port = proc_service
    pid = os.getpid()
    assert len(_children(pid)) == 1
    c = await Client.connect(port)
    try:
        # the refusals are made here, before anything is sent to the child
        lines = await c.set("AZ.TARGETPOS=10")
        assert lines[-2].endswith("FAILED 5"), lines   # power off
        await ready(c, "AZ")
        lines = await c.set("AZ.TARGETPOS=1000")
        assert "RANGE" in lines[-2], lines
        # a move: DATA OK only once the readbacks say so (readbacks before completions)
        lines = await c.set("AZ.TARGETPOS=12.5")
        assert lines[-2] == f"{lines[0].split()[0]} DATA OK AZ.TARGETPOS", lines
        real, motion = await c.nums("AZ.REALPOS", "AZ.MOTION_STATE")
        assert abs(real - 12.5) < 1e-3 and int(motion) & 8 and not int(motion) & 1
        # the cycle counters are the child's
        c1 = await c.num("CABINET.CORE.CYCLE.CYCLES")
        await asyncio.sleep(0.3)
        c2 = await c.num("CABINET.CORE.CYCLE.CYCLES")
        assert c2 > c1
        assert service.telescope.control_loop.healthy()
        # STOP at speed: a controlled stop, the pending SET fails, no fault
        cmd = await c.start("AZ.TARGETPOS=-60")
        await c.wait("AZ.CURRSPEED", lambda v: abs(v) > 1.0)
        await c.set("AZ.STOP=1")
        lines = await c.until(cmd, 30)
        assert "FAILED" in lines[-2], lines
        await c.wait("AZ.MOTION_STATE", lambda v: not int(v) & 1)
        assert await c.num("AZ.POWER_STATE") == 1.0
        assert await c.num("AZ.ERROR_STATE") == 0
    finally:
        await c.close()


async def test_trajectory_through_the_control_process(proc_service):
    service, port = proc_service
    c = await Client.connect(port)
    try:
        await ready(c, "ZD")
        t0 = await c.num("LOCAL.UT1") + 1.0
        p0 = await c.num("ZD.REALPOS")
        free = int(await c.num("ZD.TRAJECTORY.FREEPOINTS"))
        n = 20
        await upload(c, "ZD", [(t0 + 0.5 * i, p0 + 0.01 * i) for i in range(n)])
        assert await c.num("ZD.TRAJECTORY.FREEPOINTS") == free - n  # the child's queue, at once
        assert await c.num("ZD.TRAJECTORY.STARTTIME") == pytest.approx(t0)
        # a point that does not follow the last one: refused by the child's queue, same reply
        await c.set(f"ZD.TRAJECTORY.BUFFER[0].TIME={t0!r};ZD.TRAJECTORY.BUFFER[0].TARGETPOS=1")
        lines = await c.set("ZD.TRAJECTORY.ADDPOINTS=1")
        assert lines[-2].endswith("DATA ERROR ZD.TRAJECTORY.ADDPOINTS FAILED 11"), lines  # (issue 24: not RANGE)
        cmd = await c.start("ZD.TRAJECTORY.RUN=1")
        await c.wait("ZD.MOTION_STATE", lambda v: int(v) & 2)
        assert await c.num("ZD.TRAJECTORY.RUN") == 1
        assert await c.num("ZD.TRAJECTORY.RUNTIME") > 0
        lines = await c.until(cmd, 30)
        assert lines[-2].endswith("DATA OK ZD.TRAJECTORY.RUN"), lines
        # (the follower brakes from the path's last speed, 0.02 °/s: a little past the end)
        assert abs(await c.num("ZD.REALPOS") - (p0 + 0.01 * (n - 1))) < 5e-3
    finally:
        await c.close()


async def test_tracking_through_the_control_process(proc_service):
    """POINTING.TRACK: the tracker's points go to the child's queues, its checks read the
    child's follower; CURRENT follows TARGET within an arcsecond while the axes move."""
    service, port = proc_service
    c = await Client.connect(port)
    try:
        await ready(c, "AZ", "ZD")
        await c.set("AZ.TARGETPOS=120")
        await c.set("ZD.TARGETPOS=35")
        ra, dec = await c.nums("POINTING.CURRENT.RA", "POINTING.CURRENT.DEC")
        await c.set(f"POINTING.TARGET.RA={ra + 0.01!r};POINTING.TARGET.DEC={dec + 0.1!r}")
        cmd = await c.start("POINTING.TRACK=1")
        for ax in ("AZ", "ZD"):
            await c.wait(f"{ax}.MOTION_STATE", lambda v: (int(v) & 10) == 10, 60)   # trajectory, on path
        az0 = await c.num("AZ.REALPOS")
        for _ in range(5):
            await asyncio.sleep(0.4)
            cra, cdec, tra, tdec = await c.nums("POINTING.CURRENT.RA", "POINTING.CURRENT.DEC",
                                                "POINTING.TARGET.RA", "POINTING.TARGET.DEC")
            assert abs(cra - tra) * 15 * 3600 < 1.5 and abs(cdec - tdec) * 3600 < 1.0
            assert await c.num("POINTING.TARGETDISTANCE") < 1 / 3600
        assert await c.num("AZ.REALPOS") != az0                          # the sky turns
        assert await c.num("AZ.TRAJECTORY.RUNTIME") > 0
        lines = await c.set("POINTING.TRACK=0")
        assert lines[-2].endswith("DATA OK POINTING.TRACK"), lines
        lines = await c.until(cmd, 30)
        assert lines[-2].endswith("DATA OK POINTING.TRACK"), lines
        await c.wait("AZ.MOTION_STATE", lambda v: not int(v) & 2)
    finally:
        await c.close()


async def test_a_crashed_control_process_is_restarted_in_place(proc_service):
    """kill -9 of the control process during a move: the move fails, the axes read stale
    (FAILED 4) with a latched error; a new control process is started, the client stays
    connected, the axes read fresh again, the drives are off (nothing moves until commanded)
    and the error stays until acknowledged; then the axis works again."""
    service, port = proc_service
    c = await Client.connect(port)
    try:
        await ready(c, "AZ")
        cmd = await c.start("AZ.TARGETPOS=80")
        await c.wait("AZ.CURRSPEED", lambda v: abs(v) > 1.0)
        (child,) = _children(os.getpid())
        os.kill(child, signal.SIGKILL)
        lines = await c.until(cmd, 30)
        assert "FAILED" in lines[-2], lines            # the pending move fails
        await c.wait("AZ.ERROR_STATE", lambda v: int(v) & 2)
        deadline = time.monotonic() + 120
        while _children(os.getpid()) in ([], [child]):
            assert time.monotonic() < deadline, "no new control process"
            await asyncio.sleep(0.1)
        process = service.telescope.can
        while process.respawning or process._gone is not None or \
                not service.telescope.control_loop.healthy():
            assert time.monotonic() < deadline and not process.given_up, "not restarted"
            await asyncio.sleep(0.1)
        real = await c.num("AZ.REALPOS")                 # fresh again (not FAILED 4)
        assert await c.num("AZ.POWER_STATE") == 0.0       # taken over: off
        assert int(await c.num("AZ.ERROR_STATE")) & 2    # latched until acknowledged
        await asyncio.sleep(0.5)
        assert await c.num("AZ.REALPOS") == pytest.approx(real, abs=1e-6)  # nothing moves
        listing = await c.command(78, "GET CABINET.STATUS.LIST", 10)
        assert any("control process" in line for line in listing), listing
        lines = await c.set("AZ.ERROR_STATE=0")
        assert "OK" in lines[-2] or "COMPLETE" in lines[-1], lines
        await c.wait("AZ.ERROR_STATE", lambda v: int(v) == 0)
        await ready(c, "AZ")
        lines = await c.set(f"AZ.TARGETPOS={await c.num('AZ.REALPOS') + 1.0!r}")
        assert lines[-2].endswith("DATA OK AZ.TARGETPOS"), lines
        assert await c.value("LOCAL.UT1")             # the rest of the service still answers
    finally:
        await c.close()


def test_a_killed_service_leaves_no_control_process(tmp_path):
    """kill -9 of tcs-server with an axis powered: its control process (which stops and
    powers off the axes first) ends by itself."""
    from test_cli_server import free_port
    from test_sigterm import Client as SyncClient

    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"))
    port = free_port()
    server = subprocess.Popen([sys.executable, "-m", "tcs.cli.server", "--port", str(port),
                               "--opentsi-port", "-1", "--alpaca-port", "-1", "--web-port", "-1", "--indi-port", "-1"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    children = []
    try:
        c = SyncClient(port)
        children = _children(server.pid)
        assert len(children) == 1
        c.send("1 SET CABINET.POWER=1")
        assert c.until(1)[-1].endswith(b"COMMAND COMPLETE")
        c.send("2 SET AZ.POWER=1")
        assert c.until(2)[-1].endswith(b"COMMAND COMPLETE")
        c.close()
        server.kill()
        server.wait(10)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and _is_control_process(children[0]):
            time.sleep(0.05)
        assert not _is_control_process(children[0]), "the control process outlived its service"
        # what it did is in the log (its stderr: the journal under systemd), not lost with
        # the service it used to log through
        err = server.stderr.read()
        assert "the service is gone; stopping and powering off every axis" in err, err
        line = next(x for x in err.splitlines() if "axes stopped and powered off: " in x)
        assert "MOVING" not in line and " ON" not in line and "stopped off" in line, line
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
        server.stderr.close()
        for pid in children:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


async def test_threaded_mode_still_runs(tmp_path):
    """``control_process = false``: the loop is a thread of the service (tests that reach the
    simulated drives in-process use it)."""
    base = make_config(tmp_path / "state")
    config = dataclasses.replace(base, can=dataclasses.replace(base.can, control_process=False))
    object.__setattr__(config, "source", base.source)
    service = Service(config)
    port = await service.start()
    try:
        assert not _children(os.getpid())
        assert service.telescope.sims is not None
        c = await Client.connect(port)
        await ready(c, "AZ")
        await c.set("AZ.TARGETPOS=3")
        assert abs(await c.num("AZ.REALPOS") - 3) < 1e-3
        await c.close()
    finally:
        await service.stop()


async def test_start_up_readbacks_are_not_dropped(tmp_path, caplog):
    """The child's loop sends readbacks before the model has built its axes: those batches
    are taken (their statistics kept), never dropped with an IndexError."""
    import logging
    caplog.set_level(logging.ERROR, logger="tcs.axes.control_process")
    config = make_config(tmp_path / "state")
    service = Service(config)
    await service.start()
    try:
        await asyncio.sleep(0.5)
        failed = [r for r in caplog.records if "handling batch failed" in r.getMessage()]
        assert not failed, failed[0].exc_text
        assert service.telescope.can.stats.get("cycles", 0) > 0
    finally:
        await service.stop()


def test_orphan_stop_time_follows_the_configured_stop(tmp_path):
    """An orphaned control process waits for the longest configured stop (max speed / stop
    deceleration) plus a margin — not a fixed 10 s that a slow-braking axis outlasts."""
    from types import SimpleNamespace

    from tcs.axes.control_core import STOP_MARGIN, orphan_stop_time

    config = make_config(tmp_path / "state")
    axes = [SimpleNamespace(section=s) for s in config.axes.values()]
    expected = max(s.max_velocity / (s.stop_deceleration or 2 * s.max_acceleration)
                   for s in config.axes.values())
    assert orphan_stop_time(axes) == pytest.approx(expected + STOP_MARGIN)
    slow = dataclasses.replace(config.axes["az"], stop_deceleration=0.25)   # 20 s from 5 °/s
    assert orphan_stop_time([SimpleNamespace(section=slow)]) == pytest.approx(20.0 + STOP_MARGIN)


async def test_core_drive_diagnostics_come_from_the_control_process(proc_service):
    """CABINET.CORE.DRIVE[] reads the drives of the control process: names, states and
    positions, not blanks, ``none`` and 0."""
    service, port = proc_service
    c = await Client.connect(port)
    try:
        await ready(c, "AZ")
        await c.set("AZ.TARGETPOS=12.5")
        deadline = time.monotonic() + 30
        while await c.get("CABINET.CORE.DRIVE[0].NAME") != '"az"':
            assert time.monotonic() < deadline
            await asyncio.sleep(0.1)
        assert await c.get("CABINET.CORE.DRIVE[0].AXIS") == '"AZ"'
        assert await c.get("CABINET.CORE.DRIVE[0].STATE") == '"operation enabled"'
        await c.wait("CABINET.CORE.DRIVE[0].POSITION", lambda v: abs(v - 12.5) < 1e-3)
    finally:
        await c.close()


def test_an_unchanged_readback_carries_only_its_times_and_never_hides_a_change():
    """An axis whose readbacks but their times are those sent last sends ``(measured_ut1,
    sample)``; when the service has not taken the full snapshot before it yet, the pending one
    keeps its values and takes the new times (a change is never coalesced away)."""
    from tcs.axes.control_core import MEASURED, READBACKS, SAMPLE, Outbox, merge_unchanged, unchanged_key

    width = 1 + len(READBACKS) + 8
    full = tuple(range(width))
    full = (*full[:MEASURED], 10.0, *full[MEASURED + 1:SAMPLE], (10.0, 5.0, 10.01, 5.0),
            *full[SAMPLE + 1:-1], None)
    later = (*full[:MEASURED], 10.01, *full[MEASURED + 1:SAMPLE], (10.01, 5.0, 10.02, 5.0),
             *full[SAMPLE + 1:])
    assert unchanged_key(later) == unchanged_key(full)  # only times differ
    moved = (*full[:3], 99.0, *full[4:])
    assert unchanged_key(moved) != unchanged_key(full)
    outbox = Outbox()
    outbox.cycle({0: full}, None)
    outbox.cycle({0: (10.01, later[SAMPLE])}, None)  # unchanged, before the sender took `full`
    batch, _ = outbox.take()
    assert batch[1][0] == later == merge_unchanged(full, (10.01, later[SAMPLE]))
    outbox.cycle({0: (10.02, later[SAMPLE])}, None)  # after it: the times alone
    assert outbox.take()[0][1][0] == (10.02, later[SAMPLE])


def test_quiet_cycles_wake_the_sender_every_fifth_time_and_anything_else_at_once():
    """An idle telescope's readbacks (times only) go to the service every QUIET_EVERY-th
    cycle, the newest times each; a change, an event or the statistics go at once."""
    from tcs.axes.control_core import QUIET_EVERY, Outbox

    outbox = Outbox()
    for k in range(1, 3 * QUIET_EVERY + 1):
        outbox.cycle({0: (float(k), None), 1: (float(k), None)}, None)
        assert outbox.wake.is_set() == (k % QUIET_EVERY == 0), k
        if outbox.wake.is_set():
            outbox.wake.clear()
            assert outbox.take()[0][1] == {0: (float(k), None), 1: (float(k), None)}
    outbox.cycle({0: (1.0, None), 1: tuple(range(20))}, None)   # a change
    assert outbox.wake.is_set()
    outbox.wake.clear()
    outbox.take()
    outbox.item(("event", "INFO", "AZ", 1, "", None))
    outbox.cycle({0: (2.0, None)}, None)                        # an event
    assert outbox.wake.is_set()
    outbox.wake.clear()
    outbox.take()
    outbox.cycle({0: (3.0, None)}, {"cycles": 1})               # the statistics
    assert outbox.wake.is_set()
