"""Figures of a DSM without ground truth (real image sets): completeness over the block's footprint and
the noise on flat areas.

* **Footprint** of the block: the DSM cells whose centre (at the DSM's height, or the median height
  where the DSM has none) projects inside at least ``min_images`` images (default 2: what stereo can
  possibly measure). **Completeness** = cells of the footprint with a measured height / footprint
  cells, counted per class of the dense step's mask (measured at full resolution, at coarse
  resolution, interpolated, no data).
* **Noise on flat areas**: the DSM is cut into square windows (``window_m``, 3 m); in each window with
  at least 80 % measured cells a plane is fitted (least squares) and the NMAD of its residuals taken;
  the figure is the median NMAD of the best-fitting 10 % of the windows (roads, pads, flat roofs: where
  the surface really is a plane, what is left is the DSM's noise; rough or sloping-and-curved windows
  are not noise and are not used).
"""

from __future__ import annotations

import numpy as np

from .dsm_raster import MASK_COARSE, MASK_FILLED, MASK_MEASURED, RasterGrid


def footprint_counts(views, frame, grid: RasterGrid, dsm: np.ndarray, chunk: int = 400_000) -> np.ndarray:
    """Number of images each DSM cell centre projects into (uint16)."""
    h = np.where(np.isfinite(dsm), dsm, np.nanmedian(dsm) if np.isfinite(dsm).any() else 0.0)
    E, N = grid.centres()
    e, n, z = E.ravel(), N.ravel(), h.ravel().astype(np.float64)
    out = np.zeros(e.size, np.uint16)
    for s in range(0, e.size, chunk):
        enu = frame.grid_to_enu(e[s:s + chunk], n[s:s + chunk], z[s:s + chunk])
        for v in views:
            uv, zc = v.project_distorted(enu)
            out[s:s + chunk] += ((zc > 0) & v.inside(uv)).astype(np.uint16)
    return out.reshape(dsm.shape)


def completeness(mask: np.ndarray, footprint: np.ndarray) -> dict:
    """Shares of the footprint cells per mask class."""
    n = int(footprint.sum())
    m = mask[footprint]

    def share(v):
        return round(float(np.count_nonzero(m == v)) / max(n, 1), 4)

    full, coarse, interp = share(MASK_MEASURED), share(MASK_COARSE), share(MASK_FILLED)
    return {"footprint_cells": n, "measured_full_resolution": full, "measured_coarse": coarse,
            "completeness": round(full + coarse, 4), "interpolated": interp,
            "no_data": round(1.0 - full - coarse - interp, 4)}


def flat_area_noise(dsm: np.ndarray, measured: np.ndarray, resolution_m: float, window_m: float = 3.0,
                    best_fraction: float = 0.1, min_valid: float = 0.8) -> dict:
    """Median NMAD of plane-fit residuals over the best-fitting ``best_fraction`` of ``window_m`` windows."""
    k = max(3, int(round(window_m / resolution_m)))
    H, W = dsm.shape
    yy, xx = np.mgrid[0:k, 0:k].astype(np.float64) * resolution_m
    nmads = []
    for r in range(0, H - k + 1, k):
        for c in range(0, W - k + 1, k):
            ok = measured[r:r + k, c:c + k]
            if ok.mean() < min_valid:
                continue
            z = dsm[r:r + k, c:c + k][ok].astype(np.float64)
            A = np.column_stack([xx[ok], yy[ok], np.ones(len(z))])
            coef, *_ = np.linalg.lstsq(A, z, rcond=None)
            res = z - A @ coef
            nmads.append(1.4826 * np.median(np.abs(res - np.median(res))))
    if not nmads:
        return {"windows": 0}
    a = np.sort(np.asarray(nmads))
    best = a[: max(1, int(round(best_fraction * len(a))))]
    return {"windows": int(len(a)), "window_m": round(k * resolution_m, 3), "best_windows": int(len(best)),
            "nmad_m": round(float(np.median(best)), 4), "all_windows_median_nmad_m": round(float(np.median(a)), 4)}
