"""The small drive interface the axis layer talks to (architecture.md rule 2).

A :class:`Drive` is one servo axis in **user units** (degrees, mm). Every command is a
non-blocking *request*: it records what is wanted and returns at once; the drive's per-cycle
``step()`` — called by the control loop once per SYNC period, in the control-loop thread —
carries it out over the following cycles. :meth:`Drive.status` returns an immutable
:class:`DriveStatus` snapshot and may be called from any thread.

Nothing here knows CANopen: :class:`tcs.drivers.cia402_drive.Cia402Drive` implements the
interface on a CiA-402 drive; an EtherCAT or simulated-in-memory drive could implement it too.

Threads: requests (``enable()`` …) may come from any thread; ``set_setpoint()`` and ``step()``
belong to the control-loop thread.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from tcs.errors import TcsError


class DriveState(enum.Enum):
    """CiA-402 power states (docs/cia402.md, statusword table), plus the driver's own two."""

    OFFLINE = "offline"                      # not booted, or no heartbeat
    NOT_READY = "not ready to switch on"
    SWITCH_ON_DISABLED = "switch on disabled"
    READY_TO_SWITCH_ON = "ready to switch on"
    SWITCHED_ON = "switched on"
    OPERATION_ENABLED = "operation enabled"
    QUICK_STOP_ACTIVE = "quick stop active"
    FAULT_REACTION_ACTIVE = "fault reaction active"
    FAULT = "fault"


class Mode(enum.IntEnum):
    """Modes of operation (0x6060 / 0x6061) the driver uses."""

    PP = 1    # profile position: move_to()
    HM = 6    # homing: start_homing()
    IP = 7    # interpolated position: set_setpoint() every cycle (0x60C1:1, enable-IP bit 4)
    CSP = 8   # cyclic synchronous position: set_setpoint() every cycle
    CSV = 9   # cyclic synchronous velocity: set_setpoint() every cycle, the driver closes
    #           the position loop (velocity feed-forward + PI on the following error)


#: The modes a trajectory is streamed in (``set_setpoint`` every cycle). A drive offers one of
#: them as its ``cyclic_mode``; the axis layer asks for that one.
CYCLIC_MODES = frozenset({Mode.IP, Mode.CSP, Mode.CSV})


class Progress(enum.Enum):
    """Outcome of a long request (homing, profile move)."""

    IDLE = "idle"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"


@dataclass(frozen=True)
class DriveStatus:
    """One consistent snapshot of a drive; positions in user units.

    ``fault`` is the error that keeps the drive from working (drive fault decoded from the
    EMCY / 0x603F, lost heartbeat, failed boot) with its OpenTCI number; ``warning`` the last
    EMCY that did not (yet) stop it; ``request_error`` the last refused or failed request
    (enable time-out, mode switch, homing, move). ``heartbeat_age`` is the time since the
    drive's last heartbeat, or since the TCS's own last stall if that came later
    (``heartbeat_ok`` turns False past ``can.heartbeat_tolerance`` heartbeat periods), ``age``
    the time since its last TPDO; both in seconds at the moment of the snapshot.
    """

    name: str
    state: DriveState
    position: float = 0.0
    velocity: float = 0.0
    following_error: float = 0.0
    statusword: int = 0
    controlword: int = 0
    mode: Mode | int | None = None
    fault: TcsError | None = None
    warning: TcsError | None = None
    request_error: TcsError | None = None
    limit_negative: bool = False
    limit_positive: bool = False
    home_switch: bool = False
    homing: Progress = Progress.IDLE
    homing_progress: float = 0.0
    homed: bool = False
    move: Progress = Progress.IDLE
    target_reached: bool = False
    setpoint: float | None = None
    heartbeat_ok: bool = False
    heartbeat_age: float = float("inf")
    booted: bool = False
    age: float = float("inf")
    reboots: int = 0  # boot-ups of the node seen after its first boot (position may be lost)

    @property
    def enabled(self) -> bool:
        """Power stage on and following commands (Operation enabled)."""
        return self.state is DriveState.OPERATION_ENABLED


@runtime_checkable
class Drive(Protocol):
    """What the axis layer needs from one drive (all requests are non-blocking).

    ``power_timeout``: the longest (s) an enable or a disable may take before the drive
    itself reports it failed (``request_error``); the axis waits at least that long.
    """

    name: str
    power_timeout: float

    def status(self) -> DriveStatus:
        """The latest snapshot (any thread)."""

    def enable(self) -> None:
        """Request Operation enabled (in the current mode; CSP holds the actual position)."""

    def disable(self) -> None:
        """Request power off (Switch on disabled); aborts homing and moves."""

    def quick_stop(self) -> None:
        """Request a quick stop with the drive's quick-stop deceleration."""

    def halt(self) -> None:
        """End a homing run or a profile-position move with the drive's normal deceleration."""

    def fault_reset(self) -> None:
        """Request one fault reset; the drive ends in Switch on disabled, never re-enabled."""

    def set_mode(self, mode: Mode) -> None:
        """Request a mode of operation; active once the drive reads it back."""

    def set_setpoint(self, position: float, velocity: float | None = None) -> None:
        """CSP: the position for the next SYNC (control-loop thread, once per cycle)."""

    def start_homing(self) -> None:
        """Request homing with the configured method; progress in ``status().homing``."""

    def move_to(self, position: float, velocity: float | None = None) -> None:
        """Request a profile-position move; progress in ``status().move``."""

    def step(self) -> None:
        """Carry out requests for one cycle (control-loop thread, once per SYNC period)."""
