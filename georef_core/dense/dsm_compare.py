"""A DSM against a reference DSM (e.g. the simulator's truth): vertical differences and completeness.

The reference is resampled onto the DSM's cells by area averaging (GDAL ``average``), so a cell is compared
with the mean reference height over the same square - what a median of points in the cell estimates.
Statistics are given for the measured cells and for all cells (filled ones included), optionally only
inside a box of the project CRS (e.g. the work area).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from rasterio.warp import Resampling, reproject

from .dsm_raster import MASK_FILLED, MASK_MEASURED


def _stats(d: np.ndarray) -> dict:
    if len(d) == 0:
        return {"n": 0}
    med = float(np.median(d))
    return {"n": int(len(d)), "rmse_m": float(np.sqrt(np.mean(d * d))), "mean_m": float(np.mean(d)), "median_m": med,
            "nmad_m": float(1.4826 * np.median(np.abs(d - med))), "p95_abs_m": float(np.percentile(np.abs(d), 95)),
            "max_abs_m": float(np.max(np.abs(d)))}


def compare_dsm(dsm_path, reference_path, mask_path=None, bounds: tuple[float, float, float, float] | None = None) -> dict:
    """Statistics of DSM - reference (m). ``bounds`` = (west, south, east, north) in the project CRS limits
    the comparison and the completeness; completeness = measured cells / cells where the reference has data."""
    with rasterio.open(dsm_path) as ds:
        dsm = ds.read(1, masked=True).filled(np.nan).astype(np.float64)
        transform, crs, shape = ds.transform, ds.crs, ds.shape
    with rasterio.open(reference_path) as rs:
        ref = np.full(shape, np.nan, np.float64)
        src = rs.read(1).astype(np.float64)
        if rs.nodata is not None:
            src[src == rs.nodata] = np.nan
        reproject(src, ref, src_transform=rs.transform, src_crs=rs.crs, dst_transform=transform, dst_crs=crs,
                  resampling=Resampling.average, src_nodata=np.nan, dst_nodata=np.nan)
        # cells only partly covered by the reference are not compared
        cover = np.zeros(shape, np.float64)
        reproject(np.isfinite(src).astype(np.float64), cover, src_transform=rs.transform, src_crs=rs.crs,
                  dst_transform=transform, dst_crs=crs, resampling=Resampling.average)
        ref[cover < 0.999] = np.nan
        ref_bounds = rs.bounds
    if mask_path is not None and Path(mask_path).is_file():
        with rasterio.open(mask_path) as ms:
            mask = ms.read(1)
    else:
        mask = np.where(np.isfinite(dsm), MASK_MEASURED, 255).astype(np.uint8)
    rows, cols = np.indices(shape)
    e = transform.c + (cols + 0.5) * transform.a
    n = transform.f + (rows + 0.5) * transform.e
    inside = np.ones(shape, bool)
    if bounds is not None:
        w, s, ea, no = bounds
        inside = (e >= w) & (e <= ea) & (n >= s) & (n <= no)
    have_ref = np.isfinite(ref) & inside
    diff = dsm - ref
    measured = have_ref & np.isfinite(dsm) & (mask == MASK_MEASURED)
    filled = have_ref & np.isfinite(dsm) & (mask == MASK_FILLED)
    # the reference's footprint may extend beyond the DSM grid: count its cells in the DSM's resolution
    res = abs(transform.a)
    if bounds is not None:
        w, s, ea, no = bounds
        w, s, ea, no = max(w, ref_bounds.left), max(s, ref_bounds.bottom), min(ea, ref_bounds.right), min(no, ref_bounds.top)
    else:
        w, s, ea, no = ref_bounds.left, ref_bounds.bottom, ref_bounds.right, ref_bounds.top
    ref_cells = max(1.0, (ea - w) * (no - s) / (res * res))
    return {
        "measured": _stats(diff[measured]),
        "all": _stats(diff[measured | filled]),
        "completeness": float(min(1.0, measured.sum() / ref_cells)),
        "filled_fraction": float(filled.sum() / max(1, (measured | filled).sum())),
        "resolution_m": float(res),
        "bounds": [float(w), float(s), float(ea), float(no)],
    }
