"""Mount orientation and cable-wrap choice: which mechanical axis angles track a sky path.

How it works
------------
A sky position has two mechanical realisations on a mount that can go over the top:

* AZ-ZD: normal (AZ, ZD ≥ 0) and reverse (AZ + 180°, −ZD) (OpenTCI Appendix C.1,
  POINTING.TRACK = 3);
* RA-DEC: normal (HA, Dec) and reverse, through the pole (HA + 180°, 180° − Dec).

and axis 1 (azimuth / hour angle) may in addition be shifted by whole turns where its
limits span more than 360°. :func:`mount_path` turns a sampled ideal path (the astrometry's
observed AZ/ZD or HA/Dec over the coming minutes) into a continuous mechanical path in one
orientation, on the turn nearest a reference angle. :func:`choose_path` tries every
orientation and turn that the POINTING.TRACK mode allows and picks, in this order:

1. the candidate that stays inside both axes' limits for the most leading samples,
2. then (mode 2) the normal orientation, or (modes 1, 3, 4) the shortest slew,
3. then the shortest slew / normal orientation as a tie-break.

Slew time is estimated as the larger of |Δaxis| / speed over the two axes from the current
position to the path's first sample (a ruckig-based estimate can replace it later).

All angles are degrees; axis 1 of an RA-DEC mount is the hour angle in degrees.

What may touch it
-----------------
Pure functions on numpy arrays: no state, no I/O, safe from any thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcs.errors import ErrorNumber, RequestRefused, TcsError

__all__ = [
    "AxisRange", "MountPath", "TRACK_NORMAL", "TRACK_AUTO_LIMITS", "TRACK_REVERSE",
    "TRACK_AUTO_SLEW", "to_reverse", "to_normal", "mount_path", "choose_path",
]

TRACK_NORMAL = 1       # POINTING.TRACK values (§14)
TRACK_AUTO_LIMITS = 2
TRACK_REVERSE = 3
TRACK_AUTO_SLEW = 4

_MOUNTS = ("AZ-ZD", "RA-DEC")


@dataclass(frozen=True)
class AxisRange:
    """Software limits of one axis, degrees (inclusive)."""

    minimum: float
    maximum: float

    def __post_init__(self):
        if not self.minimum < self.maximum:
            raise RequestRefused(f"axis range {self.minimum}…{self.maximum} is empty")

    def contains(self, x) -> np.ndarray:
        x = np.asarray(x, float)
        return (x >= self.minimum) & (x <= self.maximum)


@dataclass(frozen=True)
class MountPath:
    """A mechanical path chosen by :func:`choose_path`.

    Attributes
    ----------
    reverse : True for the reverse orientation (POINTING.TRACK reads 3), else 1.
    axis1, axis2 : mechanical positions per sample, degrees (axis 1 continuous, unwrapped).
    in_limits : number of leading samples inside both axes' limits.
    slew_time : estimated seconds from the current position to the first sample.
    """

    reverse: bool
    axis1: np.ndarray
    axis2: np.ndarray
    in_limits: int
    slew_time: float

    @property
    def track_mode(self) -> int:
        return TRACK_REVERSE if self.reverse else TRACK_NORMAL


def _check_mount(mount: str) -> None:
    if mount not in _MOUNTS:
        raise RequestRefused(f"orientation: mount {mount!r} is not one of {list(_MOUNTS)}")


def to_reverse(axis1, axis2, mount: str = "AZ-ZD"):
    """Normal → reverse mechanical angles: (AZ+180, −ZD) or (HA+180, 180−Dec)."""
    _check_mount(mount)
    a1 = np.add(axis1, 180.0)
    a2 = np.negative(axis2) if mount == "AZ-ZD" else np.subtract(180.0, axis2)
    return a1, a2


def to_normal(axis1, axis2, mount: str = "AZ-ZD"):
    """Mechanical angles (either orientation, any turn) → ideal frame and orientation.

    Returns
    -------
    (axis1, axis2, reverse)
        AZ in 0…360 with ZD ≥ 0, or HA in −180…180 with −90 ≤ Dec ≤ 90; ``reverse`` tells
        whether the input was in the reverse orientation (ZD < 0, or |Dec| > 90).
    """
    _check_mount(mount)
    a1 = np.asarray(axis1, float)
    a2 = np.asarray(axis2, float)
    if mount == "AZ-ZD":
        rev = a2 < 0.0
        n1 = np.where(rev, a1 + 180.0, a1) % 360.0
        n2 = np.abs(a2)
    else:
        a2w = (a2 + 180.0) % 360.0 - 180.0
        rev = np.abs(a2w) > 90.0
        n1 = (np.where(rev, a1 + 180.0, a1) + 180.0) % 360.0 - 180.0
        n2 = np.where(rev, np.copysign(180.0, a2w) - a2w, a2w)
    if n1.ndim == 0:
        return float(n1), float(n2), bool(rev)
    return n1, n2, rev


def mount_path(axis1, axis2, *, mount: str = "AZ-ZD", reverse: bool = False,
               near: float | None = None):
    """Ideal sampled path → continuous mechanical path in one orientation.

    Parameters
    ----------
    axis1, axis2 : ideal path, degrees (AZ 0…360 / ZD ≥ 0, or HA / Dec), in time order.
    mount : "AZ-ZD" or "RA-DEC".
    reverse : use the reverse orientation.
    near : put the first sample's axis 1 within ±180° of this angle (default: as given).

    Returns
    -------
    (axis1, axis2) : numpy arrays; axis 1 unwrapped so that consecutive samples never jump
    by more than 180°.
    """
    _check_mount(mount)
    a1 = np.atleast_1d(np.asarray(axis1, float))
    a2 = np.atleast_1d(np.asarray(axis2, float))
    if reverse:
        a1, a2 = to_reverse(a1, a2, mount)
    a1 = np.unwrap(a1, period=360.0)
    if near is not None and a1.size:
        a1 = a1 - 360.0 * math.floor((a1[0] - near + 180.0) / 360.0)
    return a1, a2


def _leading_true(mask: np.ndarray) -> int:
    bad = np.flatnonzero(~mask)
    return int(bad[0]) if bad.size else int(mask.size)


def choose_path(axis1, axis2, *, mode: int, axis1_range: AxisRange, axis2_range: AxisRange,
                mount: str = "AZ-ZD", current: tuple[float, float] | None = None,
                speed: tuple[float, float] = (1.0, 1.0)) -> MountPath:
    """Pick orientation and axis-1 turn for a sampled ideal path (POINTING.TRACK modes).

    Parameters
    ----------
    axis1, axis2 : the ideal path over the horizon that must stay reachable, degrees.
    mode : 1 normal, 2 automatic (stay within limits, prefer normal), 3 reverse,
        4 automatic (shortest slew). Flags (128, 256) must be masked off by the caller.
    axis1_range, axis2_range : the axes' software limits (mechanical degrees).
    mount : "AZ-ZD" or "RA-DEC".
    current : current mechanical (axis1, axis2), for the slew estimate (None: slew 0).
    speed : maximum speeds of the axes, degrees/s, for the slew estimate.

    Returns
    -------
    MountPath

    Raises
    ------
    RequestRefused
        Unknown mode or mount.
    TcsError (number 9, softlimit)
        No allowed orientation has even the first sample inside the limits.
    """
    _check_mount(mount)
    if mode not in (TRACK_NORMAL, TRACK_AUTO_LIMITS, TRACK_REVERSE, TRACK_AUTO_SLEW):
        raise RequestRefused(f"track mode {mode} is not 1, 2, 3 or 4")
    if speed[0] <= 0 or speed[1] <= 0:
        raise RequestRefused(f"axis speeds {speed} must be positive")
    orientations = {TRACK_NORMAL: (False,), TRACK_REVERSE: (True,)}.get(mode, (False, True))
    best: tuple | None = None
    for reverse in orientations:
        p1, p2 = mount_path(axis1, axis2, mount=mount, reverse=reverse)
        if p1.size == 0:
            raise RequestRefused("orientation: empty path")
        lo, hi = float(p1.min()), float(p1.max())
        k_min = math.floor((axis1_range.minimum - hi) / 360.0) - 1
        k_max = math.ceil((axis1_range.maximum - lo) / 360.0) + 1
        ok2 = axis2_range.contains(p2)
        for k in range(k_min, k_max + 1):
            c1 = p1 + 360.0 * k
            n_ok = _leading_true(axis1_range.contains(c1) & ok2)
            if current is None:
                slew = 0.0
            else:
                slew = max(abs(c1[0] - current[0]) / speed[0], abs(p2[0] - current[1]) / speed[1])
            if mode == TRACK_AUTO_LIMITS:
                key = (-n_ok, reverse, slew)
            else:
                key = (-n_ok, slew, reverse)
            if best is None or key < best[0]:
                best = (key, MountPath(reverse, c1, p2, n_ok, slew))
    assert best is not None
    chosen = best[1]
    if chosen.in_limits == 0:
        raise TcsError("target is outside the axis limits in every allowed orientation",
                       ErrorNumber.SOFTLIMIT)
    return chosen
