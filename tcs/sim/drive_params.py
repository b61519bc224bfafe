"""Physical description of one simulated servo axis (what a real axis would be built with).

Used by :class:`tcs.sim.cia402_drive.SimDrive`; user units are degrees or mm as the axis has
them, the drive itself works in increments on the wire (``increments_per_unit``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


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
        Seconds from ``start()`` (and from an NMT reset) to the boot-up message.
    eds:
        The EDS the drive behaves as (None: the simulated drive's own).
    velocity_scale, acceleration_scale:
        Wire units of the velocity objects (0x606C, 0x6081, 0x607F, 0x60FF, 0x6099, 0x60B1)
        per increment/s, and of the acceleration objects (0x6083-0x6085, 0x609A) per
        increment/s²: 1.0 = the drive counts increments; a drive in rpm of a motor with
        ``N`` counts per revolution has ``60 / N``.
    objects:
        ``{(index, sub): value}`` for objects the EDS gives no default (else built-ins).
    pdo_timer_in_operational:
        Whether the PDO event timers (0x1400+n:5, 0x1800+n:5) may be written in operational,
        as CiA 301 allows; False: like some devices, every PDO parameter only in
        pre-operational (abort 0x08000022).
    tpdo_latency:
        Seconds from a SYNC to the synchronous TPDOs sampled at it (0: at once, as the
        simulator's host allows): a drive or gateway that answers late.
    bridging:
        What the drive does in CSP and IP while synchronous setpoints are missing (the master
        stalled), until the RPDO deadline 0x1400:5 (or the SYNC loss) makes it apply the
        abort connection reaction 0x6007: ``"extrapolate"`` — the demand goes on at the
        setpoint stream's speed (bounded extrapolation, as drives that bridge lost frames
        do); ``"hold"`` — the demand stays at the last setpoint (the interpolator runs dry:
        the motor brakes at its own limit). CSV keeps the last target velocity either way.
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
    eds: str | None = None
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    objects: dict | None = None
    pdo_timer_in_operational: bool = True
    tpdo_latency: float = 0.0
    bridging: str = "extrapolate"

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
        if not self.velocity_scale > 0 or not self.acceleration_scale > 0:
            out.append("velocity_scale and acceleration_scale must be positive")
        if self.boot_delay < 0:
            out.append("boot_delay must not be negative")
        if not 0 <= self.tpdo_latency < 1:
            out.append("tpdo_latency must be at least 0 and below 1 s")
        if self.bridging not in ("extrapolate", "hold"):
            out.append('bridging must be "extrapolate" or "hold"')
        if (self.negative_limit_switch is not None and self.positive_limit_switch is not None
                and self.negative_limit_switch >= self.positive_limit_switch):
            out.append("negative_limit_switch must lie below positive_limit_switch")
        if len(self.identity) != 4 or any(not 0 <= int(v) <= 0xFFFFFFFF for v in self.identity):
            out.append("identity must be four 32-bit unsigned numbers")
        return out


#: 0x6502 bits -> the mode (0x6060 value) they allow.
_MODE_BITS = {0: 1, 1: 2, 2: 3, 3: 4, 5: 6, 6: 7, 7: 8, 8: 9, 9: 10}
#: 0x6502 of the simulated drive's own modes (PP, PV, HM, IP, CSP, CSV): what a drive whose
#: EDS states no default answers, unless ``[simulation.drives.x] objects`` gives "0x6502:0".
SIM_MODES = 0x000001E5
VELOCITY_OBJECTS = (0x606C, 0x6081, 0x607F, 0x60FF, 0x6099, 0x60B1)
ACCELERATION_OBJECTS = (0x6083, 0x6084, 0x6085, 0x609A)


def store_options(od, params: SimDriveParams, node_id: int) -> dict[str, Any]:
    """``ObjectStore`` options making the simulated drive behave as its EDS describes.

    ``builtins``: sane values for objects the EDS lacks or gives no default (the model keeps
    working; the wire still says the object is absent); ``scale``: the velocity and
    acceleration units of this drive; ``allowed``: the modes of 0x6502 (when the EDS has it);
    ``answers``: {index: value} the drive answers whatever its EDS default (0x6502 of 0 or
    none: the modes it has, as a real drive fills that placeholder).
    """
    fixed = {(0x1000, 0): 0x00020192, (0x1005, 0): 0x80, (0x1014, 0): 0x80 + node_id, (0x6065, 0): 0xFFFFFFFF,
             (0x6066, 0): 100, (0x6067, 0): 100, (0x60C2, 1): 10, (0x60C2, 2): -3,
             (0x605A, 0): 2, (0x605E, 0): 1, (0x6098, 0): 37, (0x608F, 1): 1, (0x608F, 2): 1,
             (0x6091, 1): 1, (0x6091, 2): 1}

    given = params.objects or {}

    def builtins(index: int, sub: int):
        if (index, sub) in given:
            return given[(index, sub)]
        if (0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF) and sub == 1:
            return 0x80000000  # a PDO the drive does not have is never valid
        if (index, sub) == (0x6502, 0):
            return SIM_MODES
        return fixed.get((index, sub))

    scale = {}
    if params.velocity_scale != 1.0:
        scale.update(dict.fromkeys(VELOCITY_OBJECTS, params.velocity_scale))
    if params.acceleration_scale != 1.0:
        scale.update(dict.fromkeys(ACCELERATION_OBJECTS, params.acceleration_scale))
    allowed = {}
    answer: dict[int, int] = {}
    modes_var = od.get(0x6502)
    modes = None
    if modes_var is not None and not hasattr(modes_var, "subindices"):
        modes = modes_var.value if modes_var.value is not None else modes_var.default
        if not modes:  # no EDS default (or 0): what [simulation] objects say, else all it has
            modes = given.get((0x6502, 0), SIM_MODES)
            answer[0x6502] = modes
    if isinstance(modes, int):
        allowed[(0x6060, 0)] = {0} | {mode for bit, mode in _MODE_BITS.items() if modes >> bit & 1}
    return {"builtins": builtins, "scale": scale, "allowed": allowed, "answers": answer}
