"""Taking over a drive that is still powered: a controlled stop before anything is reconfigured.

When the master restarts (after a crash, or a restart by systemd) a drive may still be enabled
— and moving: a profile move or a homing run goes on without a master, and a drive whose
heartbeat consumer is off does not notice that the master went away. Reconfiguring such a
drive (PDO mapping, mode, limits, speeds) or sending it *disable voltage* (transition 9) would
cut the motor at speed. So :func:`stop_if_powered` runs at boot right after the node answered
and before anything else is sent to it (no NMT command, no configuration):

==========================  ======================================================================
state read (0x6041, SDO)    what is done
==========================  ======================================================================
Operation enabled           *quick stop* (0x6040 = 0x0002, transition 11); the drive ramps down
                            with its quick-stop deceleration (0x6085) per its option code 0x605A;
                            then as below
Quick stop active           wait for standstill (0x606C within :data:`STANDSTILL` user units/s, or
                            the drive's own transition 12 to Switch on disabled), then *disable
                            voltage* (0x0000, transition 12)
Fault reaction active       wait until the drive's own reaction reached Fault
Switched on, ready to       *disable voltage* (transitions 10, 7): no torque is applied there
switch on
anything else               nothing: Switch on disabled, Not ready, Fault (the operator
                            acknowledges faults, the boot reports them); nor when the statusword
                            cannot be read (the boot's next step fails and says why)
==========================  ======================================================================

The wait is bounded by twice the stopping time the drive's own velocity and quick-stop
deceleration give, plus :data:`STOP_MARGIN`; a drive still moving then is left in Quick stop
active (never disabled at speed) and the boot fails naming it. Blocking; boot only.
"""

from __future__ import annotations

import logging
import time

from tcs.config.can import DriveSection
from tcs.drivers import cia402 as sm
from tcs.drivers.drive import DriveState
from tcs.errors import HardwareError

log = logging.getLogger(__name__)

STANDSTILL = 1e-3   # user units/s: below this the axis counts as standing still
STOP_MARGIN = 2.0   # s added to the expected stopping time
POLL = 0.02         # s between two reads while waiting

S = DriveState


def _read_state(sdo) -> tuple[DriveState | None, int]:
    sw = sdo.read(0x6041, 0, "<H")
    return sm.decode_state(sw), sw


def _velocity(sdo, scale: float) -> float | None:
    """Velocity actual value in user units/s, or None when the drive does not tell."""
    try:
        return sdo.read(0x606C, 0, "<i") / scale
    except HardwareError:
        return None


def stop_if_powered(sdo, section: DriveSection, clock=time.monotonic) -> str | None:
    """Bring a powered drive to a controlled stop and disable it (see the module docstring).

    Parameters
    ----------
    sdo:
        The node's :class:`~tcs.drivers.boot.Sdo`.
    section:
        Its hardware-file table (scale, quick-stop deceleration as a fallback).

    Returns
    -------
    str or None
        What was done, for the log; None when the drive was not powered.

    Raises
    ------
    HardwareError
        The drive did not come to a standstill in time (it is left in Quick stop active).
    """
    device = sdo.device
    scale = abs(section.increments_per_unit) or 1.0
    try:
        state, sw = _read_state(sdo)
    except HardwareError:
        return None  # it does not answer SDO: the boot's next step fails and names why
    if state is S.FAULT_REACTION_ACTIVE:
        stopping = section.max_velocity / max(section.max_acceleration, 1e-9)
        deadline = clock() + STOP_MARGIN + stopping
        while state is S.FAULT_REACTION_ACTIVE and clock() < deadline:
            time.sleep(POLL)
            state, sw = _read_state(sdo)
        return f"was in fault reaction; now {state.value if state else hex(sw)}"
    if state in (S.READY_TO_SWITCH_ON, S.SWITCHED_ON):
        sdo.write(0x6040, 0, "<H", sm.DISABLE_VOLTAGE)
        return f"was {state.value}: disabled"
    if state not in (S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE):
        return None

    speed = _velocity(sdo, scale)
    before = state
    if state is S.OPERATION_ENABLED:
        sdo.write(0x6040, 0, "<H", sm.QUICK_STOP)                     # transition 11
    try:
        dec = sdo.read(0x6085, 0, "<I") / scale
    except HardwareError:
        dec = 0.0
    if dec <= 0:
        dec = section.quick_stop_deceleration or section.max_acceleration
    v0 = abs(speed) if speed is not None else abs(section.max_velocity)
    timeout = 2.0 * v0 / max(dec, 1e-9) + STOP_MARGIN
    start = clock()
    while True:
        state, sw = _read_state(sdo)
        speed = _velocity(sdo, scale)
        still = speed is None or abs(speed) <= STANDSTILL
        if state is not S.QUICK_STOP_ACTIVE or still:
            break
        if clock() - start > timeout:
            raise HardwareError(device, f"found {before.value} at this master's start; still "
                                        f"moving at {speed:g} units/s {timeout:.1f} s after quick "
                                        "stop: left in quick stop active, not disabled")
        time.sleep(POLL)
    if state is S.QUICK_STOP_ACTIVE:
        sdo.write(0x6040, 0, "<H", sm.DISABLE_VOLTAGE)                # transition 12
    state, sw = _read_state(sdo)
    what = (f"found {before.value} at {v0:g} units/s at this master's start: quick stop, "
            f"standstill after {clock() - start:.2f} s, now {state.value if state else hex(sw)}")
    log.warning("%s: %s", device, what)
    return what
