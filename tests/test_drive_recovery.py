"""Recovery in place (issue 10): a drive that was power-cycled or lost the TCS heartbeat is
booted again by the running service; the operator's ``ERROR_STATE=0`` (complete only when the
drive's fault reset is done) and ``POWER=1`` bring its axis back — no restart of the service.
Over TPL2 against the fast simulated telescope, faults made with real CAN frames."""

from __future__ import annotations

import asyncio
import dataclasses
import time
from pathlib import Path

import can

from support.opentci_client import Client, done_ok
from support.service import make_config
from tcs.app import Service
from test_axes import MOVING, ready

FAST = Path(__file__).with_name("hw_axes_fast.toml")
WAIT = 30.0


def fast_config(tmp_path, **zd):
    config = make_config(tmp_path / "state", FAST)
    drives = dict(config.drives)
    drives["zd"] = dataclasses.replace(drives["zd"], **zd)
    new = dataclasses.replace(config, drives=drives)
    object.__setattr__(new, "source", config.source)
    return new


async def acknowledge(c: Client, axis: str) -> list[str]:
    """``ERROR_STATE=0`` as an operator does: again while the drive is still being booted
    (that answer says so); the successful one completes when the reset is done."""
    deadline = time.monotonic() + WAIT
    while True:
        lines = await c.set(f"{axis}.ERROR_STATE=0")
        if done_ok(lines, f"{axis}.ERROR_STATE"):
            return lines
        assert time.monotonic() < deadline, lines
        assert any("FAILED" in line for line in lines), lines
        await asyncio.sleep(0.2)


async def power_on_and_move(c: Client, axis: str, target: float) -> None:
    lines = await c.set(f"{axis}.POWER=1")  # at once after ERROR_STATE=0 completed
    assert done_ok(lines, f"{axis}.POWER"), lines
    if await c.num(f"{axis}.REFERENCED") < 1.0:
        await c.set(f"{axis}.REINIT=0")
        await c.wait(f"{axis}.REFERENCED", lambda v: v == 1.0)
    lines = await c.set(f"{axis}.TARGETPOS={target}")
    assert done_ok(lines, f"{axis}.TARGETPOS"), lines
    await c.wait(f"{axis}.MOTION_STATE", lambda v: not int(v) & MOVING)


async def test_power_cycled_drive_recovers_without_restart(tmp_path):
    svc = Service(fast_config(tmp_path))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        await ready(c, "ZD")
        lines = await c.set("ZD.TARGETPOS=3")
        assert done_ok(lines, "ZD.TARGETPOS"), lines
        # a power blip of the ZD drive: NMT reset node, put on the bus by a third party
        with can.Bus(interface="virtual", channel=svc.config.can.channel) as bus:
            bus.send(can.Message(arbitration_id=0x000, data=[0x81, 2], is_extended_id=False))
        await c.wait("ZD.ERROR_STATE", lambda v: int(v) & 2)
        # (FAILED 4 while the rebooting drive gives no data: unknown, not the last value)
        await c.wait("ZD.POWER_STATE", lambda v: v == 0.0)
        await acknowledge(c, "ZD")
        assert await c.num("ZD.ERROR_STATE") == 0
        assert await c.num("ZD.REFERENCED") == 0.0  # its position was lost with the reboot
        assert await c.num("CABINET.REFERENCED") < 1.0
        await power_on_and_move(c, "ZD", 5.0)
        assert abs(await c.num("ZD.REALPOS") - 5.0) <= 0.0005
        assert svc.telescope.can.recoveries >= 1
    finally:
        await c.close()
        await svc.stop()


