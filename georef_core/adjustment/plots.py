"""Plots a surveyor reads: check-point residual vectors on a map, GNSS residuals over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_check_residuals(path, checks, loo, control, frame) -> Path:
    """Horizontal residual vectors (arrows, scale stated) and vertical residuals (colour) on a map."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 6))
    rows = [(r, "check") for r in checks.rows] + [(r, "control, left out") for r in loo.rows]
    if rows:
        d = np.array([[r.dx_m, r.dy_m] for r, _ in rows])
        scale = 0.2 * 50.0 / max(float(np.max(np.hypot(d[:, 0], d[:, 1]))), 1e-3)  # longest arrow ~ 10 m on the map
    for r, kind in rows:
        p = control.points[r.name]
        e, n = _grid(p, frame)
        ax.plot(e, n, "o" if kind == "check" else "^", color="C0" if kind == "check" else "C1", ms=6)
        ax.annotate("", xy=(e + r.dx_m * scale, n + r.dy_m * scale), xytext=(e, n),
                    arrowprops=dict(arrowstyle="->", color="C3", lw=1.5))
        ax.text(e, n, f" {r.name}\n dz {100 * r.dz_m:+.1f} cm", fontsize=8, va="top")
    for name, p in control.points.items():
        if p.role == "control" and not any(r.name == name for r, _ in rows):
            e, n = _grid(p, frame)
            ax.plot(e, n, "^", color="0.5", ms=6)
    ax.set_aspect("equal")
    ax.set_xlabel(f"easting (m, EPSG:{frame.epsg})")
    ax.set_ylabel("northing (m)")
    if rows:
        ax.set_title(f"Residuals (red arrows, x{scale:.0f}): o check, ^ control left out")
    ax.ticklabel_format(useOffset=False, style="plain")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def _grid(p, frame):
    from pyproj import CRS, Transformer

    crs = CRS.from_user_input(p.crs)
    if crs.to_epsg() == frame.epsg:
        return float(p.xyz_crs[0]), float(p.xyz_crs[1])
    e, n = Transformer.from_crs(crs, f"EPSG:{frame.epsg}", always_xy=True).transform(p.xyz_crs[0], p.xyz_crs[1])
    return float(e), float(n)


def plot_gnss_residuals(path, gnss_rows: list[dict]) -> Path:
    """Camera-centre minus GNSS-predicted centre (E, N, U) per image over time; outliers marked."""
    plt = _plt()
    t = np.array([r["gps_time_s"] for r in gnss_rows])
    t = t - t.min()
    res = np.array([r["residual_enu_m"] for r in gnss_rows]) * 100
    out = np.array([r["outlier"] for r in gnss_rows])
    fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
    for k, lab in enumerate(("east", "north", "up")):
        axes[k].plot(t, res[:, k], ".-", lw=0.6)
        if out.any():
            axes[k].plot(t[out], res[out, k], "rx")
        axes[k].axhline(0, color="0.6", lw=0.5)
        axes[k].set_ylabel(f"{lab} (cm)")
    axes[-1].set_xlabel("time since the first image (s)")
    axes[0].set_title("GNSS camera-position residuals (adjusted - GNSS model); x: flagged outliers")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
