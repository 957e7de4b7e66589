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
   Two more rules mark object cells that the opening cannot see (vegetation):

   * **stepped cells**: a classification cell whose own DSM cells span more than
     ``elevation_threshold_m + slope * cell_m * sqrt(2)`` [1.15 m] (more than ground of slope ``slope`` spans
     across the cell's diagonal) holds a vertical step: foliage over ground seen through a gap in it, whose
     minimum is the ground, or an object's edge;
   * **rough cells**: groups (at least 2 x 2) of classification cells whose median DSM roughness (RMS residual
     of a plane over 3 x 3 DSM cells) exceeds ``ROUGH_FACTOR`` [3] times its median over the site (the DSM's
     noise on ground) and ``ROUGH_FLOOR_M`` [4 cm]: foliage, matched rough where ground, piles and machines
     are smooth. Dome-shaped bushes, no steeper than a pile, are caught by this rule only.

   Ground seen through foliage gaps, clamped as a low outlier, joins the object's region (its clamped height
   must not hold the provisional ground up).
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


def block_max(values: np.ndarray, f: int) -> np.ndarray:
    """Highest finite value of each f x f block (NaN where a block has none)."""
    return -block_min(-np.asarray(values, np.float64), f)


def stepped_blocks(dsm: np.ndarray, zmin: np.ndarray, f: int, limit_m: float) -> np.ndarray:
    """Classification cells whose own DSM cells span more than ``limit_m`` in height: more than ground of
    slope ``slope`` spans across a cell's diagonal, plus the noise allowance. Such a cell holds a vertical
    step: an object's edge, or foliage over ground seen through a gap (the cell's minimum is then the ground,
    and the opening of the minimum surface cannot see the foliage)."""
    span = block_max(dsm, f) - zmin
    with np.errstate(invalid="ignore"):
        return span > limit_m


ROUGH_FACTOR = 3.0  # a classification cell is rough when its DSM roughness exceeds this many times the site's
ROUGH_FLOOR_M = 0.04  # ... and this much (a noise-free DSM: sharp crests are not rough)


def plane_residual_rms(a: np.ndarray) -> np.ndarray:
    """RMS residual (1 sigma, 6 degrees of freedom) of a least-squares plane fitted to each cell's 3 x 3
    neighbourhood: the DSM's local roughness, blind to slope (and nearly so to the curvature of a crest)."""
    m = ndimage.uniform_filter(a, 3, mode="nearest")
    m2 = ndimage.uniform_filter(a * a, 3, mode="nearest")
    kx = np.array([[-1.0, 0.0, 1.0]] * 3)
    sx = ndimage.correlate(a, kx, mode="nearest")
    sy = ndimage.correlate(a, kx.T, mode="nearest")
    rss = 9.0 * (m2 - m * m) - (sx * sx + sy * sy) / 6.0
    return np.sqrt(np.maximum(rss, 0.0) / 6.0)


def rough_blocks(dsm: np.ndarray, f: int) -> np.ndarray:
    """Classification cells (f x f DSM cells) whose median DSM roughness (:func:`plane_residual_rms`) exceeds
    ``ROUGH_FACTOR`` times the median over the site (the DSM's noise on ground, which most of a site is) and
    ``ROUGH_FLOOR_M``, in groups of at least 2 x 2: foliage, whose matched surface is rough where ground, piles
    and machines are smooth. Dome-shaped bushes escape the slope rule (their sides are no steeper than a
    pile's); their roughness gives them away."""
    valid = np.isfinite(dsm)
    a = nearest_fill(np.where(valid, dsm, 0.0), valid) if not valid.all() else np.asarray(dsm, np.float64)
    rho = np.where(valid, plane_residual_rms(a), np.nan)
    h, w = rho.shape
    hc, wc = -(-h // f), -(-w // f)
    pad = np.full((hc * f, wc * f), np.nan)
    pad[:h, :w] = rho
    with np.errstate(invalid="ignore"), __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("ignore", RuntimeWarning)
        block = np.nanmedian(pad.reshape(hc, f, wc, f).transpose(0, 2, 1, 3).reshape(hc, wc, f * f), axis=2)
    ok = np.isfinite(block)
    if not ok.any():
        return np.zeros((hc, wc), bool)
    limit = max(ROUGH_FACTOR * float(np.median(block[ok])), ROUGH_FLOOR_M)
    rough = ok & (np.where(ok, block, 0.0) > limit)
    return ndimage.binary_opening(rough, structure=np.ones((2, 2), bool))


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
    clamped = have & (z < med - o.low_outlier_m)
    z = np.maximum(z, med - o.low_outlier_m)

    kmax = max(1, int(np.ceil(0.5 * o.max_object_m / cell)))
    thr = o.elevation_threshold_m + o.slope * cell
    objects = np.zeros(z.shape, bool)
    prev = z
    for k in range(1, kmax + 1):
        opened = ndimage.grey_opening(prev, footprint=disk(k), mode="nearest")
        objects |= (prev - opened) > thr
        prev = opened
    objects |= stepped_blocks(dsm, zmin, f, o.elevation_threshold_m + o.slope * cell * np.sqrt(2.0))
    objects |= rough_blocks(dsm, f)
    objects &= have
    # ground seen through gaps in a canopy is clamped as a low outlier (its neighbours are foliage): it is not
    # an object, but its clamped height (the foliage less low_outlier_m) must not hold the provisional ground
    # up under the crown: clamped cells joined to an object (8-neighbourhood) go into the object's region
    near = ndimage.binary_dilation(objects, structure=np.ones((3, 3), bool))
    gaps = ndimage.binary_propagation(clamped & near, structure=np.ones((3, 3), bool), mask=clamped)
    region = ndimage.binary_dilation(objects | gaps, structure=np.ones((3, 3), bool)) & have

    ground_c = harmonic_fill(z, ~region & have) if region.any() else z
    g = upsample_bilinear(ground_c, f, dsm.shape)
    region_f = np.repeat(np.repeat(region, f, axis=0), f, axis=1)[: dsm.shape[0], : dsm.shape[1]]
    with np.errstate(invalid="ignore"):
        nonground = region_f & valid & (dsm - g > o.ground_tolerance_m)
    return GroundClassification(nonground=nonground, provisional_ground=np.where(valid, g, np.nan).astype(np.float32),
                                object_cells=objects, factor=f, cell_m=cell,
                                radii_m=[round(k * cell, 6) for k in range(1, kmax + 1)], drop_threshold_m=thr)
