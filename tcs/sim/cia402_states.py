"""The CiA-402 power state machine of the simulated drive, as tables (device side).

``step(state, controlword)`` gives the state a device enters when the master writes a
controlword, with the standard's transition number; automatic transitions (0/1 at power-up,
12 at the end of the quick-stop ramp, 14 at the end of the fault reaction) and fault
transition 13 are taken by the drive logic itself, named here for the record.

Quick-stop option code 0x605A decides where "Quick stop active" leads: 1–4 end in Switch on
disabled when the motion has stopped (transition 12; 1/5 slow-down ramp, 2/6 quick-stop ramp,
3/7 current limit, 4/8 voltage limit — the simulator ramps with the profile deceleration for
1/5 and with the quick-stop deceleration otherwise); 5–8 stay in Quick stop active until the
master enables operation again (transition 16); 0 disables the drive at once (coasting to
standstill through the brake).

Fault reset (transition 15) happens on the *rising edge* of controlword bit 7 only, and leads
to Switch on disabled, never further.
"""

from __future__ import annotations

import enum


class State(enum.Enum):
    NOT_READY_TO_SWITCH_ON = "NOT READY TO SWITCH ON"
    SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
    READY_TO_SWITCH_ON = "READY TO SWITCH ON"
    SWITCHED_ON = "SWITCHED ON"
    OPERATION_ENABLED = "OPERATION ENABLED"
    QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
    FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
    FAULT = "FAULT"


S = State

#: Statusword bits 0–6 of each state (bit 5 "quick stop" is active low: 1 = not quick-stopping).
STATUS_BITS: dict[State, int] = {
    S.NOT_READY_TO_SWITCH_ON: 0x00,
    S.SWITCH_ON_DISABLED: 0x40,
    S.READY_TO_SWITCH_ON: 0x21,
    S.SWITCHED_ON: 0x23,
    S.OPERATION_ENABLED: 0x27,
    S.QUICK_STOP_ACTIVE: 0x07,
    S.FAULT_REACTION_ACTIVE: 0x0F,
    S.FAULT: 0x08,
}

#: States in which the power stage drives the motor.
POWERED = frozenset({S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE, S.FAULT_REACTION_ACTIVE})
#: States with voltage applied (statusword bit 4 "voltage enabled").
VOLTAGE = frozenset({S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE,
                     S.FAULT_REACTION_ACTIVE})

# Controlword commands: (mask, value) on bits 0-3 and 7, as in CiA-402 table "device control
# commands". Bit 2 (quick stop) is active low.
SHUTDOWN = "shutdown"                 # xxxx x110
SWITCH_ON = "switch on"               # xxxx 0111
ENABLE_OPERATION = "enable operation"  # xxxx 1111
DISABLE_VOLTAGE = "disable voltage"   # xxxx xx0x
QUICK_STOP = "quick stop"             # xxxx x01x


def command_of(controlword: int) -> str:
    """The device control command a controlword encodes (bit 7 handled separately)."""
    if not controlword & 0x02:
        return DISABLE_VOLTAGE
    if not controlword & 0x04:
        return QUICK_STOP
    if controlword & 0x07 == 0x06:
        return SHUTDOWN
    if controlword & 0x0F == 0x07:
        return SWITCH_ON
    return ENABLE_OPERATION  # xxxx 1111


# (state, command) -> (new state, transition number). Absent pairs leave the state unchanged.
TRANSITIONS: dict[tuple[State, str], tuple[State, int]] = {
    (S.SWITCH_ON_DISABLED, SHUTDOWN): (S.READY_TO_SWITCH_ON, 2),
    (S.READY_TO_SWITCH_ON, SWITCH_ON): (S.SWITCHED_ON, 3),
    (S.READY_TO_SWITCH_ON, ENABLE_OPERATION): (S.OPERATION_ENABLED, 4),  # 3 and 4 at once
    (S.SWITCHED_ON, ENABLE_OPERATION): (S.OPERATION_ENABLED, 4),
    (S.OPERATION_ENABLED, SWITCH_ON): (S.SWITCHED_ON, 5),
    (S.SWITCHED_ON, SHUTDOWN): (S.READY_TO_SWITCH_ON, 6),
    (S.READY_TO_SWITCH_ON, DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 7),
    (S.READY_TO_SWITCH_ON, QUICK_STOP): (S.SWITCH_ON_DISABLED, 7),
    (S.OPERATION_ENABLED, SHUTDOWN): (S.READY_TO_SWITCH_ON, 8),
    (S.OPERATION_ENABLED, DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 9),
    (S.SWITCHED_ON, DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 10),
    (S.SWITCHED_ON, QUICK_STOP): (S.SWITCH_ON_DISABLED, 10),
    (S.OPERATION_ENABLED, QUICK_STOP): (S.QUICK_STOP_ACTIVE, 11),
    (S.QUICK_STOP_ACTIVE, DISABLE_VOLTAGE): (S.SWITCH_ON_DISABLED, 12),
    # 12 also happens on its own at the end of the quick-stop ramp (option codes 1-4);
    # 13 (any -> FAULT REACTION ACTIVE) and 14 (-> FAULT) are taken by the drive logic;
    # 15 (FAULT -> SWITCH ON DISABLED) needs the rising edge of bit 7: see step().
    (S.QUICK_STOP_ACTIVE, ENABLE_OPERATION): (S.OPERATION_ENABLED, 16),  # option codes 5-8 only
}


def step(state: State, controlword: int, previous_controlword: int, quick_stop_option: int) -> tuple[State, int]:
    """The state after the master writes ``controlword``; transition 0 = no change.

    Parameters
    ----------
    state:
        Current state.
    controlword, previous_controlword:
        New and previous value of 0x6040 (bit 7 acts on its rising edge only).
    quick_stop_option:
        0x605A; transition 16 exists for options 5–8 only.
    """
    if state is S.FAULT:
        if controlword & 0x80 and not previous_controlword & 0x80:
            return S.SWITCH_ON_DISABLED, 15
        return state, 0
    if state in (S.FAULT_REACTION_ACTIVE, S.NOT_READY_TO_SWITCH_ON):
        return state, 0
    result = TRANSITIONS.get((state, command_of(controlword)))
    if result is None:
        return state, 0
    if result[1] == 16 and not 5 <= quick_stop_option <= 8:
        return state, 0
    return result
