"""Boot and configuration of CiA-402 drives by the TCS driver, against simulated drives."""

from __future__ import annotations

import pytest
from cia402_rig import SCALE, SLOWDOWN, AxisSpec, Rig

from tcs.drivers.drive import DriveState, Mode
from tcs.errors import CommunicationError, ErrorNumber, HardwareError
from tcs.sim.cia402_drive import DEFAULT_EDS, SimDriveParams


def test_several_drives_boot_configured_and_disabled(can_channel):
    axes = {"az": AxisSpec(1), "alt": AxisSpec(2), "rot": AxisSpec(5, section={"default_mode": "pp"})}
    with Rig(can_channel, axes, sync_period=0.004) as rig:
        assert rig.boot_and_start() == {}
        for name in axes:
            status = rig.status(name)
            assert status.booted and status.heartbeat_ok and status.fault is None
            assert status.state is DriveState.SWITCH_ON_DISABLED
        assert rig.status("az").mode is Mode.CSP and rig.status("rot").mode is Mode.PP
        sim = rig.sims["alt"]
        # What the hardware file says arrived in the drive, in increments.
        assert sim.read_object(0x6065) == round(0.5 * SCALE)
        assert sim.read_object(0x607D, 1) == round(-100 * SCALE)
        assert sim.read_object(0x607D, 2) == round(100 * SCALE)
        assert sim.read_object(0x6081) == round(4.0 * SCALE)
        assert sim.read_object(0x6098) == 37
        assert (sim.read_object(0x60C2, 1), sim.read_object(0x60C2, 2)) == (4 * SLOWDOWN, -3)
        assert sim.read_object(0x1017) == 200 * SLOWDOWN
        assert sim.read_object(0x1016, 1) == (127 << 16) | 1000 * SLOWDOWN
        assert [sim.read_object(0x1600, i) for i in range(3)] == [2, 0x60400010, 0x607A0020]
        assert [sim.read_object(0x1A01, i) for i in range(3)] == [2, 0x606C0020, 0x60F40020]
        assert sim.read_object(0x1802, 2) == 255  # TPDO3 (inputs, error code) event driven
        assert sim.nmt_state_name == "OPERATIONAL"


def test_drive_that_never_boots_is_named_and_others_work(can_channel):
    axes = {"az": AxisSpec(1), "ghost": AxisSpec(9, sim=False)}
    with Rig(can_channel, axes, boot_timeout=1.0) as rig:
        failures = rig.boot_and_start()
        assert set(failures) == {"ghost"}
        error = failures["ghost"]
        assert isinstance(error, CommunicationError) and error.number == ErrorNumber.NOCON
        assert "drive ghost (node 9)" in str(error) and "did not boot" in str(error)
        ghost = rig.status("ghost")
        # (retried for ever with back-off: the fault is the newest attempt's, never none)
        assert ghost.state is DriveState.OFFLINE and isinstance(ghost.fault, CommunicationError)
        assert "did not boot" in str(ghost.fault)
        with pytest.raises(CommunicationError, match="not booted"):
            rig.drive("ghost").enable()
        rig.enable("az")  # the others are unaffected


def test_wrong_identity_is_named_and_others_work(can_channel):
    wrong = SimDriveParams(identity=(0xABC, 0x00402999, 0x00010000, 7))
    axes = {"az": AxisSpec(1), "alt": AxisSpec(2, params=wrong)}
    with Rig(can_channel, axes) as rig:
        failures = rig.boot_and_start()
        assert set(failures) == {"alt"}
        message = str(failures["alt"])
        assert message.startswith("drive alt (node 2): wrong identity")
        assert "product 0x00402999 (hardware file: 0x00402001)" in message
        rig.enable("az")


def test_serial_number_is_checked_when_given(can_channel):
    from tcs.config.can import IdentitySection
    ident = IdentitySection(vendor=0xABC, product=0x00402001, revision=0x00010000, serial=42)
    with Rig(can_channel, {"az": AxisSpec(1, section={"identity": ident})}) as rig:
        failures = rig.boot_and_start()
        assert "serial 0x00000001 (hardware file: 0x0000002A)" in str(failures["az"])


def test_sdo_abort_during_configuration_is_named_and_others_work(can_channel):
    axes = {"az": AxisSpec(1), "alt": AxisSpec(2), "foc": AxisSpec(3)}
    with Rig(can_channel, axes) as rig:
        rig.sims["alt"].set_refuse_sdo(True)
        failures = rig.boot_and_start()
        assert set(failures) == {"alt"}
        error = failures["alt"]
        assert isinstance(error, HardwareError) and error.number == ErrorNumber.LIBFAIL
        assert str(error).startswith("drive alt (node 2): SDO read 0x1000:0 device type aborted: 0x08000020")
        rig.enable("az", "foc")
        # Once the drive answers again, booting it again works.
        rig.sims["alt"].set_refuse_sdo(False)
        assert rig.system.boot(["alt"]) == {}
        rig.enable("alt")


def test_sdo_abort_in_the_middle_of_configuration_names_the_object(can_channel, tmp_path):
    # A drive whose software limits are read-only: the write of 0x607D:1 is aborted.
    eds = DEFAULT_EDS.read_text()
    start = eds.index("[607Dsub1]")
    end = eds.index("\n\n", start)
    eds = eds[:start] + eds[start:end].replace("AccessType=rw", "AccessType=ro") + eds[end:]
    (tmp_path / "ro.eds").write_text(eds)
    axes = {"az": AxisSpec(1, sim_eds=tmp_path / "ro.eds"), "alt": AxisSpec(2)}
    with Rig(can_channel, axes) as rig:
        failures = rig.boot_and_start()
        assert set(failures) == {"az"}
        assert str(failures["az"]) == ("drive az (node 1): SDO write 0x607D:1 software position "
                                       "limit aborted: 0x06010002 read-only object")
        rig.enable("alt")


def test_drive_already_running_is_found_without_boot_up(can_channel):
    """A TCS restart: the drive booted long ago (no boot-up to hear) and is found anyway."""
    with Rig(can_channel, {"az": AxisSpec(1)}) as rig:
        assert rig.boot_and_start() == {}
        rig.system.stop()
        assert rig.system.boot() == {}
        rig.system.start()
        rig.enable("az")