async def test_tcs_heartbeat_loss_recovers_without_restart(tmp_path):
    """ZD's drive watches the TCS heartbeat with 0.3 s (the others 5 s): a heartbeat gap
    faults it (0x8130) and drops it to pre-operational; the service boots it again, and
    ERROR_STATE=0 (fault reset done) + POWER=1 make it work."""
    svc = Service(fast_config(tmp_path, heartbeat_consumer_timeout=0.3))
    port = await svc.start()
    c = await Client.connect(port)
    sim = svc.telescope.sims[2]
    try:
        await ready(c, "ZD")
        bus = svc.telescope.can.bus
        bus.stop_heartbeat()
        deadline = time.monotonic() + WAIT
        while 0x8130 not in sim.emcy_sent:
            assert time.monotonic() < deadline
            await asyncio.sleep(0.02)
        bus.start_heartbeat()
        await c.wait("ZD.ERROR_STATE", lambda v: int(v) & 2)
        await c.wait("ZD.POWER_STATE", lambda v: v == 0.0)
        await acknowledge(c, "ZD")
        assert sim.error_code == 0 and sim.state == "SWITCH ON DISABLED"
        assert await c.num("ZD.REFERENCED") == 1.0  # no power loss: still referenced
        await power_on_and_move(c, "ZD", 4.0)
        assert abs(await c.num("ZD.REALPOS") - 4.0) <= 0.0005
        assert svc.telescope.can.recoveries >= 1
    finally:
        await c.close()
        await svc.stop()


async def test_bus_off_stops_the_axes_then_they_recover(tmp_path):
    """Bus-off (an error frame on the virtual bus): every drive axis fails its motion, shows
    ERROR_STATE with an event and a CABINET.STATUS.LIST entry, its drive is quick-stopped
    (never cut at speed); when the controller is back (error frame "restarted") the axes work
    again after ERROR_STATE=0 and POWER=1."""
    from tcs.drivers.canbus import CAN_ERR_BUSOFF, CAN_ERR_RESTARTED

    svc = Service(fast_config(tmp_path))
    port = await svc.start()
    c = await Client.connect(port)
    sim = svc.telescope.sims[2]
    try:
        await ready(c, "ZD")
        start = await c.num("ZD.REALPOS")
        cmd = await c.start(f"ZD.TARGETPOS={-start if abs(start) > 20 else 60}")
        await c.wait("ZD.REALPOS", lambda v: abs(v - start) > 2)
        before = len(sim.logic.transitions)
        with can.Bus(interface="virtual", channel=svc.config.can.channel) as bus:
            bus.send(can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True,
                                 is_extended_id=False, data=bytes(8)))
            lines = await c.until(cmd, WAIT)
            assert "FAILED" in lines[-2], lines
            await c.event(r"^\d+ EVENT ERROR ZD:\d+ .*bus-off")
            assert int(await c.num("ZD.ERROR_STATE")) & 2
            assert int(await c.num("AZ.ERROR_STATE")) & 2
            assert "bus-off" in await c.value("CABINET.STATUS.LIST")
            await c.wait("ZD.POWER_STATE", lambda v: v == 0.0)
            deadline = time.monotonic() + WAIT
            while sim.state != "SWITCH ON DISABLED":
                assert time.monotonic() < deadline
                await asyncio.sleep(0.02)
            taken = sim.logic.transitions[before:]
            assert taken[0] == 11 and 9 not in taken, taken
            bus.send(can.Message(arbitration_id=CAN_ERR_RESTARTED, is_error_frame=True,
                                 is_extended_id=False, data=bytes(8)))
        await acknowledge(c, "ZD")
        await power_on_and_move(c, "ZD", 2.0)
    finally:
        await c.close()
        await svc.stop()


async def test_values_without_fresh_data_fail(tmp_path):
    """While ZD's drive sends no TPDOs its measured values answer FAILED 4 instead of a frozen
    position; they are live again when the data is."""
    svc = Service(fast_config(tmp_path))
    port = await svc.start()
    c = await Client.connect(port)
    sim = svc.telescope.sims[2]
    try:
        await ready(c, "ZD")
        float(await c.value("ZD.REALPOS"))
        sim.mute_tpdos(True)
        deadline = time.monotonic() + WAIT
        while True:
            lines = await c.command(77, "GET ZD.REALPOS;ZD.CURRPOS;ZD.CURRSPEED;AZ.REALPOS")
            if "FAILED" in lines[1]:
                break
            assert time.monotonic() < deadline, lines
            await asyncio.sleep(0.05)
        assert lines[1:4] == ["77 DATA INLINE ZD.REALPOS=FAILED 4", "77 DATA INLINE ZD.CURRPOS=FAILED 4",
                              "77 DATA INLINE ZD.CURRSPEED=FAILED 4"], lines
        assert lines[4].startswith("77 DATA INLINE AZ.REALPOS=") and "FAILED" not in lines[4], lines
        sim.mute_tpdos(False)
        await c.wait("ZD.REALPOS", lambda v: isinstance(v, float))
    finally:
        await c.close()
        await svc.stop()


