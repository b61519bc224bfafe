"""The [can] and [drives.<name>] tables: good files load, bad ones are named precisely."""

import pytest

from tcs.config import parse_config
from tcs.config.can import DEFAULT_PDO_MAPPING, interpolation_period, pdo_mapping
from tcs.errors import ConfigErrors

DRIVE = """
[drives.{name}]
node_id = {node}
identity = {{ vendor = 0xABC, product = 0x402001, revision = 0x10000 }}
increments_per_unit = 10000.0
min_position = -90.0
max_position = 90.0
following_error_window = 0.5
max_velocity = 3.0
max_acceleration = 2.0
{extra}
"""


def drive(name="az", node=1, extra=""):
    return DRIVE.format(name=name, node=node, extra=extra)


def problems(text: str) -> list[str]:
    with pytest.raises(ConfigErrors) as info:
        parse_config(text, "bad.toml")
    return [e.message for e in info.value.errors]


def test_a_minimal_bus_and_two_drives_load():
    config = parse_config("[can]\n" + drive("az", 1) + drive("alt", 2, "default_mode = 'pp'"))
    assert config.can.interface == "virtual" and config.can.sync_period == 0.010
    assert set(config.drives) == {"az", "alt"}
    assert config.drives["alt"].default_mode == "pp"
    assert config.drives["az"].mapping == DEFAULT_PDO_MAPPING
    assert config.drives["az"].homing.method == 37


def test_identity_fields_left_out_are_not_checked():
    text = "[can]\n" + drive(extra="identity = { vendor = 1, product = 2 }").replace(
        "identity = { vendor = 0xABC, product = 0x402001, revision = 0x10000 }\n", "")
    ident = parse_config(text).drives["az"].identity
    assert (ident.vendor, ident.product, ident.revision, ident.serial) == (1, 2, None, None)


def test_new_drive_keys_load_with_their_defaults():
    config = parse_config("[can]\n" + drive(extra="velocity_factor = 16.5\nabsolute = true\n"
                                                   "sdo = { '0x6091:1' = 100, '0x6091:2' = 1, '0x6067:0' = 5 }"))
    az = config.drives["az"]
    assert az.velocity_scale == 16.5 and az.acceleration_scale == 10000.0 and az.absolute
    assert az.raw_writes == [("0x6091:1", 0x6091, 1, 100), ("0x6091:2", 0x6091, 2, 1),
                             ("0x6067:0", 0x6067, 0, 5)]  # file order
    assert (az.enable_timeout, az.fault_reset_timeout, az.mode_switch_timeout) == (2.0, 1.0, 1.0)
    assert az.sdo_timeout is None and az.sdo_retries == 1


def test_no_can_section_means_no_bus():
    config = parse_config("")
    assert config.can is None and config.drives == {}


def test_socketcand_options_become_bus_arguments():
    config = parse_config('[can]\ninterface = "socketcand"\nchannel = "can0"\nport = 29999\n'
                          'options = { tcp_tune = "true", x = "5" }\n')
    assert config.can.bus_kwargs() == {"interface": "socketcand", "channel": "can0",
                                       "host": "127.0.0.1", "port": 29999, "tcp_tune": True, "x": 5}


@pytest.mark.parametrize("seconds, expected", [
    (0.010, (10, -3)), (0.004, (4, -3)), (0.0025, (25, -4)), (0.00125, (125, -5)),
    (0.1, (100, -3)), (0.001001, None), (0.0000005, None),
])
def test_interpolation_period(seconds, expected):
    assert interpolation_period(seconds) == expected


