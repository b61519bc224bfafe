"""The point queue of ``<axis>.TRAJECTORY`` and its smooth interpolation (spec §5.1.1).

How it works
------------
A :class:`TrajectoryQueue` holds (time, position) points — UT1 seconds since 1970, axis
units — in strictly increasing time, at most ``capacity`` of them (``FREEPOINTS`` is what is
left). :meth:`TrajectoryQueue.add_points` takes a whole batch or nothing: a time that does not
increase is refused (``RequestRefused``, the offending index named), a batch that does not fit
raises :class:`TrajectoryBufferFull` (Appendix B 12, ``nobuffer``). Points wholly in the past
(before the segment that contains ``now``) are dropped and counted, so the axis module can
tell the client.

Interpolation: quintic Hermite segments with C2 continuity, built locally.
  At every point ("knot") the first and second derivatives are those of the polynomial
  through the ``stencil`` nearest points (5 by default: two before, two after; Fornberg
  finite-difference weights, any spacing). Between two knots the quintic matching position,
  velocity and acceleration at both ends is used. Position, velocity and acceleration are
  therefore continuous everywhere (the drive sees no acceleration steps at knots), and a
  segment depends only on the points within two knots of it.

Why local and not a global C2 (natural) spline: a spline's coefficients change everywhere
when a point is appended, so the segment being followed would jump each time a client
refills the queue. Here a knot's derivatives only change while its right-hand neighbours are
still arriving, and a knot is *frozen* the first time a follower samples a segment touching
it (``sample(t, freeze=True)``), so the path under the axis never changes. Accuracy (maximum
error away from the ends, points every 2 s): a 2° sinusoid of period 60 s (0.21°/s) is
reproduced to 0.014″ (0.0004″ with 1 s points); a cubic Hermite with centred-difference
slopes (Catmull-Rom) gives 1.07″ and a global natural cubic spline 0.036″; a sidereal-rate
path with curvature is exact to the float resolution of the UT1 time stamps (< 1e-5″). At the
first and last knots the stencil is one-sided and the error is a few times larger (0.08″ on
that sinusoid). ``tools/bench/motion_cost.py`` prints these figures.

On a cyclic axis each new point is unwrapped to within half a cycle of the point before it,
so 359.9 → 0.1 is a step of +0.2, not −359.8; where the whole path sits (``k·cycle``) is the
follower's choice.

``add_points`` may run on the asyncio side while the control loop samples: every public
method takes an internal lock (uncontended: ~0.1 µs). ``sample`` costs ~1 µs.
"""

from __future__ import annotations

import bisect
import math
import threading
from typing import NamedTuple, Sequence

from tcs.errors import ErrorNumber, RangeRefused, RequestRefused, TcsError, TypeRefused

#: shortest accepted spacing of two points, s (strictly increasing, and not absurdly close)
MIN_SPACING = 1e-6


class TrajectoryBufferFull(TcsError):
    """The batch does not fit into the trajectory queue (Appendix B 12, nobuffer)."""

    default_number = ErrorNumber.NOBUFFER


class AddResult(NamedTuple):
    """What :meth:`TrajectoryQueue.add_points` did: points accepted from the batch, and points
    (old or new) dropped because they were already in the past."""

    accepted: int
    dropped: int


def fd_weights(z: float, x: Sequence[float], m: int) -> list[list[float]]:
    """Finite-difference weights (Fornberg 1988) for derivatives 0..m at ``z`` from nodes ``x``.

    Returns ``w`` with ``w[k][i]`` the weight of node ``i`` for the k-th derivative.
    """
    n = len(x)
    c = [[0.0] * n for _ in range(m + 1)]
    c[0][0] = 1.0
    c1 = 1.0
    c4 = x[0] - z
    for i in range(1, n):
        mn = min(i, m)
        c2 = 1.0
        c5 = c4
        c4 = x[i] - z
        for j in range(i):
            c3 = x[i] - x[j]
            c2 *= c3
            if j == i - 1:
                for k in range(mn, 0, -1):
                    c[k][i] = c1 * (k * c[k - 1][i - 1] - c5 * c[k][i - 1]) / c2
                c[0][i] = -c1 * c5 * c[0][i - 1] / c2
            for k in range(mn, 0, -1):
                c[k][j] = (c4 * c[k][j] - k * c[k - 1][j]) / c3
            c[0][j] = c4 * c[0][j] / c3
        c1 = c2
    return c


