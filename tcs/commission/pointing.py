"""``tcs-commission pointing``: samples for a pointing model, the fit, and a report directory.

Where the samples come from (one of):

* ``--dump FILE`` — a dump file written by the service (POINTINGPARAMS.DUMPFILE) or by an
  earlier run of this tool;
* ``--synthetic N`` — for the simulator: N positions spread over the sky (azimuth on a
  golden-angle spiral, elevation 15–85° evenly in sin E; equatorial mounts: hour angle ±5 h,
  every declination above 15° altitude), their ICRS place at the time of the "measurement"
  (:class:`~tcs.pointing.astrometry.Astrometry` with the file's site and time base), and
  measured positions from a known model (``--true TERM=ARCSEC``, default a plausible set)
  plus Gaussian noise on the sky (``--noise``, arcsec). The default when the hardware file
  has ``[simulation]`` and no source is given (N = 40);
* ``--guided STARS`` — a guided run on the real telescope: STARS is a text file
  ``name ra_hours dec_degrees`` per line (ICRS J2000, '#' comments). The visible stars
  (inside the axis limits, elevation 15–85°) best spread over the sky are offered one after
  the other (up to ``--count``); for each, point the telescope with the service, centre the
  star, and type the axes' positions (REALPOS, degrees) as ``AXIS1 AXIS2`` (``s`` skips,
  ``q`` ends). The ideal position is computed for the moment the line is entered; every
  sample is appended to ``samples.dump`` at once, so an interrupted run keeps its data.

The fit (:func:`tcs.pointing.model.fit_samples`) uses ``--terms`` (default: all terms of
the mount) with ``--fix TERM=ARCSEC`` held; the report directory ``--out`` (default
``pointing-<UTC time>``) gets :mod:`tcs.commission.pointing_report`'s files, with PNG plots
unless ``--no-plots`` (they need matplotlib, the ``commission`` extra).

A fit with fewer than :data:`MIN_SAMPLES_PER_TERM` (3) samples per fitted term is refused
(exit 1) unless ``--force``: with 6 samples for 8 terms the least-squares solution follows the
noise (thousands of arcseconds, exit 0 before). The report and the output warn about too few
samples and about strongly correlated terms.

Exit codes: 0 fitted and written, 1 the fit failed or was refused (too few samples,
inseparable terms), 2 bad options / unreadable dump / no matplotlib without ``--no-plots``.
"""

from __future__ import annotations

import datetime
import math
import sys
import time
from pathlib import Path

import numpy as np

from tcs.errors import TcsError
from tcs.pointing.astrometry import Astrometry, Refraction, Site, TimeBase
from tcs.pointing.model import MOUNT_TERMS, PointingModel, Sample, fit_samples
from tcs.pointing.storage import DumpHeader, append_sample, load_dump, write_dump_header

from tcs.commission import plots
from tcs.commission.common import CommissionError, ExitCode, Outcome
from tcs.commission.pointing_report import ARCSEC, write_report

#: The "true" model of synthetic samples, arcsec (TPOINT-like magnitudes of a real mount).
DEFAULT_TRUE = {
    "AZ-ZD": {"IA": 45.0, "IE": -25.0, "NPAE": 8.0, "CA": -15.0, "AN": 12.0, "AW": -6.0, "TF": 20.0},
    "RA-DEC": {"IH": 30.0, "ID": -20.0, "CH": 10.0, "NP": 5.0, "MA": 15.0, "ME": -12.0, "TF": 18.0},
}
MIN_SAMPLES_PER_TERM = 3
GOLDEN_ANGLE = 180.0 * (3.0 - math.sqrt(5.0))
MIN_ELEVATION, MAX_ELEVATION = 15.0, 85.0