async def test_fault_of_one_mount_axis_stops_the_other_under_control(tmp_path):
    """ZD faults (over-current) while AZ slews: AZ is given up too — its TARGETPOS fails, it
    is powered off — with a quick stop of its drive, never disable voltage at speed."""
    svc = Service(fast_config(tmp_path))
    port = await svc.start()
    c = await Client.connect(port)
    az_sim, zd_sim = svc.telescope.sims[1], svc.telescope.sims[2]
    try:
        await ready(c, "AZ", "ZD")
        start = await c.num("AZ.REALPOS")
        cmd = await c.start(f"AZ.TARGETPOS={start - 200 if start > 0 else start + 200}")
        deadline = time.monotonic() + WAIT
        while abs(az_sim.velocity) < 50:  # well under way (max 200/s)
            assert time.monotonic() < deadline
            await asyncio.sleep(0.01)
        before = len(az_sim.logic.transitions)
        zd_sim.inject_fault("overcurrent")
        lines = await c.until(cmd, WAIT)
        assert "DATA ERROR AZ.TARGETPOS FAILED 2" in lines[-2], lines
        await c.event(r"^\d+ EVENT ERROR AZ:21 .*ZD faulted")
        await c.wait("AZ.POWER_STATE", lambda v: v == 0.0)
        taken = az_sim.logic.transitions[before:]
        assert taken and taken[0] == 11 and 9 not in taken, taken
        assert int(await c.num("ZD.ERROR_STATE")) & 2
        lines = await c.set("AZ.POWER=1")  # AZ itself has no fault
        assert done_ok(lines, "AZ.POWER"), lines
    finally:
        await c.close()
        await svc.stop()


async def test_an_acknowledge_while_the_drive_still_brakes_completes_once_it_stopped(tmp_path):
    """ERROR_STATE=0 at once after a drive faulted at speed: the drive's fault reaction (a
    ramp with its quick-stop deceleration, 4°/s² here: ~7.5 s from 30°/s) outlasts the axis's
    3 s for a reset; the acknowledge completes when the drive has stopped and reset, and
    POWER=1 works. Before, the master raised the reset bit during the reaction, so there was
    no rising edge in Fault, and the acknowledge failed after 3 s."""
    svc = Service(fast_config(tmp_path, quick_stop_deceleration=4.0))
    port = await svc.start()
    c = await Client.connect(port)
    zd_sim = svc.telescope.sims[2]
    try:
        await ready(c, "ZD")
        lines = await c.set("ZD.TARGETPOS=-80")
        assert done_ok(lines, "ZD.TARGETPOS"), lines
        cmd = await c.start("ZD.TARGETPOS=80")
        deadline = time.monotonic() + WAIT
        while abs(zd_sim.velocity) < 30:
            assert time.monotonic() < deadline
            await asyncio.sleep(0.01)
        zd_sim.inject_fault("following_error")
        await c.until(cmd, WAIT)
        assert zd_sim.state == "FAULT REACTION ACTIVE"
        t0 = time.monotonic()
        lines = await c.set("ZD.ERROR_STATE=0")
        assert done_ok(lines, "ZD.ERROR_STATE"), lines
        assert time.monotonic() - t0 > 1.0   # (it waited for the drive's stop)
        assert zd_sim.state == "SWITCH ON DISABLED" and zd_sim.error_code == 0
        await power_on_and_move(c, "ZD", 0.0)
    finally:
        await c.close()
        await svc.stop()


