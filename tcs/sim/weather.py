"""Simulated sensors of a PLC: temperature, pressure, humidity, wind, rain, an uptime counter.

Each value is a pure function of the clock: a mean plus a slow variation (three sines of
incommensurate periods, phases from the seed), so it changes plausibly, is the same for the
same time and seed, and needs no background task. Values are in engineering units; the
register map's type and scale turn them into registers (``int16`` with ``scale = 0.1`` for a
temperature in 0.1 °C steps, …).

Interlock tests override any point with :meth:`tcs.sim.plc.SimPlc.force` (rain on, a gale).
"""

from __future__ import annotations

import math
import random

from tcs.config.plc import SimSensorSection

#: model -> (mean, amplitude, period s, low clip, high clip)
MODELS: dict[str, tuple[float, float, float, float | None, float | None]] = {
    "temperature": (8.0, 4.0, 7200.0, None, None),        # °C
    "pressure": (770.0, 3.0, 20000.0, 0.0, None),          # hPa (a 2300 m site)
    "humidity": (40.0, 20.0, 5000.0, 0.0, 100.0),          # %
    "wind_speed": (5.0, 4.0, 600.0, 0.0, None),            # m/s
    "wind_direction": (220.0, 60.0, 1800.0, None, None),   # deg, wrapped to 0..360
    "rain": (0.0, 0.0, 3600.0, None, None),                # bool: dry unless forced
    "uptime": (0.0, 0.0, 3600.0, None, None),              # s since the simulator started
    "constant": (0.0, 0.0, 3600.0, None, None),
}


class SimSensor:
    """One sensor point; ``update(now)`` gives its value."""

    def __init__(self, point: str, section: SimSensorSection, seed: int, start: float):
        mean, amplitude, period, self.low, self.high = MODELS[section.model]
        self.point = point
        self.model = section.model
        self.mean = section.mean if section.mean is not None else mean
        self.amplitude = section.amplitude if section.amplitude is not None else amplitude
        self.period = section.period if section.period is not None else period
        self.start = start
        rng = random.Random(f"{seed}:{point}")
        self.phases = [rng.uniform(0, 2 * math.pi) for _ in range(3)]

    @property
    def points(self) -> tuple[str, ...]:
        return (self.point,)

    def value(self, now: float) -> float | bool:
        if self.model == "rain":
            return bool(self.mean)
        if self.model == "uptime":
            return max(0.0, now - self.start)
        w = 2 * math.pi / self.period
        p = self.phases
        x = (0.6 * math.sin(w * now + p[0]) + 0.3 * math.sin(w * now / 0.37 + p[1])
             + 0.1 * math.sin(w * now / 0.11 + p[2]))
        v = self.mean + self.amplitude * x
        if self.model == "wind_direction":
            return v % 360.0
        if self.low is not None:
            v = max(self.low, v)
        if self.high is not None:
            v = min(self.high, v)
        return v

    def update(self, now: float) -> dict[str, float | bool]:
        return {self.point: self.value(now)}

    def write(self, point: str, value, now: float) -> int | None:
        return None  # a sensor point written by a client is ignored
