"""Simulated switches of a PLC: pumps, lights, fans.

A switch is a writable point (a coil, or a holding register for multi-state switches); its
optional feedback point (usually a discrete input) follows the commanded value after
``delay`` seconds, as a contactor's auxiliary contact would. State is (value, time of the last
change), so the feedback is a pure function of the clock.
"""

from __future__ import annotations

from tcs.config.plc import SimSwitchSection


class SimSwitch:
    def __init__(self, point: str, section: SimSwitchSection, now: float):
        self.point = point
        self.feedback = section.feedback
        self.delay = section.delay
        self.value = 0
        self.previous = 0
        self.changed = now - section.delay

    @property
    def points(self) -> tuple[str, ...]:
        return (self.point, self.feedback) if self.feedback else (self.point,)

    def state(self, now: float):
        """What the feedback reports at ``now``."""
        return self.value if now - self.changed >= self.delay else self.previous

    def update(self, now: float) -> dict:
        out = {self.point: self.value}
        if self.feedback:
            out[self.feedback] = self.state(now)
        return out

    def write(self, point: str, value, now: float) -> int | None:
        if point == self.point and value != self.value:
            self.previous = self.state(now)
            self.value = value
            self.changed = now
        return None
