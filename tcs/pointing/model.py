"""The pointing model: TPOINT-named geometric terms, applied, inverted and fitted (OpenTCI §14.2).

How it works
------------
A model maps the *ideal* position of a star in the mount's own axis frame (the observed place
from :mod:`tcs.pointing.astrometry`, put into the chosen orientation by
:mod:`tcs.pointing.orientation`) to the *demand* for the axes (§14 step 3)::

    demand = ideal + Δ(ideal),      Δ = Σ_term  coefficient × basis_term(ideal)

Every term is linear in its coefficient, so a fit is one weighted linear least-squares
problem (``numpy.linalg.lstsq``). The inverse (encoder → ideal, for POINTING.CURRENT) is a
fixed-point iteration ``x ← encoder − Δ(x)``.

Frames and units
----------------
* AZ-ZD mounts: axis 1 = AZ (degrees, 0 = north, 90 = east), axis 2 = ZD (degrees). The
  terms are written with the elevation E = 90° − ZD, and ΔZD = −ΔE. In reverse orientation
  the mechanical position is (AZ + 180°, −ZD), i.e. E > 90°: the same formulas hold there.
* RA-DEC mounts: axis 1 = HA in **degrees** (west positive), axis 2 = Dec (degrees); the
  reverse (through-the-pole) orientation is (HA + 180°, 180° − Dec).
* Coefficients are in **degrees** (the spec's unit for POINTINGPARAMS); reports show arcsec.

The terms (TPOINT names; φ = site latitude)::

    AZ-ZD   ΔA = +IA + CA·sec E + NPAE·tan E + AN·sin A·tan E − AW·cos A·tan E
            ΔE = +IE + AN·cos A + AW·sin A − TF·cos E − TX·cot E
    RA-DEC  Δh = −IH − CH·sec δ − NP·tan δ − MA·cos h·tan δ + ME·sin h·tan δ
                 + TF·cos φ·sin h·sec δ
            Δδ = −ID + MA·sin h + ME·cos h + TF·(cos φ·cos h·sin δ − sin φ·cos δ)

Sign convention: these are TPOINT's formulas in the sense *demand minus observed*. TPOINT
writes its alt-az terms for its own azimuth (0 = south, 90 = east, i.e. A_TPOINT = 180° − A);
they are rewritten above for the OpenTCI azimuth, which flips the sign of IA, CA, NPAE and of
the AN/AW azimuth parts. What the coefficients then mean on the mount (checked by
tests/test_pointing_model.py against a rotated-axes simulation):

* IA / IE: the azimuth / elevation encoder reads IA / IE more than the true angle.
* AN / AW: the azimuth axis is tilted towards north / east by AN / AW.
* ME / MA: the north end of the polar axis is turned by ME towards the meridian's equator
  point (h = 0, δ = 0) / by MA towards the west (h = +6 h): ME > 0 is a polar axis set
  too high in the northern hemisphere (too low in the southern).
* TF, TX: demand lowered by TF·sin ZD (TX·tan ZD): a tube that droops has TF < 0.
* IH / ID: the HA / Dec encoder reads IH / ID less than the true angle.

Sites bringing coefficients from another program should check the sense on a few stars
(negating all coefficients switches to the opposite convention).

Near a pole of the mount (E → 90° or δ → ±90°) sec and tan are held at their value 0.25°
from the pole, and cot E at its value 1° above the horizon, so the model stays finite.

The fit weights the axis-1 residuals by |cos E| (|cos δ|) so that every residual is an
angle on the sky, reports coefficient errors (σ from the covariance scaled by the
residual variance), the covariance and correlation matrices and the RMS on the sky; terms
can be held fixed at given values. IA/CA/NPAE are strongly correlated unless the samples
span a wide range of elevation: a rank-deficient design is refused with the terms named.

What may touch it
-----------------
Pure functions and frozen dataclasses: no I/O (files: :mod:`tcs.pointing.storage`), no
clock, safe from any thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from tcs.errors import RequestRefused, TcsError

#: A pointing-model fit that cannot run (no or too few samples, terms the samples cannot
#: separate): ``FAILED 1013`` — the request was well formed, the computation is impossible.
FIT_IMPOSSIBLE = 1013

__all__ = [
    "ALTAZ_TERMS", "EQUATORIAL_TERMS", "MOUNT_TERMS", "PointingModel", "Sample", "FitResult",
    "fit", "fit_samples", "basis",
]

ALTAZ_TERMS = ("IA", "IE", "NPAE", "CA", "AN", "AW", "TF", "TX")
EQUATORIAL_TERMS = ("IH", "ID", "CH", "NP", "MA", "ME", "TF")
MOUNT_TERMS = {"AZ-ZD": ALTAZ_TERMS, "RA-DEC": EQUATORIAL_TERMS}

_D2R = math.pi / 180.0
_COS_MIN = math.sin(0.25 * _D2R)   # |cos| floor near a pole of the mount
_SIN_MIN = math.sin(1.0 * _D2R)    # |sin E| floor for cot E near the horizon
_ARCSEC = 3600.0


def _terms_of(mount: str) -> tuple[str, ...]:
    try:
        return MOUNT_TERMS[mount]
    except KeyError:
        raise RequestRefused(f"pointing model: mount {mount!r} is not one of {list(MOUNT_TERMS)}")


def _floor(x: np.ndarray, minimum: float) -> np.ndarray:
    """``x`` with its magnitude at least ``minimum``, keeping the sign (+ for 0)."""
    return np.where(x >= 0.0, np.maximum(x, minimum), np.minimum(x, -minimum))


def basis(mount: str, terms: Sequence[str], axis1, axis2, latitude: float = 0.0) -> np.ndarray:
    """Partial derivatives of (Δaxis1, Δaxis2) with respect to each term's coefficient.

    Parameters
    ----------
    mount : "AZ-ZD" or "RA-DEC".
    terms : term names, all of the mount's.
    axis1, axis2 : ideal mechanical positions, degrees (AZ, ZD) or (HA, Dec); broadcastable.
    latitude : site latitude, degrees (used by the equatorial TF term).

    Returns
    -------
    ndarray, shape (len(terms), 2, N)
        Dimensionless: a coefficient in degrees times the basis gives degrees.
    """
    known = _terms_of(mount)
    a1, a2 = np.broadcast_arrays(np.atleast_1d(np.asarray(axis1, float)).ravel(),
                                 np.atleast_1d(np.asarray(axis2, float)).ravel())
    out = np.zeros((len(terms), 2, a1.size))
    one, zero = np.ones(a1.size), np.zeros(a1.size)
    if mount == "AZ-ZD":
        az = a1 * _D2R
        el = (90.0 - a2) * _D2R
        cos_e = _floor(np.cos(el), _COS_MIN)
        sin_e = np.sin(el)
        sec_e, tan_e = 1.0 / cos_e, sin_e / cos_e
        cot_e = np.cos(el) / _floor(sin_e, _SIN_MIN)
        sa, ca = np.sin(az), np.cos(az)
        # (ΔA, ΔE) per unit coefficient; ΔZD = −ΔE below.
        table = {
            "IA": (one, zero),
            "IE": (zero, one),
            "NPAE": (tan_e, zero),
            "CA": (sec_e, zero),
            "AN": (sa * tan_e, ca),
            "AW": (-ca * tan_e, sa),
            "TF": (zero, -np.cos(el)),
            "TX": (zero, -cot_e),
        }
        sign2 = -1.0
    else:
        h = a1 * _D2R
        d = a2 * _D2R
        cos_d = _floor(np.cos(d), _COS_MIN)
        sin_d = np.sin(d)
        sec_d, tan_d = 1.0 / cos_d, sin_d / cos_d
        sh, ch = np.sin(h), np.cos(h)
        phi = latitude * _D2R
        table = {
            "IH": (-one, zero),
            "ID": (zero, -one),
            "CH": (-sec_d, zero),
            "NP": (-tan_d, zero),
            "MA": (-ch * tan_d, sh),
            "ME": (sh * tan_d, ch),
            "TF": (math.cos(phi) * sh * sec_d,
                   math.cos(phi) * ch * sin_d - math.sin(phi) * np.cos(d)),
        }
        sign2 = 1.0
    for i, name in enumerate(terms):
        if name not in known:
            raise RequestRefused(f"pointing model: term {name!r} is not one of {mount} {list(known)}")
        f1, f2 = table[name]
        out[i, 0] = f1
        out[i, 1] = sign2 * f2
    return out


def _sky_weight(mount: str, axis2: np.ndarray) -> np.ndarray:
    """Factor turning an axis-1 angle into an angle on the sky: |cos E| or |cos δ|."""
    lat = (90.0 - axis2) if mount == "AZ-ZD" else axis2
    return np.maximum(np.abs(np.cos(lat * _D2R)), _COS_MIN)


@dataclass(frozen=True)
class PointingModel:
    """Coefficients (degrees) of one mount's terms; absent terms are 0.

    Parameters
    ----------
    mount : "AZ-ZD" or "RA-DEC".
    coefficients : term name → degrees.
    latitude : site latitude in degrees (the equatorial TF term needs it).
    """

    mount: str = "AZ-ZD"
    coefficients: Mapping[str, float] = field(default_factory=dict)
    latitude: float = 0.0

    def __hash__(self):
        return hash((self.mount, tuple(sorted(self.coefficients.items())), self.latitude))

    def __post_init__(self):
        known = _terms_of(self.mount)
        clean = {}
        for name, value in dict(self.coefficients).items():
            if name not in known:
                raise RequestRefused(
                    f"pointing model: term {name!r} is not one of {self.mount} {list(known)}")
            value = float(value)
            if not math.isfinite(value) or abs(value) > 10.0:
                raise RequestRefused(f"pointing model: {name} = {value} degrees is not plausible")
            clean[name] = value
        object.__setattr__(self, "coefficients", clean)

    @property
    def terms(self) -> tuple[str, ...]:
        """All terms of this mount, in the canonical order."""
        return MOUNT_TERMS[self.mount]

    def get(self, name: str) -> float:
        """Coefficient of a term in degrees (0 if unset)."""
        if name not in self.terms:
            raise RequestRefused(f"pointing model: term {name!r} is not one of {list(self.terms)}")
        return self.coefficients.get(name, 0.0)

    def replace(self, **coefficients: float) -> "PointingModel":
        """A copy with some coefficients (degrees) changed."""
        return PointingModel(self.mount, {**self.coefficients, **coefficients}, self.latitude)

    def corrections(self, axis1, axis2):
        """(Δaxis1, Δaxis2) in degrees at ideal mechanical positions (scalars or arrays)."""
        a1 = np.asarray(axis1, float)
        a2 = np.asarray(axis2, float)
        shape = np.broadcast_shapes(a1.shape, a2.shape)
        names = [n for n in self.terms if self.coefficients.get(n, 0.0) != 0.0]
        if not names:
            d1 = np.zeros(shape)
            d2 = np.zeros(shape)
        else:
            b = basis(self.mount, names, a1, a2, self.latitude)
            c = np.array([self.coefficients[n] for n in names])
            d1 = (c @ b[:, 0, :]).reshape(shape)
            d2 = (c @ b[:, 1, :]).reshape(shape)
        if not shape:
            return float(d1), float(d2)
        return d1, d2

    def apply(self, axis1, axis2):
        """Demand for the axes (degrees) for ideal mechanical positions (§14 step 3)."""
        d1, d2 = self.corrections(axis1, axis2)
        return np.add(axis1, d1), np.add(axis2, d2)

    def invert(self, axis1, axis2, *, tolerance: float = 1e-10, max_iterations: int = 50):
        """Ideal mechanical positions whose demand is the given axis positions (degrees).

        Fixed-point iteration ``x ← demand − Δ(x)`` until the step is below ``tolerance``
        degrees; raises :class:`TcsError` if it does not converge (absurd coefficients).
        """
        m1 = np.asarray(axis1, float)
        m2 = np.asarray(axis2, float)
        x1, x2 = m1, m2
        for _ in range(max_iterations):
            d1, d2 = self.corrections(x1, x2)
            n1, n2 = m1 - d1, m2 - d2
            step = max(np.max(np.abs(n1 - x1), initial=0.0), np.max(np.abs(n2 - x2), initial=0.0))
            x1, x2 = n1, n2
            if step < tolerance:
                break
        else:
            raise TcsError(f"pointing model inverse did not converge (last step {step:.3g} deg)")
        if np.ndim(x1) == 0:
            return float(x1), float(x2)
        return x1, x2


@dataclass(frozen=True)
class Sample:
    """One pointing measurement (one line of a dump file).

    Attributes
    ----------
    utc : Unix seconds (UTC) of the measurement.
    ra, dec : the target, ICRS J2000: hours, degrees.
    ideal1, ideal2 : the target's ideal mechanical position (observed place in the mount
        frame and orientation in use), degrees.
    axis1, axis2 : the axes' measured mechanical positions (REALPOS, i.e. including the
        OFFSET the operator set to centre the star), degrees.
    offset1, offset2 : the axes' OFFSET at that time, degrees (kept for the record).
    """

    utc: float
    ra: float
    dec: float
    ideal1: float
    ideal2: float
    axis1: float
    axis2: float
    offset1: float = 0.0
    offset2: float = 0.0


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    model : the fitted model (fixed terms at their given values).
    fitted : names of the fitted terms, the order of ``covariance``/``correlation``.
    errors : term → 1σ error in degrees (0 for fixed terms).
    covariance, correlation : (p, p) matrices of the fitted terms (degrees²; unitless).
    residuals : (N, 2) residuals on the sky after the fit, degrees (axis 1 × |cos E|).
    rms : radial RMS on the sky, degrees: sqrt(mean(r1² + r2²)).
    rms_axis : per-axis RMS on the sky, degrees.
    """

    model: PointingModel
    fitted: tuple[str, ...]
    errors: dict[str, float]
    covariance: np.ndarray
    correlation: np.ndarray
    residuals: np.ndarray
    rms: float
    rms_axis: tuple[float, float]

    @property
    def n_samples(self) -> int:
        return int(self.residuals.shape[0])

    @property
    def rms_arcsec(self) -> float:
        return self.rms * _ARCSEC

    def report(self) -> str:
        """Human-readable table: coefficients ± errors in arcsec, RMS, strong correlations."""
        lines = [f"pointing model fit: mount {self.model.mount}, {self.n_samples} samples, "
                 f"sky RMS {self.rms * _ARCSEC:.2f}\" "
                 f"(axis 1 {self.rms_axis[0] * _ARCSEC:.2f}\", axis 2 {self.rms_axis[1] * _ARCSEC:.2f}\")"]
        for name in self.model.terms:
            value = self.model.get(name) * _ARCSEC
            if name in self.fitted:
                lines.append(f"  {name:<5} {value:+12.3f}\"  ± {self.errors[name] * _ARCSEC:.3f}\"")
            elif name in self.model.coefficients:
                lines.append(f"  {name:<5} {value:+12.3f}\"  (fixed)")
        for i, a in enumerate(self.fitted):
            for j in range(i + 1, len(self.fitted)):
                if abs(self.correlation[i, j]) > 0.9:
                    lines.append(f"  correlation {a}/{self.fitted[j]} = {self.correlation[i, j]:+.3f}")
        return "\n".join(lines)


