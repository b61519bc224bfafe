"""Residual plots of a pointing fit as PNG files (matplotlib, Agg, no pyplot state).

Three figures per fit, from the residuals on the sky (arcsec; axis 1 multiplied by |cos E|
or |cos δ|, as :class:`~tcs.pointing.model.FitResult` gives them):

* ``residuals_<axis1>.png`` — both residuals against axis 1 (azimuth or hour angle);
* ``residuals_<axis2>.png`` — both residuals against elevation (AZ-ZD) or declination;
* ``skymap.png`` — every sample on the sky with its residual as an arrow (AZ-ZD: a map
  around the zenith, north up, east right; RA-DEC: HA against Dec).

matplotlib is the ``commission`` extra (also in ``dev``); :func:`available` tells whether it
is installed, and the pointing subcommand asks for ``--no-plots`` otherwise. Figures are
built with :class:`matplotlib.figure.Figure` and the Agg canvas directly, so nothing global
(pyplot, a display) is touched and it is safe in any thread.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ARCSEC = 3600.0


def available() -> bool:
    """True when matplotlib can be imported."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, format="png")
    return path


def residual_plots(directory: Path, mount: str, ideal1: np.ndarray, ideal2: np.ndarray,
                   residuals: np.ndarray, rms_arcsec: float) -> list[Path]:
    """Write the three PNG files into ``directory``; returns their paths.

    Parameters
    ----------
    mount : "AZ-ZD" or "RA-DEC".
    ideal1, ideal2 : the samples' ideal positions, degrees (AZ, ZD) or (HA, Dec).
    residuals : (N, 2) residuals on the sky after the fit, degrees.
    rms_arcsec : the fit's radial RMS (for the titles).
    """
    r = np.asarray(residuals, float) * ARCSEC
    i1 = np.asarray(ideal1, float)
    i2 = np.asarray(ideal2, float)
    if mount == "AZ-ZD":
        x1, x1_label, name1 = np.mod(i1, 360.0), "azimuth (deg, 0 = north, 90 = east)", "az"
        x2, x2_label, name2 = 90.0 - i2, "elevation (deg)", "el"
        r_labels = ("ΔAZ·cos E (\")", "ΔZD (\")")
    else:
        x1, x1_label, name1 = i1 / 15.0, "hour angle (h)", "ha"
        x2, x2_label, name2 = i2, "declination (deg)", "dec"
        r_labels = ("ΔHA·cos δ (\")", "ΔDec (\")")
    out = []
    for x, label, name in ((x1, x1_label, name1), (x2, x2_label, name2)):
        fig = _figure(7.0, 5.0)
        axes = fig.subplots(2, 1, sharex=True)
        for ax, column, ylabel in zip(axes, (0, 1), r_labels):
            ax.axhline(0.0, color="0.6", lw=0.8)
            ax.plot(x, r[:, column], "o", ms=4)
            ax.set_ylabel(ylabel)
            ax.grid(True, lw=0.3)
        axes[1].set_xlabel(label)
        axes[0].set_title(f"pointing residuals after the fit, {len(r)} samples, "
                          f"RMS {rms_arcsec:.2f}\"")
        out.append(_save(fig, directory / f"residuals_{name}.png"))
    out.append(_skymap(directory, mount, x1, x2, i1, i2, r, rms_arcsec))
    return out


def _skymap(directory: Path, mount: str, x1, x2, i1, i2, r, rms_arcsec: float) -> Path:
    scale_ref = max(float(np.max(np.hypot(r[:, 0], r[:, 1]), initial=0.0)), 1e-3)
    if mount == "AZ-ZD":
        # Zenith-centred map: X = ZD·sin A (east right), Y = ZD·cos A (north up). A residual
        # (ΔA·cos E, ΔZD) at (A, ZD) points along the azimuth direction (cos A, −sin A) and
        # the zenith-distance direction (sin A, cos A) of that place.
        fig = _figure(6.5, 6.5)
        ax = fig.add_subplot()
        a = np.radians(np.mod(i1, 360.0))
        zd = np.asarray(i2, float)
        x, y = zd * np.sin(a), zd * np.cos(a)
        k = 10.0 / scale_ref                 # the largest residual is drawn 10 degrees long
        u = k * (r[:, 0] * np.cos(a) + r[:, 1] * np.sin(a))
        v = k * (-r[:, 0] * np.sin(a) + r[:, 1] * np.cos(a))
        edge = max(90.0, float(np.max(zd, initial=0.0)) + 5.0)
        t = np.linspace(0.0, 2 * np.pi, 361)
        for ring in (30.0, 60.0, 90.0):
            ax.plot(ring * np.sin(t), ring * np.cos(t), color="0.8", lw=0.6)
        ax.plot(x, y, "o", ms=3)
        ax.quiver(x, y, u, v, angles="xy", scale_units="xy", scale=1.0, color="C3", width=0.003)
        for label, (lx, ly) in (("N", (0, edge)), ("E", (edge, 0)), ("S", (0, -edge)),
                                ("W", (-edge, 0))):
            ax.annotate(label, (lx, ly), ha="center", va="center")
        ax.set_xlim(-edge * 1.08, edge * 1.08)
        ax.set_ylim(-edge * 1.08, edge * 1.08)
        ax.set_aspect("equal")
        ax.set_xlabel("ZD·sin AZ (deg)")
        ax.set_ylabel("ZD·cos AZ (deg)")
        ax.set_title(f"residuals on the sky, RMS {rms_arcsec:.2f}\" (arrow of {scale_ref:.1f}\" "
                     f"= 10°)\nzenith in the centre, rings at ZD 30/60/90°", fontsize=10)
    else:
        fig = _figure(7.0, 5.5)
        ax = fig.add_subplot()
        ax.plot(x1, x2, "o", ms=3)
        k = 1.0 / scale_ref
        ax.quiver(x1, x2, r[:, 0] * k, r[:, 1] * k, angles="xy", scale_units="xy", scale=1.0,
                  color="C3", width=0.003)
        ax.set_xlabel("hour angle (h)")
        ax.set_ylabel("declination (deg)")
        ax.invert_xaxis()
        ax.grid(True, lw=0.3)
        ax.set_title(f"residuals on the sky (arrow of {scale_ref:.1f}\" = 1 unit), "
                     f"RMS {rms_arcsec:.2f}\"")
    return _save(fig, directory / "skymap.png")
