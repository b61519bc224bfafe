"""The driver's pure tables: CiA-402 states and transitions, homing bits, EMCY codes, PDO layouts."""

import struct

import pytest

from tcs.config.can import DEFAULT_PDO_MAPPING
from tcs.drivers import cia402 as sm
from tcs.drivers.cia402 import HomingBits, Want
from tcs.drivers.drive import DriveState as S
from tcs.drivers.emcy import decode_emcy, describe
from tcs.drivers.pdo import EVENT, SYNCHRONOUS, configuration_writes, layouts
from tcs.errors import ErrorNumber

# Statusword values of docs/cia402.md (with unrelated bits set to show the masks work).
STATUSWORDS = [
    (0x0000, S.NOT_READY), (0x0040, S.SWITCH_ON_DISABLED), (0x0250, S.SWITCH_ON_DISABLED),
    (0x0021, S.READY_TO_SWITCH_ON), (0x0231, S.READY_TO_SWITCH_ON), (0x0023, S.SWITCHED_ON),
    (0x0027, S.OPERATION_ENABLED), (0x1637, S.OPERATION_ENABLED), (0x0007, S.QUICK_STOP_ACTIVE),
    (0x000F, S.FAULT_REACTION_ACTIVE), (0x0008, S.FAULT), (0x0218, S.FAULT),
]


@pytest.mark.parametrize("statusword, state", STATUSWORDS)
def test_statusword_decodes_to_its_state(statusword, state):
    assert sm.decode_state(statusword) is state