def segment_extremes(coef: tuple) -> tuple[float, float, float]:
    """Largest |velocity|, |acceleration| and |jerk| of one quintic segment
    ``(c0..c5, h)`` (position ``sum c_k s^k``, ``s = (t - t_i) / h``), exactly: the
    acceleration's extremes are where the (quadratic) jerk is zero, the velocity's where the
    acceleration is zero, found by bisection between those points, where the acceleration is
    monotonic. (Sampling 9 points a segment missed 2.3 % of the acceleration of a sine of
    5 s period given at 2 s spacing: more than the 2 % margin the follower keeps.)"""
    _, c1, c2, c3, c4, c5, h = coef

    def vel(s: float) -> float:
        return c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))

    def acc(s: float) -> float:
        return 2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))

    def jerk(s: float) -> float:
        return 6 * c3 + s * (24 * c4 + s * 60 * c5)

    # roots of the jerk 60 c5 s^2 + 24 c4 s + 6 c3 in (0, 1)
    qa, qb, qc = 60 * c5, 24 * c4, 6 * c3
    roots: list[float] = []
    if qa != 0.0:
        disc = qb * qb - 4 * qa * qc
        if disc >= 0.0:
            r = math.sqrt(disc)
            roots = [(-qb - r) / (2 * qa), (-qb + r) / (2 * qa)]
    elif qb != 0.0:
        roots = [-qc / qb]
    points = [0.0] + sorted(x for x in roots if 0.0 < x < 1.0) + [1.0]
    accs = [acc(s) for s in points]
    amax = max(abs(a) for a in accs)
    vmax = max(abs(vel(s)) for s in points)
    for k in range(len(points) - 1):
        lo, hi, a_lo = points[k], points[k + 1], accs[k]
        if a_lo * accs[k + 1] >= 0.0:
            continue
        for _ in range(48):                    # the acceleration is monotonic on [lo, hi]
            mid = 0.5 * (lo + hi)
            if (acc(mid) < 0.0) == (a_lo < 0.0):
                lo = mid
            else:
                hi = mid
        vmax = max(vmax, abs(vel(0.5 * (lo + hi))))
    jerks = [jerk(0.0), jerk(1.0)]
    if qa != 0.0 and 0.0 < -qb / (2 * qa) < 1.0:
        jerks.append(jerk(-qb / (2 * qa)))
    jmax = max(abs(j) for j in jerks)
    return vmax / h, amax / (h * h), jmax / h ** 3