async def test_axis_waits_for_a_slow_drives_own_enable_timeout(tmp_path):
    """A drive configured with ``enable_timeout`` above the axis's 10 s (a commutation
    search): the axis's POWER waits at least the drive's own time-out plus a margin, so the
    drive's error (or its success) comes first; drives with the default keep 10 s. (Checked
    through the computed time-out: the simulated drive has no slow enable to wait for.)"""
    svc = Service(fast_config(tmp_path, enable_timeout=30.0))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        axes = {a.module_name: a for a in svc.telescope.axes}
        assert axes["ZD"].power_timeout > 30.0 + 1.0  # 30 s + mode switch + a margin
        assert axes["AZ"].power_timeout == 10.0
        await ready(c, "ZD")  # and it powers on as before
    finally:
        await c.close()
        await svc.stop()


async def test_a_drive_that_drops_out_without_a_fault_latches_an_error(tmp_path):
    """ZD's drive leaves Operation enabled by itself without a fault (its 0x6007 reaction to
    a lost master set to quick stop, 3): the power loss is an error the operator sees —
    ZD.ERROR_STATE and CABINET.ERROR_STATE, a STATUS.LIST entry — and only ERROR_STATE=0, then
    POWER=1, bring the axis back (it used to read POWER_STATE=0 with ERROR_STATE=0)."""
    svc = Service(fast_config(tmp_path))
    port = await svc.start()
    c = await Client.connect(port)
    sim = svc.telescope.sims[2]
    try:
        await ready(c, "ZD")
        with sim.lock:
            sim.store.set(0x6007, 0, 3)
            sim.logic.update(sim.clock())
            sim.logic.connection_lost(None)
        await c.wait("ZD.POWER_STATE", lambda v: v == 0.0)
        await c.wait("ZD.ERROR_STATE", lambda v: int(v) & 2)
        assert sim.error_code == 0                      # no drive fault: the TCS latched it
        assert int(await c.num("CABINET.ERROR_STATE")) & 2
        listed = await c.value("CABINET.STATUS.LIST")
        assert "ZD:drive left operation enabled by itself" in listed, listed
        lines = await c.set("ZD.POWER=1")
        assert not done_ok(lines, "ZD.POWER") and "acknowledge with ERROR_STATE=0" in " ".join(lines)
        assert "ZD: ZD:" not in " ".join(lines)
        await acknowledge(c, "ZD")
        assert await c.num("ZD.ERROR_STATE") == 0
        await power_on_and_move(c, "ZD", 4.0)
    finally:
        await c.close()
        await svc.stop()


async def test_a_slew_failed_by_its_drive_tells_the_client_why(tmp_path):
    """AZ's drive faults during a slew: ``AZ.TARGETPOS FAILED 2`` comes with its reason as an
    event under the command's id. The drive-fault event the control loop sends is
    unsolicited (id 0), which a client waiting for its command does not show; it used to
    count as "already told" and the command's own event was left out."""
    svc = Service(fast_config(tmp_path))
    port = await svc.start()
    c = await Client.connect(port)
    az_sim = svc.telescope.sims[1]
    try:
        await ready(c, "AZ")
        start = await c.num("AZ.REALPOS")
        cmd = await c.start(f"AZ.TARGETPOS={start - 100 if start > 0 else start + 100}")
        deadline = time.monotonic() + WAIT
        while abs(az_sim.velocity) < 10:
            assert time.monotonic() < deadline
            await asyncio.sleep(0.01)
        az_sim.inject_fault("overcurrent")
        lines = await c.until(cmd, WAIT)
        assert lines[-2] == f"{cmd} DATA ERROR AZ.TARGETPOS FAILED 2", lines
        reasons = [line for line in lines if line.startswith(f"{cmd} EVENT ERROR AZ:2 ")]
        assert reasons and "over-current" in reasons[0], lines
    finally:
        await c.close()
        await svc.stop()


