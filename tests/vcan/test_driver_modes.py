"""Trajectory axes in interpolated position (IP) and cyclic synchronous velocity (CSV), issue 21.

Drives whose EDS offers only IP or only CSV (``tests/vcan/eds/vendor-ip-only.eds``,
``vendor-csv-only.eds``, written by us) are booted by the TCS's driver in the mode their 0x6502
offers, follow a streamed path, and end every failure — drive fault, lost TCS heartbeat, quick
stop, and in CSV the following error the TCS supervises itself — in the same controlled stop
as CSP. Real CANopen frames between the driver and simulated drives; tests wait for states,
never for durations.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from cia402_rig import AxisSpec, Rig

from tcs.drivers.drive import DriveState, Mode
from tcs.errors import ErrorNumber
from tcs.sim.cia402_drive import SimDriveParams

EDS = Path(__file__).parent / "eds"
MODE_FIXTURES = {Mode.IP: "vendor-ip-only", Mode.CSV: "vendor-csv-only",
                 Mode.CSP: "vendor-revision"}


def spec(mode: Mode, node: int = 1, **section) -> AxisSpec:
    name = str(EDS / f"{MODE_FIXTURES[mode]}.eds")
    return AxisSpec(node, params=SimDriveParams(max_velocity=5.0, max_acceleration=20.0),
                    section={"eds": name, **section}, sim_eds=name)


def ramp(rig: Rig, name: str, speed: float) -> dict:
    """Stream a path from the present position at ``speed`` (units/s) after a gentle start."""
    drive = rig.drive(name)
    state = {"x": rig.status(name).position, "v": 0.0}

    def hook(cycle):
        dt = rig.can.sync_period
        state["v"] = min(speed, state["v"] + 4.0 * dt)  # 4 units/s² up to speed
        state["x"] += state["v"] * dt
        drive.set_setpoint(state["x"], state["v"])
    rig.cycle_hooks.append(hook)
    return state


def settle(rig: Rig, name: str, state: dict, distance: float) -> None:
    start = rig.status(name).position
    rig.wait(lambda: rig.status(name).position - start > distance, timeout=20,
             what=f"{name} moved {distance}")


@pytest.mark.parametrize("mode", [Mode.IP, Mode.CSV])
def test_a_drive_offering_only_this_mode_follows_a_streamed_path(can_channel, mode):
    with Rig(can_channel, {"az": spec(mode)}) as rig:
        assert rig.boot_and_start() == {}
        drive, sim = rig.drive("az"), rig.sims["az"]
        assert drive.cyclic_mode is mode and drive.mode_choice.mode == mode.name.lower()
        assert "0x6502" in drive.mode_choice.reason
        rig.drive("az").set_mode(mode)
        rig.enable("az")
        rig.wait(lambda: rig.status("az").mode is mode, what="mode")
        before = sim.position
        state = ramp(rig, "az", 1.0)
        settle(rig, "az", state, 1.0)
        # at constant speed the drive is where the path was two cycles ago, within a hair
        rig.wait(lambda: abs(state["x"] - 2 * rig.can.sync_period * state["v"]
                             - sim.position) < 0.02, what="following the path")
        assert sim.position > before + 1.0
        assert sim.mode_display == int(mode)
        if mode is Mode.IP:
            assert rig.status("az").statusword & 0x1000  # IP active
            assert rig.status("az").controlword & 0x0010  # enable IP
        else:
            assert abs(rig.status("az").following_error) < 0.05  # the TCS's own loop
            assert sim.read_object(0x60FF) != 0
        rig.cycle_hooks.clear()


def test_enable_in_ip_does_not_move_the_drive(can_channel):
    """Target = actual before enabling: no jump when IP is enabled without a setpoint."""
    params = SimDriveParams(position=3.25)
    name = str(EDS / "vendor-ip-only.eds")
    with Rig(can_channel, {"az": AxisSpec(1, params=params, section={"eds": name},
                                         sim_eds=name)}) as rig:
        assert rig.boot_and_start() == {}
        rig.drive("az").set_mode(Mode.IP)
        rig.enable("az")
        rig.wait(lambda: rig.status("az").statusword & 0x1000, what="IP active")
        for _ in range(3):
            rig.wait(lambda: rig.status("az").age < 0.1, what="fresh data")
        assert rig.sims["az"].position == pytest.approx(3.25, abs=1e-6)


@pytest.mark.parametrize("mode", [Mode.IP, Mode.CSV, Mode.CSP])
@pytest.mark.parametrize("failure", ["fault", "heartbeat", "quick_stop"])
def test_a_failure_while_streaming_ends_in_a_controlled_stop(can_channel, mode, failure):
    """Drive fault, lost TCS heartbeat and STOP (quick stop) end the same in every mode: the
    drive ramps down (never cut at speed) and ends at rest, not re-enabled."""
    with Rig(can_channel, {"az": spec(mode)}) as rig:
        assert rig.boot_and_start() == {}
        sim = rig.sims["az"]
        rig.drive("az").set_mode(mode)
        rig.enable("az")
        rig.wait(lambda: rig.status("az").mode is mode, what="mode")
        state = ramp(rig, "az", 2.0)
        rig.wait(lambda: sim.velocity > 1.9, timeout=20, what="at speed")
        if failure == "fault":
            sim.inject_fault(0x4310)  # over-temperature: the fault reaction ramps down
        elif failure == "heartbeat":
            rig.system.bus.stop_heartbeat()
        else:
            rig.drive("az").quick_stop()
        seen = []
        rig.wait(lambda: seen.append(sim.velocity) or abs(sim.velocity) < 1e-9, timeout=20,
                 what="standstill")
        rig.cycle_hooks.clear()
        speeds = [abs(v) for v in seen]
        assert any(0.05 < v < 1.9 for v in speeds), speeds[:50]  # a ramp, not a cut
        status = rig.status("az")
        if failure == "fault":
            assert status.fault is not None and status.fault.code == 0x4310
        elif failure == "heartbeat":  # the drive noticed (it is booted again afterwards)
            assert 0x8130 in sim.emcy_sent
        assert sim.state in ("FAULT", "SWITCH ON DISABLED", "QUICK STOP ACTIVE"), sim.state


def test_csv_following_error_is_supervised_by_the_tcs(can_channel):
    """In CSV the drive has no position demand: a path the axis cannot follow (a jump) is a
    following error of the TCS's own loop, the axis faults with a controlled stop."""
    with Rig(can_channel, {"az": spec(Mode.CSV, following_error_window=0.2,
                                      following_error_timeout=0.1)}) as rig:
        assert rig.boot_and_start() == {}
        rig.drive("az").set_mode(Mode.CSV)
        rig.enable("az")
        rig.wait(lambda: rig.status("az").mode is Mode.CSV, what="mode")
        base = rig.status("az").position
        rig.cycle_hooks.append(lambda cycle: rig.drive("az").set_setpoint(base + 3.0))
        rig.wait(lambda: rig.status("az").fault is not None, what="following error")
        rig.cycle_hooks.clear()
        status = rig.status("az")
        assert "following error" in str(status.fault) and "CSV" in str(status.fault)
        assert status.fault.number == ErrorNumber.LIBFAIL
        rig.wait(lambda: rig.status("az").state is DriveState.SWITCH_ON_DISABLED, what="stopped")
        rig.wait(lambda: abs(rig.sims["az"].velocity) < 1e-9, what="standstill")
        rig.drive("az").fault_reset()
        rig.wait(lambda: rig.status("az").fault is None, what="reset")
        assert rig.status("az").state is DriveState.SWITCH_ON_DISABLED  # not re-enabled
