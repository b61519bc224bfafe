"""The CAN bus comes back (issue 14 item 2): the socketcand peer (the simulated cabinet) dies
and is started again; the TCS reopens the bus by itself, boots the drives again as after a
power blip, and they can be enabled — no restart. Repeated log lines are rate-limited."""

from __future__ import annotations

import asyncio
import logging
import time
import uuid

import can
from cia402_rig import drive_section

from tcs.config.can import CanSection
from tcs.drivers.can_system import CanDrives
from tcs.drivers.drive import DriveState
from tcs.log_repeat import RepeatFilter
from tcs.sim.cia402_drive import SimDrive
from tcs.sim.socketcand_server import SocketcandServer

logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)


class Cabinet:
    """Simulated drives on a virtual bus, offered over socketcand (what ``tcs-sim`` does)."""

    def __init__(self, port: int = 0):
        self.channel = f"tcs-rc-{uuid.uuid4().hex[:8]}"
        self.port = port
        self.server = SocketcandServer(self.channel, port=port)
        self.bus = None
        self.sims: list[SimDrive] = []

    async def start(self) -> int:
        self.port = await self.server.start()
        self.bus = can.Bus(interface="virtual", channel=self.channel)
        self.sims = [SimDrive(self.bus, 1)]
        for sim in self.sims:
            sim.start()
        return self.port

    async def kill(self) -> None:
        for sim in self.sims:
            sim.stop()
        self.bus.shutdown()
        await self.server.stop()


async def wait(predicate, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.05)


async def test_socketcand_peer_dies_and_comes_back(monkeypatch):
    import canopen

    monkeypatch.setattr(canopen.network.Network, "NOTIFIER_SHUTDOWN_TIMEOUT", 0.0)
    cabinet = Cabinet()
    port = await cabinet.start()
    section = CanSection(interface="socketcand", channel="can0", port=port, sync_period=0.01,
                         heartbeat_period=0.05, boot_timeout=3.0, sdo_timeout=0.3,
                         options={"tcp_tune": "true"})
    system = CanDrives(section, {"az": drive_section(1)})
    system.cycle.add_callback(system.step_all)
    drive = system.drives["az"]
    try:
        await asyncio.to_thread(system.open)
        assert await asyncio.to_thread(system.boot) == {}
        system.start()
        drive.enable()
        await wait(lambda: drive.status().state is DriveState.OPERATION_ENABLED, "enabled")

        await cabinet.kill()  # kill -9 of tcs-sim, as far as the bus is concerned
        await wait(lambda: drive.status().state is DriveState.OFFLINE, "drive given up")
        await asyncio.sleep(0.5)
        cabinet = Cabinet(port)  # tcs-sim started again: the drives power up afresh
        await cabinet.start()
        await wait(lambda: system.bus.reconnects >= 1, "bus reopened")
        await wait(lambda: drive.status().state is DriveState.SWITCH_ON_DISABLED
                   and drive.status().fault is None, "drive booted again")
        assert drive.status().reboots == 1  # (its position may be lost: REFERENCED drops)
        drive.enable()
        await wait(lambda: drive.status().state is DriveState.OPERATION_ENABLED, "enabled again")
    finally:
        await asyncio.to_thread(system.close)
        await cabinet.kill()


def test_repeated_log_lines_are_counted_not_repeated():
    now = [0.0]
    flt = RepeatFilter(interval=10.0, clock=lambda: now[0])
    records = []
    handler = logging.Handler()
    handler.emit = lambda record: records.append(record.getMessage())
    handler.addFilter(flt)
    logger = logging.getLogger("test.repeat")
    logger.addHandler(handler)
    logger.propagate = False
    logger.setLevel(logging.DEBUG)
    try:
        for i in range(1000):
            now[0] = i * 0.01
            logger.warning("send of 0x%03X failed after %.2f s", 0x80, i * 0.01)
        logger.warning("something else")
        logger.info("an info line")
        logger.info("an info line")  # (INFO is never limited)
        now[0] = 12.0
        logger.warning("send of 0x%03X failed after %.2f s", 0x80, 12.0)
    finally:
        logger.removeHandler(handler)
    assert records == ["send of 0x080 failed after 0.00 s", "something else", "an info line",
                       "an info line",
                       "send of 0x080 failed after 12.00 s (999 more like it in the last 12 s)"]


async def test_a_reconnect_try_to_a_silent_peer_fails_at_once(monkeypatch, caplog):
    """While the socketcand peer is gone, each reconnect try fails at once (nothing listens)
    and the tries follow the back-off — not one try blocked in python-can's 10 s of retries."""
    import canopen

    monkeypatch.setattr(canopen.network.Network, "NOTIFIER_SHUTDOWN_TIMEOUT", 0.0)
    caplog.set_level(logging.WARNING, logger="tcs.drivers.canbus")
    cabinet = Cabinet()
    port = await cabinet.start()
    section = CanSection(interface="socketcand", channel="can0", port=port, sync_period=0.01,
                         heartbeat_period=0.05, boot_timeout=3.0, sdo_timeout=0.3,
                         options={"tcp_tune": "true"})
    system = CanDrives(section, {"az": drive_section(1)})
    system.cycle.add_callback(system.step_all)
    try:
        await asyncio.to_thread(system.open)
        assert await asyncio.to_thread(system.boot) == {}
        system.start()
        await cabinet.kill()

        def tries() -> int:
            return sum("reopening failed" in r.getMessage() for r in caplog.records)

        await wait(lambda: tries() >= 3, "three reconnect tries", timeout=8.0)
    finally:
        await asyncio.to_thread(system.close)
