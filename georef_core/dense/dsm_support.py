"""The DSM from tiers of support, the per-cell support raster and the measurement classes of the mask.

A cell takes its height from the best tier that has points in it:

1. full-resolution points agreed by ``min_views`` views or more (the fusion's first sweep);
2. full-resolution points agreed by two views (the edge sweep: block edges, beside tall objects);
3. the coarse pass (images matched at 1/4 of the size, ``coarse_pass.py``), binned at its own cell
   (``coarse_resolution_m``) and read at the fine cell's centre: measured, at a lower resolution; only
   in holes wider than 2 cells (narrower gaps are depth-map sampling gaps, better interpolated from
   the fine cells around them).

Remaining empty cells inside the coverage are interpolated (``dsm_raster.fill_holes``: harmonic).
A tier only fills cells the better tiers left empty, so cells of tier 1 are exactly what they were
without the other tiers.

Outputs: the DSM; the mask ``dsm_filled_mask.tif`` (0 measured at full resolution, 2 measured by the
coarse pass only, 1 interpolated, 255 no data); the support raster ``dsm_support.tif`` (uint8: the
median number of views that agreed on the cell's points, 0 for an interpolated cell (no support),
255 outside the coverage).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dsm_raster import MASK_COARSE, MASK_FILLED, MASK_MEASURED, RasterGrid, bin_median, fill_holes

SUPPORT_NONE = 0
SUPPORT_NODATA = 255


@dataclass
class TieredDsm:
    dsm: np.ndarray  # float32, NaN outside the coverage (filled cells included)
    mask: np.ndarray  # uint8: 0 measured, 2 coarse, 1 interpolated, 255 no data
    support: np.ndarray  # uint8: views agreeing (median over the cell's points), 0 interpolated, 255 none
    counts: np.ndarray  # points per cell (the tier used)
    stats: dict


def _bin(grid: RasterGrid, e, n, h, min_points: int):
    """bin_median that accepts no points."""
    if len(e) == 0:
        return np.full((grid.height, grid.width), np.nan, np.float32), np.zeros((grid.height, grid.width), np.int32)
    return bin_median(grid, e, n, h, min_points)


def _coarse_on_grid(grid: RasterGrid, e, n, h, nv, res_c: float, min_points: int):
    """Coarse heights and views binned at ``res_c`` (cells aligned on multiples of res_c), read at the
    fine grid's cell centres (the coarse cell containing each centre)."""
    from .dsm_raster import grid_covering

    if len(e) == 0:
        nan = np.full((grid.height, grid.width), np.nan, np.float32)
        return nan, nan.copy()
    cg = grid_covering(e, n, res_c)
    zc, _ = bin_median(cg, e, n, h, min_points)
    vc, _ = bin_median(cg, e, n, nv.astype(np.float64), min_points)
    E, N = grid.centres()
    r, c = cg.cell_index(E, N)
    ok = (r >= 0) & (r < cg.height) & (c >= 0) & (c < cg.width)
    z = np.full(E.shape, np.nan, np.float32)
    v = np.full(E.shape, np.nan, np.float32)
    z[ok] = zc[r[ok], c[ok]]
    v[ok] = vc[r[ok], c[ok]]
    return z, v


