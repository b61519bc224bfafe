"""ICRS target → axis demands, and axis positions → sky place (OpenTCI §14 steps 1–3), vectorised.

How it works
------------
:class:`Pipeline` joins the three numerical cores for one mount:

1. astrometry (:mod:`tcs.pointing.astrometry`): ICRS J2000 → observed place, refraction
   included (steps 1–2); the *ideal* position in the mount's normal frame is (AZ, ZD) on an
   AZ-ZD mount and (HA·15, Dec) — hour angle in degrees — on an RA-DEC mount;
2. orientation (:mod:`tcs.pointing.orientation`): the reverse orientation is
   (AZ + 180°, −ZD) / (HA + 180°, 180° − Dec);
3. the pointing model (:mod:`tcs.pointing.model`): demand = ideal + Δ(ideal) (step 3).

:meth:`Pipeline.demand` runs them forward for arrays of times (one call per refill of the
trajectory queues: a few µs per sample). :meth:`Pipeline.place` runs them backwards for
POINTING.CURRENT: encoder positions (REALPOS, i.e. including any OFFSET) → model inverse →
normal frame → exact inverse astrometry → ICRS, then forward again for HA and PA.

Field rotation (POINTING.TRACK flag 256): :func:`field_angle` gives the derotator angle that
keeps the sky fixed on the detector, in degrees anti-clockwise (App. C.2), with the
derotator's referenced zero as the origin:

* AZ-ZD, Cassegrain, M2 and tube ports (0, 1, 4–11): ``q + 180°·reverse``;
* AZ-ZD, Nasmyth 1 (port 2): ``q + ZD + 180°·reverse``; Nasmyth 2 (port 3): ``q − ZD + 180°·reverse``
  (``q`` the parallactic angle, ``ZD`` the *mechanical* zenith distance, negative in reverse);
* RA-DEC: the field does not rotate: ``180°·reverse``.

A site whose optics turn the other way sees the field turn at twice the rate: the sign
convention is this file's and must be checked on the sky once.

What may touch it
-----------------
Pure: immutable inputs, no clock, no I/O; safe from any thread.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcs.errors import RequestRefused
from tcs.pointing.astrometry import Astrometry, Observed
from tcs.pointing.model import PointingModel
from tcs.pointing.orientation import to_normal, to_reverse

__all__ = ["Pipeline", "Demand", "Place", "field_angle", "NASMYTH_SIGN", "MOUNTS"]

MOUNTS = ("AZ-ZD", "RA-DEC")
#: Sign of the mechanical ZD in the field angle, by derotator port (App. C.2): Nasmyth 1 / 2.
NASMYTH_SIGN = {2: 1.0, 3: -1.0}


def field_angle(mount: str, pa, axis2, reverse: bool, port: int):
    """Derotator angle (degrees, −180…540) compensating field rotation; see the module docstring.

    Parameters
    ----------
    mount : "AZ-ZD" or "RA-DEC".
    pa : parallactic angle, degrees (scalar or array).
    axis2 : mechanical ZD (AZ-ZD), degrees, same shape as ``pa``.
    reverse : the orientation the telescope tracks in.
    port : derotator port index (App. C.2).
    """
    flip = 180.0 if reverse else 0.0
    if mount == "RA-DEC":
        return np.zeros_like(np.asarray(pa, float)) + flip
    return np.asarray(pa, float) + NASMYTH_SIGN.get(port, 0.0) * np.asarray(axis2, float) + flip


@dataclass(frozen=True)
class Demand:
    """A target's path on the mount at some times (numpy arrays, degrees).

    Attributes
    ----------
    ideal1, ideal2 : ideal mechanical position in the chosen orientation (no model).
    axis1, axis2 : the demand for the axes: ideal + pointing model (axis 1 not unwrapped).
    observed : the observed place (AZ/ZD, HA/Dec, PA, LST) per time.
    """

    ideal1: np.ndarray
    ideal2: np.ndarray
    axis1: np.ndarray
    axis2: np.ndarray
    observed: Observed

    @property
    def zd(self) -> np.ndarray:
        """Observed zenith distance (the altitude limit is checked on it)."""
        return self.observed.zd


@dataclass(frozen=True)
class Place:
    """Where the axes point (POINTING.CURRENT), floats.

    Attributes
    ----------
    ra, dec : ICRS J2000, hours and degrees.
    ha, pa, lst : observed hour angle (h), parallactic angle (deg), sidereal time (h).
    ideal1, ideal2 : the ideal mechanical position the axes correspond to (model removed).
    correction1, correction2 : the model's correction there, degrees (CURRENT.DA/DZ, DH/DD).
    reverse : the axes are in the reverse orientation.
    """

    ra: float
    dec: float
    ha: float
    pa: float
    lst: float
    ideal1: float
    ideal2: float
    correction1: float
    correction2: float
    reverse: bool


class Pipeline:
    """ICRS ↔ mount axes for one mount with one astrometry and one pointing model.

    Parameters
    ----------
    astrometry : site, time base and refraction.
    model : the pointing model (its ``mount`` must be ``mount``).
    mount : "AZ-ZD" or "RA-DEC".
    """

    def __init__(self, astrometry: Astrometry, model: PointingModel, mount: str = "AZ-ZD"):
        if mount not in MOUNTS:
            raise RequestRefused(f"POINTING supports the mounts {list(MOUNTS)}, not {mount!r}")
        if model.mount != mount:
            raise RequestRefused(f"pointing model is for {model.mount}, the mount is {mount}")
        self.astrometry = astrometry
        self.model = model
        self.mount = mount

    def ideal(self, observed: Observed):
        """Ideal mechanical position in the normal orientation, degrees."""
        if self.mount == "AZ-ZD":
            return observed.az, observed.zd
        return np.multiply(observed.ha, 15.0), observed.dec

    def demand(self, ra_h: float, dec_deg: float, utc, reverse: bool = False) -> Demand:
        """The target's ideal position and the axis demand at the UTC times ``utc`` (array)."""
        utc = np.atleast_1d(np.asarray(utc, float))
        return self.demand_observed(self.astrometry.observed(ra_h, dec_deg, utc), reverse)

    def demand_observed(self, obs: Observed, reverse: bool = False) -> Demand:
        """As :meth:`demand` for an observed place already computed (any kind of target,
        :mod:`tcs.pointing.targets`)."""
        i1, i2 = self.ideal(obs)
        if reverse:
            i1, i2 = to_reverse(i1, i2, self.mount)
        d1, d2 = self.model.apply(i1, i2)
        return Demand(np.asarray(i1, float), np.asarray(i2, float), np.asarray(d1, float),
                      np.asarray(d2, float), obs)

    def place(self, axis1: float, axis2: float, utc: float) -> Place:
        """Sky place of mechanical axis positions (REALPOS) at ``utc`` (POINTING.CURRENT)."""
        i1, i2 = self.model.invert(float(axis1), float(axis2))
        n1, n2, reverse = to_normal(i1, i2, self.mount)
        if self.mount == "AZ-ZD":
            ra, dec = self.astrometry.icrs_from_observed(n1, n2, utc)
        else:
            ra, dec = self.astrometry.icrs_from_hadec(n1 / 15.0, n2, utc)
        obs = self.astrometry.observed(ra, dec, utc)
        c1, c2 = self.model.corrections(i1, i2)
        return Place(float(ra), float(dec), float(obs.ha), float(obs.pa), float(obs.lst),
                     float(i1), float(i2), float(c1), float(c2), bool(reverse))
