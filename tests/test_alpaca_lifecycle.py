"""The Alpaca life cycle of a fresh service, driven by alpyca over real HTTP (issue 26).

One service (module scope) runs ``tests/hw_alpaca.toml`` cold, as ``tcs-server`` starts: no
power, nothing referenced. The first test sees it as a client application does on a first
night — a parked telescope that ``Unpark`` makes ready in the background, equipment whose
``Connect`` readies its own axis — so it must run first in this file (it checks the cold state
before it changes it). The others make the telescope ready themselves.
"""

from __future__ import annotations

import asyncio
import functools
import time
from pathlib import Path

import pytest

alpaca = pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
from alpaca.exceptions import DriverException, InvalidOperationException, ParkedException  # noqa: E402
from alpaca.telescope import Telescope  # noqa: E402

from support.live import live_service  # noqa: E402
from support.waits import alpaca_address as address, until as wait_until  # noqa: E402

HW = Path(__file__).with_name("hw_alpaca.toml")
WAIT = 90.0
until = functools.partial(wait_until, timeout=WAIT)

live = live_service(HW)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


def make_ready(live, t: Telescope) -> None:
    """Unpark and wait until ready (a failure an earlier test left for the next completion read
    is read and passed over here: this test did not start that operation)."""
    def parked() -> bool:
        try:
            return t.AtPark
        except DriverException:
            return True
    parked()
    t.Action("AcknowledgeFaults", "")   # (a drive fault of a loaded machine: as an operator would)
    t.Unpark()
    until(lambda: not t.AtPark, "unparked and ready")
    assert live.telescope.operations.ready_state == 1.0


def test_cold_start_life_cycle(live):
    """Fresh service: the telescope is AtPark (cold) and refuses moves as parked. Connecting a
    focuser, filter wheel or rotator powers its own axis (Connecting meanwhile) and moves
    nothing else: the wheel references at once (Position −1 meanwhile), the focuser and the
    rotator on their first move (IsMoving True from the reply on). Unpark is an asynchronous
    initiator: it returns before the telescope is ready; Slewing and AtPark stay True until it is."""
    from alpaca.filterwheel import FilterWheel
    from alpaca.focuser import Focuser
    from alpaca.rotator import Rotator

    ops = live.telescope.operations
    az, zd, focus = (live.telescope.axis(n) for n in ("AZ", "ZD", "FOCUS"))
    wheel_axis = next(w for w in live.telescope.axis_array("FILTER") if w is not None)
    rot_axis = next(d for d in live.telescope.axis_array("DEROTATOR") if d is not None)
    assert focus.power_state != 1.0 and az.referenced < 1.0   # really cold

    t = Telescope(address(live), 0)
    t.Connect()
    assert t.Connected and not t.Connecting      # nothing to power for the telescope itself
    assert t.AtPark                               # cold: clients unpark a parked mount
    assert [x.lower() for x in t.SupportedActions] == ["acknowledgefaults"]
    t.Tracking = False
    with pytest.raises(ParkedException):
        t.Tracking = True

    focuser, wheel, rotator = Focuser(address(live), 0), FilterWheel(address(live), 0), Rotator(address(live), 0)
    for device in (focuser, wheel, rotator):
        device.Connect()
        until(lambda d=device: not d.Connecting, f"{type(device).__name__} connected")
        assert device.Connected
    assert focus.power_state == 1.0 and rot_axis.power_state == 1.0 and wheel_axis.power_state == 1.0
    assert not focuser.IsMoving and not rotator.IsMoving   # standing still after Connect

    focuser.Move(4321)                   # halted while it references: it does not go on to move
    # (the referencing runs to its end, IsMoving True until then; then it stands still)
    assert focuser.IsMoving
    focuser.Halt()
    until(lambda: not focuser.IsMoving, "the focuser halted")
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        assert focuser.Position != 4321 and not focuser.IsMoving
        time.sleep(0.1)

    focuser.Move(4321)                   # references first, then moves: IsMoving all along
    assert focuser.IsMoving
    until(lambda: not focuser.IsMoving, "the focus move to end")
    assert focuser.Position == 4321 and focus.referenced >= 1.0

    rotator.MoveAbsolute(33.0)
    assert rotator.IsMoving
    until(lambda: not rotator.IsMoving, "the rotator move to end")
    assert abs(rotator.Position - 33.0) < 0.01 and rot_axis.referenced >= 1.0

    until(lambda: wheel.Position != -1, "the wheel referenced")
    wheel.Position = 2
    assert wheel.Position in (-1, 2)
    until(lambda: wheel.Position == 2, "filter slot 2")

    assert az.referenced < 1.0 and zd.referenced < 1.0 and t.AtPark   # the mount was left alone

    t.Unpark()
    assert ops.ready_state != 1.0        # returned before the referencing ended
    assert t.Slewing and t.AtPark        # completion: Slewing False, AtPark False once ready
    until(lambda: not t.Slewing, "unparked")
    assert not t.AtPark
    assert ops.ready_state == 1.0 and az.referenced >= 1.0 and zd.referenced >= 1.0
    for device in (focuser, wheel, rotator, t):
        device.Disconnect()