def add_parser(subparsers, parents) -> None:
    p = subparsers.add_parser("pointing", parents=parents,
                              help="sample stars / read a dump, fit a pointing model, write a report",
                              description=__doc__.split("\n\n")[0])
    src = p.add_mutually_exclusive_group()
    src.add_argument("--dump", metavar="FILE", help="fit the samples of this dump file")
    src.add_argument("--synthetic", type=int, metavar="N", help="synthesise N samples (simulator)")
    src.add_argument("--guided", metavar="STARS", help="guided run with this star list (real telescope)")
    p.add_argument("--out", metavar="DIR", help="report directory (default pointing-<UTC time>)")
    p.add_argument("--terms", help="comma-separated terms to fit (default: all of the mount's)")
    p.add_argument("--fix", action="append", default=[], metavar="TERM=ARCSEC",
                   help="hold a term at a value (repeatable)")
    p.add_argument("--true", action="append", default=[], metavar="TERM=ARCSEC",
                   help="synthetic: the true model (repeatable; default a plausible model)")
    p.add_argument("--noise", type=float, default=1.5, help="synthetic: noise on the sky, arcsec (default 1.5)")
    p.add_argument("--seed", type=int, default=1, help="synthetic: random seed (default 1)")
    p.add_argument("--count", type=int, default=30, help="guided: stars to offer (default 30)")
    p.add_argument("--no-plots", action="store_true", help="no PNG files (no matplotlib needed)")


def parse_terms(mount: str, text: str | None, fixes: list[str]) -> tuple[tuple[str, ...] | None, dict]:
    """``(--terms, --fix)`` → (terms or None, {term: degrees}); exit 2 for unknown terms."""
    known = MOUNT_TERMS[mount]
    terms = None
    if text:
        terms = tuple(t.strip().upper() for t in text.split(",") if t.strip())
        bad = [t for t in terms if t not in known]
        if bad:
            raise CommissionError(f"--terms: {', '.join(bad)} not among the {mount} terms "
                                  f"{', '.join(known)}", ExitCode.USAGE)
    return terms, parse_assignments(mount, fixes, "--fix")


def parse_assignments(mount: str, items: list[str], option: str) -> dict[str, float]:
    """``["IA=30", …]`` (arcsec) → {term: degrees}."""
    known = MOUNT_TERMS[mount]
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip().upper()
        try:
            if not sep or name not in known:
                raise ValueError
            out[name] = float(value) / ARCSEC
        except ValueError:
            raise CommissionError(f"{option} {item!r}: use TERM=ARCSEC with a term of "
                                  f"{', '.join(known)}", ExitCode.USAGE) from None
    return out


def dump_header(config, mount: str) -> DumpHeader:
    s, t = config.site, config.time
    return DumpHeader(mount=mount, site=Site(s.latitude, s.longitude, s.height),
                      timebase=TimeBase(t.tai_utc, t.ut1_utc), refraction=Refraction())


def sky_plan(mount: str, n: int, latitude: float, zd_range: tuple[float, float] = (0.0, 90.0)):
    """N ideal positions spread over the sky: (axis1, axis2) arrays in degrees."""
    if mount == "AZ-ZD":
        lo_el = max(MIN_ELEVATION, 90.0 - zd_range[1])
        hi_el = min(MAX_ELEVATION, 90.0 - max(zd_range[0], 0.0))
        i = np.arange(n)
        az = np.mod(i * GOLDEN_ANGLE, 360.0)
        s = np.sin(np.radians(lo_el)) + (np.sin(np.radians(hi_el)) - np.sin(np.radians(lo_el))) * (i + 0.5) / n
        return az, 90.0 - np.degrees(np.arcsin(s))
    # equatorial: hour angle ±75°, declinations that stay above MIN_ELEVATION
    phi = math.radians(latitude)
    ha, dec = [], []
    k = 0
    while len(ha) < n and k < 100 * n:
        h = -75.0 + 150.0 * ((k * 0.618034) % 1.0)
        d = -60.0 + 145.0 * ((k + 0.5) / (n * 3) % 1.0)
        k += 1
        alt = math.degrees(math.asin(math.sin(phi) * math.sin(math.radians(d)) +
                                     math.cos(phi) * math.cos(math.radians(d)) * math.cos(math.radians(h))))
        if MIN_ELEVATION <= alt <= MAX_ELEVATION and abs(d) < 85.0:
            ha.append(h)
            dec.append(d)
    return np.array(ha), np.array(dec)


