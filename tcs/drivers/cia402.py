"""CiA-402 state machine as tables: statusword -> state, (wanted, state) -> controlword.

Pure functions and constants, no I/O (docs/cia402.md has the facts; transition numbers of the
device control state machine are written beside each row). :mod:`tcs.drivers.cia402_drive`
looks up one row per cycle with the statusword of the latest TPDO and sends the controlword in
the RPDO of the same cycle, so a multi-step path (Switch on disabled -> Ready to switch on ->
Operation enabled) takes one cycle per hop and nothing ever waits.

Fault reset is not in the table: it is a one-shot request handled by the driver (0x0000 for a
cycle, then 0x0080 — the rising edge of bit 7 — until the drive leaves Fault, transition 15;
asked during the fault reaction, 0x0000 until the drive is in Fault, which ignores a reset
before), and it always ends in Switch on disabled.
"""

from __future__ import annotations

import enum

from tcs.drivers.drive import DriveState

# Controlword bits (0x6040).
CW_SWITCH_ON = 0x0001
CW_ENABLE_VOLTAGE = 0x0002
CW_QUICK_STOP = 0x0004          # active low
CW_ENABLE_OPERATION = 0x0008
CW_NEW_SETPOINT = 0x0010        # PP: new set-point; HM: start homing (rising edge)
CW_ENABLE_IP = 0x0010           # IP: enable interpolation (statusword bit 12 = IP active)
CW_CHANGE_IMMEDIATELY = 0x0020  # PP
CW_RELATIVE = 0x0040            # PP
CW_FAULT_RESET = 0x0080         # rising edge
CW_HALT = 0x0100

# Controlword commands.
SHUTDOWN = 0x0006
SWITCH_ON = 0x0007
ENABLE_OPERATION = 0x000F
DISABLE_VOLTAGE = 0x0000
QUICK_STOP = 0x0002
FAULT_RESET = 0x0080

# Statusword bits (0x6041).
SW_READY = 0x0001
SW_SWITCHED_ON = 0x0002
SW_OPERATION_ENABLED = 0x0004
SW_FAULT = 0x0008
SW_VOLTAGE_ENABLED = 0x0010
SW_QUICK_STOP = 0x0020          # active low
SW_SWITCH_ON_DISABLED = 0x0040
SW_WARNING = 0x0080
SW_REMOTE = 0x0200
SW_TARGET_REACHED = 0x0400
SW_INTERNAL_LIMIT = 0x0800
SW_MODE_12 = 0x1000             # PP set-point ack / HM homing attained / CSP following / IP active
SW_MODE_13 = 0x2000             # PP, CSP following error / HM homing error

#: statusword -> state: (mask, value, state), checked in order (docs/cia402.md table).
STATES: tuple[tuple[int, int, DriveState], ...] = (
    (0x4F, 0x00, DriveState.NOT_READY),
    (0x4F, 0x40, DriveState.SWITCH_ON_DISABLED),
    (0x6F, 0x21, DriveState.READY_TO_SWITCH_ON),
    (0x6F, 0x23, DriveState.SWITCHED_ON),
    (0x6F, 0x27, DriveState.OPERATION_ENABLED),
    (0x6F, 0x07, DriveState.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, DriveState.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, DriveState.FAULT),
)


def decode_state(statusword: int) -> DriveState | None:
    """The power state a statusword shows, or None for a combination no state has."""
    for mask, value, state in STATES:
        if statusword & mask == value:
            return state
    return None


class Want(enum.Enum):
    """Where the driver steers the state machine."""

    DISABLED = "disabled"       # Switch on disabled (power off)
    ENABLED = "enabled"         # Operation enabled
    QUICK_STOP = "quick stop"   # Quick stop active, then wherever the drive's 0x605A leads


S = DriveState
#: (wanted, current state) -> (controlword, transition taken). A state missing for a ``Want``
#: means "send DISABLE_VOLTAGE and wait" (Not ready, Fault reaction, Fault: the drive moves by
#: itself, transitions 0/1, 13/14; leaving Fault needs the explicit fault reset).
TABLE: dict[tuple[Want, DriveState], tuple[int, str]] = {
    # --- enable ------------------------------------------------------------------------
    (Want.ENABLED, S.SWITCH_ON_DISABLED): (SHUTDOWN, "2"),
    (Want.ENABLED, S.READY_TO_SWITCH_ON): (ENABLE_OPERATION, "3+4"),
    (Want.ENABLED, S.SWITCHED_ON): (ENABLE_OPERATION, "4"),
    (Want.ENABLED, S.OPERATION_ENABLED): (ENABLE_OPERATION, "-"),
    (Want.ENABLED, S.QUICK_STOP_ACTIVE): (DISABLE_VOLTAGE, "12"),   # then 2, 3+4
    # --- disable (power off) -------------------------------------------------------------
    (Want.DISABLED, S.SWITCH_ON_DISABLED): (DISABLE_VOLTAGE, "-"),
    (Want.DISABLED, S.READY_TO_SWITCH_ON): (DISABLE_VOLTAGE, "7"),
    (Want.DISABLED, S.SWITCHED_ON): (DISABLE_VOLTAGE, "10"),
    (Want.DISABLED, S.OPERATION_ENABLED): (DISABLE_VOLTAGE, "9"),
    (Want.DISABLED, S.QUICK_STOP_ACTIVE): (DISABLE_VOLTAGE, "12"),
    # --- quick stop ----------------------------------------------------------------------
    (Want.QUICK_STOP, S.OPERATION_ENABLED): (QUICK_STOP, "11"),
    (Want.QUICK_STOP, S.QUICK_STOP_ACTIVE): (QUICK_STOP, "- (12 by the drive)"),
    (Want.QUICK_STOP, S.SWITCHED_ON): (QUICK_STOP, "10"),
    (Want.QUICK_STOP, S.READY_TO_SWITCH_ON): (QUICK_STOP, "7"),
    (Want.QUICK_STOP, S.SWITCH_ON_DISABLED): (QUICK_STOP, "-"),
}


def controlword(want: Want, state: DriveState | None) -> int:
    """The controlword that moves ``state`` one hop towards ``want`` (no mode-specific bits)."""
    if state is None:
        return DISABLE_VOLTAGE
    return TABLE.get((want, state), (DISABLE_VOLTAGE, ""))[0]


class HomingBits(enum.Enum):
    """Statusword bits 13/12/10 in homing mode (docs/cia402.md, "Homing")."""

    RUNNING = "in progress"                    # 000
    IDLE = "interrupted or not started"        # 001
    ATTAINED = "attained, not at target"       # 010
    DONE = "completed"                         # 011
    ERROR_MOVING = "error while moving"        # 1x0
    ERROR_AT_REST = "error at rest"            # 1x1


def homing_bits(statusword: int) -> HomingBits:
    """Decode bits 13 (error), 12 (attained), 10 (target reached)."""
    error = bool(statusword & SW_MODE_13)
    attained = bool(statusword & SW_MODE_12)
    reached = bool(statusword & SW_TARGET_REACHED)
    if error:
        return HomingBits.ERROR_AT_REST if reached else HomingBits.ERROR_MOVING
    if attained:
        return HomingBits.DONE if reached else HomingBits.ATTAINED
    return HomingBits.IDLE if reached else HomingBits.RUNNING
