"""Benchmark of the astrometry: µs of CPU per computed sample, fast path vs ``erfa.atco13``.

Run: ``python3 tools/bench/astrometry_cost.py``. Prints the figures, then (last line) one JSON
object with them. The goal is < 10 µs per sample amortised for trajectory generation (60
points at 2 s spacing per call); the baseline is ``erfa.atco13`` (full context per sample).

Cases:

* ``batch60_warm`` — the tracker's call: 60 points over 120 s, window sliding by 2 s per call,
  contexts mostly cached (one new context every 15 calls at the default 30 s interval).
* ``batch60_cold`` — the same on a fresh instance each time (every context computed).
* ``single`` — one sample per call (status: POINTING.CURRENT / TARGET values).
* ``inverse_single`` / ``inverse60`` — observed → ICRS (POINTING.CURRENT).
* ``atco13_batch60`` / ``atco13_single`` — the baseline, vectorised and scalar.

It also prints the largest difference of the fast path from atco13 over the samples (mas).
"""

from __future__ import annotations

import json
import math
import time

import erfa
import numpy as np

from tcs.pointing.astrometry import HUMIDITY, WAVELENGTH_UM, Astrometry, Refraction, Site, TimeBase

SITE = Site(52.38, 13.06, 40.0)
TIMEBASE = TimeBase(37.0, -0.17)
REFRACTION = Refraction(2, 10.0, 1005.0)
T0 = 1.72e9


def per_call_us(fn, n: int) -> float:
    """Best of 5 runs of n calls, µs of CPU per call."""
    best = float("inf")
    for _ in range(5):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, time.process_time() - t0)
    return best / n * 1e6


def atco13(ra_h, dec_deg, utc):
    days = np.floor(utc / 86400.0)
    return erfa.atco13(np.radians(ra_h * 15.0), np.radians(dec_deg), 0.0, 0.0, 0.0, 0.0,
                       2440587.5 + days, (utc - days * 86400.0) / 86400.0, TIMEBASE.ut1_utc,
                       math.radians(SITE.longitude), math.radians(SITE.latitude), SITE.height,
                       0.0, 0.0, REFRACTION.pressure, REFRACTION.temperature, HUMIDITY,
                       WAVELENGTH_UM)


def main() -> None:
    ra, dec = 5.5, 40.0
    steps = np.arange(60) * 2.0
    astro = Astrometry(SITE, TIMEBASE, REFRACTION)
    state = {"t": T0}

    def warm():
        state["t"] += 2.0
        astro.observed(ra, dec, state["t"] + steps)

    def cold():
        state["t"] += 2.0
        Astrometry(SITE, TIMEBASE, REFRACTION).observed(ra, dec, state["t"] + steps)

    def single():
        state["t"] += 0.1
        astro.observed(ra, dec, state["t"])

    obs = astro.observed(ra, dec, T0 + steps)

    def inverse_single():
        astro.icrs_from_observed(float(obs.az[0]), float(obs.zd[0]), T0)

    def inverse60():
        astro.icrs_from_observed(obs.az, obs.zd, T0 + steps)

    figures = {
        "batch60_warm_us_per_sample": per_call_us(warm, 300) / 60,
        "batch60_cold_us_per_sample": per_call_us(cold, 100) / 60,
        "single_us": per_call_us(single, 2000),
        "inverse_single_us": per_call_us(inverse_single, 500),
        "inverse60_us_per_sample": per_call_us(inverse60, 100) / 60,
        "atco13_batch60_us_per_sample": per_call_us(lambda: atco13(ra, dec, T0 + steps), 20) / 60,
        "atco13_single_us": per_call_us(lambda: atco13(ra, dec, T0), 500),
    }
    figures["ratio_atco13_to_batch60_warm"] = (figures["atco13_batch60_us_per_sample"]
                                               / figures["batch60_warm_us_per_sample"])
    figures["ratio_atco13_to_single"] = figures["atco13_single_us"] / figures["single_us"]

    # Accuracy over many stars and times (context age up to half the interval).
    rng = np.random.default_rng(1)
    n = 5000
    ras, decs = rng.uniform(0, 24, n), np.degrees(np.arcsin(rng.uniform(-1, 1, n)))
    utc = rng.uniform(T0, T0 + 86400.0, n)
    fast = Astrometry(SITE, TIMEBASE, REFRACTION).observed(ras, decs, utc)
    az, zd, *_ = atco13(ras, decs, utc)
    sep = erfa.seps(np.radians(fast.az), np.radians(90.0 - fast.zd), az, np.pi / 2 - zd)
    figures["max_fast_vs_atco13_mas"] = float(np.degrees(sep.max()) * 3.6e6)

    width = max(map(len, figures))
    for key, value in figures.items():
        print(f"{key:<{width}}  {value:10.3f}")
    print(json.dumps({k: round(v, 4) for k, v in figures.items()}))


if __name__ == "__main__":
    main()
