"""Ground classification of a DSM raster: a progressive morphological filter (after Zhang et al. 2003 and
SMRF, Pingel et al. 2013) on a minimum-surface raster, tuned to keep stockpiles and remove machines.

Rule (parameters in :class:`GroundFilterOptions`, defaults in brackets):

1. **Minimum surface**: the DSM's cells are grouped into classification cells of ``cell_m`` [0.5 m]; each
   holds the lowest DSM height in it. Low outliers are clamped: a cell lower than the median of its 3 x 3
   neighbourhood by more than ``low_outlier_m`` [1 m] is raised to that median less ``low_outlier_m``.
2. **Progressive opening**: the surface is opened (grey erosion then dilation) with discs of radius
   ``k * cell_m``, k = 1, 2, ... up to ``max_object_m / 2`` [7 m], each opening applied to the previous one.
   A cell is an **object** when one step lowers it by more than ``elevation_threshold_m + slope * cell_m``
   [0.3 m + 1.2 x 0.5 m = 0.9 m]. Between two steps the disc grows by one cell, so ground of slope s drops
   by about ``s * cell_m`` per step: slopes up to ``slope`` [1.2 = 50 deg] are never objects, whatever their
   height, so stockpiles (30-45 deg) stay ground; a block with vertical sides vanishes in one step, when the
   disc no longer fits on its top, and drops by its full height (machines, cabins: 2.5-4 m).
3. **Provisional ground**: the minimum surface with the object cells (grown by one classification cell)
   replaced by harmonic interpolation from the ground around them, bilinearly resampled to the DSM grid.
4. **Non-ground DSM cells**: inside the grown object regions, the DSM cells higher than the provisional
   ground by more than ``ground_tolerance_m`` [0.25 m]. Elsewhere every cell is ground.

Objects wider than ``max_object_m`` on their narrow side (a building) are not removed; raise it (the cost
grows with its square).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass
class GroundFilterOptions:
    cell_m: float = 0.5  # classification cell (m); rounded to a whole number of DSM cells
    max_object_m: float = 14.0  # objects up to this wide (on their narrow side) are removed
    slope: float = 1.2  # slope threshold (rise over run): steeper steps between openings mark objects
    elevation_threshold_m: float = 0.3  # added to slope x cell: the drop per step that marks an object
    ground_tolerance_m: float = 0.25  # a DSM cell or point within this of the provisional ground / DTM is ground
    low_outlier_m: float = 1.0  # minimum-surface cells this far below their 3x3 median are clamped
    low_noise_m: float = 1.0  # points this far below the DTM are classed low noise (ASPRS 7)
    min_object_area_m2: float = 1.0  # removed regions smaller than this are counted as spikes, not objects

    def check(self) -> None:
        for name in ("cell_m", "max_object_m", "slope", "ground_tolerance_m", "low_outlier_m", "low_noise_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"ground filter: {name} must be a positive number, got {v!r}")
        if self.elevation_threshold_m < 0 or self.min_object_area_m2 < 0:
            raise ValueError("ground filter: elevation_threshold_m and min_object_area_m2 must be >= 0")


@dataclass
class GroundClassification:
    nonground: np.ndarray  # bool, DSM grid: cells classified non-ground
    provisional_ground: np.ndarray  # float32, DSM grid: the provisional ground surface (NaN outside the data)
    object_cells: np.ndarray  # bool, classification grid: object cells found by the opening (before growing)
    factor: int  # DSM cells per classification cell (each side)
    cell_m: float  # classification cell actually used
    radii_m: list  # opening disc radii
    drop_threshold_m: float  # drop per step that marks an object


def disk(radius_cells: int) -> np.ndarray:
    k = int(radius_cells)
    yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
    return (xx * xx + yy * yy) <= k * k + 1e-9


def block_min(values: np.ndarray, f: int) -> np.ndarray:
    """Lowest finite value of each f x f block (NaN where a block has none); the array is padded with NaN."""
    h, w = values.shape
    hc, wc = -(-h // f), -(-w // f)
    pad = np.full((hc * f, wc * f), np.inf, np.float64)
    pad[:h, :w] = np.where(np.isfinite(values), values, np.inf)
    out = pad.reshape(hc, f, wc, f).min(axis=(1, 3))
    out[~np.isfinite(out)] = np.nan
    return out


def nearest_fill(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Every cell takes the value of the nearest known cell."""
    if known.all():
        return values.copy()
    idx = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
    return values[tuple(idx)]


