"""The Alpaca life cycle of a fresh service, driven by alpyca over real HTTP (issue 26).

One service (module scope) runs ``tests/hw_alpaca.toml`` cold, as ``tcs-server`` starts: no
power, nothing referenced. The first test sees it as a client application does on a first
night — a parked telescope that ``Unpark`` makes ready in the background, equipment whose
``Connect`` readies its own axis — so it must run first in this file (it checks the cold state
before it changes it). The others make the telescope ready themselves.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest

alpaca = pytest.importorskip("alpaca", reason="alpyca (the 'dev' extra) is not installed")
from alpaca.exceptions import DriverException, ParkedException  # noqa: E402
from alpaca.telescope import Telescope  # noqa: E402

from support.live import live_service  # noqa: E402

HW = Path(__file__).with_name("hw_alpaca.toml")
WAIT = 90.0

live = live_service(HW)


@pytest.fixture(autouse=True)
def _no_leaked_threads():  # the module's service thread is expected; LiveService.stop checks
    yield


def address(live) -> str:
    return f"127.0.0.1:{live.service.alpaca_port}"


def until(condition, what: str, timeout: float = WAIT, period: float = 0.05):
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(period)


def make_ready(live, t: Telescope) -> None:
    t.Unpark()
    until(lambda: not t.AtPark, "unparked and ready")
    assert live.telescope.operations.ready_state == 1.0


def test_cold_start_life_cycle(live):
    """Fresh service: the telescope is AtPark (cold) and refuses moves as parked; a focuser's
    Connect powers and references its own axis only (Connecting meanwhile) and then moves;
    Unpark is an asynchronous initiator: it returns before the telescope is ready, AtPark stays
    True until it is."""
    from alpaca.focuser import Focuser

    ops = live.telescope.operations
    az, zd, focus = (live.telescope.axis(n) for n in ("AZ", "ZD", "FOCUS"))
    assert focus.power_state != 1.0 and az.referenced < 1.0   # really cold

    t = Telescope(address(live), 0)
    t.Connect()
    assert t.Connected and not t.Connecting      # nothing to power for the telescope itself
    assert t.AtPark                               # cold: clients unpark a parked mount
    assert [x.lower() for x in t.SupportedActions] == ["acknowledgefaults"]
    t.Tracking = False
    with pytest.raises(ParkedException):
        t.Tracking = True

    focuser = Focuser(address(live), 0)
    focuser.Connect()
    until(lambda: not focuser.Connecting, "the focuser connected")
    assert focuser.Connected
    assert focus.power_state == 1.0 and focus.referenced >= 1.0
    focuser.Move(4321)
    assert focuser.IsMoving
    until(lambda: not focuser.IsMoving, "the focus move to end")
    assert focuser.Position == 4321
    assert az.referenced < 1.0 and zd.referenced < 1.0 and t.AtPark   # the mount was left alone

    t.Unpark()
    assert ops.ready_state != 1.0        # returned before the referencing ended
    assert t.AtPark                      # completion: AtPark False once ready
    until(lambda: not t.AtPark, "unparked and ready")
    assert ops.ready_state == 1.0 and az.referenced >= 1.0 and zd.referenced >= 1.0
    t.Tracking = True
    t.Tracking = False
    for device in (focuser, t):
        device.Disconnect()


def test_a_slew_ended_by_a_fault_is_reported_and_unpark_makes_ready(live):
    """A drive fault ends a slew: the next Slewing read answers the failure (DriverError 0x500)
    instead of a silent False; Unpark acknowledges the fault and makes the telescope ready."""
    t = Telescope(address(live), 0)
    t.Connect()
    make_ready(live, t)
    t.Tracking = True
    until(lambda: not t.Slewing, "tracking where it stands")
    t.SlewToCoordinatesAsync((t.SiderealTime - 3.0) % 24.0, -15.0)
    assert t.Slewing
    zd_sim = live.telescope.sims[2]
    asyncio.run(live.call(zd_sim.inject_fault, "overcurrent"))

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