def tiered_dsm(grid: RasterGrid, pts: np.ndarray, n_views: np.ndarray, min_views: int,
               coarse_pts: np.ndarray | None, coarse_views: np.ndarray | None, coarse_resolution_m: float | None,
               max_gap_cells: float, min_points: int = 1) -> TieredDsm:
    """The DSM of ``pts`` (E, N, h; their agreeing views ``n_views``) on ``grid``, completed by the coarse
    points where the fine ones leave cells empty, then interpolated; with the mask and support rasters."""
    e, n, h = pts[:, 0], pts[:, 1], pts[:, 2]
    nv = n_views.astype(np.float64)
    strong = n_views >= min_views
    z1, c1 = _bin(grid, e[strong], n[strong], h[strong], min_points)
    v1, _ = _bin(grid, e[strong], n[strong], nv[strong], min_points)
    weak = ~strong
    z2, c2 = _bin(grid, e[weak], n[weak], h[weak], min_points)
    v2, _ = _bin(grid, e[weak], n[weak], nv[weak], min_points)
    dsm = z1.copy()
    views = v1.copy()
    counts = c1.copy()
    t2 = ~np.isfinite(dsm) & np.isfinite(z2)
    dsm[t2], views[t2], counts[t2] = z2[t2], v2[t2], c2[t2]
    fine = np.isfinite(dsm)
    stats = {"full_resolution_cells": int(np.count_nonzero(np.isfinite(z1))), "two_view_cells": int(t2.sum()),
             "coarse_cells": 0}
    coarse = np.zeros(dsm.shape, bool)
    if coarse_pts is not None and len(coarse_pts) and coarse_resolution_m:
        zc, vc = _coarse_on_grid(grid, coarse_pts[:, 0], coarse_pts[:, 1], coarse_pts[:, 2], coarse_views,
                                 coarse_resolution_m, min_points)
        # narrow gaps (up to 2 cells wide: depth-map sampling gaps) are interpolated from the fine cells around
        # them, closer to the truth than the coarse pass's smoother, noisier heights; wider holes take the coarse
        from scipy import ndimage

        far = ndimage.distance_transform_edt(~fine) >= 1.5 if fine.any() else np.ones(fine.shape, bool)
        coarse = ~fine & np.isfinite(zc) & far
        dsm[coarse], views[coarse] = zc[coarse], vc[coarse]
        stats["coarse_cells"] = int(coarse.sum())
        both = fine & np.isfinite(zc)
        if both.sum() >= 10:  # the coarse pass against the fine one where both measured: its own check
            d = (zc[both] - dsm[both]).astype(np.float64)
            med = float(np.median(d))
            stats["coarse_minus_fine_m"] = {"n": int(both.sum()), "median": round(med, 4),
                                            "nmad": round(float(1.4826 * np.median(np.abs(d - med))), 4),
                                            "p95_abs": round(float(np.percentile(np.abs(d), 95)), 4)}
    filled, mask = fill_holes(dsm, max_gap_cells)
    mask[coarse & (mask == MASK_MEASURED)] = MASK_COARSE
    support = np.full(dsm.shape, SUPPORT_NODATA, np.uint8)
    measured = (mask == MASK_MEASURED) | (mask == MASK_COARSE)
    support[measured] = np.clip(np.rint(views[measured]), 1, 254).astype(np.uint8)
    support[mask == MASK_FILLED] = SUPPORT_NONE
    stats["interpolated_cells"] = int(np.count_nonzero(mask == MASK_FILLED))
    return TieredDsm(filled, mask, support, counts, stats)


# band 2 of dsm_support.tif: why a cell has, or lacks, a measurement (the volumes and a user can leave out what
# was interpolated, and tell a hole nobody saw from one the images saw without agreeing on a depth)
CAUSE_MEASURED = 0            # measured at full resolution
CAUSE_COARSE = 1              # measured by the coarse pass only
CAUSE_FILLED_SEEN = 2         # interpolated; >= 2 images see it but gave no consistent depth (texture, water, motion)
CAUSE_FILLED_UNSEEN = 3       # interpolated; fewer than 2 images see it
CAUSE_EMPTY_SEEN = 4          # no data; >= 2 images see it but gave no consistent depth (beyond the filling's reach)
CAUSE_EMPTY_UNSEEN = 5        # no data; fewer than 2 images see it
CAUSE_NODATA = 255            # outside the step's cells (a tiled merge: outside every tile)
CAUSE_VALUES = ("0 measured, 1 measured by the coarse pass only, 2 interpolated: seen by 2+ images without a "
                "consistent depth, 3 interpolated: seen by fewer than 2 images, 4 no data: seen by 2+ images without "
                "a consistent depth, 5 no data: seen by fewer than 2 images, 255 outside")
CAUSE_NAMES = {CAUSE_MEASURED: "measured", CAUSE_COARSE: "coarse", CAUSE_FILLED_SEEN: "interpolated_seen",
               CAUSE_FILLED_UNSEEN: "interpolated_unseen", CAUSE_EMPTY_SEEN: "no_data_seen",
               CAUSE_EMPTY_UNSEEN: "no_data_unseen"}


