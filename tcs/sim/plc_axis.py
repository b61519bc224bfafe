"""A PLC-run axis of the simulated PLC: trapezoidal motion as a pure function of time.

Register convention (the same as :mod:`tcs.drivers.plc_axis`; addresses from
:func:`axis_points`, ``hbase``/``ibase`` per axis)::

    holding hbase+0..1  X_target    float32 rw  target position
    holding hbase+2     X_command   uint16  rw  0 idle, 1 move to target, 2 stop, 3 reset fault;
                                                 reads 0 again once the PLC accepted it
    input   ibase+0..1  X_position  float32 r   actual position
    input   ibase+2..3  X_speed     float32 r   actual speed (signed)
    input   ibase+4     X_status    uint16  r   bit 0 moving, 1 at_target, 2 closed (end switch
                                                 at min), 3 open (end switch at max), 4 fault,
                                                 5 stalled

Refusals (Modbus exception on the write of the command): 3 (illegal value) for an unknown
command or a target outside ``min..max``; 4 (device failure) for a move while in fault.

Motion is a :class:`Profile` — constant-acceleration segments anchored at the time of the last
command — so the state at any instant is computed from the clock, never integrated in a loop.
A new command re-anchors the profile at the command's time (decelerating first if the axis
moves the wrong way). A circular axis (dome azimuth) takes the shortest way and reports
positions in ``min..max`` (0..360).

Fault injection: :meth:`SimPlcAxis.inject_stall` freezes the motor; a commanded motion then
shows ``moving`` for ``stall_detect`` seconds and ends with ``fault`` and ``stalled``, as a
PLC's standstill monitoring would report it. ``command = 3`` (reset) clears the fault;
:meth:`SimPlcAxis.clear_stall` repairs the motor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tcs.config.plc import AXIS_IDLE, AXIS_MOVE, AXIS_RESET, AXIS_STOP, SimAxisSection

ILLEGAL_VALUE, DEVICE_FAILURE = 3, 4
STATUS_BITS = {"moving": 0, "at_target": 1, "closed": 2, "open": 3, "fault": 4, "stalled": 5}


@dataclass(frozen=True)
class AxisParams:
    """Resolved physics of one axis (preset values overridden by the hardware file)."""

    speed: float
    acceleration: float
    min: float
    max: float
    circular: bool = False
    position: float = 0.0
    tolerance: float = 0.01
    stall_detect: float = 0.5

    @classmethod
    def resolve(cls, section: SimAxisSection, presets: dict[str, AxisParams]) -> AxisParams:
        base = presets.get(section.preset, presets["generic"])
        changes = {k: getattr(section, k) for k in ("speed", "acceleration", "min", "max", "circular",
                                                     "position", "tolerance", "stall_detect")
                   if getattr(section, k) is not None}
        return cls(**{**base.__dict__, **changes})


GENERIC = AxisParams(speed=1.0, acceleration=1.0, min=0.0, max=100.0)


@dataclass(frozen=True)
class Profile:
    """Motion from ``t0``: segments ``(duration, p, v, a)`` (p, v at the segment's start)."""

    t0: float
    segments: tuple[tuple[float, float, float, float], ...]
    final: float

    @classmethod
    def rest(cls, t0: float, position: float) -> Profile:
        return cls(t0, (), position)

    @property
    def end(self) -> float:
        return self.t0 + sum(s[0] for s in self.segments)

    def at(self, t: float) -> tuple[float, float]:
        """Position and velocity at time ``t``."""
        dt = t - self.t0
        for duration, p, v, a in self.segments:
            if dt < duration:
                dt = max(dt, 0.0)
                return p + v * dt + 0.5 * a * dt * dt, v + a * dt
            dt -= duration
        return self.final, 0.0


def _advance(p: float, v: float, a: float, d: float) -> tuple[float, float]:
    return p + v * d + 0.5 * a * d * d, v + a * d


def plan_stop(t0: float, p: float, v: float, amax: float) -> Profile:
    """Decelerate from (p, v) to standstill."""
    if v == 0.0:
        return Profile.rest(t0, p)
    d = abs(v) / amax
    a = -math.copysign(amax, v)
    return Profile(t0, ((d, p, v, a),), _advance(p, v, a, d)[0])


def plan_move(t0: float, p: float, v: float, target: float, vmax: float, amax: float) -> Profile:
    """Fastest trapezoidal motion from (p, v) to rest at ``target``."""
    segments = []
    dist = target - p
    if v != 0.0 and (v * dist <= 0.0 or v * v / (2 * amax) > abs(dist)):
        stop = plan_stop(t0, p, v, amax)
        segments.extend(stop.segments)
        p, v = stop.final, 0.0
        dist = target - p
    if dist == 0.0:
        return Profile(t0, tuple(segments), target)
    s = math.copysign(1.0, dist)
    distance, u = abs(dist), abs(v)
    peak = min(vmax, math.sqrt((2 * amax * distance + u * u) / 2))
    t1 = abs(peak - u) / amax
    a1 = s * amax * (1.0 if peak >= u else -1.0)
    d1 = abs(peak * peak - u * u) / (2 * amax)
    t3 = peak / amax
    d3 = peak * peak / (2 * amax)
    t2 = max(0.0, distance - d1 - d3) / peak if peak > 0 else 0.0
    pos, vel = p, v
    for duration, acc in ((t1, a1), (t2, 0.0), (t3, -s * amax)):
        if duration > 0:
            segments.append((duration, pos, vel, acc))
            pos, vel = _advance(pos, vel, acc, duration)
    return Profile(t0, tuple(segments), target)


class SimPlcAxis:
    """One axis: its points are ``<name>_target/_command/_position/_speed/_status``."""

    def __init__(self, name: str, params: AxisParams, now: float):
        self.name = name
        self.params = params
        p = params.position
        self.profile = Profile.rest(now, p)
        self.target = p            # the target register
        self.goal = p              # target of the last accepted move (unwrapped)
        self.fault = False
        self.stalled = False
        self._stall_injected = False
        self._stall_since: float | None = None  # a commanded motion blocked by the stall
        self._frozen_at: float | None = None

    @property
    def points(self) -> tuple[str, ...]:
        return tuple(f"{self.name}_{s}" for s in ("target", "command", "position", "speed", "status"))

    # ------------------------------------------------------------- the physics

    def _wrap(self, p: float) -> float:
        if not self.params.circular:
            return p
        span = self.params.max - self.params.min
        return (p - self.params.min) % span + self.params.min

    def _now_state(self, now: float) -> tuple[float, float]:
        if self._frozen_at is not None:
            return self._frozen_at, 0.0
        return self.profile.at(now)

    def _settle_stall(self, now: float) -> None:
        if self._stall_since is not None and now - self._stall_since >= self.params.stall_detect:
            self._stall_since = None
            self.fault = self.stalled = True

    def update(self, now: float) -> dict[str, float | int]:
        """Values of the axis' points at ``now`` (status as its raw integer)."""
        self._settle_stall(now)
        p, v = self._now_state(now)
        tol = self.params.tolerance
        moving = self._stall_since is not None or (self._frozen_at is None and now < self.profile.end)
        shown = self._wrap(p)
        flags = {
            "moving": moving,
            "at_target": not moving and not self.fault and abs(p - self.goal) <= tol,
            "closed": not self.params.circular and shown <= self.params.min + tol,
            "open": not self.params.circular and shown >= self.params.max - tol,
            "fault": self.fault,
            "stalled": self.stalled,
        }
        status = sum(1 << STATUS_BITS[k] for k, on in flags.items() if on)
        n = self.name
        return {f"{n}_target": self.target, f"{n}_command": AXIS_IDLE, f"{n}_position": shown,
                f"{n}_speed": v, f"{n}_status": status}

    # ------------------------------------------------------------- commands

    def write(self, point: str, value, now: float) -> int | None:
        """Apply a write of one of the axis' points; a Modbus exception code refuses it."""
        if point == f"{self.name}_target":
            self.target = float(value)
            return None
        if point != f"{self.name}_command":
            return None
        self._settle_stall(now)
        p, v = self._now_state(now)
        if value == AXIS_MOVE:
            return self._move(now, p, v)
        if value == AXIS_STOP:
            self._stall_since = None
            if self._frozen_at is None:
                self.profile = plan_stop(now, p, v, self.params.acceleration)
            return None
        if value == AXIS_RESET:
            self.fault = self.stalled = False
            return None
        if value == AXIS_IDLE:
            return None
        return ILLEGAL_VALUE

    def _move(self, now: float, p: float, v: float) -> int | None:
        prm = self.params
        if self.fault:
            return DEVICE_FAILURE
        target = self.target
        if prm.circular:
            span = prm.max - prm.min
            delta = (target - self._wrap(p) + span / 2) % span - span / 2
            goal = p + delta
        else:
            if not prm.min - prm.tolerance <= target <= prm.max + prm.tolerance:
                return ILLEGAL_VALUE
            goal = min(max(target, prm.min), prm.max)
        self.goal = goal
        if self._stall_injected:
            self._stall_since = now if abs(goal - p) > prm.tolerance else None
            return None
        self.profile = plan_move(now, p, v, goal, prm.speed, prm.acceleration)
        return None

    # ------------------------------------------------------------- fault injection

    def inject_stall(self, now: float) -> None:
        """The motor stops turning at ``now``; a motion in progress becomes a detected stall."""
        if self._stall_injected:
            return
        self._settle_stall(now)
        p, v = self.profile.at(now)
        moving = now < self.profile.end
        self._stall_injected = True
        self._frozen_at = p
        self.profile = Profile.rest(now, p)
        if moving:
            self._stall_since = now

    def clear_stall(self, now: float) -> None:
        """The motor works again (the fault, if reported, stays until a reset command)."""
        if self._frozen_at is not None:
            self.profile = Profile.rest(now, self._frozen_at)
        self._stall_injected = False
        self._stall_since = None
        self._frozen_at = None


def axis_points(name: str, hbase: int, ibase: int, unit: str = "", description: str = "") -> dict[str, dict]:
    """The register-map tables of axis ``name`` (TOML-ready dicts for ``[plcs.X.points]``)."""
    return {
        f"{name}_target": {"kind": "holding", "address": hbase, "type": "float32", "unit": unit,
                           "description": f"{description} target".strip()},
        f"{name}_command": {"kind": "holding", "address": hbase + 2, "type": "uint16",
                            "description": "0 idle, 1 move, 2 stop, 3 reset fault"},
        f"{name}_position": {"kind": "input", "address": ibase, "type": "float32", "unit": unit,
                             "description": f"{description} position".strip()},
        f"{name}_speed": {"kind": "input", "address": ibase + 2, "type": "float32",
                          "unit": f"{unit}/s" if unit else ""},
        f"{name}_status": {"kind": "input", "address": ibase + 4, "type": "uint16",
                           "bits": dict(STATUS_BITS)},
    }
