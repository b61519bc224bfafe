"""Vendor-like drives (issue 15): the TCS boots, enables, references and moves a simulated
drive that behaves as another vendor's EDS — or refuses the start naming drive, object and
remedy.

Each test writes a small AZ-ZD telescope (hardware file in ``tmp_path``) whose AZ drive uses
one fixture of ``tests/vcan/eds/`` (written by us, see ``make_fixtures.py``) both for the TCS
and for the simulated drive; ZD is the usual simulated drive. The service runs for real:
CANopen frames on a virtual bus, TPL2 over a socket. Waits are for states, never durations.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from support.opentci_client import Client, done_ok
from tcs.app import Service
from tcs.config import load_config
from tcs.errors import ConfigErrors

from support.service import make_config

EDS = Path(__file__).parent / "vcan" / "eds"

TEMPLATE = """
[server]
host = "127.0.0.1"
port = 0

[[users]]
name = "admin"
password = "pbkdf2_sha256$120000$glupqAhvSBwfMxoJeAHX/g==$OIS7/dlbJCTFBQtvuXE0R7DrrBch8ZDApDPUP0VlQFo="
rlevel = 0
wlevel = 0

[site]
latitude = 28.7606
longitude = -17.8792
height = 2326.0

[mount]
type = "AZ-ZD"
options = ["AZ-ZD"]

[can]
interface = "virtual"
channel = "tcs-test-vendor"
sync_period = 0.010
heartbeat_period = 0.1
boot_timeout = 5.0

[drives.az]
node_id = 1
eds = "{eds}"
heartbeat_period = 1.0
heartbeat_consumer_timeout = 5.0
identity = {{ {identity} }}
increments_per_unit = 10000.0
min_position = -200.0
max_position = 200.0
following_error_window = 5.0
max_velocity = 40.0
max_acceleration = 100.0
homing = {{ method = 37, timeout = 10.0 }}
{az_extra}

[drives.zd]
node_id = 2
heartbeat_period = 1.0
heartbeat_consumer_timeout = 5.0
identity = {{ vendor = 0xABC, product = 0x00402001, revision = 0x00010000, serial = 2 }}
increments_per_unit = 10000.0
min_position = -87.0
max_position = 87.0
following_error_window = 5.0
max_velocity = 40.0
max_acceleration = 100.0
homing = {{ method = 37, timeout = 10.0 }}

[axes.az]
module = "AZ"
drive = "az"
min = -180.0
max = 180.0
max_velocity = 20.0
max_acceleration = 40.0
max_jerk = 400.0
tolerance = 0.001

[axes.zd]
module = "ZD"
drive = "zd"
min = -85.0
max = 85.0
max_velocity = 20.0
max_acceleration = 40.0
max_jerk = 400.0
tolerance = 0.001

[simulation.drives.az]
max_velocity = 60.0
max_acceleration = 400.0
boot_time = 0.05
{sim_extra}

