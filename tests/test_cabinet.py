"""CABINET over a real TPL2 socket: power, referencing, STOP, error state, status list, log,
setup and core diagnostics.

The tree is SERVER + the real CABINET declaration around a real :class:`Cabinet`; the axes and
modules it switches are test-owned stand-ins (the small interface the cabinet relies on: power,
reference, stop, drive_status, error conditions) whose actions finish when the test opens
their gate, so every outcome is produced on demand and nothing depends on timing.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import re
import threading
from types import SimpleNamespace

import pytest

import tcs
from support.tpl2 import RawClient
from tcs.config import load_config
from tcs.config.passwords import hash_password
from tcs.config.sections import ServerSection, UserSection
from tcs.drivers.drive import DriveState, DriveStatus
from tcs.drivers.emcy import DriveFault
from tcs.errors import ErrorNumber, HardwareError, TcsError
from tcs.model.cabinet import Cabinet
from tcs.model.events import EventHub
from tcs.model.health import ERROR, WARNING, ModuleHealth
from tcs.model.state_store import StateStore
from tcs.opentci_server.opentci import SERVER, Root
from tcs.opentci_server.opentci.cabinet import CABINET
from tcs.opentci_server.server import Tpl2Server
from tcs.opentci_server.tree import Tree
from tcs import state_epoch

HWFILE = """
[cabinet]
manufacturer = "Test Cabinets Ltd"
hw_id = "CAB-42"
hw_version = "3b"
config_version = "7"
hw_type = 7
log_lines = 5

[can]
interface = "virtual"
channel = "cabinet-test"

