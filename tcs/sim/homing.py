"""Homing (CiA-402 mode 6) of the simulated drive: the methods as tables of search phases.

A method is a list of **phases**; each phase moves at a speed in a direction until a signal
reaches a value (a limit switch, the home switch or an index pulse). The phases of a method
depend on where the axis starts (a switch already active skips the search for it). The last
phase's event is the home point: the drive latches it, brakes to a stop with the homing
acceleration, and sets its position so that the latched point reads the home offset 0x607C
(the axis is *not* moved back onto the point). The search speed is 0x6099:1 for the first
search for a switch and 0x6099:2 for everything after it.

The physical switches (:class:`Switches`, positions in user units):

* negative limit switch active for ``x <= negative_limit``, positive for ``x >= positive_limit``;
* home switch active for ``x >= home_switch`` ("positive home switch"), or ``x <= home_switch``
  when ``home_active_below`` ("negative home switch");
* an index pulse at every multiple of ``index_spacing``.

Methods (CiA-402 numbering; "on/off" = the signal becomes active/inactive):

====== ============================================================== =========================
method search                                                         home point
====== ============================================================== =========================
1      ↓ fast until negative limit on; ↑ slow until it goes off       next index pulse ↑
2      ↑ fast until positive limit on; ↓ slow until it goes off       next index pulse ↓
17     as 1 without index                                             negative limit goes off
18     as 2 without index                                             positive limit goes off
19     positive home switch: ↑ fast until on (if off); ↓ slow         home switch goes off ↓
21     negative home switch: ↓ fast until on (if off); ↑ slow         home switch goes off ↑
33     ↓ slow                                                         next index pulse ↓
34     ↑ slow                                                         next index pulse ↑
35, 37 none                                                           the absolute encoder's
                                                                      home place (see below)
====== ============================================================== =========================

Methods 35/37 stand for an absolute encoder: "current position is home" sets the position
from the encoder, which knows where it is. The home point is therefore a *place* (the
``home`` given to :class:`Homing`, by default where the axis stood at power-up), not wherever
the axis happens to stand: homing again elsewhere gives the same zero, as on a real axis.

Running into a limit switch that the method does not search for is a homing error (statusword
bit 13): the axis brakes and stays there; the drive does not fault. A method whose switch does
not exist (or lies the other way, e.g. method 21 with a positive home switch) searches until a
limit switch stops it with a homing error — or forever when there is none, as a real drive
would: the master's homing time-out is what ends that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tcs.sim.drive_physics import Axis, Event, Threshold, stop_profile, velocity_profile

SUPPORTED_METHODS = frozenset({1, 2, 17, 18, 19, 21, 33, 34, 35, 37})

UP, DOWN = 1, -1
NEG, POS, HOME, INDEX = "negative limit", "positive limit", "home switch", "index pulse"


@dataclass(frozen=True)
class Switches:
    """Physical positions (user units) of the switches of one axis; None = not fitted."""

    negative_limit: float | None = None
    positive_limit: float | None = None
    home_switch: float | None = None
    home_active_below: bool = False
    index_spacing: float = 1.0

    def active(self, signal: str, x: float) -> bool:
        if signal == NEG:
            return self.negative_limit is not None and x <= self.negative_limit
        if signal == POS:
            return self.positive_limit is not None and x >= self.positive_limit
        if signal == HOME:
            if self.home_switch is None:
                return False
            return x <= self.home_switch if self.home_active_below else x >= self.home_switch
        return False

    def limit_thresholds(self) -> list[Threshold]:
        out = []
        if self.negative_limit is not None:
            # Crossing downward through the threshold = switch becomes active (x <= position).
            out.append(Threshold(NEG, math.nextafter(self.negative_limit, math.inf)))
        if self.positive_limit is not None:
            out.append(Threshold(POS, self.positive_limit))
        return out

    def home_threshold(self) -> list[Threshold]:
        if self.home_switch is None:
            return []
        pos = math.nextafter(self.home_switch, math.inf) if self.home_active_below else self.home_switch
        return [Threshold(HOME, pos)]

    def next_index(self, x: float, direction: int) -> float:
        """The first index pulse strictly beyond ``x`` in ``direction``."""
        s = self.index_spacing
        k = math.floor(x / s) + 1 if direction > 0 else math.ceil(x / s) - 1
        p = k * s
        if direction > 0 and p <= x:
            p += s
        if direction < 0 and p >= x:
            p -= s
        return p


@dataclass(frozen=True)
class Phase:
    direction: int
    fast: bool          # True: 0x6099:1 speed, False: 0x6099:2
    signal: str         # what ends the phase
    becomes: bool       # the signal's value that ends it (ignored for INDEX)


def plan(method: int, sw: Switches, x: float) -> list[Phase]:
    """The phases of ``method`` for an axis starting at ``x`` (empty: home is here)."""
    if method in (35, 37):
        return []
    if method in (33, 34):
        return [Phase(DOWN if method == 33 else UP, False, INDEX, True)]
    if method in (1, 2, 17, 18):
        limit, toward = (NEG, DOWN) if method in (1, 17) else (POS, UP)
        phases = [] if sw.active(limit, x) else [Phase(toward, True, limit, True)]
        phases.append(Phase(-toward, False, limit, False))
        if method in (1, 2):
            phases.append(Phase(-toward, False, INDEX, True))
        return phases
    if method in (19, 21):
        # 19 expects a positive home switch (active above its edge), 21 a negative one.
        toward = UP if method == 19 else DOWN
        on_expected_side = sw.active(HOME, x)
        phases = [] if on_expected_side else [Phase(toward, True, HOME, True)]
        phases.append(Phase(-toward, False, HOME, False))
        return phases
    raise ValueError(f"homing method {method} not supported")


class Homing:
    """One homing run on an axis; the drive logic feeds it the axis events.

    States: ``running`` (searching), ``stopping`` (home found, braking), ``done``, ``error``
    (``error_moving`` while braking after an error), ``interrupted``.
    """

    def __init__(self, axis: Axis, sw: Switches, method: int, fast: float, slow: float, acc: float,
                 home: float | None = None):
        self.axis, self.sw = axis, sw
        self.fast, self.slow = abs(fast), abs(slow)
        self.acc = abs(acc)
        self.phases = plan(method, sw, axis.x)
        self.home_position: float | None = None
        self.state = "running"
        if not self.phases:  # 35/37: the absolute encoder's home place (default: here)
            self.home_position = axis.x if home is None else home
            self.state = "done"
        elif self.fast <= 0 or self.slow <= 0 or self.acc <= 0:
            self._fail()
        else:
            self._begin_phase()

    # -- status ------------------------------------------------------------------------------
    @property
    def attained(self) -> bool:
        return self.home_position is not None

    @property
    def moving(self) -> bool:
        return self.state in ("running", "stopping", "error_moving", "interrupting")

    # -- phases ------------------------------------------------------------------------------
    def thresholds(self) -> list[Threshold]:
        """Positions the axis must watch for this run (besides the limit switches)."""
        if self.state != "running":
            return []
        phase = self.phases[0]
        if phase.signal == INDEX:
            return [Threshold(INDEX, self.sw.next_index(self.axis.x, phase.direction))]
        if phase.signal == HOME:
            return self.sw.home_threshold()
        return []

    def _begin_phase(self) -> None:
        phase = self.phases[0]
        speed = self.fast if phase.fast else self.slow
        ax = self.axis
        ax.set_reference(velocity_profile(ax.t, ax.x, ax.v, phase.direction * speed, self.acc, self.acc))

    def _brake(self, state: str) -> None:
        ax = self.axis
        profile = stop_profile(ax.t, ax.x, ax.v, self.acc)
        ax.set_reference(profile)
        self.state = state
        ax.alarm = profile.end_time if profile.end_time > ax.t else ax.t

    def _fail(self) -> None:
        if abs(self.axis.v) > 0:
            self._brake("error_moving")
        else:
            self.state = "error"

    def interrupt(self) -> None:
        """The master cleared bit 4 or set halt: stop; status "interrupted"."""
        if self.state in ("running", "stopping"):
            self._brake("interrupting")

    def on_event(self, event: Event) -> None:
        """React to an axis event during the run."""
        if event.kind == "alarm":
            self.state = {"stopping": "done", "error_moving": "error", "interrupting": "interrupted"}.get(
                self.state, self.state)
            return
        if event.kind != "crossing" or self.state != "running":
            return
        phase = self.phases[0]
        name = event.threshold.name
        x = self.axis.x
        if name in (NEG, POS) and name != phase.signal and self.sw.active(name, x):
            self._fail()  # a limit switch the method does not look for
            return
        if name != phase.signal:
            return
        if name != INDEX and self.sw.active(name, x) != phase.becomes:
            return
        if name == INDEX and (event.upward != (phase.direction > 0)):
            return
        self.phases.pop(0)
        if self.phases:
            self._begin_phase()
        else:
            self.home_position = event.threshold.position
            self._brake("stopping")

    def status_bits(self) -> int:
        """Statusword bits 13 (error), 12 (attained) and 10 (target reached)."""
        bit13, bit12, bit10 = 1 << 13, 1 << 12, 1 << 10
        if self.state == "done":
            return bit12 | bit10
        if self.state == "error":
            return bit13 | bit10
        if self.state == "error_moving":
            return bit13
        if self.state == "interrupted":
            return bit10
        if self.state == "interrupting":
            return 0
        return bit12 if self.attained else 0