def fit(ideal1, ideal2, measured1, measured2, *, mount: str, terms: Iterable[str] | None = None,
        fixed: Mapping[str, float] | None = None, latitude: float = 0.0) -> FitResult:
    """Least-squares pointing model from ideal and measured mechanical positions.

    Parameters
    ----------
    ideal1, ideal2 : ideal mechanical positions of the stars, degrees (arrays of N).
    measured1, measured2 : where the axes were with each star centred, degrees.
    mount : "AZ-ZD" or "RA-DEC".
    terms : the terms to use (default: all of the mount's); fixed terms may be among them.
    fixed : term → value in degrees, held during the fit (and included in the model).
    latitude : site latitude, degrees.

    Returns
    -------
    FitResult

    Raises
    ------
    RequestRefused
        Unknown terms, fewer equations than free terms, or terms the samples cannot
        separate (the message names them: fix one of them).
    """
    known = _terms_of(mount)
    fixed = dict(fixed or {})
    use = tuple(known if terms is None else terms)
    for name in (*use, *fixed):
        if name not in known:
            raise RequestRefused(f"pointing model: term {name!r} is not one of {mount} {list(known)}")
    free = tuple(n for n in known if n in use and n not in fixed)
    i1 = np.atleast_1d(np.asarray(ideal1, float))
    i2 = np.atleast_1d(np.asarray(ideal2, float))
    m1 = np.atleast_1d(np.asarray(measured1, float))
    m2 = np.atleast_1d(np.asarray(measured2, float))
    n = i1.size
    if not (i2.size == m1.size == m2.size == n):
        raise RequestRefused("pointing model fit: ideal and measured positions differ in length")
    if 2 * n <= len(free):
        raise TcsError(f"pointing model fit: {n} samples are too few for {len(free)} terms "
                       f"({', '.join(free)})", FIT_IMPOSSIBLE)
    y1 = (m1 - i1 + 180.0) % 360.0 - 180.0
    y2 = m2 - i2
    if fixed:
        fixed_model = PointingModel(mount, fixed, latitude)
        f1, f2 = fixed_model.corrections(i1, i2)
        y1, y2 = y1 - f1, y2 - f2
    w = _sky_weight(mount, i2)
    y = np.concatenate([y1 * w, y2])
    if free:
        b = basis(mount, free, i1, i2, latitude)
        design = np.concatenate([b[:, 0, :] * w, b[:, 1, :]], axis=1).T   # (2N, p)
        scale = np.sqrt((design ** 2).sum(axis=0))
        scale[scale == 0.0] = 1.0
        dn = design / scale
        coef_n, _res, rank, sv = np.linalg.lstsq(dn, y, rcond=None)
        if rank < len(free):
            _u, _s, vt = np.linalg.svd(dn, full_matrices=False)
            weight = np.abs(vt[rank:]).max(axis=0)       # the null space's share of each term
            involved = [free[i] for i in range(len(free)) if weight[i] > 0.1]
            raise TcsError("pointing model fit: the samples cannot separate terms "
                           f"{', '.join(involved)}; fix one of them or add samples", FIT_IMPOSSIBLE)
        coef = coef_n / scale
        resid = y - design @ coef
        dof = max(2 * n - len(free), 1)
        s2 = float(resid @ resid) / dof
        cov_n = np.linalg.inv(dn.T @ dn) * s2
        cov = cov_n / np.outer(scale, scale)
        sig = np.sqrt(np.diag(cov))
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov / np.outer(sig, sig)
        corr = np.nan_to_num(corr)
    else:
        coef = np.zeros(0)
        resid = y
        cov = corr = np.zeros((0, 0))
        sig = np.zeros(0)
    coefficients = {**fixed, **{name: float(c) for name, c in zip(free, coef)}}
    model = PointingModel(mount, coefficients, latitude)
    residuals = np.stack([resid[:n], resid[n:]], axis=1)
    rms = float(np.sqrt(np.mean(residuals[:, 0] ** 2 + residuals[:, 1] ** 2)))
    rms_axis = (float(np.sqrt(np.mean(residuals[:, 0] ** 2))),
                float(np.sqrt(np.mean(residuals[:, 1] ** 2))))
    errors = {name: 0.0 for name in fixed}
    errors.update({name: float(s) for name, s in zip(free, sig)})
    return FitResult(model=model, fitted=free, errors=errors, covariance=cov, correlation=corr,
                     residuals=residuals, rms=rms, rms_axis=rms_axis)


def fit_samples(samples: Sequence[Sample], *, mount: str, terms: Iterable[str] | None = None,
                fixed: Mapping[str, float] | None = None, latitude: float = 0.0) -> FitResult:
    """:func:`fit` on recorded :class:`Sample` s (ideal vs measured axis positions)."""
    if not samples:
        raise TcsError("pointing model fit: no samples recorded", FIT_IMPOSSIBLE)
    cols = np.array([(s.ideal1, s.ideal2, s.axis1, s.axis2) for s in samples], float)
    return fit(cols[:, 0], cols[:, 1], cols[:, 2], cols[:, 3], mount=mount, terms=terms,
               fixed=fixed, latitude=latitude)