[simulation.drives.zd]
max_velocity = 60.0
max_acceleration = 400.0
boot_time = 0.05
"""

IDENTITY = "vendor = 0xABC, product = 0x00402001, revision = 0x00010000, serial = 1"


def write_config(tmp_path: Path, fixture: str, az_extra: str = "", sim_extra: str = "",
                 identity: str = IDENTITY) -> Path:
    path = tmp_path / "hw.toml"
    path.write_text(TEMPLATE.format(eds=(EDS / f"{fixture}.eds").as_posix(), identity=identity,
                                    az_extra=az_extra, sim_extra=sim_extra), encoding="utf-8")
    return path


async def ready_and_move(c: Client, target: float) -> None:
    """AZ powered, referenced and moved to ``target`` over TPL2."""
    if await c.value("CABINET.POWER_STATE") not in ("UNKNOWN", "1.0"):
        lines = await c.set("CABINET.POWER=1")
        assert done_ok(lines, "CABINET.POWER"), lines
    if await c.num("AZ.POWER_STATE") != 1.0:
        lines = await c.set("AZ.POWER=1")
    else:
        lines = ["DATA OK AZ.POWER", "COMMAND COMPLETE"]
    assert done_ok(lines, "AZ.POWER"), lines
    if await c.num("AZ.REFERENCED") < 1.0:
        await c.set("AZ.REINIT=0")
        await c.wait("AZ.REFERENCED", lambda v: v == 1.0)
    lines = await c.set(f"AZ.TARGETPOS={target}")
    assert done_ok(lines, "AZ.TARGETPOS"), lines
    assert abs(await c.num("AZ.REALPOS") - target) < 0.01


CASES = {
    "vendor-no-hbconsumer": ("", ""),
    "vendor-no-softlimits": ("", ""),
    "vendor-fe-limited": ("following_error_timeout = 0.0", ""),
    "vendor-no-homing": ("absolute = true", ""),
    # 4096 counts/rev motor, 100:1 gear, degrees: 1 °/s = 100/360 rev/s = 16.67 rpm
    "vendor-rpm": ("velocity_factor = 16.666666666666668\nacceleration_factor = 16.666666666666668",
                   "velocity_factor = 16.666666666666668\nacceleration_factor = 16.666666666666668"),
    "vendor-pdo-restricted": ("", ""),
    "vendor-revision": ("", "revision = 0x00020003"),
    # issue 21: drives without CSP, and three EDS defects
    "vendor-ip-only": ("", ""),
    "vendor-csv-only": ("", ""),
    "vendor-ip-no-607a-map": ("", ""),
    "vendor-homing-list": ("", ""),
    "vendor-hb16": ("", ""),
    "vendor-no-devtype-default": ("", ""),
    # issue 40: PDO layouts from the EDS, modes from what is mappable, absolute axes
    "vendor-pdo1-single": ("", ""),
    "vendor-tpdo2-empty": ("absolute = true", ""),
    "vendor-ip-nomodes": ("", "objects = { '0x6502:0' = 0x61 }"),
    "vendor-absolute-ro6098": ("absolute = true", ""),
    "vendor-no-modes-default": ("", "objects = { '0x6502:0' = 0x61 }"),  # CSP assumed, IP answered
}

#: The mode each fixture's drive must be run in (auto): the one its 0x6502 offers.
MODES = {"vendor-ip-only": 7, "vendor-csv-only": 9, "vendor-ip-no-607a-map": 7,
         "vendor-ip-nomodes": 7, "vendor-no-modes-default": 7}


@pytest.mark.parametrize("fixture", list(CASES))
async def test_vendor_drive_boots_enables_references_and_moves(tmp_path, fixture):
    az_extra, sim_extra = CASES[fixture]
    identity = IDENTITY
    if fixture == "vendor-revision":  # revision left out: another firmware is accepted
        identity = "vendor = 0xABC, product = 0x00402001, serial = 1"
    path = write_config(tmp_path, fixture, az_extra, sim_extra, identity)
    svc = Service(make_config(tmp_path / "state", path))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        await ready_and_move(c, 12.5)
        if fixture == "vendor-no-hbconsumer":  # said loudly: an axis WARNING in STATUS.LIST
            assert "no_heartbeat_consumer" in await c.value("CABINET.STATUS.LIST")
            assert int(await c.num("AZ.ERROR_STATE")) & 4
        else:
            assert "no_heartbeat_consumer" not in await c.value("CABINET.STATUS.LIST")
        if fixture == "vendor-revision":
            sim = svc.telescope.sims[1]
            assert sim.read_object(0x1018, 3) == 0x00020003
        sim = svc.telescope.sims[1]
        assert sim.mode_display == MODES.get(fixture, 8)  # the simulated drive moved in it
    finally:
        await c.close()
        await svc.stop()


@pytest.mark.parametrize("fixture, az_extra, key, needles", [
    ("vendor-no-csp", "", "axes.az.drive", ["drive az (node 1)", "0x6502", "CSP"]),
    ("vendor-no-csp", "default_mode = 'pp'", "axes.az.drive", ["0x6502", "CSP"]),
    ("vendor-fe-limited", "", "drives.az.following_error_timeout",
     ["drive az (node 1)", "0x6066", "= 50", "0..0", "vendor-fe-limited.eds"]),
    ("vendor-no-homing", "", "drives.az.eds", ["0x6098", "absolute = true"]),
    ("vendor-no-homing", "", "drives.az.homing", ["0x6502", "homing mode", "absolute = true"]),
    ("vendor-rpm", "velocity_factor = 1000.0", "drives.az.max_velocity",
     ["0x607F", "0..6000", "units/s"]),
    ("vendor-pdo-restricted", "pdo = { rpdo1 = ['0x6040', '0x607A'], tpdo1 = ['0x6041', '0x6064'], "
                              "tpdo3 = ['0x60FD', '0x603F'] }",
     "drives.az.pdo.tpdo3[1]", ["0x603F", "cannot be mapped"]),
])
def test_vendor_drive_refused_at_start_naming_drive_object_and_remedy(tmp_path, fixture, az_extra,
                                                                        key, needles):
    path = write_config(tmp_path, fixture, az_extra)
    with pytest.raises(ConfigErrors) as info:
        load_config(path)
    found = [e for e in info.value.errors if e.key == key]
    assert found, [e.message for e in info.value.errors]
    text = found[0].message
    assert text.startswith(f"{path}: {key}: "), text
    for needle in needles:
        assert needle in text, text


def test_homing_methods_an_eds_does_not_state_are_unknown_not_absent(tmp_path):
    """0x60E3 entries without a DefaultValue: method 19 is not refused (issue 21, defect 1)."""
    path = write_config(tmp_path, "vendor-homing-list")
    path.write_text(path.read_text().replace("homing = { method = 37, timeout = 10.0 }",
                                             "homing = { method = 19, timeout = 10.0 }", 1))
    config = load_config(path)
    assert config.drives["az"].homing.method == 19


def test_heartbeat_consumer_limit_bounds_the_time_only(tmp_path):
    """0x1016:1 = node 127 << 16 | 5000 ms against a HighLimit of 0xFFFF (defect 2) is fine;
    a time above it is refused naming the time part."""
    load_config(write_config(tmp_path, "vendor-hb16"))  # 5.0 s
    from tcs.drivers.eds_check import load_od, verdict
    od = load_od(EDS / "vendor-hb16.eds", 1)
    assert verdict(od, 0x1016, 1, 127 << 16 | 5000, True).action == "write"
    assert verdict(od, 0x1016, 1, 127 << 16 | 65535, True).action == "write"
    from tcs.sim.object_store import ObjectStore
    store = ObjectStore(od)
    store.write_value(od[0x1016][1], 127 << 16 | 5000)  # the simulated drive takes it too
    assert store.get(0x1016, 1) == 127 << 16 | 5000


@pytest.mark.parametrize("az_extra, key, needles", [
    ("", "axes.az.drive", ["drive az (node 1)", "0x6502", "= PP, PV, HM", "(CSP)", "(IP)",
                           "(CSV)", "remedy"]),
    ("mode = 'ip'", "drives.az.mode", ["drive az (node 1)", "0x6502", "PP, PV, HM",
                                       "interpolated position (IP)", "remedy"]),
])
def test_drive_without_a_cyclic_mode_is_refused_naming_the_modes(tmp_path, az_extra, key, needles):
    path = write_config(tmp_path, "vendor-no-csp", az_extra)
    with pytest.raises(ConfigErrors) as info:
        load_config(path)
    found = [e for e in info.value.errors if e.key == key]
    assert found, [e.message for e in info.value.errors]
    for needle in needles:
        assert needle in found[0].message, found[0].message


def test_auto_mode_prefers_csp_then_ip_then_csv_and_says_why():
    from tcs.config.can import DriveSection, IdentitySection
    from tcs.drivers.eds_check import SIM_EDS, drive_mode
    base = dict(identity=IdentitySection(), node_id=1, increments_per_unit=1.0, min_position=-1.0, max_position=1.0,
                following_error_window=1.0, max_velocity=1.0, max_acceleration=1.0)
    section = DriveSection(**base)
    assert drive_mode(section, SIM_EDS, 1).mode == "csp"  # the simulated drive offers all three
    ip = drive_mode(section, EDS / "vendor-ip-only.eds", 1)
    assert ip.mode == "ip" and "IP" in ip.reason and "0x6502" in ip.reason
    assert drive_mode(section, EDS / "vendor-csv-only.eds", 1).mode == "csv"
    assert drive_mode(DriveSection(**base, mode="csv"), SIM_EDS, 1).mode == "csv"


def test_simulation_section_describes_the_simulated_drive(tmp_path):
    from tcs.sim.drive_network import params_from_config
    path = write_config(tmp_path, "vendor-rpm", az_extra="velocity_factor = 30.0",
                        sim_extra="velocity_factor = 30.0\nrevision = 0x00020003\n"
                                                          "objects = { '0x2100:0' = 7 }",
                        identity="vendor = 0xABC, product = 0x00402001")
    params = params_from_config(load_config(path))
    az, zd = params[1], params[2]
    assert az.eds == str(EDS / "vendor-rpm.eds") and zd.eds is None
    assert az.velocity_scale == pytest.approx(30.0 / 10000.0) and az.acceleration_scale == 1.0
    assert az.identity == (0xABC, 0x00402001, 0x00020003, 1)
    assert az.boot_delay == 0.05 and az.objects == {(0x2100, 0): 7}


# ------------------------------------------------------------------------------- issue 40
async def test_absolute_axis_is_referenced_by_configuration_even_on_a_forced_reinit(tmp_path):
    """Read-only 0x6098, no homing mode, absolute = true: REFERENCED is 1 after power, and a
    REINIT=1 (force) completes at once — nothing waits for a homing run that never comes."""
    path = write_config(tmp_path, "vendor-absolute-ro6098", "absolute = true")
    svc = Service(make_config(tmp_path / "state", path))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        lines = await c.set("CABINET.POWER=1")
        assert done_ok(lines, "CABINET.POWER"), lines
        assert await c.num("AZ.REFERENCED") == 1.0
        lines = await c.set("AZ.REINIT=1")
        assert done_ok(lines, "AZ.REINIT"), lines
        await c.wait("AZ.REFERENCED", lambda v: v == 1.0)
        await ready_and_move(c, -7.5)
        assert svc.telescope.sims[1].mode_display == 8  # never homing mode (6)
    finally:
        await c.close()
        await svc.stop()


def _derived(tmp_path: Path, fixture: str, drop: tuple[str, ...]) -> str:
    """Fixture ``fixture`` without the EDS sections named in ``drop`` (and their sub-indices)."""
    import re
    text = (EDS / f"{fixture}.eds").read_text(encoding="utf-8")
    parts = re.split(r"(?m)^(?=\[)", text)
    keep = [p for p in parts if not any(re.match(rf"\[{d}(sub[0-9A-Fa-f]+)?\]", p) for d in drop)]
    out = tmp_path / f"{fixture}-derived.eds"
    out.write_text("".join(keep), encoding="utf-8")
    return out.as_posix()


def test_a_layout_that_cannot_fit_names_the_objects_and_the_pdos_tried(tmp_path):
    """RPDO1 takes one object and there is no other RPDO: no mode's setpoint fits. Refused at
    start (load_config, as --check-config), naming drive, object, the PDOs tried, a remedy."""
    eds = _derived(tmp_path, "vendor-pdo1-single", ("1401", "1402", "1403", "1601", "1602", "1603"))
    path = tmp_path / "hw.toml"
    path.write_text(TEMPLATE.format(eds=eds, identity=IDENTITY, az_extra="", sim_extra=""),
                    encoding="utf-8")
    with pytest.raises(ConfigErrors) as info:
        load_config(path)
    found = [e.message for e in info.value.errors if e.key == "drives.az.pdo"]
    assert found, [e.message for e in info.value.errors]
    text = found[0]
    for needle in ("drive az (node 1)", "0x607A (target_position) does not fit", "tried RPDO1 (1 entry)",
                   "already used: RPDO1 = 0x6040", "remedy:"):
        assert needle in text, text
    assert "acknowledge" not in text


@pytest.mark.parametrize("fixture, pdo, key, needles", [
    ("vendor-tpdo2-empty", "pdo = { rpdo1 = ['0x6040', '0x607A'], tpdo1 = ['0x6041', '0x6064'], "
                           "tpdo2 = ['0x606C', '0x60F4'] }",
     "drives.az.pdo.tpdo2", ["maps 2 objects", "TPDO2 takes at most 0", "remedy: leave pdo out"]),
    ("vendor-pdo1-single", "pdo = { rpdo1 = ['0x6040', '0x607A'], tpdo1 = ['0x6041', '0x6064'] }",
     "drives.az.pdo.rpdo1", ["RPDO1 takes at most 1", "remedy: leave pdo out"]),
])
def test_a_hand_written_layout_the_drive_cannot_take_is_refused_at_start(tmp_path, fixture, pdo,
                                                                         key, needles):
    """Found at start (never at power-on) with a remedy that can work: leave pdo out, and the
    TCS lays the PDOs out itself."""
    path = write_config(tmp_path, fixture, pdo + ("\nabsolute = true" if "tpdo2" in fixture else ""))
    with pytest.raises(ConfigErrors) as info:
        load_config(path)
    found = [e.message for e in info.value.errors if e.key == key]
    assert found, [e.message for e in info.value.errors]
    for needle in ["drive az (node 1)", *needles]:
        assert needle in found[0], found[0]


@pytest.mark.parametrize("fixture, sim_extra, offered, mode, layout", [
    ("vendor-pdo1-single", "", "PP, PV, HM, IP, CSP, CSV", "CSP",
     ["RPDO1 0x201 SYNC: 0x6040 controlword", "RPDO2 0x301 SYNC: 0x607A target_position"]),
    ("vendor-tpdo2-empty", "", "PP, PV, HM, IP, CSP, CSV", "CSP",
     ["TPDO1 0x181 SYNC: 0x6041 statusword + 0x6064 position_actual",
      "TPDO3 0x381 SYNC: 0x606C velocity_actual + 0x60F4 following_error_actual"]),
    ("vendor-ip-nomodes", "objects = { '0x6502:0' = 0x61 }", "PP, HM, IP", "IP",
     ["RPDO1 0x201 SYNC: 0x6040 controlword + 0x60C1:1 ip_data_record"]),
    ("vendor-absolute-ro6098", "", "PP, PV, CSP, CSV", "CSP",
     ["RPDO1 0x201 SYNC: 0x6040 controlword + 0x607A target_position"]),
])
def test_scan_shows_offered_modes_chosen_mode_and_pdo_layout(tmp_path, capsys, fixture, sim_extra,
                                                             offered, mode, layout):
    import json
    import uuid
    from tcs.commission.cli import main
    az_extra = "absolute = true" if fixture in ("vendor-tpdo2-empty", "vendor-absolute-ro6098") else ""
    path = write_config(tmp_path, fixture, az_extra, sim_extra)
    path.write_text(path.read_text().replace('channel = "tcs-test-vendor"',
                                             f'channel = "tcs-scan-{uuid.uuid4().hex[:8]}"'))
    assert main(["scan", "--config", str(path), "--nodes", "1-2", "--json"]) == 0
    az = next(n for n in json.loads(capsys.readouterr().out)["nodes"] if n["node_id"] == 1)
    assert az["offered"] == offered and az["tcs_mode"] == mode, az
    for line in layout:
        assert any(entry.startswith(line) for entry in az["pdo_layout"]), az["pdo_layout"]
    assert az["pdo_problems"] == []
    main(["scan", "--config", str(path), "--nodes", "1"])  # the text form says the same
    text = capsys.readouterr().out
    assert f"modes offered: {offered}; the TCS uses {mode}" in text and "PDO layout (from the EDS):" in text
    assert all(line in text for line in layout), text


@pytest.mark.parametrize("quirk", ["cp1252", "bom", "repeats"])
def test_eds_files_as_vendors_write_them_are_read_by_tcs_and_simulator(tmp_path, quirk):
    """Windows-1252 text, a byte-order mark, a key or section written twice: the TCS and the
    simulated drive read the file alike (the first value of a repeated key counts)."""
    from tcs.drivers.eds import load_od, supported_modes
    from tcs.sim.cia402_drive import _load_od
    text = (EDS / "vendor-ip-only.eds").read_text(encoding="utf-8")
    text = text.replace("ParameterName=Target position", "ParameterName=Target position (°)")
    if quirk == "repeats":
        text = text.replace("[6502]\n", "[6502]\nDefaultValue=0x00000121\n", 1)
        text += "\n[6502]\nParameterName=again\n"
    data = text.encode("cp1252" if quirk == "cp1252" else "utf-8")
    if quirk == "bom":
        data = b"\xef\xbb\xbf" + data
    path = tmp_path / f"{quirk}.eds"
    path.write_bytes(data)
    for od in (load_od(path, 1), _load_od(path, 1)):
        assert od[0x607A].name == "Target position (°)"
        assert supported_modes(od) == (0x121 if quirk == "repeats" else 0x61)
        assert od[0x6502].name == "Supported drive modes"
    hw = tmp_path / "hw.toml"
    hw.write_text(TEMPLATE.format(eds=path.as_posix(), identity=IDENTITY, az_extra="", sim_extra=""),
                  encoding="utf-8")
    assert load_config(hw).drives["az"].eds == path.as_posix()  # the start check read it too


async def test_a_pdo_mapping_written_with_compactsubobj_takes_its_n_entries(tmp_path):
    """0x1600 as an ARRAY with CompactSubObj=8 (canopen keeps only its sub-index 1): both the
    TCS and the simulated drive see eight entries; the axis moves."""
    import re
    text = (EDS / "vendor-pdo1-single.eds").read_text(encoding="utf-8")
    parts = re.split(r"(?m)^(?=\[)", text)
    parts = [p for p in parts if not re.match(r"\[1600(sub[0-9A-Fa-f]+)?\]", p)]
    parts.append("[1600]\nParameterName=RPDO1 mapping parameter\nObjectType=0x8\nDataType=0x0007\n"
                 "AccessType=rw\nDefaultValue=0x60400010\nPDOMapping=0\nCompactSubObj=8\n\n")
    path = tmp_path / "compact.eds"
    path.write_text("".join(parts), encoding="utf-8")
    from tcs.drivers.eds import load_od
    from tcs.drivers.pdo import pdo_slots
    assert pdo_slots(load_od(path, 1), True, 1)[0].entries == 8
    hw = tmp_path / "hw.toml"
    hw.write_text(TEMPLATE.format(eds=path.as_posix(), identity=IDENTITY, az_extra="", sim_extra=""),
                  encoding="utf-8")
    svc = Service(make_config(tmp_path / "state", hw))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        await ready_and_move(c, 4.0)
        sim = svc.telescope.sims[1]
        assert [sim.read_object(0x1600, i) for i in range(3)] == [2, 0x60400010, 0x607A0020]
    finally:
        await c.close()
        await svc.stop()


async def test_a_mode_the_drive_does_not_offer_found_at_boot_names_a_remedy_not_acknowledge(tmp_path):
    """The EDS states no 0x6502, mode = 'csp' is configured, the drive answers PP, HM, IP: the
    boot fails naming drive, 0x6502 and the remedy (mode = 'ip'); POWER says so and does not
    advise an acknowledge that cannot help."""
    path = write_config(tmp_path, "vendor-no-modes-default", "mode = 'csp'",
                        "objects = { '0x6502:0' = 0x61 }")
    svc = Service(make_config(tmp_path / "state", path))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        lines = await c.set("CABINET.POWER=1")
        text = " ".join(lines)
        assert not done_ok(lines, "CABINET.POWER"), lines
        for needle in ("drive az (node 1)", "0x6502", "PP, HM, IP", "read from the drive over SDO",
                       "remedy: mode = 'ip'"):
            assert needle in text, lines
        assert "acknowledge" not in text, lines
    finally:
        await c.close()
        await svc.stop()


async def test_no_homing_mode_in_the_drives_answer_fails_the_boot_with_the_absolute_remedy(tmp_path):
    """0x6502 unknown at start, the drive answers PP, PV, CSP (no homing mode) and the axis is
    not absolute: the boot says so with the remedy, instead of a homing run that cannot start."""
    path = write_config(tmp_path, "vendor-no-modes-default", "", "objects = { '0x6502:0' = 0x85 }")
    svc = Service(make_config(tmp_path / "state", path))
    port = await svc.start()
    c = await Client.connect(port)
    try:
        lines = await c.set("CABINET.POWER=1")
        text = " ".join(lines)
        assert not done_ok(lines, "CABINET.POWER"), lines
        for needle in ("drive az (node 1)", "0x6502", "no homing mode", "remedy: absolute = true"):
            assert needle in text, lines
        assert "acknowledge" not in text, lines
    finally:
        await c.close()
        await svc.stop()