def test_a_slew_ended_by_a_fault_is_reported_and_unpark_makes_ready(live):
    """A drive fault ends a slew: the next Slewing read answers the failure (DriverError 0x500)
    instead of a silent False. Unpark does not acknowledge the drive fault behind the operator's
    back: it is refused (InvalidOperation naming the fault and how to acknowledge it) and the
    fault stays latched; after Action("AcknowledgeFaults") it makes the telescope ready."""
    t = Telescope(address(live), 0)
    t.Connect()
    make_ready(live, t)
    t.Tracking = True
    until(lambda: not t.Slewing, "tracking where it stands")
    zd_sim = live.telescope.sims[2]
    pointing = live.telescope.pointing

    def fault_mid_slew() -> bool:
        """On the service's loop, in one step: the fault goes in only while the slew is still far
        from its target (a loaded host may otherwise let a 1-2 s slew arrive first)."""
        if not (pointing.track and pointing.targetdistance > 5.0):
            return False
        zd_sim.inject_fault("overcurrent")
        return True

    for hour_angle in (3.0, -3.0, 3.0, -3.0, 3.0, -3.0):
        t.SlewToCoordinatesAsync((t.SiderealTime - hour_angle) % 24.0, -15.0)
        assert t.Slewing
        if asyncio.run(live.call(fault_mid_slew)):
            break
        until(lambda: not t.Slewing, "the slew (arrived before the fault) to end")
    else:
        pytest.skip("every slew arrived before the fault could be put in (a very loaded host)")

    failures = []

    def ended() -> bool:
        try:
            return not t.Slewing
        except DriverException as exc:
            failures.append(str(exc))
            return True
    until(ended, "the slew to end")
    assert failures, "the slew ended by a fault read as finished"
    assert "slew failed" in failures[0]
    assert not t.Tracking
    until(lambda: live.telescope.cabinet.error_state & 2, "the fault latched")

    with pytest.raises(InvalidOperationException) as refused:
        t.Unpark()                       # the make-ready does not hide the fault
    assert "drive fault" in str(refused.value) and "AcknowledgeFaults" in str(refused.value), refused.value
    assert live.telescope.cabinet.error_state & 2 and t.AtPark
    assert t.Action("AcknowledgeFaults", "") == "acknowledged"   # the operator saw it
    t.Unpark()                           # the operator's "make ready"
    until(lambda: not t.AtPark, "ready again after the fault")
    assert live.telescope.operations.ready_state == 1.0
    assert not live.telescope.cabinet.error_state & 3
    t.Disconnect()


def test_acknowledge_faults_action(live):
    """Action("AcknowledgeFaults") acknowledges a latched fault without powering anything."""
    t = Telescope(address(live), 0)
    t.Connect()
    make_ready(live, t)
    asyncio.run(live.call(live.telescope.sims[7].inject_fault, "overcurrent"))   # the M3 drive
    until(lambda: live.telescope.cabinet.error_state & 2, "the fault latched")
    assert t.Action("AcknowledgeFaults", "") == "acknowledged"
    until(lambda: not live.telescope.cabinet.error_state & 3, "the fault acknowledged")
    with pytest.raises(Exception, match="not supported"):
        t.Action("NoSuchAction", "")
    t.Unpark()
    until(lambda: not t.AtPark, "ready again")
    t.Disconnect()


def test_a_failure_is_read_even_before_the_operations_callback_ran():
    """An operation that ended with an error is failed for a completion read served between the
    task's end and its done-callback (the event loop runs them in turn): never a read that finds
    it neither running nor failed — a slew ended by a fault once read as arrived that way."""
    from tcs.alpaca.device import Device
    from tcs.alpaca.protocol import AscomError
    from tcs.errors import TcsError

    async def scenario() -> str:
        device = Device(0, "t", "t", None)

        async def slew() -> None:
            raise TcsError("ZD: cannot run a trajectory: drive fault")

        device.start_operation("slew", slew(), "the slew")
        while device.running("slew"):
            await asyncio.sleep(0)   # (wakes right after the task's end, before its callback)
        try:
            device.report_failure()
        except AscomError as exc:
            return str(exc)
        return ""

    assert "the slew failed: ZD: cannot run a trajectory" in asyncio.run(scenario())