async def test_cabinet_acknowledge_fails_when_an_axis_cannot_be_reset(tmp_path):
    """CABINET.ERROR_STATE=0 while ZD's drive is in fault and silent: ZD's fault reset cannot
    be done, so the cabinet's acknowledge fails with that reason (it answered done while
    ZD.ERROR_STATE stayed 2)."""
    svc = Service(fast_config(tmp_path))
    port = await svc.start()
    c = await Client.connect(port)
    sim = svc.telescope.sims[2]
    try:
        await ready(c, "ZD")
        sim.inject_fault("overcurrent")
        await c.wait("ZD.ERROR_STATE", lambda v: int(v) & 2)
        sim.set_responding(False)
        await c.wait("ZD.REALPOS", lambda v: v == "FAILED 4")     # offline: cannot be reset
        lines = await c.set("CABINET.ERROR_STATE=0")
        assert "DATA ERROR CABINET.ERROR_STATE FAILED" in lines[-2], lines
        assert "cannot reset" in " ".join(lines), lines
        assert int(await c.num("ZD.ERROR_STATE")) & 2
    finally:
        sim.set_responding(True)
        await c.close()
        await svc.stop()


async def test_status_without_fresh_data_is_unknown_on_every_front_end(tmp_path):
    """While ZD's drive sends no data, its power and motion states are unknown too, not the
    last value: OpenTCI POWER_STATE / MOTION_STATE / LIMIT_STATE answer FAILED 4, OpenTSI
    TELESCOPE.MOTION_STATE FAILED 4, Alpaca's position and Slewing an error; live again after."""
    import json
    import urllib.error
    import urllib.request

    base = make_config(tmp_path / "state")
    config = dataclasses.replace(base, can=dataclasses.replace(base.can, control_process=False))
    object.__setattr__(config, "source", base.source)
    svc = Service(config)
    port = await svc.start()
    c = await Client.connect(port)
    tsi = await Client.connect(svc.opentsi_port)
    sim = svc.telescope.sims[config.drives["zd"].node_id]

    def alpaca(member: str) -> dict:
        url = f"http://127.0.0.1:{svc.alpaca_port}/api/v1/telescope/0/{member}"
        with urllib.request.urlopen(url, timeout=10) as r:
            return json.loads(r.read())

    try:
        await ready(c, "ZD")
        assert await c.num("ZD.POWER_STATE") == 1.0
        await asyncio.to_thread(lambda: urllib.request.urlopen(urllib.request.Request(
            f"http://127.0.0.1:{svc.alpaca_port}/api/v1/telescope/0/connected",
            data=b"Connected=True&ClientID=1&ClientTransactionID=1", method="PUT"), timeout=10).close())
        assert (await asyncio.to_thread(alpaca, "altitude"))["ErrorNumber"] == 0
        sim.mute_tpdos(True)
        deadline = time.monotonic() + WAIT
        while "FAILED" not in (lines := await c.command(77, "GET ZD.REALPOS"))[1]:
            assert time.monotonic() < deadline, lines
            await asyncio.sleep(0.05)
        lines = await c.command(78, "GET ZD.POWER_STATE;ZD.MOTION_STATE;ZD.LIMIT_STATE;ZD.POWER")
        assert lines[1:5] == ["78 DATA INLINE ZD.POWER_STATE=FAILED 4", "78 DATA INLINE ZD.MOTION_STATE=FAILED 4",
                              "78 DATA INLINE ZD.LIMIT_STATE=FAILED 4", "78 DATA INLINE ZD.POWER=FAILED 4"], lines
        lines = await tsi.command(79, "GET TELESCOPE.MOTION_STATE")
        assert lines[1].endswith("TELESCOPE.MOTION_STATE=FAILED 4"), lines
        for member in ("altitude", "azimuth", "slewing"):
            answer = await asyncio.to_thread(alpaca, member)
            assert answer["ErrorNumber"] != 0 and "no fresh data" in answer["ErrorMessage"], answer
        sim.mute_tpdos(False)
        await c.wait("ZD.POWER_STATE", lambda v: isinstance(v, float))
        assert (await asyncio.to_thread(alpaca, "altitude"))["ErrorNumber"] == 0
    finally:
        await c.close()
        await tsi.close()
        await svc.stop()