def harmonic_fill(values: np.ndarray, known: np.ndarray, fallback: np.ndarray | None = None) -> np.ndarray:
    """Unknown cells solved from Laplace's equation with the known cells as boundary values (the dense step's
    hole filler, georef_core.dense.dsm_raster); cells it leaves (regions open to the raster's edge) take
    ``fallback`` there, else the nearest known value."""
    from ..dense.dsm_raster import fill_holes

    if known.all():
        return values.astype(np.float64)
    if not known.any():
        raise ValueError("no ground cell to interpolate from")
    v = np.where(known, values, np.nan).astype(np.float64)
    filled, _mask = fill_holes(v, max_gap_cells=float(max(v.shape)))
    filled = np.asarray(filled, np.float64)
    filled[known] = values[known]
    left = ~np.isfinite(filled)
    if left.any():
        other = fallback if fallback is not None else nearest_fill(np.where(known, values, 0.0), known)
        filled[left] = np.asarray(other, np.float64)[left]
    return filled


def upsample_bilinear(coarse: np.ndarray, f: int, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear resampling of a raster of f x f blocks to the fine grid (cell centres aligned)."""
    h, w = shape
    r = (np.arange(h) + 0.5) / f - 0.5
    c = (np.arange(w) + 0.5) / f - 0.5
    rr, cc = np.meshgrid(r, c, indexing="ij")
    return ndimage.map_coordinates(coarse, [rr, cc], order=1, mode="nearest")


def classify_dsm(dsm: np.ndarray, resolution_m: float, options: GroundFilterOptions | None = None) -> GroundClassification:
    """Ground / non-ground of every DSM cell (NaN: no data, never non-ground). See the module documentation."""
    o = options or GroundFilterOptions()
    o.check()
    dsm = np.asarray(dsm, np.float64)
    valid = np.isfinite(dsm)
    if not valid.any():
        raise ValueError("the DSM has no data")
    f = max(1, int(round(o.cell_m / resolution_m)))
    cell = f * resolution_m
    zmin = block_min(dsm, f)
    have = np.isfinite(zmin)
    z = nearest_fill(np.where(have, zmin, 0.0), have)
    med = ndimage.median_filter(z, size=3, mode="nearest")
    z = np.maximum(z, med - o.low_outlier_m)

    kmax = max(1, int(np.ceil(0.5 * o.max_object_m / cell)))
    thr = o.elevation_threshold_m + o.slope * cell
    objects = np.zeros(z.shape, bool)
    prev = z
    for k in range(1, kmax + 1):
        opened = ndimage.grey_opening(prev, footprint=disk(k), mode="nearest")
        objects |= (prev - opened) > thr
        prev = opened
    objects &= have
    region = ndimage.binary_dilation(objects, structure=np.ones((3, 3), bool)) & have

    ground_c = harmonic_fill(z, ~region & have) if region.any() else z
    g = upsample_bilinear(ground_c, f, dsm.shape)
    region_f = np.repeat(np.repeat(region, f, axis=0), f, axis=1)[: dsm.shape[0], : dsm.shape[1]]
    with np.errstate(invalid="ignore"):
        nonground = region_f & valid & (dsm - g > o.ground_tolerance_m)
    return GroundClassification(nonground=nonground, provisional_ground=np.where(valid, g, np.nan).astype(np.float32),
                                object_cells=objects, factor=f, cell_m=cell,
                                radii_m=[round(k * cell, 6) for k in range(1, kmax + 1)], drop_threshold_m=thr)
