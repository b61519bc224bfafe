"""The report directory of a pointing fit: Markdown, JSON, the model file, the samples, plots.

Files written by :func:`write_report` into one directory (created if needed):

* ``report.md`` — summary (samples, RMS before and after the fit), the coefficients with
  their 1σ errors in arcsec, the correlation matrix of the fitted terms with the strong
  correlations (|r| > 0.9) named, and the figures;
* ``model.json`` — the same for scripts: coefficients (degrees and arcsec) with errors and a
  ``fixed`` flag, correlation and covariance matrices, RMS figures, and every sample with its
  ideal position and residuals;
* ``pointing.model`` — the fitted model in the TCS's saved-model format
  (:class:`tcs.pointing.storage.ModelStore`), ready to be copied into the service's model
  directory and loaded with POINTINGPARAMS.LOAD;
* ``samples.dump`` — the samples in dump-file format (what was fitted);
* ``residuals_*.png``, ``skymap.png`` — :mod:`tcs.commission.plots` (unless ``plots=False``).

Blocking file I/O; pure otherwise.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from tcs.pointing.model import FitResult, Sample
from tcs.pointing.storage import DumpHeader, ModelStore, append_sample, write_dump_header

from tcs.commission import plots

ARCSEC = 3600.0
STRONG = 0.9


def raw_rms(mount: str, samples: Sequence[Sample]) -> float:
    """Radial RMS on the sky of measured − ideal before any model, degrees."""
    i1 = np.array([s.ideal1 for s in samples])
    i2 = np.array([s.ideal2 for s in samples])
    d1 = (np.array([s.axis1 for s in samples]) - i1 + 180.0) % 360.0 - 180.0
    d2 = np.array([s.axis2 for s in samples]) - i2
    lat = (90.0 - i2) if mount == "AZ-ZD" else i2
    w = np.abs(np.cos(np.radians(lat)))
    return float(np.sqrt(np.mean((d1 * w) ** 2 + d2 ** 2)))


def summary(result: FitResult, samples: Sequence[Sample], source: str) -> dict:
    """The JSON-able content of ``model.json``."""
    model = result.model
    coefficients = {}
    for term in model.terms:
        if term in result.fitted or term in model.coefficients:
            value = model.get(term)
            coefficients[term] = {
                "degrees": value, "arcsec": value * ARCSEC,
                "error_degrees": result.errors.get(term, 0.0),
                "error_arcsec": result.errors.get(term, 0.0) * ARCSEC,
                "fixed": term not in result.fitted}
    fitted = list(result.fitted)
    corr = np.asarray(result.correlation, float).tolist()
    strong = [{"terms": [a, fitted[j]], "r": corr[i][j]}
              for i, a in enumerate(fitted) for j in range(i + 1, len(fitted))
              if abs(corr[i][j]) > STRONG]
    res = np.asarray(result.residuals, float)
    return {
        "source": source, "mount": model.mount, "latitude": model.latitude,
        "n_samples": result.n_samples,
        "rms_before_arcsec": raw_rms(model.mount, samples) * ARCSEC,
        "rms_arcsec": result.rms * ARCSEC,
        "rms_axis_arcsec": [result.rms_axis[0] * ARCSEC, result.rms_axis[1] * ARCSEC],
        "coefficients": coefficients,
        "correlation": {"terms": fitted, "matrix": corr},
        "covariance_deg2": {"terms": fitted, "matrix": np.asarray(result.covariance, float).tolist()},
        "strong_correlations": strong,
        "samples": [{"utc": s.utc, "ra": s.ra, "dec": s.dec, "ideal": [s.ideal1, s.ideal2],
                     "measured": [s.axis1, s.axis2],
                     "residual_arcsec": [res[i, 0] * ARCSEC, res[i, 1] * ARCSEC]}
                    for i, s in enumerate(samples)],
    }


def warnings_of(info: dict, min_per_term: int = 3) -> list[str]:
    """What makes a fit doubtful: too few samples per fitted term, strongly correlated terms."""
    out = []
    n_terms = len(info["correlation"]["terms"])
    if n_terms and info["n_samples"] < min_per_term * n_terms:
        out.append(f"only {info['n_samples']} samples for {n_terms} fitted terms (fewer than "
                   f"{min_per_term} per term): the coefficients are not trustworthy")
    if info["strong_correlations"]:
        out.append("strongly correlated terms (|r| > " f"{STRONG}): " + ", ".join(
            f"{c['terms'][0]}/{c['terms'][1]} ({c['r']:+.3f})" for c in info["strong_correlations"])
            + ": their values trade off against each other; spread the samples over more "
              "elevations/declinations or fix one of each pair")
    return out


def markdown(info: dict, figures: list[str], fit_text: str) -> str:
    """``report.md`` from :func:`summary`'s dict."""
    lines = ["# Pointing model fit", ""]
    warnings = warnings_of(info)
    if warnings:
        lines += [f"> **Warning:** {w}." for w in warnings] + [""]
    lines += [
             f"- samples: {info['n_samples']} ({info['source']})",
             f"- mount: {info['mount']}, site latitude {info['latitude']:.4f}°",
             f"- RMS on the sky: {info['rms_before_arcsec']:.2f}\" before the fit, "
             f"**{info['rms_arcsec']:.2f}\"** after (axis 1 {info['rms_axis_arcsec'][0]:.2f}\", "
             f"axis 2 {info['rms_axis_arcsec'][1]:.2f}\")", "",
             "## Coefficients", "", "| term | value (\") | 1σ (\") | |", "|---|---:|---:|---|"]
    for term, c in info["coefficients"].items():
        flag = "fixed" if c["fixed"] else ""
        if not c["fixed"] and c["error_arcsec"] > 0 and abs(c["arcsec"]) < 2 * c["error_arcsec"]:
            flag = "not significant (< 2σ)"
        lines.append(f"| {term} | {c['arcsec']:+.3f} | {c['error_arcsec']:.3f} | {flag} |")
    terms = info["correlation"]["terms"]
    matrix = info["correlation"]["matrix"]
    if terms:
        lines += ["", "## Correlations of the fitted terms", "",
                  "| | " + " | ".join(terms) + " |", "|---|" + "---:|" * len(terms)]
        for name, row in zip(terms, matrix):
            lines.append(f"| **{name}** | " + " | ".join(f"{v:+.2f}" for v in row) + " |")
        if info["strong_correlations"]:
            lines += ["", f"Strongly correlated (|r| > {STRONG}): " + ", ".join(
                f"{c['terms'][0]}/{c['terms'][1]} ({c['r']:+.3f})" for c in info["strong_correlations"])
                + ". Spread the samples over more elevations/declinations or fix one of each pair."]
    if figures:
        lines += ["", "## Figures", ""]
        lines += [f"![{Path(f).stem}]({Path(f).name})" for f in figures]
    lines += ["", "## Fit", "", "```", fit_text, "```", ""]
    return "\n".join(lines)