[drives.az]
node_id = 5
identity = { vendor = 0x29A, product = 0x402, revision = 0x10001 }
increments_per_unit = 1000.0
min_position = -270.0
max_position = 270.0
following_error_window = 0.5
max_velocity = 5.0
max_acceleration = 5.0
"""


class StandIn(ModuleHealth):
    """A test-owned axis or module with the interface the cabinet uses.

    ``power``/``reference`` wait for their gate (open by default) and then succeed or raise the
    error the test put in ``power_error``/``reference_error``.
    """

    def __init__(self, name: str, journal: list, order: int = 2, events=None, drive=None):
        super().__init__(name, events)
        self.reference_order = order
        self.journal = journal
        self.power_state = 0.0
        self.referenced = 0.0
        self.motion_state = 0
        self.power_gate = asyncio.Event()
        self.power_gate.set()
        self.reference_gate = asyncio.Event()
        self.reference_gate.set()
        self.power_error: TcsError | None = None
        self.reference_error: TcsError | None = None
        self.stops = 0
        self.cancelled: list[str] = []
        self.drive = drive

    async def power(self, on: bool) -> None:
        self.journal.append(("power", self.module_name, on))
        try:
            await self.power_gate.wait()
        except asyncio.CancelledError:
            self.cancelled.append("power")
            raise
        if self.power_error is not None:
            raise self.power_error
        self.power_state = 1.0 if on else 0.0

    async def reference(self, force: bool = False) -> None:
        self.journal.append(("reference", self.module_name, force))
        self.referenced = 0.5
        try:
            await self.reference_gate.wait()
        except asyncio.CancelledError:
            self.cancelled.append("reference")
            raise
        if self.reference_error is not None:
            self.referenced = 0.0
            raise self.reference_error
        self.referenced = 1.0

    def stop(self) -> None:
        self.stops += 1

    def drive_status(self):
        return self.drive


class Clock:
    def __init__(self, t: float = 1_700_000_000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


class Rig:
    """Cabinet + stand-ins + TPL2 server on a free port."""

    def __init__(self, tmp_path, clock: Clock):
        path = tmp_path / "cabinet.toml"
        if not path.exists():
            path.write_text(HWFILE)
        self.config = load_config(path)
        self.state_dir = tmp_path / "state"
        self.clock = clock
        self.journal: list = []
        self.events = EventHub()
        self.store = StateStore(self.state_dir)
        fault = DriveFault("az", 0x8611)
        drive = DriveStatus("az", DriveState.FAULT, position=12.5, velocity=-0.25, following_error=0.01,
                            statusword=0x0008, fault=fault, heartbeat_ok=True)
        ev = self.events
        self.zd = StandIn("ZD", self.journal, order=0, events=ev)
        self.az = StandIn("AZ", self.journal, order=1, events=ev, drive=drive)
        self.derot = StandIn("DEROTATOR[2]", self.journal, order=2, events=ev)
        self.focus = StandIn("FOCUS", self.journal, order=2, events=ev)
        self.dome = StandIn("DOME", self.journal, events=ev)
        self.local = ModuleHealth("LOCAL", ev)
        self.cabinet = Cabinet(self.config, self.store, ev, modules=[self.local, self.dome],
                               axes=[self.az, self.zd], clock=clock)
        self.cabinet.attach(axes=[self.derot, self.focus])  # axes may come after the cabinet
        self.server: Tpl2Server | None = None
        self.client: RawClient | None = None
        self.closed = False

    async def start(self) -> int:
        self.events.bind_loop()
        await self.cabinet.start()
        users = (UserSection("admin", hash_password("admin", iterations=1000), 0, 0),)
        self.server = Tpl2Server(ServerSection(port=0, auth_fail_delay=0.01, abort_timeout=2.0),
                                 users, self.events)
        root = Root(SimpleNamespace(cabinet=self.cabinet), self.server)
        self.server.tree = Tree.build((SERVER, CABINET), root)
        return await self.server.start("127.0.0.1", 0)

    async def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        await self.client.close()
        if self.server is not None:
            await self.server.stop()
        await self.cabinet.close()

    def axes(self):
        return [self.zd, self.az, self.derot, self.focus]


@pytest.fixture
async def make_rig(tmp_path):
    rigs: list[Rig] = []

    async def make(clock: Clock | None = None) -> tuple[Rig, RawClient]:
        rig = Rig(tmp_path, clock or Clock())
        rigs.append(rig)
        port = await rig.start()
        client = await RawClient.connect(port)
        rig.client = client
        return rig, client

    yield make
    for rig in rigs:
        await rig.close()


async def wait_for(predicate, timeout: float = 10.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        assert loop.time() < deadline, "condition not reached"
        await asyncio.sleep(0.002)


async def event_line(c: RawClient, pattern: str) -> str:
    """The next line matching ``pattern`` (lines read before it are dropped)."""
    while True:
        line = await c.readline()
        if re.search(pattern, line):
            return line


def power_journal(rig: Rig):
    return [(name, on) for kind, name, on in rig.journal if kind == "power"]


# ----------------------------------------------------------------------------------- POWER


async def test_power_on_completes_only_when_every_component_is_on(make_rig):
    rig, c = await make_rig()
    assert await c.get("CABINET.POWER_STATE") == "0.0"
    rig.az.power_gate.clear()
    await c.send("1 SET CABINET.POWER=1")
    await wait_for(lambda: ("AZ", True) in power_journal(rig))
    assert rig.cabinet.main_power is True  # individual axis POWER may now be used
    assert await c.get("CABINET.POWER_STATE") == "0.0"  # not all on yet
    assert await c.get("CABINET.POWER") == "1"
    rig.az.power_gate.set()
    lines = await c.until(1)
    assert lines[0] == "1 COMMAND OK"
    assert "1 EVENT INFO CABINET:21 main power on, switching the components on" in lines
    assert lines[-3:] == ["1 EVENT INFO CABINET:21 power on", "1 DATA OK CABINET.POWER",
                          "1 COMMAND COMPLETE"]
    # main axes first (ZD order 0, AZ order 1), then the other axes, then the modules
    assert power_journal(rig) == [("ZD", True), ("AZ", True), ("DEROTATOR[2]", True),
                                  ("FOCUS", True), ("DOME", True)]
    assert await c.get("CABINET.POWER_STATE") == "1.0"


async def test_power_on_failure_reports_the_components_number(make_rig):
    rig, c = await make_rig()
    rig.az.power_error = HardwareError("az", "enable timed out", ErrorNumber.TIMEOUT)
    lines = await c.command(1, "SET CABINET.POWER=1")
    assert "1 EVENT ERROR CABINET:7 power on stopped at AZ: az: enable timed out" in lines
    assert lines[-2:] == ["1 DATA ERROR CABINET.POWER FAILED 7", "1 COMMAND COMPLETE"]
    assert power_journal(rig) == [("ZD", True), ("AZ", True)]  # nothing after the failure
    assert await c.get("CABINET.POWER_STATE") == "0.0"
    assert rig.cabinet.main_power is True


async def test_power_off_stops_then_switches_off_in_reverse_order(make_rig):
    rig, c = await make_rig()
    assert (await c.command(1, "SET CABINET.POWER=1"))[-1] == "1 COMMAND COMPLETE"
    rig.journal.clear()
    lines = await c.command(2, "SET CABINET.POWER=0")
    assert lines == ["2 COMMAND OK", "2 EVENT INFO CABINET:21 switching power off",
                     "2 EVENT INFO CABINET:21 power off", "2 DATA OK CABINET.POWER", "2 COMMAND COMPLETE"]
    assert power_journal(rig) == [("DOME", False), ("FOCUS", False), ("DEROTATOR[2]", False),
                                  ("AZ", False), ("ZD", False)]
    assert all(m.stops == 1 for m in (*rig.axes(), rig.dome))
    assert await c.get("CABINET.POWER_STATE") == "0.0"
    assert rig.cabinet.main_power is False
    # a failing component keeps neither the others nor main power on
    assert (await c.command(3, "SET CABINET.POWER=1"))[-1] == "3 COMMAND COMPLETE"
    rig.journal.clear()
    rig.derot.power_error = HardwareError("derot", "does not disable", ErrorNumber.LIBFAIL)
    lines = await c.command(4, "SET CABINET.POWER=0")
    assert lines[-2:] == ["4 DATA ERROR CABINET.POWER FAILED 2", "4 COMMAND COMPLETE"]
    assert [n for n, _ in power_journal(rig)] == ["DOME", "FOCUS", "DEROTATOR[2]", "AZ", "ZD"]
    assert rig.cabinet.main_power is False


async def test_newer_power_supersedes_and_stop_ends_the_sequence(make_rig):
    rig, c = await make_rig()
    rig.az.power_gate.clear()
    await c.send("1 SET CABINET.POWER=1")
    await wait_for(lambda: ("AZ", True) in power_journal(rig))
    await c.send("2 SET CABINET.POWER=0")
    assert (await c.until(1))[-2:] == ["1 DATA ERROR CABINET.POWER FAILED 10", "1 COMMAND COMPLETE"]
    assert rig.az.cancelled == ["power"]
    rig.az.power_gate.set()
    assert (await c.until(2))[-2:] == ["2 DATA OK CABINET.POWER", "2 COMMAND COMPLETE"]

    rig.az.power_gate.clear()
    await c.send("3 SET CABINET.POWER=1")
    await wait_for(lambda: power_journal(rig).count(("AZ", True)) == 2)
    stops = rig.zd.stops
    assert await c.command(4, "SET CABINET.STOP=1") == [
        "4 COMMAND OK", "4 DATA OK CABINET.STOP", "4 COMMAND COMPLETE"]
    assert (await c.until(3))[-2:] == ["3 DATA ERROR CABINET.POWER FAILED 10", "3 COMMAND COMPLETE"]
    assert rig.zd.stops == stops + 1 and rig.dome.stops >= 1
    assert await c.get("CABINET.POWER_STATE") == "0.0"


async def test_abort_of_power_ends_the_sequence(make_rig):
    rig, c = await make_rig()
    rig.az.power_gate.clear()
    await c.send("1 SET CABINET.POWER=1")
    await wait_for(lambda: ("AZ", True) in power_journal(rig))
    assert (await c.command(2, "ABORT 1"))[-1] == "2 COMMAND COMPLETE"
    assert (await c.until(1))[-1] == "1 COMMAND ABORTEDBY 2"
    await wait_for(lambda: rig.az.cancelled == ["power"])
    assert ("DEROTATOR[2]", True) not in power_journal(rig)


async def test_stop_before_the_sequence_ran_still_ends_the_set(tmp_path):
    events = EventHub()
    events.bind_loop()
    journal: list = []
    axis = StandIn("AZ", journal, order=1, events=events)
    cabinet = Cabinet(load_config(None), StateStore(tmp_path), events, axes=[axis])
    pending = cabinet.set_power(1)
    cabinet.stop()  # in the same loop iteration: the sequence never started
    with pytest.raises(TcsError) as info:
        await asyncio.wait_for(pending, 10)
    assert info.value.number == ErrorNumber.TARGETCHANGE
    assert journal == [] and axis.stops == 1
    await cabinet.close()


async def test_emergency_off(make_rig):
    rig, c = await make_rig()
    assert (await c.command(1, "SET CABINET.POWER=1"))[-1] == "1 COMMAND COMPLETE"
    rig.cabinet.set_emergency_off(True, "emergency stop button pressed")
    assert await c.get("CABINET.POWER_STATE") == "-1.0"
    assert int(await c.get("CABINET.ERROR_STATE")) & 1  # PANIC
    assert rig.cabinet.main_power is False and rig.az.stops == 1
    assert (await c.command(2, "SET CABINET.POWER=1"))[-2] == "2 DATA ERROR CABINET.POWER FAILED 5"
    rig.cabinet.set_emergency_off(False)
    assert await c.get("CABINET.POWER_STATE") == "0.0"
    assert (await c.command(3, "SET CABINET.POWER=1"))[-2] == "3 DATA OK CABINET.POWER"


# ----------------------------------------------------------------------------------- REINIT


async def test_reinit_references_main_axes_first_and_returns_at_once(make_rig):
    rig, c = await make_rig()
    assert await c.get("CABINET.REFERENCED") == "0.0"
    assert (await c.command(1, "SET CABINET.REINIT=0"))[-2] == "1 DATA ERROR CABINET.REINIT FAILED 5"
    assert (await c.command(2, "SET CABINET.POWER=1"))[-1] == "2 COMMAND COMPLETE"
    rig.az.referenced = 1.0  # already referenced: REINIT=0 leaves it alone
    rig.zd.reference_gate.clear()
    lines = await c.command(3, "SET CABINET.REINIT=0")  # returns at once
    assert lines == ["3 COMMAND OK", "3 EVENT INFO CABINET:18 referencing ZD, DEROTATOR[2], FOCUS",
                     "3 DATA OK CABINET.REINIT", "3 COMMAND COMPLETE"]
    await wait_for(lambda: rig.zd.referenced == 0.5)
    assert await c.get("CABINET.REFERENCED") == "0.375"  # (0.5 + 1 + 0 + 0) / 4
    assert [n for k, n, _ in rig.journal if k == "reference"] == ["ZD"]  # the rest waits for ZD
    assert (await c.command(4, "SET CABINET.REINIT=1"))[1] == "4 DATA ERROR CABINET.REINIT BUSY"
    rig.zd.reference_gate.set()
    assert await event_line(c, "CABINET:19") == "0 EVENT INFO CABINET:19 referenced ZD, DEROTATOR[2], FOCUS"  # after REINIT ended: id 0
    assert [n for k, n, _ in rig.journal if k == "reference"] == ["ZD", "DEROTATOR[2]", "FOCUS"]
    assert await c.get("CABINET.REFERENCED") == "1.0"

    rig.journal.clear()
    assert await c.command(5, "SET CABINET.REINIT=0") == [
        "5 COMMAND OK", "5 EVENT INFO CABINET:19 all components are referenced",
        "5 DATA OK CABINET.REINIT", "5 COMMAND COMPLETE"]
    lines = await c.command(6, "SET CABINET.REINIT=1")  # force: every axis again
    assert lines[1] == "6 EVENT INFO CABINET:18 referencing ZD, AZ, DEROTATOR[2], FOCUS"
    await event_line(c, "CABINET:19")
    assert [(n, f) for k, n, f in rig.journal if k == "reference"] == [
        ("ZD", True), ("AZ", True), ("DEROTATOR[2]", True), ("FOCUS", True)]


async def test_reinit_failure_of_a_main_axis_skips_the_rest(make_rig):
    rig, c = await make_rig()
    await c.command(1, "SET CABINET.POWER=1")
    rig.zd.reference_error = HardwareError("zd", "homing error (limit switch)", ErrorNumber.LIMIT)
    await c.command(2, "SET CABINET.REINIT=1")
    assert await event_line(c, "CABINET:20") == (
        "0 EVENT ERROR CABINET:20 referencing failed: ZD: zd: homing error (limit switch); "
        "not started: AZ, DEROTATOR[2], FOCUS")
    assert [n for k, n, _ in rig.journal if k == "reference"] == ["ZD"]


async def test_reinit_failure_of_another_axis_does_not_stop_the_others(make_rig):
    rig, c = await make_rig()
    await c.command(1, "SET CABINET.POWER=1")
    rig.derot.reference_error = TcsError("derotator timed out", ErrorNumber.TIMEOUT)
    await c.command(2, "SET CABINET.REINIT=1")
    assert await event_line(c, "CABINET:20") == (
        "0 EVENT ERROR CABINET:20 referencing failed: DEROTATOR[2]: derotator timed out")
    assert rig.focus.referenced == 1.0 and rig.az.referenced == 1.0
    assert await c.get("CABINET.REFERENCED") == "0.75"


async def test_stop_ends_referencing(make_rig):
    rig, c = await make_rig()
    await c.command(1, "SET CABINET.POWER=1")
    rig.derot.reference_gate.clear()
    await c.command(2, "SET CABINET.REINIT=1")
    await wait_for(lambda: rig.derot.referenced == 0.5)
    assert (await c.command(3, "SET CABINET.STOP=1"))[-1] == "3 COMMAND COMPLETE"
    assert await event_line(c, "CABINET:20") == "0 EVENT INFO CABINET:20 referencing stopped"
    assert rig.derot.cancelled == ["reference"] and rig.focus.cancelled == []
    assert all(m.stops == 1 for m in rig.axes())
    # nothing runs any more: a new REINIT is accepted
    rig.derot.reference_gate.set()
    assert "4 DATA OK CABINET.REINIT" in await c.command(4, "SET CABINET.REINIT=0")
    assert await event_line(c, "CABINET:19") == "0 EVENT INFO CABINET:19 referenced DEROTATOR[2]"


# ----------------------------------------------------------------------------------- ERROR_STATE


async def test_error_state_is_the_or_of_all_and_zero_acknowledges(make_rig):
    rig, c = await make_rig()
    assert await c.get("CABINET.ERROR_STATE") == "0"
    rig.az.raise_condition("drive_fault", ERROR, "following error")
    assert await event_line(c, "CABINET:15") == "0 EVENT ERROR CABINET:15 AZ: following error"
    rig.dome.raise_condition("oil_low", WARNING, "oil pressure low")
    assert await c.get("CABINET.ERROR_STATE") == "6"
    assert await c.get("CABINET.STATUS.GLOBAL") == "6"
    rig.az.clear_condition("drive_fault")  # gone, but latched until acknowledged
    assert await c.get("CABINET.ERROR_STATE") == "6"
    assert (await c.command(1, "SET CABINET.ERROR_STATE=1"))[1] == "1 DATA ERROR CABINET.ERROR_STATE RANGE"
    lines = await c.command(2, "SET CABINET.ERROR_STATE=0")
    assert lines == ["2 COMMAND OK", "2 EVENT INFO AZ:15 acknowledged",
                     "2 EVENT INFO CABINET:15 acknowledged",  # once, not once per module
                     "2 DATA OK CABINET.ERROR_STATE", "2 COMMAND COMPLETE"]
    assert rig.az.error_state == 0
    assert await c.get("CABINET.ERROR_STATE") == "4"  # the dome's condition is still there
    rig.dome.clear_condition("oil_low")
    rig.cabinet.raise_condition("ups_on_battery", WARNING, "UPS on battery")  # cabinet's own
    assert await c.get("CABINET.ERROR_STATE") == "4"
    await c.command(3, "SET CABINET.ERROR_STATE=0")
    assert rig.dome.error_state == 0
    assert await c.get("CABINET.ERROR_STATE") == "4"  # UPS still on battery


# ----------------------------------------------------------------------------------- STATUS.LIST


async def test_status_list_format_counters_and_clear(make_rig):
    clock = Clock(1_700_000_000.0)
    rig, c = await make_rig(clock)
    assert await c.get("CABINET.STATUS.LIST") == '""'
    rig.az.raise_condition("drive_fault", ERROR, "following error")
    rig.az.clear_condition("drive_fault")
    clock.t += 10
    rig.az.raise_condition("drive_fault", ERROR, "following error again")
    clock.t += 10
    rig.dome.raise_condition("oil_low", WARNING, "pressure: 1,2 bar")
    clock.t += 5
    # the same condition with another cause keeps the older cause as an entry of its own
    assert await c.get("CABINET.STATUS.LIST") == (
        '"5:oil_low:4:1:1:1:DOME:pressure; 1;2 bar,15:drive_fault:2:1:1:1:AZ:following error again,'
        '25:drive_fault:2:1:1:0:AZ:following error"')
    rig.az.clear_condition("drive_fault")
    rig.az.raise_condition("drive_fault", ERROR, "following error")  # the same cause again: counted
    rig.az.clear_condition("drive_fault")
    await c.command(1, "SET CABINET.ERROR_STATE=0")  # acknowledge: Count back to 0
    assert await c.get("CABINET.STATUS.LIST") == (
        '"0:drive_fault:2:2:0:0:AZ:following error,5:oil_low:4:1:0:1:DOME:pressure; 1;2 bar,'
        '15:drive_fault:2:1:0:0:AZ:following error again"')
    assert (await c.command(2, "SET CABINET.STATUS.CLEAR=1"))[1] == "2 DATA ERROR CABINET.STATUS.CLEAR RANGE"
    assert (await c.command(3, "SET CABINET.STATUS.CLEAR=-1"))[1] == "3 DATA OK CABINET.STATUS.CLEAR"
    assert await c.get("CABINET.STATUS.LIST") == '""'
    assert await c.get("CABINET.STATUS.CLEAR") == "DENIED"  # write-only (RLEVEL -1)


async def test_clearing_the_status_list_needs_configuration_level(make_rig):
    rig, admin = await make_rig()
    rig.dome.raise_condition("oil_low", WARNING, "pressure low")
    operator = await RawClient.connect(rig.server.port, login=None)
    await operator.send('AUTH PLAIN "admin" "admin" 3 3')  # operator level: moves, no configuration
    assert await operator.readline() == "AUTH OK 3 3"
    assert await operator.command(1, "SET CABINET.STATUS.CLEAR=-1") == [
        "1 COMMAND OK", "1 DATA ERROR CABINET.STATUS.CLEAR DENIED", "1 COMMAND COMPLETE"]
    assert "oil_low" in await operator.get("CABINET.STATUS.LIST")
    assert (await admin.command(2, "SET CABINET.STATUS.CLEAR=-1"))[1] == "2 DATA OK CABINET.STATUS.CLEAR"
    await operator.close()


async def test_status_list_survives_a_restart(make_rig):
    clock = Clock(1_700_000_000.0)
    rig, c = await make_rig(clock)
    rig.zd.raise_condition("nocon", ERROR, "no heartbeat")
    clock.t += 3
    rig.cabinet.raise_condition("fan_failed", WARNING)
    clock.t += 1
    # a report from another thread (the control loop) is written by the event loop
    worker = threading.Thread(target=rig.focus.raise_condition, args=("late", 16, "late setpoint"))
    worker.start()
    worker.join()
    await wait_for(lambda: "late" in json.dumps(StateStore(rig.state_dir).get("cabinet_status")))
    await rig.close()

    clock.t += 100
    rig2, c2 = await make_rig(clock)  # a new StateStore on the same directory
    assert await c2.get("CABINET.STATUS.LIST") == (
        '"100:late:16:1:1:0:FOCUS:late setpoint,101:fan_failed:4:1:1:0:CABINET,'
        '104:nocon:2:1:1:0:ZD:no heartbeat"')  # inactive: they belonged to the previous run
    rig2.zd.raise_condition("nocon", ERROR, "no heartbeat")  # happens again after the restart
    assert await c2.get("CABINET.STATUS.LIST") == (
        '"0:nocon:2:2:2:1:ZD:no heartbeat,100:late:16:1:1:0:FOCUS:late setpoint,'
        '101:fan_failed:4:1:1:0:CABINET"')


async def test_status_list_causes_differing_only_in_a_number_are_one_entry(make_rig):
    """A cause whose text differs only in a number (a reading, a duration) is the same cause
    kind: one entry, counted, showing the newest text — the list grew to 94 entries in 40 min
    of a busy machine. Entries saved that way before are merged when loaded; codes in hex
    (0x8130, 0x8250) stay apart."""
    clock = Clock(1_700_000_000.0)
    rig, c = await make_rig(clock)
    for n, seconds in enumerate((6.6, 7.25, 12.0)):
        rig.local.raise_condition("nocon", ERROR, f"no valid sentence for {seconds} s")
        rig.local.clear_condition("nocon")
        rig.dome.raise_condition("nocon", ERROR, f"within 1 s (reading {35 + n} input at 0)")
        rig.dome.clear_condition("nocon")
        clock.t += 1
    rig.az.raise_condition("drive fault", ERROR, "drive az (node 1): heartbeat lost (0x8130)")
    rig.az.clear_condition("drive fault")
    clock.t += 1
    rig.az.raise_condition("drive fault", ERROR, "drive az (node 1): RPDO time-out (0x8250)")
    assert await c.get("CABINET.STATUS.LIST") == (
        '"0:drive fault:2:1:1:1:AZ:drive az (node 1); RPDO time-out (0x8250),'
        '1:drive fault:2:1:1:0:AZ:drive az (node 1); heartbeat lost (0x8130),'
        '2:nocon:2:3:3:0:LOCAL:no valid sentence for 12.0 s,'
        '2:nocon:2:3:3:0:DOME:within 1 s (reading 37 input at 0)"')
    # entries one per number, as older versions saved them: merged at the next start
    saved = StateStore(rig.state_dir).get("cabinet_status")
    dome = next(e for e in saved if e["device"] == "DOME")
    extra = dict(dome, comment=dome["comment"].replace("37", "99"), total=5, count=0,
                 last=dome["last"] - 50)
    StateStore(rig.state_dir).update(cabinet_status=saved + [extra])
    await rig.close()
    rig2, c2 = await make_rig(clock)
    listed = (await c2.get("CABINET.STATUS.LIST")).strip('"').split(",")
    assert len(listed) == 4
    merged = [e for e in listed if "DOME" in e]
    assert len(merged) == 1 and ":8:3:0:" in merged[0] and "reading 37" in merged[0]


def test_orphan_temporary_files_of_a_killed_write_are_removed(tmp_path):
    """A kill -9 between the temporary file and the rename leaves ``.state.json.<random>``:
    the store removes such files when it opens, and nothing else."""
    store = StateStore(tmp_path)
    store.update(a=1)
    orphan = tmp_path / ".state.json.k3_xq9ab"   # the name tempfile.mkstemp gives in _write
    orphan.write_text('{"a": 2')
    keep = [tmp_path / "state.json.corrupt-1700000000", tmp_path / ".other.json.k3_xq9ab",
            tmp_path / "notes.txt"]
    for path in keep:
        path.write_text("x")
    assert StateStore(tmp_path).get("a") == 1
    assert not orphan.exists()
    assert all(path.exists() for path in keep)


# ----------------------------------------------------------------------------------- LOG[]


async def test_log_lines_newest_first(make_rig):
    rig, c = await make_rig()
    assert await c.get("CABINET.STATUS.LOG!COUNT") == "5"
    logger = logging.getLogger("tcs.test_cabinet")
    old = logger.level
    logger.setLevel(logging.INFO)
    try:
        logger.debug("not kept")
        logger.info("first line")
        logger.error("second line\nwith a second row")
    finally:
        logger.setLevel(old)
    texts = [(await c.get(f"CABINET.STATUS.LOG[{i}].TEXT")).strip('"') for i in range(5)]
    mine = [t for t in texts if "tcs.test_cabinet" in t]
    assert len(mine) == 2
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z ERROR tcs.test_cabinet: "
                        r"second line \| with a second row", mine[0]), mine[0]
    assert mine[1].endswith(" INFO tcs.test_cabinet: first line")
    i = texts.index(mine[0])
    assert await c.get(f"CABINET.STATUS.LOG[{i}].LEVEL") == '"ERROR"'
    assert await c.get(f"CABINET.STATUS.LOG[{i}].SOURCE") == '"tcs.test_cabinet"'
    assert float(await c.get(f"CABINET.STATUS.LOG[{i}].TIME")) > 1.6e9
    logging.getLogger("other.library").error("not ours")
    assert "not ours" not in [line.message for line in rig.cabinet.log_buffer.lines()]


# ----------------------------------------------------------------------------------- the rest


async def test_setup_strings_and_common_variables(make_rig):
    rig, c = await make_rig()
    assert await c.get("CABINET.SETUP.MANUFACTURER") == '"Test Cabinets Ltd"'
    assert await c.get("CABINET.SETUP.HW_ID") == '"CAB-42"'
    assert await c.get("CABINET.SETUP.HW_VERSION") == '"3b"'
    assert await c.get("CABINET.SETUP.SW_ID") == '"tcs"'
    assert await c.get("CABINET.SETUP.SW_VERSION") == f'"{tcs.__version__}"'
    assert await c.get("CABINET.SETUP.CONFIG_VERSION") == '"7"'
    assert re.fullmatch(r'"drives-[0-9a-f]{12}"', await c.get("CABINET.SETUP.CONFIG_ID"))
    digest = hashlib.sha256(rig.config.source.read_bytes()).hexdigest()[:16]
    assert await c.get("CABINET.SETUP.PARAM_ID") == f'"{digest}"'
    assert await c.get("CABINET.SETUP.PARAM_NAME") == '"cabinet.toml"'
    assert re.fullmatch(r'"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ"', await c.get("CABINET.SETUP.PARAM_VERSION"))
    text = await c.get("CABINET.SETUP.VERSION_TEXT")
    assert text.startswith(f'"tcs {tcs.__version__}; Python ')
    assert "; drive az node 5 0x0000029A:0x00000402:rev 0x00010001" in text
    assert int(await c.get("CABINET.VERSION")) >> 16 == 24
    assert await c.get("CABINET.TYPE") == "7"
    assert await c.get("CABINET.MODE") == "1"
    assert ",".join(await c.members("CABINET")) == (
        "VERSION,TYPE,ERROR_STATE,POWER,POWER_STATE,REFERENCED,REINIT,MODE,MANUAL_CONTROL,"
        "SETUP,STATUS,STOP,CORE")


async def test_manual_control(make_rig):
    rig, c = await make_rig()
    assert await c.get("CABINET.MANUAL_CONTROL.MODE") == "0"
    assert await c.get("CABINET.MANUAL_CONTROL.SELECTION") == "0"
    assert await c.command(1, "SET CABINET.MANUAL_CONTROL.ACTIVE=1") == [
        "1 COMMAND OK", "1 EVENT INFO CABINET:16 manual control enabled",
        "1 DATA OK CABINET.MANUAL_CONTROL.ACTIVE", "1 COMMAND COMPLETE"]
    assert await c.get("CABINET.MANUAL_CONTROL.ACTIVE") == "1"
    assert (await c.command(2, "SET CABINET.MANUAL_CONTROL.ACTIVE=0"))[1] == (
        "2 EVENT INFO CABINET:16 manual control disabled")
    assert (await c.command(3, "SET CABINET.MANUAL_CONTROL.BRIGHTNESS=2"))[1] == (
        "3 DATA ERROR CABINET.MANUAL_CONTROL.BRIGHTNESS RANGE")
    await c.command(4, "SET CABINET.MANUAL_CONTROL.BRIGHTNESS=0.25")
    assert await c.get("CABINET.MANUAL_CONTROL.BRIGHTNESS") == "0.25"
    assert StateStore(rig.state_dir).get("cabinet_manual_control") == {"brightness": 0.25}


async def test_core_drive_and_cycle_diagnostics(make_rig):
    rig, c = await make_rig()
    assert await c.get("CABINET.CORE.DRIVE!COUNT") == "4"  # one per axis, in the axes' order
    assert await c.get("CABINET.CORE.DRIVE[0].AXIS") == '"AZ"'
    assert await c.get("CABINET.CORE.DRIVE[0].NAME") == '"az"'
    assert await c.get("CABINET.CORE.DRIVE[0].STATE") == '"fault"'
    assert await c.get("CABINET.CORE.DRIVE[0].STATUSWORD") == "8"
    assert await c.get("CABINET.CORE.DRIVE[0].ERRORCODE") == str(0x8611)
    assert "following error (error code 0x8611)" in await c.get("CABINET.CORE.DRIVE[0].ERRORTEXT")
    assert await c.get("CABINET.CORE.DRIVE[0].POSITION") == "12.5"
    assert await c.get("CABINET.CORE.DRIVE[0].VELOCITY") == "-0.25"
    assert await c.get("CABINET.CORE.DRIVE[0].FOLLOWING_ERROR") == "0.01"
    assert await c.get("CABINET.CORE.DRIVE[0].HEARTBEAT") == "1"
    assert await c.get("CABINET.CORE.DRIVE[1].AXIS") == '"ZD"'
    assert await c.get("CABINET.CORE.DRIVE[1].STATE") == '"none"'  # no drive behind it
    assert await c.get("CABINET.CORE.DRIVE[1].ERRORCODE") == "0"

    assert await c.get("CABINET.CORE.CYCLE.CYCLES") == "0"  # no control loop yet
    assert await c.get("CABINET.CORE.CYCLE.SYNC_INTERVAL") == "0.0"
    rig.cabinet.loop_stats = lambda: {"cycles": 1200, "late": 2, "missed": 1, "max_lateness": 0.0015,
                                      "period": 0.01, "sync_divider": 5}
    state_epoch.bump()  # as the loop's readbacks do (a GET reply just made is not reused)
    assert await c.get("CABINET.CORE.CYCLE.CYCLES") == "1200"
    assert await c.get("CABINET.CORE.CYCLE.LATE") == "2"
    assert await c.get("CABINET.CORE.CYCLE.MISSED") == "1"
    assert await c.get("CABINET.CORE.CYCLE.TPDO_TIMEOUTS") == "0"
    assert await c.get("CABINET.CORE.CYCLE.MAX_LATENESS") == "0.0015"
    assert await c.get("CABINET.CORE.CYCLE.SYNC_INTERVAL") == "0.05"  # the idle SYNC

    def broken():
        raise RuntimeError("loop gone")

    rig.cabinet.loop_stats = broken
    state_epoch.bump()
    assert await c.get("CABINET.CORE.CYCLE.CYCLES") == "0"


async def test_cabinet_without_axes(tmp_path):
    events = EventHub()
    cabinet = Cabinet(load_config(None), StateStore(tmp_path), events)
    assert cabinet.referenced == 1.0
    assert cabinet.core_drives() == []
    assert cabinet.power_order() == []
    assert cabinet.error_state == 0
    await cabinet.close()