def images_seeing(grid: RasterGrid, dsm: np.ndarray, views, frame, step: int = 8, mask: np.ndarray | None = None,
                  tolerance_cells: float = 3.0, low_radius_m: float = 3.0,
                  max_face_points: int = 100) -> np.ndarray:
    """(rows, cols) uint16: how many of ``views`` see each cell.

    Without ``mask``: a count of footprints - the cell's point (at the DSM's height; empty cells at the nearest
    cell's) inside the image, on a lattice of every ``step``-th cell spread to its neighbours.

    With ``mask`` (the DSM's measurement classes), occlusion is tested: a view sees a cell when its point is
    inside the image and not hidden behind the measured surface, i.e. its depth is at most ``tolerance_cells``
    cells + 5 cm behind the view's z-buffer of the measured cells (each measured cell's point splatted into a
    coarse depth image of the view, pixels of 1.5 projected cells, as the orthophoto's test; and, unlike it, the
    cell's vertical face down to its lowest neighbour, a point per cell of height, at most ``max_face_points``:
    an oblique view looks at a wall's side, not its top, where the wall hides the ground). A measured cell is
    tested at its height; an unmeasured one at the lowest measured height within a radius (2 x the hole's largest
    distance to its rim + 2 cells, at most ``low_radius_m``; else at its filled height): the interpolation
    across a hole behind a wall or a pile ramps from the crest down to the ground and would be "seen" from the
    crest's side, while the ground it stands for is hidden there. The lower height is the conservative choice:
    on a steep flank a wide hole can count fewer views than see the true surface.
    Only unmeasured cells are counted (the classes of measured cells do not depend on it; measured cells get
    0), on a lattice of every 2nd unmeasured cell (and isolated ones) spread to its neighbours."""
    from scipy import ndimage

    z = np.asarray(dsm, np.float64)
    have = np.isfinite(z)
    if not have.any():
        return np.zeros(z.shape, np.uint16)
    if not have.all():
        idx = ndimage.distance_transform_edt(~have, return_distances=False, return_indices=True)
        z = z[idx[0], idx[1]]
    if mask is None:
        rows = np.arange(step // 2, grid.height, step) if grid.height > step else np.array([grid.height // 2])
        cols = np.arange(step // 2, grid.width, step) if grid.width > step else np.array([grid.width // 2])
        R, C = np.meshgrid(rows, cols, indexing="ij")
        X = frame.grid_to_enu(*_cell_en(grid, R.ravel(), C.ravel()), z[R, C].ravel())
        count = np.zeros(X.shape[0], np.uint16)
        for v in views:
            uv, depth = v.project_distorted(X)
            count += ((depth > 0) & v.inside(uv)).astype(np.uint16)
        lattice = count.reshape(R.shape)
        ri = np.clip(np.searchsorted(rows, np.arange(grid.height) - step / 2.0 + 0.5), 0, len(rows) - 1)
        ci = np.clip(np.searchsorted(cols, np.arange(grid.width) - step / 2.0 + 0.5), 0, len(cols) - 1)
        return lattice[ri][:, ci]

    measured = ((mask == MASK_MEASURED) | (mask == MASK_COARSE)) & have
    out = np.zeros(z.shape, np.uint16)
    todo = ~measured
    if not todo.any() or not measured.any():
        return out
    res = grid.resolution_m
    # the radius of the lower envelope grows with the hole: 2 x its largest distance to its rim + 2 cells, at most
    # low_radius_m (a one-cell sampling gap on a slope looks only at its neighbours: tested a few cm low, not
    # the slope's drop over metres), rounded up to steps of max(2 cells, 0.2 m)
    labels, n_holes = ndimage.label(todo)
    to_rim = ndimage.distance_transform_edt(todo) * res
    inradius = np.zeros(n_holes + 1)
    if n_holes:
        inradius[1:] = ndimage.maximum(to_rim, labels, np.arange(1, n_holes + 1))
    r_step = max(2.0 * res, 0.2)
    radius = np.minimum(np.ceil((2.0 * inradius[labels] + 2.0 * res) / r_step - 1e-9) * r_step, low_radius_m)
    z_meas = np.where(measured, z, np.inf)
    z_test = z.copy()
    for r_m in np.unique(radius[todo]):
        cells = todo & (radius == r_m)
        r_cells = max(1, int(round(r_m / res)))
        low = ndimage.minimum_filter(z_meas, size=2 * r_cells + 1, mode="constant", cval=np.inf)
        z_test[cells] = np.where(np.isfinite(low[cells]), np.minimum(z[cells], low[cells]), z[cells])
    # the test points: every 2nd unmeasured cell in each direction (holes are smooth at that scale), and every
    # unmeasured cell farther than one cell from those (isolated gaps off the lattice)
    lat = todo.copy()
    lat[1::2, :] = False
    lat[:, 1::2] = False
    if lat.any():
        lat |= todo & (ndimage.distance_transform_edt(~lat) > 1.5)
    else:
        lat = todo
    tr, tc = np.nonzero(lat)
    X = frame.grid_to_enu(*_cell_en(grid, tr, tc), z_test[tr, tc])
    # occluders: each measured cell's point, and its vertical face down to its lowest neighbour (a wall's or a
    # pile's side, which a height raster does not hold but which hides the ground behind it), a point per cell
    mr, mc = np.nonzero(measured)
    drop = z - ndimage.minimum_filter(np.where(measured, z, z_test), size=3, mode="nearest")
    steps = np.clip(np.floor(drop[mr, mc] / res).astype(np.int64), 0, max_face_points)
    rep = np.repeat(np.arange(len(mr)), steps)
    j = np.arange(len(rep)) - np.repeat(np.cumsum(steps) - steps, steps) + 1
    mh = np.concatenate([z[mr, mc], z[mr[rep], mc[rep]] - j * drop[mr[rep], mc[rep]] / (steps[rep] + 1)])
    mr, mc = np.concatenate([mr, mr[rep]]), np.concatenate([mc, mc[rep]])
    M = frame.grid_to_enu(*_cell_en(grid, mr, mc), mh)
    tol = tolerance_cells * res + 0.05
    sub = slice(None, None, 16)      # every 16th measured point: the view's footprint on the grid
    count = np.zeros(len(X), np.uint16)
    for v in views:
        uv, depth = v.project_distorted(X)
        cand = (depth > 0) & v.inside(uv)
        if not cand.any():
            continue
        uvs, ds = v.project_distorted(M[sub])
        ins = (ds > 0) & v.inside(uvs)
        if not ins.any():
            count[cand] += 1   # no measured surface in the image to hide anything
            continue
        pad = 32
        r0, r1 = mr[sub][ins].min() - pad, mr[sub][ins].max() + pad
        c0, c1 = mc[sub][ins].min() - pad, mc[sub][ins].max() + pad
        box = (mr >= r0) & (mr <= r1) & (mc >= c0) & (mc <= c1)
        cell_px = res * v.focal_px / float(np.median(ds[ins]))
        zb_px = max(1.0, 1.5 * cell_px)
        zw, zh = int(np.ceil(v.width / zb_px)) + 1, int(np.ceil(v.height / zb_px)) + 1
        zbuf = np.full(zh * zw, np.inf, np.float32)
        uvm, dm = v.project_distorted(M[box])
        good = (dm > 0) & v.inside(uvm)
        ui = np.floor((uvm[good, 0] + 0.5) / zb_px).astype(np.int64)
        vi = np.floor((uvm[good, 1] + 0.5) / zb_px).astype(np.int64)
        np.minimum.at(zbuf, vi * zw + ui, dm[good].astype(np.float32))
        zbuf = zbuf.reshape(zh, zw)
        k = np.nonzero(cand)[0]
        ui = np.clip(np.floor((uv[k, 0] + 0.5) / zb_px).astype(np.int64), 0, zw - 1)
        vi = np.clip(np.floor((uv[k, 1] + 0.5) / zb_px).astype(np.int64), 0, zh - 1)
        seen = depth[k] <= zbuf[vi, ui] + tol
        count[k[seen]] += 1
    # spread the lattice's counts to the other unmeasured cells (nearest lattice cell)
    grid_count = np.zeros(z.shape, np.uint16)
    grid_count[tr, tc] = count
    idx = ndimage.distance_transform_edt(~lat, return_distances=False, return_indices=True)
    spread = grid_count[idx[0], idx[1]]
    out[todo] = spread[todo]
    return out


def _cell_en(grid: RasterGrid, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E, N of cell centres."""
    return grid.west + (cols + 0.5) * grid.resolution_m, grid.north - (rows + 0.5) * grid.resolution_m


def hole_causes(mask: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Band 2 of the support raster (CAUSE_*) from the mask and the images seeing each cell."""
    two = seen >= 2
    out = np.where(two, CAUSE_EMPTY_SEEN, CAUSE_EMPTY_UNSEEN).astype(np.uint8)
    out[mask == MASK_MEASURED] = CAUSE_MEASURED
    out[mask == MASK_COARSE] = CAUSE_COARSE
    filled = mask == MASK_FILLED
    out[filled & two] = CAUSE_FILLED_SEEN
    out[filled & ~two] = CAUSE_FILLED_UNSEEN
    return out


def cause_counts(causes: np.ndarray) -> dict:
    """Cells per cause (CAUSE_NAMES), for the summary."""
    n = np.bincount(causes.ravel(), minlength=256)
    return {name: int(n[code]) for code, name in CAUSE_NAMES.items()}