def synthesise(config, mount: str, n: int, true: dict[str, float], noise_arcsec: float,
               seed: int, utc0: float | None = None) -> tuple[DumpHeader, list[Sample]]:
    """Synthetic samples of ``true`` (degrees) plus noise (see the module docstring)."""
    header = dump_header(config, mount)
    astro = Astrometry(header.site, header.timebase, header.refraction)
    zd_range = (0.0, 90.0)
    for axis in config.axes.values():
        if axis.module == "ZD" and axis.index is None:
            zd_range = (max(0.0, axis.min), min(90.0, axis.max))
    i1, i2 = sky_plan(mount, n, header.site.latitude, zd_range)
    n = len(i1)
    utc0 = time.time() if utc0 is None else utc0
    utc = utc0 + 60.0 * np.arange(n)
    if mount == "AZ-ZD":
        ra, dec = astro.icrs_from_observed(i1, i2, utc)
        w = np.maximum(np.abs(np.cos(np.radians(90.0 - i2))), 1e-3)
    else:
        ra, dec = astro.icrs_from_hadec(i1 / 15.0, i2, utc)
        w = np.maximum(np.abs(np.cos(np.radians(i2))), 1e-3)
    model = PointingModel(mount, true, header.site.latitude)
    m1, m2 = model.apply(i1, i2)
    rng = np.random.default_rng(seed)
    sigma = noise_arcsec / ARCSEC
    m1 = m1 + rng.normal(0.0, sigma, n) / w
    m2 = m2 + rng.normal(0.0, sigma, n)
    samples = [Sample(float(utc[k]), float(ra[k]), float(dec[k]), float(i1[k]), float(i2[k]),
                      float(m1[k]), float(m2[k])) for k in range(n)]
    return header, samples