# What the drive does with a controlword, per docs/cia402.md (transition -> next state).
DRIVE = {
    (S.SWITCH_ON_DISABLED, sm.SHUTDOWN): S.READY_TO_SWITCH_ON,        # 2
    (S.READY_TO_SWITCH_ON, sm.SWITCH_ON): S.SWITCHED_ON,              # 3
    (S.READY_TO_SWITCH_ON, sm.ENABLE_OPERATION): S.OPERATION_ENABLED,  # 3+4
    (S.SWITCHED_ON, sm.ENABLE_OPERATION): S.OPERATION_ENABLED,        # 4
    (S.OPERATION_ENABLED, sm.SWITCH_ON): S.SWITCHED_ON,               # 5
    (S.SWITCHED_ON, sm.SHUTDOWN): S.READY_TO_SWITCH_ON,               # 6
    (S.READY_TO_SWITCH_ON, sm.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 7
    (S.OPERATION_ENABLED, sm.SHUTDOWN): S.READY_TO_SWITCH_ON,         # 8
    (S.OPERATION_ENABLED, sm.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 9
    (S.SWITCHED_ON, sm.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,        # 10
    (S.OPERATION_ENABLED, sm.QUICK_STOP): S.QUICK_STOP_ACTIVE,        # 11
    (S.QUICK_STOP_ACTIVE, sm.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,  # 12
    (S.READY_TO_SWITCH_ON, sm.QUICK_STOP): S.SWITCH_ON_DISABLED,      # 7
    (S.SWITCHED_ON, sm.QUICK_STOP): S.SWITCH_ON_DISABLED,             # 10
}


@pytest.mark.parametrize("want, goal", [(Want.ENABLED, S.OPERATION_ENABLED),
                                        (Want.DISABLED, S.SWITCH_ON_DISABLED)])
@pytest.mark.parametrize("start", [S.SWITCH_ON_DISABLED, S.READY_TO_SWITCH_ON, S.SWITCHED_ON,
                                   S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE])
def test_table_reaches_the_wanted_state_one_hop_per_cycle(want, goal, start):
    state, hops = start, 0
    while state is not goal:
        state = DRIVE[state, sm.controlword(want, state)]
        hops += 1
        assert hops <= 4
    assert sm.controlword(want, goal) in (sm.ENABLE_OPERATION, sm.DISABLE_VOLTAGE)


def test_quick_stop_from_operation_enabled_is_transition_11():
    assert DRIVE[S.OPERATION_ENABLED, sm.controlword(Want.QUICK_STOP, S.OPERATION_ENABLED)] is S.QUICK_STOP_ACTIVE


@pytest.mark.parametrize("state", [S.FAULT, S.FAULT_REACTION_ACTIVE, S.NOT_READY, None])
@pytest.mark.parametrize("want", list(Want))
def test_fault_and_unknown_states_get_disable_voltage_never_a_reset(want, state):
    # Leaving Fault needs the explicit fault reset (bit 7), which the table never sends.
    assert sm.controlword(want, state) == sm.DISABLE_VOLTAGE


def test_every_table_row_names_its_transition():
    assert all(transition for _, transition in sm.TABLE.values())


@pytest.mark.parametrize("statusword, bits", [
    (0x0000, HomingBits.RUNNING), (0x0400, HomingBits.IDLE), (0x1000, HomingBits.ATTAINED),
    (0x1400, HomingBits.DONE), (0x2000, HomingBits.ERROR_MOVING), (0x3400, HomingBits.ERROR_AT_REST),
    (0x1637, HomingBits.DONE),
])
def test_homing_bits(statusword, bits):
    assert sm.homing_bits(statusword) is bits


@pytest.mark.parametrize("code, number, text", [
    (0x8611, ErrorNumber.LIBFAIL, "following error"),
    (0x8612, ErrorNumber.LIMIT, "position limit reached"),
    (0x8130, ErrorNumber.NOCON, "heartbeat of the TCS lost (life guard)"),
    (0x8110, ErrorNumber.CONFAIL, "CAN overrun: frames lost"),
    (0x81AA, ErrorNumber.CONFAIL, "CAN communication error"),
    (0x2310, ErrorNumber.LIBFAIL, "over-current"),
    (0x2399, ErrorNumber.LIBFAIL, "current error"),
    (0x7305, ErrorNumber.LIBFAIL, "incremental encoder fault"),
    (0xFF01, ErrorNumber.LIMIT, "negative limit switch"),
    (0xFF77, ErrorNumber.LIBFAIL, "device-specific error"),
    (0x0100, ErrorNumber.LIBFAIL, "error"),
])
def test_emcy_codes(code, number, text):
    assert describe(code) == (text, number)


def test_emcy_frame_decoding():
    fault = decode_emcy("drive az (node 1)", bytes([0x11, 0x86, 0x80, 1, 2, 0, 0, 0]))
    assert fault.code == 0x8611 and fault.register == 0x80 and fault.number == ErrorNumber.LIBFAIL
    assert str(fault) == "drive az (node 1): following error (error code 0x8611, data 0102000000)"
    assert decode_emcy("d", bytes(8)) is None          # error reset
    assert decode_emcy("d", b"\x10\x23").code == 0x2310  # short frames are padded, not dropped


def test_default_pdo_layouts_and_codecs():
    pdos = layouts(DEFAULT_PDO_MAPPING, 5)
    assert {n: p.cob_id for n, p in pdos.items()} == {"rpdo1": 0x205, "tpdo1": 0x185,
                                                       "tpdo2": 0x285, "tpdo3": 0x385}
    assert [pdos[n].transmission for n in ("rpdo1", "tpdo1", "tpdo2", "tpdo3")] == \
        [SYNCHRONOUS, SYNCHRONOUS, SYNCHRONOUS, EVENT]
    assert pdos["rpdo1"].codec.pack(0x000F, -12345) == struct.pack("<Hi", 0x000F, -12345)
    assert pdos["tpdo2"].codec.size == 8 and pdos["rpdo1"].bits == 48


def test_remap_procedure_order():
    pdo = layouts(DEFAULT_PDO_MAPPING, 3)["tpdo3"]
    writes = configuration_writes(pdo, "tpdo3", 3)
    assert writes == [
        (0x1802, 1, "<I", 0x80000383),   # invalidate
        (0x1802, 2, "<B", EVENT),
        (0x1802, 3, "<H", 100),          # inhibit 10 ms
        (0x1802, 5, "<H", 500),          # event timer
        (0x1A02, 0, "<B", 0),            # sub0 = 0
        (0x1A02, 1, "<I", 0x60FD0020),
        (0x1A02, 2, "<I", 0x603F0010),
        (0x1A02, 0, "<B", 2),            # sub0 = n
        (0x1802, 1, "<I", 0x383),        # validate
    ]
    assert configuration_writes(None, "rpdo2", 3) == [(0x1401, 1, "<I", 0x80000303)]


# --- the handshakes, fed statuswords by hand ---------------------------------------------
from tcs.drivers.drive import Progress  # noqa: E402
from tcs.drivers.handshakes import HomingRun, ProfileMove  # noqa: E402

OE = 0x0027  # Operation enabled


def test_homing_handshake_sequence():
    run = HomingRun("d", 17, timeout=10.0, now=0.0)
    script = [  # (statusword seen, bit 4 expected)
        (OE | 0x0400, 0),            # idle (001): bit 4 stays low one cycle
        (OE | 0x0400, 0x10),         # start: bit 4 high
        (OE, 0x10),                  # running (000)
        (OE | 0x1000, 0x10),         # attained, still moving (010)
        (OE | 0x1400, 0),            # done (011): bit 4 low
        (OE | 0x1400, 0),            # finished
    ]
    for i, (sw, bits) in enumerate(script):
        assert run.step(0.01 * i, sw) == bits, i
    assert run.progress is Progress.DONE and run.fraction == 1.0


def test_homing_ignores_the_previous_runs_error_but_not_a_new_one():
    run = HomingRun("d", 17, timeout=10.0, now=0.0)
    assert run.step(0.0, OE | 0x2400) == 0     # old "error at rest" while bit 4 is low
    assert run.step(0.01, OE | 0x2400) == 0x10  # start, the drive has not reacted yet
    assert run.progress is Progress.RUNNING
    assert run.step(0.02, OE) == 0x10           # running
    assert run.step(0.03, OE | 0x2000) == 0     # error while moving
    assert run.progress is Progress.FAILED and "homing error (method 17" in str(run.error)


def test_homing_time_out_and_instant_methods():
    run = HomingRun("d", 33, timeout=1.0, now=0.0)
    run.step(0.0, OE | 0x0400)
    run.step(0.1, OE)
    assert run.step(1.5, OE) == 0 and run.progress is Progress.FAILED
    assert run.error.number == ErrorNumber.TIMEOUT
    run = HomingRun("d", 37, timeout=1.0, now=0.0)  # already "done" from an earlier run
    run.step(0.0, OE | 0x1400)
    run.step(0.01, OE | 0x1400)
    run.step(0.1, OE | 0x1400)  # still done after bit 4: the drive re-homed at once
    assert run.step(0.11, OE | 0x1400) == 0  # bit 4 low again
    run.step(0.12, OE | 0x1400)
    assert run.progress is Progress.DONE


def test_profile_move_handshake():
    move = ProfileMove("d", target=1000, window=5, deadline=10.0, now=0.0, velocity_job=None, scale=1.0)
    assert move.step(0.0, OE | 0x0400, 0) == 0          # idle: no acknowledge pending
    assert move.step(0.01, OE | 0x0400, 0) == 0x30      # new set-point + change immediately
    assert move.step(0.02, OE | 0x1000, 10) == 0        # acknowledged: bit 4 low
    assert move.step(0.03, OE, 500) == 0 and move.progress is Progress.RUNNING
    assert move.step(0.04, OE | 0x0400, 998) == 0
    assert move.progress is Progress.DONE


def test_profile_move_without_acknowledge_fails():
    move = ProfileMove("d", target=1000, window=5, deadline=10.0, now=0.0, velocity_job=None, scale=1.0)
    move.step(0.0, OE, 0)
    move.step(0.01, OE, 0)
    move.step(2.0, OE, 0)
    assert move.progress is Progress.FAILED and "not acknowledged" in str(move.error)
