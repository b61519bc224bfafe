"""The server's command lifecycle with long-running SETs, over a real socket.

The tree here is a small one declared in the test around a test-owned domain object (a
"motor" whose moves finish when the test says so), so every outcome of a long SET — done,
failed, superseded, aborted, server shutdown — can be produced on demand. The server, the
protocol core and the tree engine are the real ones.
"""

from __future__ import annotations

import asyncio

import pytest

from support.tpl2 import RawClient
from tcs.config.passwords import hash_password
from tcs.config.sections import ServerSection, UserSection
from tcs.errors import ErrorNumber, HardwareError, TcsError
from tcs.model.events import EventHub
from tcs.opentci_server.server import Tpl2Server
from tcs.opentci_server.opentci import SERVER
from tcs.opentci_server.tree import FLOAT, INT, Tree, module, var


class Motor:
    """A test-owned domain object with a long-running TARGETPOS."""

    def __init__(self, events: EventHub):
        self.events = events
        self.target = 0.0
        self.position = 0.0
        self.pending: asyncio.Future | None = None
        self.cancelled = 0
        self.holds: list[asyncio.Future] = []

    def set_target(self, value: float):
        if self.pending is not None and not self.pending.done():
            self.pending.set_exception(TcsError("target changed", ErrorNumber.TARGETCHANGE))
            self.events.emit("ERROR", "MOTOR", ErrorNumber.TARGETCHANGE, "target changed")
        self.target = value
        self.events.emit("INFO", "MOTOR", ErrorNumber.MOTIONCHANGE, "moving")
        self.pending = asyncio.get_running_loop().create_future()
        self.pending.add_done_callback(self._count_cancel)
        return self.pending

    def _count_cancel(self, fut):
        self.cancelled += fut.cancelled()

    def arrive(self) -> None:
        self.position = self.target
        self.pending.set_result(None)

    def fail(self) -> None:
        self.pending.set_exception(HardwareError("motor", "limit switch", ErrorNumber.LIMIT))

    def hold(self, value: int):
        fut = asyncio.get_running_loop().create_future()
        self.holds.append(fut)
        return fut

    def set_stop(self, value: int) -> None:
        if self.pending is not None and not self.pending.done():
            self.pending.set_exception(TcsError("stopped", ErrorNumber.TARGETCHANGE))


TREE = (SERVER, module("MOTOR",
               var("TARGETPOS", FLOAT, get="target", set="set_target", min=-10.0, max=10.0, long=True),
               var("REALPOS", FLOAT, get="position"),
               var("HOLD", INT, get=lambda m: len(m.holds), set="hold", long=True),
               var("STOP", INT, get=lambda m: 0, set="set_stop", min=0, max=1),
               bind=lambda root: root),)


@pytest.fixture
async def motor_server():
    hub = EventHub()
    hub.bind_loop()
    motor = Motor(hub)
    settings = ServerSection(port=0, max_in_flight=3, auth_fail_delay=0.01, abort_timeout=1.0)
    users = (UserSection("admin", hash_password("admin", iterations=1000), 0, 0),)
    server = Tpl2Server(settings, users, hub)
    motor.server = server
    server.tree = Tree.build(TREE, motor)
    port = await server.start("127.0.0.1", 0)
    try:
        yield motor, port, server
    finally:
        await server.stop()


async def wait_for(predicate, timeout=5.0):
    deadline = asyncio.get_running_loop().time() + timeout
    while not predicate():
        assert asyncio.get_running_loop().time() < deadline, "condition not reached"
        await asyncio.sleep(0.005)


async def test_long_set_completes_only_when_done_and_gets_answer_meanwhile(motor_server):
    motor, port, _ = motor_server
    c = await RawClient.connect(port)
    await c.send("1 SET MOTOR.TARGETPOS=5")
    assert await c.readline() == "1 COMMAND OK"
    assert await c.readline() == "1 EVENT INFO MOTOR:23 moving"  # caused by command 1
    assert await c.command(2, "GET MOTOR.REALPOS") == [
        "2 COMMAND OK", "2 DATA INLINE MOTOR.REALPOS=0.0", "2 COMMAND COMPLETE"]
    motor.arrive()
    assert await c.until(1) == ["1 DATA OK MOTOR.TARGETPOS", "1 COMMAND COMPLETE"]
    await c.close()


