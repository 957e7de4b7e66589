"""ASPRS classes (LAS 1.4, point formats 6-10) of the dense points against the DTM:

* 2 ground: within ``ground_tolerance_m`` above (and at most ``low_noise_m`` below) the DTM;
* 1 unclassified: higher than that. Machines, vehicles, cabins, vegetation and spikes are not told apart
  (the filter sees steep-sided objects, not what they are), so none of 3-6 is used;
* 7 low noise: more than ``low_noise_m`` below the DTM.

The DTM height at a point is the bilinear interpolation of its cell centres.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

CLASS_UNCLASSIFIED = 1
CLASS_GROUND = 2
CLASS_LOW_NOISE = 7
CLASS_NAMES = {CLASS_UNCLASSIFIED: "unclassified (objects above the ground)", CLASS_GROUND: "ground",
               CLASS_LOW_NOISE: "low noise"}


def dtm_at(dtm: np.ndarray, transform, e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Bilinear DTM height at (E, N) (NaN outside the data)."""
    inv = ~transform
    col, row = inv * (np.asarray(e, np.float64), np.asarray(n, np.float64))
    nanmask = ~np.isfinite(dtm)
    z = ndimage.map_coordinates(np.where(nanmask, 0.0, dtm).astype(np.float64), [row - 0.5, col - 0.5], order=1,
                                mode="nearest")
    bad = ndimage.map_coordinates(nanmask.astype(np.float32), [row - 0.5, col - 0.5], order=1, mode="nearest") > 0
    h, w = dtm.shape
    outside = (row < 0) | (row >= h) | (col < 0) | (col >= w)
    z[bad | outside] = np.nan
    return z


def classify_points(xyz: np.ndarray, dtm: np.ndarray, transform, ground_tolerance_m: float,
                    low_noise_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(ASPRS class per point (uint8), height above the DTM (NaN outside it)). Points outside the DTM stay 1."""
    xyz = np.asarray(xyz, np.float64)
    dz = xyz[:, 2] - dtm_at(dtm, transform, xyz[:, 0], xyz[:, 1])
    cls = np.full(len(xyz), CLASS_UNCLASSIFIED, np.uint8)
    with np.errstate(invalid="ignore"):
        cls[(dz <= ground_tolerance_m) & (dz >= -low_noise_m)] = CLASS_GROUND
        cls[dz < -low_noise_m] = CLASS_LOW_NOISE
    return cls, dz
