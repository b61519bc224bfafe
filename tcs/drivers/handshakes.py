"""The two mode-specific handshakes of the driver as small pure state machines.

* :class:`HomingRun` — homing (mode 6), docs/cia402.md "Homing": wait until idle, set
  controlword bit 4, wait until started, wait for attained or error with the per-axis
  time-out of the hardware file, wait for standstill, clear bit 4.
* :class:`ProfileMove` — profile position (mode 1): (profile velocity written by SDO first
  when it changes), bit 4 "new set-point" with bit 5 "change immediately" until the drive
  acknowledges with statusword bit 12, then bit 4 low until "target reached" (bit 10) with
  the axis inside the window.

Each has ``step(now, statusword, …) -> controlword bits`` called once per cycle by
:class:`tcs.drivers.cia402_drive.Cia402Drive` while the drive is in Operation enabled in the
right mode; ``fail(error)`` ends it from outside (fault, disable, superseded). No I/O, no
clock of their own: ``now`` comes in.
"""

from __future__ import annotations

from tcs.drivers import cia402 as sm
from tcs.drivers.cia402 import HomingBits, homing_bits
from tcs.drivers.drive import Progress
from tcs.drivers.worker import Job
from tcs.errors import ErrorNumber, HardwareError, TcsError

#: Seconds for a set-point acknowledge / the start of homing / a drive that shows "running"
#: before homing was requested.
HANDSHAKE_TIMEOUT = 1.0
#: Methods that complete at once (current position is home).
INSTANT_METHODS = (35, 37)


class HomingRun:
    """One homing run. ``progress`` / ``fraction`` / ``error`` are read by the status."""

    def __init__(self, device: str, method: int, timeout: float, now: float):
        self.device = device
        self.method = method
        self.timeout = timeout
        self.progress = Progress.RUNNING
        self.fraction = 0.0
        self.error: TcsError | None = None
        self.phase = "idle"
        self.since = now
        self.phase_since = now
        self.before = HomingBits.IDLE

    def _to(self, phase: str, now: float) -> None:
        self.phase, self.phase_since = phase, now

    def fail(self, error: TcsError) -> None:
        if self.progress is Progress.RUNNING:
            self.progress, self.error = Progress.FAILED, error

    def waiting(self, now: float, why: str) -> None:
        """A cycle not in Operation enabled + homing mode (mode switch, enabling): time-out only."""
        if now - self.since > self.timeout:
            self.fail(TcsError(f"{self.device}: homing timed out waiting for {why}",
                               ErrorNumber.TIMEOUT))

    def step(self, now: float, sw: int) -> int:
        """Controlword bits (0 or bit 4) for this cycle."""
        if self.progress is not Progress.RUNNING:
            return 0
        bits = homing_bits(sw)
        elapsed = now - self.since
        if self.phase != "finish" and elapsed > self.timeout:
            self.fail(TcsError(f"{self.device}: homing (method {self.method}) did not finish "
                               f"within {self.timeout:g} s", ErrorNumber.TIMEOUT))
            return 0
        error = bits in (HomingBits.ERROR_MOVING, HomingBits.ERROR_AT_REST)
        # An error shown before bit 4 went high is the previous run's: only a new one counts.
        if error and (self.phase == "running" or self.phase == "start" and bits is not self.before):
            self.fail(HardwareError(self.device, f"homing error (method {self.method}, "
                                                 f"statusword 0x{sw:04X}, {bits.value})"))
            return 0
        if self.phase == "idle":  # bit 4 low until the drive shows no homing in progress
            self.fraction = 0.05
            if bits is not HomingBits.RUNNING or now - self.phase_since > HANDSHAKE_TIMEOUT:
                self.before = bits
                self._to("start", now)
            return 0
        if self.phase == "start":  # bit 4 high until the drive started
            self.fraction = 0.1
            changed = bits is not self.before and bits in (HomingBits.ATTAINED, HomingBits.DONE)
            instant = (self.method in INSTANT_METHODS and bits is HomingBits.DONE
                       and now - self.phase_since > 0.05)
            if bits is HomingBits.RUNNING or changed or instant:
                self._to("running", now)
            elif now - self.phase_since > HANDSHAKE_TIMEOUT:
                self.fail(HardwareError(self.device, f"homing did not start (statusword "
                                                     f"0x{sw:04X}, {bits.value})"))
                return 0
            return sm.CW_NEW_SETPOINT
        if self.phase == "running":  # until attained and at standstill ("011")
            self.fraction = max(self.fraction, 0.1 + 0.8 * min(1.0, elapsed / self.timeout))
            if bits is HomingBits.DONE:
                self.fraction = 0.95
                self._to("finish", now)
                return 0
            if bits is HomingBits.ATTAINED:
                self.fraction = max(self.fraction, 0.9)
            return sm.CW_NEW_SETPOINT
        # finish: bit 4 went low this cycle
        self.progress, self.fraction = Progress.DONE, 1.0
        return 0


class ProfileMove:
    """One profile-position move to ``target`` (drive increments)."""

    def __init__(self, device: str, target: int, window: int, deadline: float, now: float,
                 velocity_job: Job | None, scale: float):
        self.device = device
        self.target = target
        self.window = window
        self.deadline = deadline
        self.progress = Progress.RUNNING
        self.error: TcsError | None = None
        self.phase = "speed"
        self.since = now
        self.job = velocity_job
        self.scale = scale

    def fail(self, error: TcsError) -> None:
        if self.progress is Progress.RUNNING:
            self.progress, self.error = Progress.FAILED, error

    def step(self, now: float, sw: int, actual: int) -> int:
        """Controlword bits (new set-point + change immediately, or 0) for this cycle."""
        if self.progress is not Progress.RUNNING:
            return 0
        if now > self.deadline:
            self.fail(TcsError(f"{self.device}: move to {self.target / self.scale:g} timed out",
                               ErrorNumber.TIMEOUT))
            return 0
        if self.phase == "speed":  # the profile velocity write, if any, must be done
            job = self.job
            if job is not None and not job.done:
                return 0
            if job is not None and job.error is not None:
                self.fail(job.error if isinstance(job.error, TcsError) else
                          HardwareError(self.device, f"profile velocity: {job.error!r}"))
                return 0
            self.phase = "idle"
        if self.phase == "idle":  # bit 4 low and no acknowledge pending
            if not sw & sm.SW_MODE_12:
                self.phase, self.since = "set", now
            return 0
        if self.phase == "set":  # until acknowledged (bit 12)
            if sw & sm.SW_MODE_12:
                self.phase = "moving"
                return 0
            if now - self.since > HANDSHAKE_TIMEOUT:
                self.fail(HardwareError(self.device, "set-point not acknowledged (bit 12)"))
                return 0
            return sm.CW_NEW_SETPOINT | sm.CW_CHANGE_IMMEDIATELY
        # moving: target reached (bit 10), acknowledge gone, inside the window
        if sw & sm.SW_TARGET_REACHED and not sw & sm.SW_MODE_12 and abs(actual - self.target) <= self.window:
            self.progress = Progress.DONE
        return 0