class TrajectoryQueue:
    """Time-stamped positions of one axis with C2 quintic interpolation.

    Parameters
    ----------
    capacity:
        Most points held at once (from the axis configuration).
    cycle:
        Period of a cyclic axis (points are unwrapped), ``None`` for a linear axis.
    stencil:
        Points used for the derivatives at a knot (odd, 3…9; 5 by default).
    """

    def __init__(self, capacity: int, cycle: float | None = None, stencil: int = 5):
        if not (isinstance(capacity, int) and capacity >= 2):
            raise ValueError(f"trajectory capacity must be an integer >= 2, got {capacity!r}")
        if stencil not in (3, 5, 7, 9):
            raise ValueError(f"trajectory stencil must be 3, 5, 7 or 9 points, got {stencil!r}")
        self.capacity = capacity
        self.cycle = cycle
        self.stencil = stencil
        self._lock = threading.Lock()
        self._t: list[float] = []
        self._p: list[float] = []
        self._v: list[float] = []     # first derivative at each knot
        self._a: list[float] = []     # second derivative at each knot
        self._frozen = 0              # knots [0, _frozen) never change again
        self._seg = 0                 # cursor: last segment sampled
        self._coef_seg = -1           # segment whose quintic coefficients are cached
        self._coef = (0.0,) * 7

    # -- size and times ----------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._t)

    @property
    def free_points(self) -> int:
        """``FREEPOINTS``: how many more points fit."""
        return self.capacity - len(self._t)

    def free_points_at(self, now: float) -> int:
        """``FREEPOINTS`` at UT1 ``now``: points already executed count as free, as
        :meth:`add_points` drops them (all but the last one at or before ``now``, which starts
        the current segment; once the path's end is past, all of them); so it rises while a
        run goes on and is the whole capacity after it ended."""
        with self._lock:
            return self.capacity - len(self._t) + self._past_count(self._t, now)

    @property
    def start_time(self) -> float | None:
        """``STARTTIME``: time of the first queued point (``None`` when empty)."""
        t = self._t
        return t[0] if t else None

    @property
    def end_time(self) -> float | None:
        """Time of the last queued point (``None`` when empty)."""
        t = self._t
        return t[-1] if t else None

    def remaining(self, now: float) -> float:
        """``RUNTIME``: seconds of path left after ``now`` (0 when empty or over)."""
        t = self._t
        return max(0.0, t[-1] - now) if t else 0.0

    def positions(self) -> tuple[list[float], list[float]]:
        """Copies of the queued times and (unwrapped) positions."""
        with self._lock:
            return list(self._t), list(self._p)

    # -- changing the queue ------------------------------------------------------------------

    def add_points(self, times: Sequence[float], positions: Sequence[float],
                   now: float | None = None) -> AddResult:
        """``ADDPOINTS``: append a batch of points, all or nothing.

        Parameters
        ----------
        times, positions:
            Equal-length sequences; times UT1 s, strictly increasing and after the last
            queued point.
        now:
            Current UT1; points wholly in the past are dropped (the last one at or before
            ``now`` stays as the start of the current segment if a later point exists).

        Returns
        -------
        AddResult

        Raises
        ------
        RequestRefused
            Lengths differ, a value is not finite, or a time does not increase (the message
            names the batch index and both times).
        TrajectoryBufferFull
            The points do not fit (``FREEPOINTS`` tells how many would).
        """
        times = [float(x) for x in times]
        positions = [float(x) for x in positions]
        if len(times) != len(positions):
            raise RequestRefused(f"trajectory: {len(times)} times but {len(positions)} positions")
        for i, (t, p) in enumerate(zip(times, positions)):
            if not (math.isfinite(t) and math.isfinite(p)):
                raise TypeRefused(f"trajectory point {i}: time {t!r} / position {p!r} "
                                  f"is not a finite number")
        with self._lock:
            last = self._t[-1] if self._t else None
            for i, t in enumerate(times):
                if last is not None and not t - last >= MIN_SPACING:
                    which = "the last queued point" if i == 0 else f"point {i - 1}"
                    raise RangeRefused(f"trajectory point {i}: time {t!r} is not after "
                                       f"{which} ({last!r}); times must increase")
                last = t
            n_old = len(self._t)
            drop = self._past_count(self._t + times, now)
            if n_old + len(times) - drop > self.capacity:
                raise TrajectoryBufferFull(
                    f"trajectory queue full: {len(times)} points offered, "
                    f"{self.capacity - n_old + drop} free")
            if self.cycle is not None:
                positions = self._unwrap(positions)
            self._t.extend(times)
            self._p.extend(positions)
            self._v.extend([0.0] * len(times))
            self._a.extend([0.0] * len(times))
            self._update_knots(n_old)
            self._drop(drop)
            return AddResult(len(times), drop)

    def drop_before(self, now: float) -> int:
        """Drop points wholly in the past (see :meth:`add_points`); returns how many."""
        with self._lock:
            n = self._past_count(self._t, now)
            self._drop(n)
            return n

    def clear(self) -> None:
        """Remove every point (``RUN=0`` frees the buffers)."""
        with self._lock:
            self._t.clear(); self._p.clear(); self._v.clear(); self._a.clear()
            self._frozen = 0
            self._seg = 0
            self._coef_seg = -1

    # -- sampling ----------------------------------------------------------------------------

    def sample(self, t: float, freeze: bool = False) -> tuple[float, float, float]:
        """Position, velocity and acceleration of the path at ``t``.

        Outside ``[start_time, end_time]`` the state at the nearer end is returned (held, not
        extrapolated). With ``freeze`` the segment's knots never change again (the follower
        uses this, so appending points cannot move the path under the axis).

        Raises
        ------
        TcsError
            The queue is empty (nopoints, 11).
        """
        with self._lock:
            ts = self._t
            n = len(ts)
            if n == 0:
                raise TcsError("trajectory queue is empty", ErrorNumber.NOPOINTS)
            if n == 1 or t <= ts[0]:
                return self._p[0], self._v[0], self._a[0]
            if t >= ts[-1]:
                return self._p[-1], self._v[-1], self._a[-1]
            i = self._seg
            if not (i < n - 1 and ts[i] <= t < ts[i + 1]):
                i = bisect.bisect_right(ts, t) - 1
                self._seg = i
            if freeze and self._frozen < i + 2:
                self._frozen = i + 2
            if self._coef_seg != i:
                self._coefficients(i)
            c0, c1, c2, c3, c4, c5, h = self._coef
            s = (t - ts[i]) / h
            p = c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))
            v = (c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))) / h
            a = (2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))) / (h * h)
            return p, v, a

    def usage(self, t0: float, t1: float) -> tuple[float, float, float]:
        """Largest |velocity|, |acceleration| and |jerk| of the path over ``[t0, t1]``
        (whole segments, exactly: see :func:`segment_extremes`; 0 for an empty queue)."""
        with self._lock:
            ts = self._t
            n = len(ts)
            if n == 0:
                return 0.0, 0.0, 0.0
            vmax = max(abs(self._v[0]), abs(self._v[-1])) if n == 1 else 0.0
            amax = jmax = 0.0
            i0 = max(0, bisect.bisect_right(ts, t0) - 1)
            i1 = min(n - 1, bisect.bisect_left(ts, t1) + 1)
            if t0 < ts[0]:
                vmax, amax = abs(self._v[0]), abs(self._a[0])
            if t1 > ts[-1]:
                vmax, amax = max(vmax, abs(self._v[-1])), max(amax, abs(self._a[-1]))
            saved = self._coef_seg, self._coef
            for i in range(i0, min(i1, n - 1)):
                self._coefficients(i)
                v, a, j = segment_extremes(self._coef)
                vmax, amax, jmax = max(vmax, v), max(amax, a), max(jmax, j)
            self._coef_seg, self._coef = saved
            return vmax, amax, jmax

    # -- internals (called with the lock held) -----------------------------------------------

    def _coefficients(self, i: int) -> None:
        t, p, v, a = self._t, self._p, self._v, self._a
        h = t[i + 1] - t[i]
        p0, p1 = p[i], p[i + 1]
        v0, v1 = v[i] * h, v[i + 1] * h
        a0, a1 = a[i] * h * h, a[i + 1] * h * h
        dp = p1 - p0
        self._coef = (
            p0, v0, 0.5 * a0,
            10 * dp - 6 * v0 - 4 * v1 - 0.5 * (3 * a0 - a1),
            -15 * dp + 8 * v0 + 7 * v1 + 0.5 * (3 * a0 - 2 * a1),
            6 * dp - 3 * (v0 + v1) - 0.5 * (a0 - a1),
            h,
        )
        self._coef_seg = i

    def _unwrap(self, positions: list[float]) -> list[float]:
        c = self.cycle
        prev = self._p[-1] if self._p else None
        out = []
        for p in positions:
            if prev is not None:
                p = prev + math.remainder(p - prev, c)
            out.append(p)
            prev = p
        return out

    def _update_knots(self, n_old: int) -> None:
        """(Re)compute derivatives of the knots whose stencil changed by appending."""
        t, p = self._t, self._p
        n = len(t)
        w = min(self.stencil, n)
        half = self.stencil // 2
        # a knot's stencil grows while it reaches past the old end (or the queue was shorter
        # than one stencil); every other knot keeps its derivatives
        first = max(self._frozen, n_old - half if n_old >= self.stencil else 0)
        for k in range(first, n):
            lo = max(0, min(k - half, n - w))
            hi = lo + w
            tk = t[k]
            weights = fd_weights(0.0, [x - tk for x in t[lo:hi]], 2)
            seg = p[lo:hi]
            self._v[k] = sum(wi * pi for wi, pi in zip(weights[1], seg))
            self._a[k] = sum(wi * pi for wi, pi in zip(weights[2], seg)) if w > 2 else 0.0
        if first <= self._coef_seg + 1:
            self._coef_seg = -1

    @staticmethod
    def _past_count(times: list[float], now: float | None) -> int:
        """Points before the segment containing ``now``; all of them if none is after now."""
        if now is None or not times:
            return 0
        j = bisect.bisect_right(times, now)      # times[:j] are <= now
        if j == len(times):
            return j                              # nothing left in the future
        return max(0, j - 1)

    def _drop(self, n: int) -> None:
        if n <= 0:
            return
        del self._t[:n], self._p[:n], self._v[:n], self._a[:n]
        self._frozen = max(0, self._frozen - n)
        self._seg = max(0, self._seg - n)
        self._coef_seg = -1
