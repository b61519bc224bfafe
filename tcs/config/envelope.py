"""The ``[envelope]`` table of a hardware file: the safety envelope the TCS keeps every planned
path of the main axes inside (:mod:`tcs.pointing.envelope`).

* ``sun_avoidance``: radius (degrees) of the cone around the Sun that no slew or tracked path
  may enter. Default 30°; **only an explicit** ``sun_avoidance = 0`` switches it off (a file
  without the key is protected).
* ``horizon``: the horizon table, ``[[az, min_alt], …]`` (degrees, azimuth 0 = north, 90 =
  east), interpolated linearly in azimuth and wrapping at 360°; ``[pointing] min_altitude``
  stays the floor (the table can only raise it).
* ``keepout``: zones of the mechanical axis angles the telescope must never enter (pier, dome
  ring, a platform): ``axis1 = [lo, hi]`` (AZ or HA, degrees, taken modulo 360: ``[350, 10]``
  wraps through 0) and ``axis2 = [lo, hi]`` (ZD or Dec, as the axis reads, reverse
  orientation included).
* ``margin``: degrees kept from every border by a *planned* slew (the prediction of the
  ruckig profiles is exact, this covers the sampling and the Sun's motion meanwhile; the
  pointing model is judged itself: the sky is read both bare and through the model).
"""

from __future__ import annotations

from dataclasses import dataclass

from tcs.config.schema import setting


@dataclass(frozen=True)
class KeepOutSection:
    name: str = setting(doc="shown in refusals and events, e.g. \"pier\"")
    axis1: list[float] = setting(doc="[lo, hi] of axis 1 (AZ or HA), degrees, modulo 360 (lo > hi wraps)")
    axis2: list[float] = setting(doc="[lo, hi] of axis 2 (ZD or Dec as the axis reads), degrees")

    def check(self):
        problems = []
        for key in ("axis1", "axis2"):
            value = getattr(self, key)
            if len(value) != 2:
                problems.append((key, "must be [lo, hi]"))
        if len(self.axis2) == 2 and not self.axis2[0] < self.axis2[1]:
            problems.append(("axis2", "lo must be below hi"))
        return problems


@dataclass(frozen=True)
class EnvelopeSection:
    sun_avoidance: float = setting(
        30.0, min=0.0, max=90.0,
        doc="degrees: radius of the cone around the Sun no slew or tracked path enters; 0 (written "
            "explicitly) switches it off")
    horizon: list[list[float]] = setting(
        factory=tuple, doc="horizon table [[az, min_alt], ...] in degrees, linear in azimuth, "
                           "wrapping; [pointing] min_altitude stays the floor")
    keepout: list[KeepOutSection] = setting(
        factory=tuple, doc="keep-out zones of the mechanical axis angles ([[envelope.keepout]])")
    margin: float = setting(0.5, min=0.0, max=10.0,
                            doc="degrees a planned slew keeps from every border of the envelope")
    engineering_sun: bool = setting(
        True, doc="the Sun cone (and the keep-outs) also bound engineering moves: OpenTCI axis "
                  "TARGETPOS/OFFSET/TRAJECTORY and jogs; false leaves them the software limits only")

    def check(self):
        problems = []
        seen = []
        for i, row in enumerate(self.horizon):
            if len(row) != 2:
                problems.append((f"horizon[{i}]", "must be [az, min_alt]"))
                continue
            az, alt = row
            if not 0.0 <= az < 360.0:
                problems.append((f"horizon[{i}]", f"azimuth {az} is outside 0 <= az < 360"))
            if not -10.0 <= alt <= 90.0:
                problems.append((f"horizon[{i}]", f"altitude {alt} is outside -10 ... 90"))
            if az in seen:
                problems.append((f"horizon[{i}]", f"azimuth {az} appears twice"))
            seen.append(az)
        names = [k.name for k in self.keepout]
        for i, name in enumerate(names):
            if name in names[:i]:
                problems.append((f"keepout[{i}].name", f"duplicate keep-out {name!r}"))
        return problems