async def test_newer_target_supersedes(motor_server):
    motor, port, _ = motor_server
    c = await RawClient.connect(port)
    await c.send("1 SET MOTOR.TARGETPOS=5")
    await c.send("2 SET MOTOR.TARGETPOS=6")
    assert await c.until(1) == ["1 COMMAND OK", "1 EVENT INFO MOTOR:23 moving",
                                "1 DATA ERROR MOTOR.TARGETPOS FAILED 10", "1 COMMAND COMPLETE"]
    motor.arrive()
    lines = await c.until(2)
    assert "2 EVENT ERROR MOTOR:10 target changed" in lines
    assert lines[-2:] == ["2 DATA OK MOTOR.TARGETPOS", "2 COMMAND COMPLETE"]
    await c.close()


async def test_hardware_failure_ends_with_its_number(motor_server):
    motor, port, _ = motor_server
    c = await RawClient.connect(port)
    await c.send("1 SET MOTOR.TARGETPOS=5")
    await wait_for(lambda: motor.pending is not None)
    motor.fail()
    assert (await c.until(1))[-2:] == ["1 DATA ERROR MOTOR.TARGETPOS FAILED 8", "1 COMMAND COMPLETE"]
    await c.close()


async def test_range_refused_before_anything_happens(motor_server):
    motor, port, _ = motor_server
    c = await RawClient.connect(port)
    assert await c.command(1, "SET MOTOR.TARGETPOS=400") == [
        "1 COMMAND OK", "1 DATA ERROR MOTOR.TARGETPOS RANGE", "1 COMMAND COMPLETE"]
    assert motor.pending is None
    await c.close()


async def test_idbusy_and_reuse_after_final_line(motor_server):
    motor, port, _ = motor_server
    c = await RawClient.connect(port)
    await c.send("4 SET MOTOR.TARGETPOS=1")
    await wait_for(lambda: motor.pending is not None)
    await c.send("4 GET MOTOR.REALPOS")
    assert await c.readline() in ("4 COMMAND OK", "4 EVENT INFO MOTOR:23 moving")
    while (line := await c.readline()) != "0 COMMAND ERROR IDBUSY 4":
        pass
    assert await c.readline() == "0 COMMAND FAILED"  # the refused line's final line
    motor.arrive()
    assert (await c.until(4))[-1] == "4 COMMAND COMPLETE"
    assert (await c.command(4, "GET MOTOR.REALPOS"))[1] == "4 DATA INLINE MOTOR.REALPOS=1.0"
    await c.close()


async def test_abort_one_and_all(motor_server):
    motor, port, _ = motor_server
    c = await RawClient.connect(port)
    await c.send("5 SET MOTOR.TARGETPOS=1")
    await wait_for(lambda: motor.pending is not None)
    await c.send("6 ABORT 5")
    assert (await c.until(5))[-1] == "5 COMMAND ABORTEDBY 6"
    assert await c.until(6) == ["6 COMMAND OK", "6 COMMAND COMPLETE"]
    assert motor.cancelled == 1  # the wait ended
    c.lines.clear()
    await c.send("7 SET MOTOR.TARGETPOS=2")
    await wait_for(lambda: motor.target == 2.0)
    await c.send("8 ABORT 0")
    assert (await c.until(7))[-1] == "7 COMMAND ABORTEDBY 8"
    assert (await c.until(8))[-1] == "8 COMMAND COMPLETE"
    await c.close()


