"""Homing (mode 6) through the driver's handshake, every method a telescope uses."""

from __future__ import annotations

import pytest
from cia402_rig import AxisSpec, Rig

from tcs.config.can import HomingSection
from tcs.drivers.drive import DriveState, Mode, Progress
from tcs.errors import ErrorNumber
from tcs.sim.cia402_drive import SimDriveParams

OFFSET = 0.25
#: method -> the switches of the simulated axis (it starts at 0): short distances, fast.
SWITCHES = {
    1: dict(negative_limit_switch=-0.3, index_pulse_spacing=0.25),
    2: dict(positive_limit_switch=0.3, index_pulse_spacing=0.25),
    17: dict(negative_limit_switch=-0.3),
    18: dict(positive_limit_switch=0.3),
    19: dict(home_switch=0.2),
    21: dict(home_switch=-0.2, home_switch_active_below=True),
    33: dict(index_pulse_spacing=0.25),
    34: dict(index_pulse_spacing=0.25),
    35: dict(),
    37: dict(),
}


def homing(method: int, timeout: float = 20.0) -> HomingSection:
    return HomingSection(method=method, speed_switch=2.0, speed_zero=0.5, acceleration=20.0,
                         offset=OFFSET, timeout=timeout)


@pytest.mark.parametrize("method", sorted(SWITCHES))
def test_homing_method(can_channel, method):
    params = SimDriveParams(position=0.0, **SWITCHES[method])
    with Rig(can_channel, {"az": AxisSpec(1, params=params, section={"homing": homing(method)})}) as rig:
        assert rig.boot_and_start() == {}
        drive = rig.drive("az")
        rig.enable("az")
        drive.start_homing()
        rig.wait(lambda: rig.status("az").homing is not Progress.IDLE, what="homing started")
        progress = [rig.status("az").homing_progress]
        rig.wait(lambda: progress.append(rig.status("az").homing_progress)
                 or rig.status("az").homing is not Progress.RUNNING, timeout=30, what="homing end")
        status = rig.status("az")
        assert status.homing is Progress.DONE, status.request_error
        assert status.homed and status.homing_progress == 1.0
        assert progress == sorted(progress)  # progress only grows
        # The latched home point reads the offset; the axis braked just past it (0.5 units/s
        # at the motor's 5 units/s²: 0.025).
        assert status.position == pytest.approx(OFFSET, abs=0.03)
        assert rig.sims["az"].read_object(0x6098) == method
        # Back in CSP, still enabled, holding where homing left it.
        rig.wait(lambda: rig.status("az").mode is Mode.CSP, what="CSP again")
        cycles = rig.system.cycle.stats().cycles
        rig.wait(lambda: rig.system.cycle.stats().cycles > cycles + 10, what="10 cycles")
        status = rig.status("az")
        assert status.state is DriveState.OPERATION_ENABLED and status.fault is None
        assert status.setpoint == pytest.approx(status.position, abs=1e-3)


def test_homing_timeout_from_the_hardware_file(can_channel):
    # Method 19 without a home switch and without limit switches searches forever.
    with Rig(can_channel, {"az": AxisSpec(1, section={"homing": homing(19, timeout=0.5)})}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        rig.drive("az").start_homing()
        rig.wait(lambda: rig.status("az").homing is Progress.FAILED, timeout=20, what="timeout")
        status = rig.status("az")
        assert status.request_error.number == ErrorNumber.TIMEOUT
        assert "homing (method 19) did not finish within 0.5 s" in str(status.request_error)
        assert not status.homed


def test_homing_error_reported_by_the_drive(can_channel):
    # Method 19 finds no home switch but runs into the positive limit switch: homing error.
    params = SimDriveParams(positive_limit_switch=0.3)
    with Rig(can_channel, {"az": AxisSpec(1, params=params, section={"homing": homing(19)})}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        rig.drive("az").start_homing()
        rig.wait(lambda: rig.status("az").homing is Progress.FAILED, timeout=20, what="homing error")
        assert "homing error" in str(rig.status("az").request_error)
        assert not rig.status("az").homed


def test_homing_needs_the_drive_enabled(can_channel):
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        assert rig.boot_and_start() == {}
        rig.drive("az").start_homing()
        rig.wait(lambda: rig.status("az").homing is Progress.FAILED, what="refusal")
        assert "needs the drive enabled" in str(rig.status("az").request_error)
        assert rig.status("az").state is DriveState.SWITCH_ON_DISABLED