def read_stars(path: str) -> list[tuple[str, float, float]]:
    """``name ra_hours dec_degrees`` lines; exit 2 naming file and line for a bad one."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CommissionError(f"--guided {path}: cannot read: {exc}", ExitCode.USAGE) from None
    stars = []
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        try:
            name, ra, dec = " ".join(parts[:-2]), float(parts[-2]), float(parts[-1])
            if not name or not 0.0 <= ra < 24.0 or not -90.0 <= dec <= 90.0:
                raise ValueError
        except (ValueError, IndexError):
            raise CommissionError(f"{path}, line {number}: expected 'name ra_hours dec_degrees'",
                                  ExitCode.USAGE) from None
        stars.append((name, ra, dec))
    return stars


def _spread(az: np.ndarray, el: np.ndarray, count: int) -> list[int]:
    """Greedy farthest-point choice on the sphere, starting at the highest star."""
    a, e = np.radians(az), np.radians(el)
    v = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    chosen = [int(np.argmax(el))]
    best = v @ v[chosen[0]]
    while len(chosen) < min(count, len(az)):
        k = int(np.argmin(best))
        chosen.append(k)
        best = np.maximum(best, v @ v[k])
    return chosen


def guided(config, mount: str, stars_file: str, count: int, dump: Path, stdin, stderr,
           clock=time.time) -> tuple[DumpHeader, list[Sample]]:
    """The interactive guided run (see the module docstring); samples also go to ``dump``."""
    stars = read_stars(stars_file)
    header = dump_header(config, mount)
    astro = Astrometry(header.site, header.timebase, header.refraction)
    now = clock()
    obs = astro.observed(np.array([s[1] for s in stars]), np.array([s[2] for s in stars]),
                         np.full(len(stars), now))
    el = 90.0 - np.atleast_1d(obs.zd)
    visible = np.flatnonzero((el >= MIN_ELEVATION) & (el <= MAX_ELEVATION))
    if visible.size == 0:
        raise CommissionError(f"{stars_file}: none of its {len(stars)} stars is between "
                              f"{MIN_ELEVATION:g}° and {MAX_ELEVATION:g}° elevation now", ExitCode.FAILED)
    order = [int(visible[i]) for i in _spread(np.atleast_1d(obs.az)[visible], el[visible], count)]
    write_dump_header(dump, header)
    names = ("AZ ZD", "HA Dec") if mount == "AZ-ZD" else ("HA Dec", "HA Dec")
    samples: list[Sample] = []
    for i, k in enumerate(order, 1):
        name, ra, dec = stars[k]
        o = astro.observed(ra, dec, clock())
        where = f"AZ {o.az:.3f} ZD {o.zd:.3f}" if mount == "AZ-ZD" else f"HA {o.ha:.4f} h Dec {o.dec:.3f}"
        stderr.write(f"[{i}/{len(order)}] {name}: now at {where}. Centre it, then type the axes' "
                     f"positions '{names[0]}' in degrees (s = skip, q = finish): ")
        stderr.flush()
        line = stdin.readline()
        if not line or line.strip().lower() == "q":
            break
        if line.strip().lower() == "s":
            continue
        try:
            a1, a2 = (float(x) for x in line.split())
        except ValueError:
            stderr.write("  not two numbers: star skipped\n")
            continue
        t = clock()
        o = astro.observed(ra, dec, t)
        ideal = (o.az, o.zd) if mount == "AZ-ZD" else (o.ha * 15.0, o.dec)
        sample = Sample(t, ra, dec, float(ideal[0]), float(ideal[1]), a1, a2)
        append_sample(dump, sample)
        samples.append(sample)
    return header, samples


def run(args, config) -> Outcome:
    out = Outcome("pointing")
    if not args.no_plots and not plots.available():
        raise CommissionError("the PNG plots need matplotlib: pip install 'tcs[commission]', or "
                              "pass --no-plots", ExitCode.USAGE)
    directory = Path(args.out or datetime.datetime.now(datetime.timezone.utc)
                     .strftime("pointing-%Y%m%dT%H%M%SZ"))
    synthetic = args.synthetic
    if args.dump is None and args.guided is None and synthetic is None:
        if config.simulation is None:
            raise CommissionError("give --dump FILE, --guided STARS or --synthetic N (no "
                                  "[simulation] in the hardware file)", ExitCode.USAGE)
        synthetic = 40
    if args.dump is not None:
        try:
            header, samples = load_dump(args.dump)
        except TcsError as exc:
            raise CommissionError(exc.message, ExitCode.USAGE) from None
        mount, source = header.mount, f"dump file {args.dump}"
    else:
        mount = config.mount.type
        if mount not in MOUNT_TERMS:
            raise CommissionError(f"mount {mount}: pointing models exist for "
                                  f"{', '.join(MOUNT_TERMS)}", ExitCode.USAGE)
        if args.guided is not None:
            if args.count < 3:
                raise CommissionError("--count must be at least 3", ExitCode.USAGE)
            directory.mkdir(parents=True, exist_ok=True)
            header, samples = guided(config, mount, args.guided, args.count,
                                     directory / "samples.dump", sys.stdin, sys.stderr)
            source = f"guided run with {args.guided}"
        else:
            if not 3 <= synthetic <= 10000 or not (math.isfinite(args.noise) and args.noise >= 0):
                raise CommissionError("--synthetic needs 3..10000 samples and --noise >= 0",
                                      ExitCode.USAGE)
            true = parse_assignments(mount, args.true, "--true") if args.true else {
                k: v / ARCSEC for k, v in DEFAULT_TRUE[mount].items()}
            header, samples = synthesise(config, mount, synthetic, true, args.noise, args.seed)
            source = f"{len(samples)} synthetic samples (noise {args.noise:g}\", seed {args.seed})"
            out.data["true_model_arcsec"] = {k: v * ARCSEC for k, v in true.items()}
    terms, fixed = parse_terms(mount, args.terms, args.fix)
    fitted = [t for t in (terms or MOUNT_TERMS[mount]) if t not in fixed]
    needed = MIN_SAMPLES_PER_TERM * len(fitted)
    if len(samples) < needed and not args.force:
        raise CommissionError(
            f"too few samples: {len(samples)} for {len(fitted)} terms ({', '.join(fitted)}); a "
            f"trustworthy fit needs at least {MIN_SAMPLES_PER_TERM} per term ({needed}): take "
            "more samples, fit fewer terms (--terms, --fix), or --force",
            ExitCode.FAILED, {"n_samples": len(samples), "needed": needed})
    try:
        result = fit_samples(samples, mount=mount, terms=terms, fixed=fixed,
                             latitude=header.site.latitude)
    except TcsError as exc:
        raise CommissionError(exc.message, ExitCode.FAILED, {"n_samples": len(samples)}) from None
    report = write_report(directory, header, samples, result, source=source,
                          make_plots=not args.no_plots)
    out.data.update(report)
    out.lines.append(result.report())
    out.lines.extend(f"WARNING: {w}" for w in report["warnings"])
    out.lines.append(f"report written to {directory}/ ({', '.join(Path(f).name for f in report['files'])})")
    return out
