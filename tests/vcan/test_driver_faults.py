"""Every fault path of the driver against simulated drives: each ends in a clear, numbered error."""

from __future__ import annotations

import can
import pytest
from cia402_rig import AxisSpec, Rig

from tcs.drivers.canbus import CAN_ERR_BUSOFF
from tcs.drivers.drive import DriveState
from tcs.errors import ErrorNumber, TcsError
from tcs.sim.cia402_drive import SimDriveParams


def wait_cycles(rig: Rig, n: int) -> None:
    start = rig.system.cycle.stats().cycles
    rig.wait(lambda: rig.system.cycle.stats().cycles >= start + n, what=f"{n} cycles")


def test_following_error_then_reset_ends_disabled_and_stays_there(can_channel):
    with Rig(can_channel, {"az": AxisSpec(1), "alt": AxisSpec(2)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az", "alt")
        base = rig.status("az").position
        # A real following error: a setpoint jump the motor cannot follow (5 units/s max).
        rig.cycle_hooks.append(lambda cycle: rig.drive("az").set_setpoint(base + 20.0))
        status = rig.wait_state("az", DriveState.FAULT)
        rig.cycle_hooks.clear()
        assert status.fault.code == 0x8611 and status.fault.number == ErrorNumber.LIBFAIL
        assert str(status.fault) == "drive az (node 1): following error (error code 0x8611)"
        assert rig.status("alt").state is DriveState.OPERATION_ENABLED  # the other is unaffected
        with pytest.raises(TcsError, match="cannot enable: drive az .*following error"):
            rig.drive("az").enable()
        rig.drive("az").fault_reset()
        rig.wait_state("az", DriveState.SWITCH_ON_DISABLED)
        wait_cycles(rig, 30)  # never re-enabled by itself
        status = rig.status("az")
        assert status.state is DriveState.SWITCH_ON_DISABLED and status.fault is None
        assert status.controlword == 0x0000
        rig.enable("az")  # only an explicit request enables again


def test_injected_following_error_fault(can_channel):
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        rig.sims["az"].inject_fault("following_error")
        status = rig.wait_state("az", DriveState.FAULT)
        assert status.fault.code == 0x8611


def test_limit_switch_is_a_limit_error(can_channel):
    params = SimDriveParams(positive_limit_switch=0.3)
    with Rig(can_channel, {"az": AxisSpec(1, params=params)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        target = {"x": rig.status("az").position}

        def creep(cycle):  # 0.5 units/s toward the switch
            target["x"] += 0.5 * rig.can.sync_period
            rig.drive("az").set_setpoint(target["x"])

        rig.cycle_hooks.append(creep)
        try:
            status = rig.wait_state("az", DriveState.FAULT)
        except AssertionError as exc:
            sim = rig.sims["az"]
            raise AssertionError(f"{exc}; creep target {target['x']}, drive at {rig.status('az').position}, "
                                 f"simulated motor at {sim.logic.axis.x}") from None
        rig.cycle_hooks.clear()
        assert status.fault.number == ErrorNumber.LIMIT and status.fault.code == 0x8612
        assert "position limit" in str(status.fault)
        rig.wait(lambda: rig.status("az").limit_positive, what="limit input")
        assert not rig.status("az").limit_negative


def test_tcs_heartbeat_stops_then_the_drive_faults(can_channel):
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        rig.system.bus.stop_heartbeat()
        rig.wait(lambda: rig.status("az").fault is not None, what="drive noticed")
        status = rig.status("az")
        assert status.fault.number == ErrorNumber.NOCON
        assert "heartbeat of the TCS lost" in str(status.fault) and "0x8130" in str(status.fault)
        assert rig.sims["az"].state in ("FAULT", "FAULT REACTION ACTIVE")


def test_drive_heartbeat_stops_reported_after_the_tolerance(can_channel):
    with Rig(can_channel, {"az": AxisSpec(1), "alt": AxisSpec(2)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az", "alt")
        # lost = silent for can.heartbeat_tolerance periods (jitter below that is no loss)
        period = rig.sections["az"].heartbeat_period * rig.can.heartbeat_tolerance
        rig.sims["az"].set_responding(False)
        seen = []

        def lost():
            status = rig.status("az")
            seen.append(status)
            return not status.heartbeat_ok

        rig.wait(lost, what="heartbeat loss reported")
        # The rule, whatever the machine's speed: silent for more than the tolerance is never
        # reported as alive, and "lost" is never said before it.
        for status in seen:
            assert status.heartbeat_ok or status.heartbeat_age > period
            assert not status.heartbeat_ok or status.heartbeat_age <= period
        status = rig.status("az")
        assert status.state is DriveState.OFFLINE and status.fault.number == ErrorNumber.NOCON
        assert str(status.fault).startswith("drive az (node 1): no heartbeat for")
        assert rig.status("alt").state is DriveState.OPERATION_ENABLED


@pytest.mark.parametrize("kind, code, number, text", [
    ("overcurrent", 0x2310, ErrorNumber.LIBFAIL, "over-current"),
    ("encoder", 0x7305, ErrorNumber.LIBFAIL, "incremental encoder fault"),
    ("position_limit", 0x8612, ErrorNumber.LIMIT, "position limit reached"),
    (0x3210, 0x3210, ErrorNumber.LIBFAIL, "DC-link over-voltage"),
    (0x4321, 0x4321, ErrorNumber.LIBFAIL, "temperature error"),
    (0x8120, 0x8120, ErrorNumber.CONFAIL, "CAN error passive"),
])
def test_emcy_decoded_into_a_numbered_error(can_channel, kind, code, number, text):
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        rig.sims["az"].inject_fault(kind)
        status = rig.wait_state("az", DriveState.FAULT)
        assert status.fault.code == code and status.fault.number == number
        assert str(status.fault) == f"drive az (node 1): {text} (error code 0x{code:04X})"
        rig.drive("az").fault_reset()
        rig.wait_state("az", DriveState.SWITCH_ON_DISABLED)
        assert rig.status("az").fault is None


def test_a_fault_reset_during_the_fault_reaction_takes_effect_when_it_ends(can_channel):
    """ERROR_STATE=0 as soon as a drive faulted while moving: the drive brakes first (fault
    reaction, 0x605E = 1: a 2 s ramp here, longer than the reset's 1 s time-out), ignoring a
    reset meanwhile, and resets on a rising edge of bit 7 once in Fault. Before, the master
    raised bit 7 during the reaction and held it, so there was no edge in Fault, and the reset
    failed ("fault reset did not clear the fault") — every acknowledgement of a fault at speed."""
    section = dict(max_acceleration=1.0, max_velocity=4.0)
    with Rig(can_channel, {"az": AxisSpec(1, section=section)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        drive = rig.drive("az")
        state = {"x": rig.status("az").position, "v": 0.0}

        def ramp(cycle):  # up to 2 units/s at 1 unit/s², well inside the drive's limits
            dt = rig.can.sync_period
            state["v"] = min(2.0, state["v"] + 1.0 * dt)
            state["x"] += state["v"] * dt
            drive.set_setpoint(state["x"])
        rig.cycle_hooks.append(ramp)
        rig.wait(lambda: state["v"] >= 2.0 and abs(rig.status("az").velocity) > 1.8, what="cruising")
        rig.sims["az"].inject_fault("following_error")
        rig.wait_state("az", DriveState.FAULT_REACTION_ACTIVE)
        rig.cycle_hooks.clear()
        drive.fault_reset()
        rig.wait_state("az", DriveState.SWITCH_ON_DISABLED, timeout=10.0)
        status = rig.status("az")
        assert status.fault is None and status.request_error is None, status.request_error
        wait_cycles(rig, 10)
        assert rig.status("az").state is DriveState.SWITCH_ON_DISABLED  # never re-enabled by itself


def test_fault_reset_without_fault_changes_nothing(can_channel):
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        rig.drive("az").fault_reset()
        wait_cycles(rig, 10)
        assert rig.status("az").state is DriveState.OPERATION_ENABLED


def test_bus_off_is_reported(can_channel):
    if can_channel["interface"] != "virtual":
        pytest.skip("error frames can only be injected on the virtual bus")
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        heard = []
        rig.system.bus.add_error_callback(heard.append)
        with can.Bus(**can_channel) as other:
            other.send(can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True,
                                   is_extended_id=False, data=bytes(8)))
        rig.wait(lambda: rig.system.bus.health().state == "bus-off", what="bus-off")
        health = rig.system.bus.health()
        assert health.bus_off_count == 1 and "bus-off" in str(health.last_error)
        assert health.last_error.number == ErrorNumber.NOCON and heard == [health.last_error]


def test_a_silent_node_is_retried_until_it_answers(can_channel):
    """A drive silent at boot (no heartbeat, no SDO answer) is booted again with back-off for
    as long as it stays silent — it used to be tried once more and then never again (the
    failed boot's fresh heartbeat watch had never heard it, so "retry while it shows life"
    was false for good) — and is booted as soon as it answers."""
    with Rig(can_channel, {"az": AxisSpec(1), "alt": AxisSpec(2)}, boot_timeout=0.5) as rig:
        rig.sims["az"].set_responding(False)
        failures = rig.boot_and_start()
        assert set(failures) == {"az"} and "no" in failures["az"].message
        rig.wait(lambda: rig.system._retry.get("az", (0, 0))[1] >= 2.0, 20.0,
                 "two more failed attempts (back-off doubled twice)")
        assert not rig.status("az").booted
        rig.sims["az"].set_responding(True)
        rig.wait(lambda: rig.status("az").booted, 60.0, "az booted again")
        assert rig.system.recoveries >= 1
        assert rig.status("alt").state is not DriveState.OFFLINE
