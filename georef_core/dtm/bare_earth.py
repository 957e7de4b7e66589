"""The bare-earth DTM raster: the DSM's ground cells as they are, the non-ground cells (machines, vehicles,
vegetation, anything with steep sides that the ground filter found) removed and filled by harmonic
interpolation from the ground around them, on the DSM's grid. And a check of that interpolation: patches of
ground the size of the removed objects are hidden and refilled the same way, and the refilled heights are
compared with the measured ones.
"""

from __future__ import annotations

import numpy as np

from .ground_filter import harmonic_fill

MASK_GROUND = 0  # DSM cell measured and ground: the DTM is the DSM there
MASK_REMOVED = 1  # non-ground, removed and interpolated
MASK_DSM_FILLED = 2  # ground, but the dense step had interpolated the DSM there (a hole in the matching)
MASK_NODATA = 255


def build_dtm(dsm: np.ndarray, nonground: np.ndarray, dsm_filled: np.ndarray | None = None,
              fallback: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(DTM float32 with NaN where the DSM has no data, mask uint8 with the MASK_* codes).

    ``dsm_filled``: the DSM cells the dense step interpolated (its mask's 1); ``fallback``: heights for removed
    cells that the interpolation cannot reach (open to the edge of the data), e.g. the provisional ground."""
    dsm = np.asarray(dsm, np.float64)
    valid = np.isfinite(dsm)
    ground = valid & ~nonground
    if not ground.any():
        raise ValueError("no ground cell left: the ground filter classified the whole DSM as objects")
    dtm = dsm.copy()
    if nonground.any():
        fb = None if fallback is None else np.where(np.isfinite(fallback), fallback, np.nan)
        filled = harmonic_fill(np.where(ground, dsm, 0.0), ground, fb)
        dtm[nonground] = filled[nonground]
    dtm[~valid] = np.nan
    mask = np.full(dsm.shape, MASK_NODATA, np.uint8)
    mask[ground] = MASK_GROUND
    if dsm_filled is not None:
        mask[ground & dsm_filled] = MASK_DSM_FILLED
    mask[nonground & valid] = MASK_REMOVED
    return dtm.astype(np.float32), mask


def interpolation_check(dsm: np.ndarray, ground: np.ndarray, resolution_m: float, patch_m: float,
                        n_patches: int = 20, seed: int = 0) -> dict | None:
    """Hide up to ``n_patches`` square patches of ground of side ``patch_m`` (each with a ring of ground around
    it), refill them as :func:`build_dtm` does and compare with the measured DSM: the RMS and the 95th
    percentile of |refilled - measured| estimate the error of the DTM under a removed object of that size on this
    site's ground (DSM noise included). None when no patch fits."""
    rng = np.random.default_rng(seed)
    h, w = dsm.shape
    side = max(2, int(round(patch_m / resolution_m)))
    ring = max(2, side // 2)
    need = side + 2 * ring
    if need >= min(h, w):
        return None
    from scipy import ndimage

    # top-left corners of windows whose whole (patch + ring) is ground
    ok = ndimage.minimum_filter(ground.astype(np.uint8), size=need, mode="constant", cval=0).astype(bool)
    cand = np.argwhere(ok)  # centres of fully-ground windows
    if len(cand) == 0:
        return None
    hide = np.zeros_like(ground)
    taken = np.zeros_like(ground)
    placed = 0
    for i in rng.permutation(len(cand))[: 20 * n_patches]:
        r, c = cand[i]
        r0, c0 = r - side // 2, c - side // 2
        if r0 - ring < 0 or c0 - ring < 0 or r0 + side + ring > h or c0 + side + ring > w:
            continue
        if taken[r0 - ring:r0 + side + ring, c0 - ring:c0 + side + ring].any():
            continue
        hide[r0:r0 + side, c0:c0 + side] = True
        taken[r0 - ring:r0 + side + ring, c0 - ring:c0 + side + ring] = True
        placed += 1
        if placed >= n_patches:
            break
    if placed == 0:
        return None
    known = ground & ~hide
    filled = harmonic_fill(np.where(known, dsm, 0.0), known)
    d = (filled - dsm)[hide]
    d = d[np.isfinite(d)]
    if d.size == 0:
        return None
    return {"patches": placed, "patch_side_m": round(side * resolution_m, 3), "cells": int(d.size),
            "rmse_m": round(float(np.sqrt(np.mean(d * d))), 4), "mean_m": round(float(d.mean()), 4),
            "p95_abs_m": round(float(np.percentile(np.abs(d), 95)), 4)}
