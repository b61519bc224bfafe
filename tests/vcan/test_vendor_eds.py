"""The CiA-402 master against drives that are not ours (issue 15): EDS-driven boot, unit
factors, raw SDO writes, and the simulator behaving as the EDS it is given.

The fixtures of ``tests/vcan/eds/`` are written by us (``make_fixtures.py``); each differs from
our simulated drive in one way real drives do. Real CANopen frames between the TCS's driver
and the simulated drives; tests wait for states, never for durations.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from cia402_rig import AxisSpec, Rig

from tcs.config.can import HomingSection, IdentitySection
from tcs.drivers.drive import DriveState, Mode, Progress
from tcs.errors import ConfigErrors, HardwareError
from tcs.sim.cia402_drive import SimDriveParams

EDS = Path(__file__).parent / "eds"


def fixture(name: str) -> str:
    return str(EDS / f"{name}.eds")


def vendor(node: int, name: str, params: SimDriveParams | None = None, **section) -> AxisSpec:
    """A drive of EDS ``name`` for both sides (the TCS's configuration and the simulator)."""
    params = params or SimDriveParams()
    return AxisSpec(node, params=params, section={"eds": fixture(name), **section},
                    sim_eds=fixture(name))


# ----------------------------------------------------------------------------- units (rpm)

def test_rpm_drive_profile_move_runs_at_the_configured_speed(can_channel):
    """10000 counts per user unit (one motor revolution): 1 unit/s = 60 rpm. A PP move of
    4 units at 1.5 units/s must run at 1.5 units/s as the drive itself reports it
    (0x606C in rpm), and take the trapezoid's time: distance / v + v / a."""
    factor = 60.0
    params = SimDriveParams(max_velocity=5.0, max_acceleration=20.0, velocity_scale=factor / 10000,
                            acceleration_scale=factor / 10000)
    spec = vendor(1, "vendor-rpm", params, default_mode="pp", velocity_factor=factor,
                  acceleration_factor=factor, max_velocity=3.0, max_acceleration=4.0)
    with Rig(can_channel, {"m": spec}) as rig:
        samples: list[tuple[int, float, float]] = []
        # (the SYNC number, not the count of cycles run: with SYNC from the kernel a slow host
        # skips cycles while the drive's profile runs on)
        rig.cycle_hooks.append(lambda cycle: samples.append(
            (cycle.index, rig.status("m").position, rig.status("m").velocity)))
        assert rig.boot_and_start() == {}
        sim = rig.sims["m"]
        assert rig.drive("m")._sdo.read(0x6083, 0, "<I") == round(4.0 * factor)  # rpm/s on the wire
        rig.enable("m")
        rig.drive("m").move_to(4.0, velocity=1.5)
        rig.wait(lambda: rig.status("m").move is not Progress.IDLE, what="move started")
        rig.wait(lambda: rig.status("m").move is not Progress.RUNNING, timeout=30, what="move end")
        assert rig.status("m").move is Progress.DONE, rig.status("m").request_error
        assert rig.drive("m")._sdo.read(0x6081, 0, "<I") == round(1.5 * factor)  # 90 rpm
        assert sim.position == pytest.approx(4.0, abs=1e-3)
        moving = [s for s in samples if abs(s[2]) > 1e-6]
        peak = max(abs(v) for _, _, v in moving)
        assert peak == pytest.approx(1.5, rel=0.05)  # rpm resolution: 1 rpm = 0.0167 units/s
        # The profile: SYNC periods spent moving ≈ (d / v + v / a) / SYNC period (from the
        # drive's own velocity reports; not a wall-clock measurement).
        cycles = moving[-1][0] - moving[0][0] + 1
        predicted = (4.0 / 1.5 + 1.5 / 4.0) / rig.can.sync_period
        assert cycles == pytest.approx(predicted, rel=0.1)


# ----------------------------------------------------------------------- [drives.x.sdo] writes

def test_raw_sdo_writes_land_after_the_configuration(can_channel):
    spec = vendor(1, "vendor-no-homing", absolute=True,
                  sdo={"0x2100:0": -1234, "0x6067:0": 77, "0x6065:0": 4321})
    with Rig(can_channel, {"az": spec}) as rig:
        assert rig.boot_and_start() == {}
        sdo = rig.drive("az")._sdo
        assert sdo.read(0x2100, 0, "<i") == -1234     # a vendor object (home offset)
        assert sdo.read(0x6067, 0, "<I") == 77
        assert sdo.read(0x6065, 0, "<I") == 4321      # after our own 0x6065 write: it wins
        # absolute: referenced by configuration, no homing run, no homing mode
        rig.enable("az")
        assert rig.status("az").homed
        rig.drive("az").start_homing()
        rig.wait(lambda: rig.status("az").homing is Progress.DONE, what="homing done at once")
        assert rig.sims["az"].mode_display == Mode.CSP


@pytest.mark.parametrize("entry, value, needle", [
    ("0x9999:0", 1, "the drive has no object 0x9999:0"),
    ("0x6041:0", 1, "0x6041:0 is read-only"),
    ("0x605A:0", 9, "9 is outside the range of 0x605A:0, 0..8"),
])
def test_bad_raw_sdo_entry_is_a_start_error_naming_file_and_key(can_channel, entry, value, needle):
    with pytest.raises(ConfigErrors) as info:
        with Rig(can_channel, {"az": AxisSpec(1, section={"sdo": {entry: value}})}):
            pass
    messages = [e.message for e in info.value.errors]
    assert any(m.startswith(f"<hardware file>: drives.az.sdo.{entry}: drive az (node 1): ")
               and needle in m for m in messages), messages


# ------------------------------------------------------------------ PDO mapping from the EDS

def test_error_code_not_mappable_is_left_out_and_faults_still_name_their_code(can_channel):
    with Rig(can_channel, {"az": vendor(1, "vendor-pdo-restricted")}) as rig:
        assert rig.boot_and_start() == {}
        sim = rig.sims["az"]
        assert [sim.read_object(0x1A02, i) for i in range(2)] == [1, 0x60FD0020]
        assert rig.drive("az").layouts["tpdo3"].indices == (0x60FD,)
        rig.enable("az")
        sim.inject_fault("following_error")
        rig.wait(lambda: rig.status("az").fault is not None, what="fault seen")
        assert "0x8611" in rig.status("az").fault.message
        # Without an EMCY (its COB-ID switched off) the code is read by SDO, once, on the fault.
        rig.drive("az").fault_reset()
        rig.wait(lambda: rig.status("az").fault is None, what="fault reset")
        rig.drive("az")._sdo.write(0x1014, 0, "<I", 0x80000081)
        rig.enable("az")
        sim.inject_fault("encoder")
        rig.wait(lambda: rig.status("az").fault is not None and "0x7305" in rig.status("az").fault.message,
                 what="error code read by SDO")


def test_identity_without_revision_accepts_another_firmware(can_channel):
    from tcs.config.can import IdentitySection
    params = SimDriveParams(identity=(0xABC, 0x00402001, 0x00020003, 1))
    ident = IdentitySection(vendor=0xABC, product=0x00402001)
    with Rig(can_channel, {"az": vendor(1, "vendor-revision", params, identity=ident),
                           "alt": AxisSpec(2, params=params)}) as rig:
        failures = rig.boot_and_start()
        assert set(failures) == {"alt"}  # the rig's default identity pins the revision
        assert "revision 0x00020003 (hardware file: 0x00010000)" in str(failures["alt"])
        rig.enable("az")


def test_a_drive_without_heartbeat_consumer_boots_and_is_reported(can_channel, caplog):
    with caplog.at_level("INFO"):
        with Rig(can_channel, {"az": vendor(1, "vendor-no-hbconsumer")}) as rig:
            assert rig.boot_and_start() == {}
            rig.enable("az")
            assert rig.system.eds_reports["az"].conditions[0][0] == "no_heartbeat_consumer"
    assert any(r.levelname == "WARNING" and "0x1016" in r.getMessage()
               and "WILL NOT NOTICE A DEAD MASTER" in r.getMessage() for r in caplog.records)


def test_optional_objects_absent_are_skipped_and_logged_at_info(can_channel, caplog):
    with caplog.at_level("INFO"):
        with Rig(can_channel, {"az": vendor(1, "vendor-no-softlimits")}) as rig:
            assert rig.boot_and_start() == {}
            rig.enable("az")
    assert any(r.levelname == "INFO" and "drive az (node 1)" in r.getMessage()
               and "0x607D" in r.getMessage() for r in caplog.records)


# ----------------------------------------------------------------- the simulator as its EDS

def test_simulator_answers_as_its_eds(can_channel):
    with Rig(can_channel, {"az": vendor(1, "vendor-no-csp", default_mode="pp"),
                           "hm": vendor(2, "vendor-no-homing", absolute=True)}) as rig:
        assert rig.boot_and_start() == {}
        sdo = rig.drive("az")._sdo
        with pytest.raises(HardwareError, match="0x06090030"):
            sdo.write(0x6060, 0, "<b", 8)  # 0x6502 has no CSP: refused
        with pytest.raises(HardwareError, match="0x06020000"):
            rig.drive("hm")._sdo.read(0x6098, 0, "<b")  # absent object
        with pytest.raises(HardwareError, match="0x06010002"):
            sdo.write(0x6041, 0, "<H", 0)  # read-only
        # SDO block upload request (ccs 5, client subcommand 0): aborted 0x05040001
        node = rig.drive("az")._node
        answer = []
        rig.system.bus.network.subscribe(0x581, lambda cob, data, ts: answer.append(bytes(data)))
        rig.system.bus.network.send_message(0x601, bytes([0xA0, 0x00, 0x10, 0x00, 0x7F, 0, 0, 0]))
        rig.wait(lambda: any(a[0] == 0x80 for a in answer), what="block upload answered")
        assert int.from_bytes(next(a for a in answer if a[0] == 0x80)[4:8], "little") == 0x05040001
        assert node is not None
        rig.enable("az")
        assert rig.status("az").state is DriveState.OPERATION_ENABLED


def test_a_bare_eds_with_only_what_the_axis_needs_still_boots_and_moves(can_channel, tmp_path):
    """The simulator never crashes on a valid EDS, however few objects it has; the master
    skips everything optional and still runs the axis in CSP."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("make_fixtures", EDS / "make_fixtures.py")
    mf = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mf)
    parts = mf.sections(mf.SOURCE.read_text(encoding="utf-8"))
    keep = {"1000", "1001", "1017", "1018", "1400", "1600", "1800", "1A00",
            "6040", "6041", "6060", "6061", "6064", "607A"}
    parts = [(n, b) for n, b in parts
             if not re.fullmatch(r"[0-9A-F]{4}(sub[0-9A-F]+)?", n) or n[:4] in keep]
    (tmp_path / "bare.eds").write_text(mf.render(mf.relist(parts)), encoding="utf-8")
    bare = str(tmp_path / "bare.eds")
    spec = AxisSpec(1, section={"eds": bare, "absolute": True}, sim_eds=bare)
    with Rig(can_channel, {"az": spec}) as rig:
        assert rig.boot_and_start() == {}
        assert set(rig.drive("az").layouts) == {"rpdo1", "tpdo1"}
        rig.enable("az")
        assert rig.status("az").homed
        rig.cycle_hooks.append(lambda cycle: rig.drive("az").set_setpoint(0.25))
        rig.wait(lambda: abs(rig.sims["az"].position - 0.25) < 1e-3, what="CSP move on a bare drive")


@pytest.mark.parametrize("method, refused", [(37, False), (35, True)])
def test_a_fixed_homing_method_is_accepted_when_it_matches_and_refused_otherwise(
        can_channel, tmp_path, method, refused):
    """0x6098 const on some drives: nothing to write when the file agrees; a start error
    naming homing.method and the fixed value when it does not."""
    eds = (EDS / "vendor-revision.eds").read_text(encoding="utf-8")
    start = eds.index("[6098]")
    end = eds.index("\n\n", start)
    block = eds[start:end].replace("AccessType=rw", "AccessType=const").replace(
        "DefaultValue=0", "DefaultValue=37")
    path = tmp_path / "const6098.eds"
    path.write_text(eds[:start] + block + eds[end:], encoding="utf-8")
    homing = HomingSection(method=method, timeout=10.0)
    spec = AxisSpec(1, section={"eds": str(path), "homing": homing}, sim_eds=path)
    if refused:
        with pytest.raises(ConfigErrors) as info:
            with Rig(can_channel, {"az": spec}):
                pass
        text = info.value.errors[0].message
        assert text.startswith("<hardware file>: drives.az.homing.method: drive az (node 1): ")
        assert "0x6098:0" in text and "fixed to 37" in text
        return
    with Rig(can_channel, {"az": spec}) as rig:
        assert rig.boot_and_start() == {}
        rig.enable("az")
        rig.drive("az").start_homing()
        rig.wait(lambda: rig.status("az").homing is Progress.DONE, what="homing with method 37")


# ------------------------------------------------------- issue 21: modes and three EDS defects
@pytest.mark.parametrize("name, mode", [
    ("vendor-ip-only", Mode.IP), ("vendor-csv-only", Mode.CSV), ("vendor-ip-no-607a-map", Mode.IP),
    ("vendor-homing-list", Mode.CSP), ("vendor-hb16", Mode.CSP),
    ("vendor-no-devtype-default", Mode.CSP)])
def test_vendor_drive_boots_enables_references_and_moves_in_its_mode(can_channel, name, mode):
    spec = vendor(1, name, heartbeat_consumer_timeout=5.0)  # 0x1016:1 = 127 << 16 | 5000
    with Rig(can_channel, {"m": spec}) as rig:
        assert rig.boot_and_start() == {}
        drive, sim = rig.drive("m"), rig.sims["m"]
        assert drive.cyclic_mode is mode
        if name == "vendor-hb16":
            assert sim.read_object(0x1016, 1) == 127 << 16 | 5000
        if name == "vendor-ip-no-607a-map":
            assert 0x607A not in drive.layouts["rpdo1"].indices
        rig.enable("m")
        drive.start_homing()
        rig.wait(lambda: rig.status("m").homed, what="referenced")
        drive.set_mode(mode)
        rig.wait(lambda: rig.status("m").mode is mode, what=f"mode {mode.name}")
        start = rig.status("m").position
        path = {"x": start}

        def stream(cycle):
            path["x"] = min(start + 0.5, path["x"] + 0.5 * rig.can.sync_period)
            drive.set_setpoint(path["x"], 0.5 if path["x"] < start + 0.5 else 0.0)
        rig.cycle_hooks.append(stream)
        rig.wait(lambda: abs(sim.position - (start + 0.5)) < 0.005, what="moved")
        rig.cycle_hooks.clear()


def test_the_mode_chosen_is_logged_with_its_reason(can_channel, caplog):
    with caplog.at_level("INFO"):
        with Rig(can_channel, {"az": vendor(1, "vendor-csv-only")}) as rig:
            assert rig.boot_and_start() == {}
    lines = [r.getMessage() for r in caplog.records if r.levelname == "INFO"]
    assert any(line.startswith("drive az: mode CSV") and "0x6502" in line
               and "PP, HM, CSV" in line and "CSP, then IP, then CSV" in line for line in lines), lines
    assert any(line.startswith("drive az: PDO layout (from the EDS) — RPDO1 0x201 SYNC: 0x6040 "
                               "controlword + 0x60FF target_velocity") for line in lines), lines


# ------------------------------------------- issue 40: PDO layouts from the EDS, modes, absolute
def _stream_and_move(rig, name: str, distance: float = 0.5) -> None:
    """Stream a ramp of ``distance`` units in the drive's cyclic mode; wait until the simulated
    drive stands there."""
    drive, sim = rig.drive(name), rig.sims[name]
    mode = drive.cyclic_mode
    drive.set_mode(mode)
    rig.wait(lambda: rig.status(name).mode is mode, what=f"mode {mode.name}")
    start = rig.status(name).position
    path = {"x": start}

    def stream(cycle):
        path["x"] = min(start + distance, path["x"] + 0.5 * rig.can.sync_period)
        drive.set_setpoint(path["x"], 0.5 if path["x"] < start + distance else 0.0)
    rig.cycle_hooks.append(stream)
    rig.wait(lambda: abs(sim.position - (start + distance)) < 0.005, what="moved")
    rig.cycle_hooks.clear()


#: fixture -> (section extras, sim params, the layout the TCS must write, the cyclic mode)
SHAPES = {
    # RPDO1/TPDO1 take one object: controlword and target, statusword and position split
    "vendor-pdo1-single": ({}, SimDriveParams(),
                           {"rpdo1": (0x6040,), "rpdo2": (0x607A,), "tpdo1": (0x6041,),
                            "tpdo2": (0x6064, 0x606C)}, Mode.CSP),
    # TPDO2 has no mapping entries at all: never used, the next TPDOs carry the rest
    "vendor-tpdo2-empty": ({"absolute": True}, SimDriveParams(),
                           {"rpdo1": (0x6040, 0x607A), "tpdo1": (0x6041, 0x6064),
                            "tpdo3": (0x606C, 0x60F4), "tpdo4": (0x60FD, 0x603F)}, Mode.CSP),
    # 0x607A not mappable, 0x6502 without default: IP through 0x60C1:1 (the drive says PP, HM, IP)
    "vendor-ip-nomodes": ({}, SimDriveParams(objects={(0x6502, 0): 0x61}),
                          {"rpdo1": (0x6040, 0x60C1)}, Mode.IP),
    # read-only 0x6098, no homing mode: absolute, referenced by configuration
    "vendor-absolute-ro6098": ({"absolute": True}, SimDriveParams(),
                               {"rpdo1": (0x6040, 0x607A), "tpdo1": (0x6041, 0x6064)}, Mode.CSP),
}


@pytest.mark.parametrize("name", list(SHAPES))
def test_drive_of_each_pdo_shape_is_laid_out_from_its_eds_and_moves(can_channel, name):
    """No pdo = {…} anywhere: the TCS spreads the objects over the PDOs the EDS gives, the
    simulated drive (which refuses what its EDS does not allow) takes the layout, and the
    axis is referenced and moved in its mode."""
    extra, params, layout, mode = SHAPES[name]
    with Rig(can_channel, {"m": vendor(1, name, params, **extra)}) as rig:
        assert rig.boot_and_start() == {}
        drive, sim = rig.drive("m"), rig.sims["m"]
        assert drive.cyclic_mode is mode
        for pdo, indices in layout.items():
            assert drive.layouts[pdo].indices == indices, (pdo, drive.layouts)
            base = 0x1600 if pdo.startswith("rpdo") else 0x1A00
            n = int(pdo[4:]) - 1
            assert sim.read_object(base + n, 0) == len(indices)      # the drive holds it
            assert sim.read_object(base + n, 1) >> 16 == indices[0]
        if name == "vendor-tpdo2-empty":
            assert "tpdo2" not in drive.layouts
            assert sim.read_object(0x1801, 1) & 0x80000000          # switched off
        rig.enable("m")
        drive.start_homing()
        rig.wait(lambda: rig.status("m").homed and rig.status("m").homing is Progress.DONE,
                 what="referenced")
        if extra.get("absolute"):
            assert sim.logic.homing is None and sim.mode_display != 6  # no homing run
        _stream_and_move(rig, "m")


@pytest.mark.parametrize("default", [None, "0"])
def test_0x6502_without_eds_default_is_read_from_the_drive_and_settles_the_mode(
        can_channel, tmp_path, caplog, default):
    """Everything mappable, 0x6502 without default (or the placeholder 0): CSP is assumed at
    start; the drive answers PP, HM, IP at boot, so the axis runs in IP (layout with 0x60C1:1)
    — logged with where the value came from."""
    eds = (EDS / "vendor-revision.eds").read_text(encoding="utf-8")
    start = eds.index("[6502]")
    end = eds.find("\n\n", start)
    block = eds[start:end if end > 0 else len(eds)]
    path = tmp_path / "nomodes.eds"
    lines = [line for line in block.splitlines() if not line.startswith("DefaultValue=")]
    if default is not None:
        lines.append(f"DefaultValue={default}")
    path.write_text(eds.replace(block, "\n".join(lines)), encoding="utf-8")
    params = SimDriveParams(identity=(0xABC, 0x00402001, 0x00020003, 1), objects={(0x6502, 0): 0x61})
    spec = AxisSpec(1, params=params, section={"eds": str(path), "identity": IdentitySection(
        vendor=0xABC, product=0x00402001)}, sim_eds=path)
    with caplog.at_level("INFO"):
        with Rig(can_channel, {"m": spec}) as rig:
            assert rig.drive("m").cyclic_mode is Mode.CSP            # assumed at start
            assert rig.boot_and_start() == {}
            drive = rig.drive("m")
            assert drive.cyclic_mode is Mode.IP
            assert drive.layouts["rpdo1"].indices == (0x6040, 0x60C1)
            rig.enable("m")
            drive.start_homing()
            rig.wait(lambda: rig.status("m").homed, what="referenced")
            _stream_and_move(rig, "m")
    lines = [r.getMessage() for r in caplog.records]
    assert any("0x6502" in line and "= PP, HM, IP" in line and "read from the drive over SDO" in line
               and "nomodes.eds gives no default" in line for line in lines), lines


def test_simulated_drive_honours_mapping_entries_mappability_and_modes(can_channel):
    """What the EDS says about PDOs holds on the wire: a mapping longer than its entries, an
    entry a PDO does not have, an unmappable object, a mode 0x6502 (from [simulation]) lacks."""
    from tcs.drivers.boot import NMT_PRE_OPERATIONAL, send_nmt
    specs = {"one": vendor(1, "vendor-pdo1-single"), "empty": vendor(2, "vendor-tpdo2-empty"),
             "ip": vendor(3, "vendor-ip-nomodes", SimDriveParams(objects={(0x6502, 0): 0x61}))}
    with Rig(can_channel, specs) as rig:
        assert rig.boot_and_start() == {}
        for node in (1, 2, 3):
            send_nmt(rig.system.bus.network, NMT_PRE_OPERATIONAL, node)
        rig.wait(lambda: all(s.nmt_state_name == "PRE-OPERATIONAL" for s in rig.sims.values()),
                 what="pre-operational")
        one, empty, ip = (rig.drive(n)._sdo for n in ("one", "empty", "ip"))
        one.write(0x1400, 1, "<I", 0x80000201)
        one.write(0x1600, 0, "<B", 0)
        with pytest.raises(HardwareError, match="0x06090031"):
            one.write(0x1600, 0, "<B", 2)                  # RPDO1 takes one object
        with pytest.raises(HardwareError, match="0x06090011"):
            one.write(0x1600, 2, "<I", 0x607A0020)         # it has no second entry
        empty.write(0x1801, 1, "<I", 0x80000282)
        with pytest.raises(HardwareError, match="0x06090011"):
            empty.write(0x1A01, 1, "<I", 0x60640020)       # TPDO2: no mapping entries
        with pytest.raises(HardwareError, match="0x06090031"):
            empty.write(0x1A01, 0, "<B", 1)
        ip.write(0x1400, 1, "<I", 0x80000203)
        ip.write(0x1600, 0, "<B", 0)
        with pytest.raises(HardwareError, match="0x06040041"):
            ip.write(0x1600, 2, "<I", 0x607A0020)          # 0x607A is not mappable
        assert ip.read(0x6502, 0, "<I") == 0x61            # as [simulation] says
        assert empty.read(0x6502, 0, "<I") == 0x1E5        # the EDS's default
        with pytest.raises(HardwareError, match="0x06090030"):
            ip.write(0x6060, 0, "<b", 8)                   # no CSP on this drive


def test_a_hand_written_layout_still_wins(can_channel):
    """pdo = {…} in the hardware file is used as written (checked against the EDS), not the
    layout the TCS would choose."""
    pdo = {"rpdo1": ["0x6040", "0x607A"], "tpdo1": ["0x6041", "0x6064"], "tpdo3": ["0x60FD"]}
    with Rig(can_channel, {"m": vendor(1, "vendor-tpdo2-empty", pdo=pdo, absolute=True)}) as rig:
        assert rig.boot_and_start() == {}
        drive, sim = rig.drive("m"), rig.sims["m"]
        assert {n: p.indices for n, p in drive.layouts.items()} == {
            "rpdo1": (0x6040, 0x607A), "tpdo1": (0x6041, 0x6064), "tpdo3": (0x60FD,)}
        assert sim.read_object(0x1803, 1) & 0x80000000 and sim.read_object(0x1A02, 0) == 1
        rig.enable("m")
        _stream_and_move(rig, "m", 0.25)


def test_cob_id_and_timer_limits_do_not_stop_a_remap(can_channel, tmp_path):
    """EDS files often give a PDO COB-ID HighLimit of 0x7FF: switching a PDO off (bit 31) is
    still taken by the TCS's check and by the simulated drive; an event timer / RPDO deadline
    the drive's limits do not take is left as commissioned. The axis moves."""
    import re
    text = (EDS / "vendor-pdo1-single.eds").read_text(encoding="utf-8")
    text = re.sub(r"(\[1[48]0[0-3]sub1\]\n(?:[^\[\n].*\n)*?)(PDOMapping=0)", r"\1\2\nLowLimit=0x181\nHighLimit=0x7FF",
                  text)
    assert text.count("HighLimit=0x7FF") == 8
    # event timers / RPDO deadlines limited to 100 ms: the TCS's 500 ms are left out
    text = re.sub(r"(\[1[48]0[0-3]sub5\]\n(?:[^\[\n].*\n)*?)(PDOMapping=0)", r"\1\2\nHighLimit=100", text)
    assert text.count("HighLimit=100") == 8
    path = tmp_path / "coblimit.eds"
    path.write_text(text, encoding="utf-8")
    spec = AxisSpec(1, section={"eds": str(path)}, sim_eds=path)
    with Rig(can_channel, {"m": spec}) as rig:
        assert rig.boot_and_start() == {}
        assert rig.sims["m"].read_object(0x1403, 1) & 0x80000000   # RPDO4 switched off
        rig.enable("m")
        rig.drive("m").start_homing()
        rig.wait(lambda: rig.status("m").homed, what="referenced")
        _stream_and_move(rig, "m", 0.25)