@pytest.mark.parametrize("text, expected", [
    ("[can]\ninterface = 'kvaser'\n", "bad.toml: can.interface: must be one of"),
    ("[can]\nsync_period = 0.0005\n", "bad.toml: can.sync_period: 0.0005 is out of range"),
    ("[can]\nsync_period = 0.2\n", "bad.toml: can.sync_period: 0.2 is out of range"),
    ("[can]\nsync_period = 0.0010015\n", "bad.toml: can.sync_period: 0.0010015 s is not a whole number of µs"),
    ("[can]\nidle_sync_period = 0.015\n", "bad.toml: can.idle_sync_period: must be 0 (off) or a whole multiple"),
    ("[can]\nidle_sync_period = 0.01\n", "bad.toml: can.idle_sync_period: must be 0 (off) or a whole multiple"),
    ("[can]\nidle_sync_period = 0.2\n", "bad.toml: can.idle_sync_period: must be at most heartbeat_period"),
    ("[can]\nheartbeat_period = 0.0105\n", "bad.toml: can.heartbeat_period: must be a whole number of milliseconds"),
    ("[can]\noptions = { channel = 'x' }\n", "bad.toml: can.options.channel: set it in [can] itself"),
    ("[can]\nnode_id = 0\n", "bad.toml: can.node_id: 0 is out of range"),
    (drive(), "bad.toml: can: drives are configured but there is no [can] section"),
    ("[can]\n" + drive(node=128), "bad.toml: drives.az.node_id: 128 is out of range"),
    ("[can]\n" + drive(node=0), "bad.toml: drives.az.node_id: 0 is out of range"),
    ("[can]\n" + drive("az", 3) + drive("alt", 3), "bad.toml: drives.alt.node_id: node id 3 is already used by drive 'az'"),
    ("[can]\nnode_id = 5\n" + drive(node=5), "bad.toml: drives.az.node_id: node id 5 is the TCS's own"),
    ("[can]\n" + drive().replace("max_position = 90.0", "max_position = -100.0"), "bad.toml: drives.az.max_position: must be above min_position"),
    ("[can]\n" + drive(extra="increments_per_unit = 0.0").replace("increments_per_unit = 10000.0\n", ""),
     "bad.toml: drives.az.increments_per_unit: must not be zero"),
    ("[can]\n" + drive(extra="homing = { method = 3 }"), "bad.toml: drives.az.homing.method: must be one of"),
    ("[can]\n" + drive().replace("identity = { vendor = 0xABC, product = 0x402001, revision = 0x10000 }\n", ""),
     "bad.toml: drives.az.identity: missing"),
    ("[can]\nsync_period = 0.002\n" + drive(extra="min_sync_period = 0.004"),
     "bad.toml: can.sync_period: 0.002 s is shorter than drive 'az' accepts"),
    ("[can]\nheartbeat_period = 0.5\n" + drive(),
     "bad.toml: drives.az.heartbeat_consumer_timeout: must be at least 1.5 × can.heartbeat_period"),
    ("[can]\n" + drive("bad-name", 1), "bad.toml: drives.bad-name: drive names are letters"),
    ("[can]\n" + drive(extra="velocity_factor = -3.0"), "bad.toml: drives.az.velocity_factor: must be positive"),
    ("[can]\n" + drive(extra="sdo = { '6091:1' = 1 }"), "bad.toml: drives.az.sdo.6091:1: write entries as"),
    ("[can]\n" + drive(extra="sdo = { '0x6091:1' = 'x' }"), "bad.toml: drives.az.sdo.0x6091:1: must be an integer"),
    ("[can]\n" + drive(extra="sdo = { '0x6091:3' = 1 }"),
     "bad.toml: drives.az.sdo.0x6091:3: drive az (node 1): the drive has no object 0x6091:3"),
    ("[can]\nidle_sync_period = 0.05\n" + drive(extra="sdo = { '0x1006:0' = 5000 }"),
     "bad.toml: drives.az.sdo.0x1006:0: the idle SYNC (can.idle_sync_period) writes this object"),
    ("[can]\nidle_sync_period = 0.05\n" + drive(extra="sdo = { '0x1400:5' = 100 }"),
     "bad.toml: drives.az.sdo.0x1400:5: the idle SYNC (can.idle_sync_period) writes this object"),
    ("[can]\n" + drive(extra="enable_timeout = 0.0"), "bad.toml: drives.az.enable_timeout: 0.0 is out of range"),
    ("[can]\n" + drive(extra="following_error_timeout = 70.0"),
     "bad.toml: drives.az.following_error_timeout: 70.0 is out of range"),
])
def test_problem_is_named(text, expected):
    found = problems(text)
    assert any(p.startswith(expected) for p in found), found


@pytest.mark.parametrize("override, expected", [
    ({"rpdo1": ("0x6040", "0x607A", "0x60B1")}, ("pdo.rpdo1", "maps 80 bits; a PDO carries at most 64")),
    ({"rpdo1": ("0x6040",), "tpdo1": ("0x6041", "0x6064")}, ("pdo.rpdo1", "must map a setpoint: 0x607A")),
    ({"rpdo1": ("0x6040", "0x607A")}, ("pdo", "a TPDO must map 0x6041")),
    ({"rpdo2": ("0x60B1",)}, ("pdo.rpdo2", "unknown PDO")),
    ({"tpdo1": ("0x6041", "0x2000")}, ("pdo.tpdo1[1]", "'0x2000' is not an object the driver maps")),
    ({"tpdo1": ("0x6040",)}, ("pdo.tpdo1[0]", "0x6040 cannot go into a transmit PDO")),
    ({"tpdo1": ("0x6041", "0x6064"), "tpdo2": ("0x6064",)}, ("pdo.tpdo2[0]", "0x6064 is already mapped in tpdo1")),
])
def test_pdo_override_problems(override, expected):
    _, found = pdo_mapping(override)
    assert any(k == expected[0] and expected[1] in p for k, p in found), found


def test_pdo_override_too_long_is_refused_with_its_key_path():
    text = "[can]\n" + drive(extra="pdo = { rpdo1 = ['0x6040', '0x607A', '0x60B1'], "
                                   "tpdo1 = ['0x6041', '0x6064'] }")
    assert any(p.startswith("bad.toml: drives.az.pdo.rpdo1: maps 80 bits") for p in problems(text))


def test_pdo_override_that_fits_replaces_the_default():
    text = "[can]\n" + drive(extra="pdo = { rpdo1 = ['0x6040', '0x607A'], "
                                   "tpdo1 = ['0x6041', '0x6064'], tpdo2 = ['0x60FD', '0x603F', '0x6061'] }")
    mapping = parse_config(text).drives["az"].mapping
    assert mapping == {"rpdo1": (0x6040, 0x607A), "tpdo1": (0x6041, 0x6064),
                       "tpdo2": (0x60FD, 0x603F, 0x6061)}


def test_every_problem_of_a_drive_is_reported_at_once():
    text = "[can]\n" + drive(extra="following_error_window = -1.0\nmax_velocity = 0.0").replace(
        "following_error_window = 0.5\nmax_velocity = 3.0\n", "")
    found = problems(text)
    assert any("following_error_window: must be positive" in p for p in found)
    assert any("max_velocity: must be positive" in p for p in found)