async def test_too_many_in_flight(motor_server):
    motor, port, server = motor_server
    c = await RawClient.connect(port)
    for i in (1, 2, 3):  # max_in_flight = 3
        await c.send(f"{i} SET MOTOR.HOLD=1")
        assert await c.readline() == f"{i} COMMAND OK"
    await c.send("4 SET MOTOR.HOLD=1")
    assert await c.until(4) == ["4 COMMAND ERROR TOOMANY", "4 COMMAND FAILED"]
    assert (await c.command(5, "GET MOTOR.REALPOS")) == ["5 COMMAND ERROR TOOMANY", "5 COMMAND FAILED"]
    for fut in motor.holds:
        fut.set_result(None)
    for i in (1, 2, 3):
        assert (await c.until(i))[-2:] == [f"{i} DATA OK MOTOR.HOLD", f"{i} COMMAND COMPLETE"]
    assert (await c.command(6, "GET MOTOR.REALPOS"))[0] == "6 COMMAND OK"
    await c.close()


async def test_events_ids_across_connections_and_mask(motor_server):
    motor, port, server = motor_server
    a = await RawClient.connect(port)
    b = await RawClient.connect(port)
    quiet = await RawClient.connect(port)
    await a.send("9 SET MOTOR.TARGETPOS=2")
    assert await a.readline() == "9 COMMAND OK"
    assert await a.readline() == "9 EVENT INFO MOTOR:23 moving"
    conn_a = max(server.sessions) - 2
    assert await b.readline() == f"{(conn_a << 32) | 9} EVENT INFO MOTOR:23 moving"
    server.events.emit("WARN", "MOTOR", 1000, "unsolicited")
    assert await b.readline() == "0 EVENT WARN MOTOR:1000 unsolicited"
    motor.arrive()
    assert (await a.until(9))[-1] == "9 COMMAND COMPLETE"
    for c in (a, b, quiet):
        await c.close()


async def test_event_mask_filters(motor_server):
    motor, port, server = motor_server
    c = await RawClient.connect(port)
    await c.command(1, "SET SERVER.CONNECTION.EVENTMASK=1")  # errors only
    server.events.emit("INFO", "MOTOR", 23, "filtered")
    server.events.emit("ERROR", "MOTOR", 8, "limit")
    assert await c.readline() == "0 EVENT ERROR MOTOR:8 limit"
    await c.close()


async def test_no_events_before_login(motor_server):
    motor, port, server = motor_server
    c = await RawClient.connect(port, login=None)
    server.events.emit("ERROR", "MOTOR", 8, "limit")
    await c.send('AUTH PLAIN "admin" "admin"')
    assert await c.readline() == "AUTH OK 0 0"
    await c.close()


async def test_disconnect_without_abort_lets_the_action_finish(motor_server):
    motor, port, server = motor_server
    c = await RawClient.connect(port)
    await c.send("1 SET MOTOR.TARGETPOS=3")
    await wait_for(lambda: motor.target == 3.0)
    await c.send("DISCONNECT")
    while await c.readline() != "DISCONNECT OK":
        pass
    await c.close()
    await asyncio.sleep(0.05)
    assert motor.cancelled == 0 and not motor.pending.done()
    motor.arrive()  # its lines go nowhere; nothing breaks
    other = await RawClient.connect(port)
    assert await other.get("MOTOR.REALPOS") == "3.0"
    await other.close()


async def test_disconnect_with_abort_on_disconnect(motor_server):
    motor, port, server = motor_server
    c = await RawClient.connect(port)
    await c.command(1, "SET SERVER.CONNECTION.ABORT_ON_DISCONNECT=1")
    await c.send("2 SET MOTOR.TARGETPOS=3")
    await wait_for(lambda: motor.target == 3.0)
    await c.close()  # EOF counts as DISCONNECT
    await wait_for(lambda: motor.pending.cancelled())


async def test_shutdown_fails_pending_commands(motor_server):
    motor, port, server = motor_server
    c = await RawClient.connect(port)
    await c.send("3 SET MOTOR.TARGETPOS=3")
    await wait_for(lambda: motor.target == 3.0)
    await server.stop()
    assert (await c.until(3))[-1] == "3 COMMAND FAILED"
    assert await c.reader.read() == b""
    await c.close()