def write_report(directory: str | Path, header: DumpHeader, samples: Sequence[Sample],
                 result: FitResult, *, source: str, make_plots: bool = True) -> dict:
    """Write the report files; returns ``{"directory", "files", ...summary without samples}``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    info = summary(result, samples, source)
    figures: list[str] = []
    if make_plots:
        cols = np.array([(s.ideal1, s.ideal2) for s in samples], float)
        figures = [str(p) for p in plots.residual_plots(directory, result.model.mount, cols[:, 0],
                                                        cols[:, 1], result.residuals,
                                                        result.rms * ARCSEC)]
    (directory / "model.json").write_text(json.dumps(_finite(info), indent=2) + "\n", encoding="utf-8")
    (directory / "report.md").write_text(markdown(info, figures, result.report()), encoding="utf-8")
    ModelStore(directory).save("pointing", result.model, errors=result.errors, report=result.report())
    dump = directory / "samples.dump"
    write_dump_header(dump, header)
    for s in samples:
        append_sample(dump, s)
    files = [str(directory / n) for n in ("report.md", "model.json", "pointing.model", "samples.dump")]
    brief = {k: v for k, v in info.items() if k != "samples"}
    return {"directory": str(directory), "files": files + figures, **brief,
            "warnings": warnings_of(info)}


def _finite(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value
