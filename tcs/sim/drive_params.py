"""Physical description of one simulated servo axis (what a real axis would be built with).

Used by :class:`tcs.sim.cia402_drive.SimDrive`; user units are degrees or mm as the axis has
them, the drive itself works in increments on the wire (``increments_per_unit``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class SimDriveParams:
    """Everything physical about one simulated axis, in user units unless noted.

    Attributes
    ----------
    increments_per_unit:
        Encoder increments per user unit; the drive's 0x608F/0x6091 defaults say the same
        (0x608F = this as a fraction, 0x6091 = 1/1).
    max_velocity, max_acceleration:
        Hard limits of the motor (units/s, units/s²); profile values above them are capped.
    position:
        Physical position at power-up (units); the encoder reads ``position *
        increments_per_unit`` until a homing run moves its zero.
    negative_limit_switch, positive_limit_switch:
        Positions of the hardware limit switches: the negative one is active for positions
        ``<=`` it, the positive one for ``>=``; None = not fitted.
    absolute_home:
        Homing methods 35/37 ("current position is home": an absolute encoder): the physical
        place that reads the home offset after homing, wherever the axis stands when it is
        homed — re-homing never moves the zero. None: the position at power-up.
    home_switch:
        Position of the home switch's edge; active for positions ``>=`` it (a "positive"
        home switch, for homing methods 3/4/19/20), or ``<=`` it when
        ``home_switch_active_below`` (a "negative" one, methods 5/6/21/22).
    index_pulse_spacing:
        The encoder's index pulse comes at every multiple of this (units).
    identity:
        0x1018 vendor, product, revision, serial number.
    boot_delay:
        Seconds from ``start()`` to the boot-up message.
    """

    increments_per_unit: float = 10000.0
    max_velocity: float = 5.0
    max_acceleration: float = 5.0
    position: float = 0.0
    negative_limit_switch: float | None = None
    positive_limit_switch: float | None = None
    home_switch: float | None = None
    home_switch_active_below: bool = False
    index_pulse_spacing: float = 1.0
    absolute_home: float | None = None
    identity: tuple[int, int, int, int] = (0xABC, 0x00402001, 0x00010000, 1)
    boot_delay: float = 0.0

    def problems(self) -> list[str]:
        """What is wrong with these parameters (empty when they are usable)."""
        out = []
        if not self.increments_per_unit > 0:
            out.append("increments_per_unit must be positive")
        if not self.max_velocity > 0:
            out.append("max_velocity must be positive")
        if not self.max_acceleration > 0:
            out.append("max_acceleration must be positive")
        if not self.index_pulse_spacing > 0:
            out.append("index_pulse_spacing must be positive")
        if self.boot_delay < 0:
            out.append("boot_delay must not be negative")
        if (self.negative_limit_switch is not None and self.positive_limit_switch is not None
                and self.negative_limit_switch >= self.positive_limit_switch):
            out.append("negative_limit_switch must lie below positive_limit_switch")
        if len(self.identity) != 4 or any(not 0 <= int(v) <= 0xFFFFFFFF for v in self.identity):
            out.append("identity must be four 32-bit unsigned numbers")
        return out
