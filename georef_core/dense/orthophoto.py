"""True orthophoto from the DSM and the oriented images.

For each ortho cell (project CRS, E/N at the cell centre): the height comes from the DSM (bilinear), the
3-D point is converted to ENU and projected into the images through the full camera model (lens
distortion included, so the original images are sampled directly; no resampled undistorted copies).
Views are ranked per cell by the horizontal distance from the cell to the view's *centre ground point*
(where its optical axis meets the ground): the first-ranked view sees the cell closest to its image
centre, i.e. the most nadir, least leaning view with the least vignetting. A view is used only when the
cell projects inside the image and passes the occlusion test: its depth is not more than a tolerance
behind the view's z-buffer of the DSM (the DSM cells rendered into a coarse depth image of the view),
so ground hidden behind a stockpile is taken from a view that sees it (true ortho, no lean).
The two best visible views are blended across a ``feather_m`` band around the boundary of their
regions (weights from the difference of the two distances), which hides exposure and vignetting
seams; elsewhere the cell comes from the best view alone. Colours are sampled bilinearly. Alpha is 255
where a view was found, 0 elsewhere (no DSM or not seen).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .camera_views import CameraView
from ..project_frame import ProjectFrame
from .dsm_raster import RasterGrid
from .ortho_radiometry import (camera_index, estimate_radiometry, normalised_radius, observe,
                               sample_points)
from .ortho_seams import luminance, multiband_blend, refine_seams


@dataclass
class OrthoOptions:
    feather_m: float = 1.0  # blend=False: width of the feathered band between two views' regions
    tile_cells: int = 512
    max_rank: int = 6  # views tried per cell (nearest centre points first)
    occlusion_tolerance_cells: float = 3.0  # depth tolerance of the z-buffer test, in DSM cells (+ 5 cm)
    image_cache: int = 16
    # radiometric compensation (ortho_radiometry.py): per-image gains and per-camera vignetting
    compensate: bool = True
    compensate_vignetting: bool = True
    radiometry_samples: int = 20000  # ground points sampled for the estimate
    # seamlines along low-difference paths + multi-band blending (ortho_seams.py); False: feathering only
    blend: bool = True
    seam_band_m: float = 3.0  # seams may move where the second view is less than this farther than the best
    blend_levels: int = 5  # pyramid levels: coarse brightness mixed over ~2^levels cells


class DsmSampler:
    """The DSM at arbitrary (E, N): bilinear heights (NaN where the nearest cell has no value) and the ENU
    point of the surface there. ENU is interpolated from the exact ENU of the surrounding cell centres (the
    map from the project CRS to ENU is affine to ~1e-9 m over a cell), so the exact conversion runs once per
    DSM cell, not once per ortho cell."""

    def __init__(self, dsm: np.ndarray, grid: RasterGrid, frame: ProjectFrame):
        self.grid = grid
        self.have = np.isfinite(dsm)
        if self.have.all():
            self.full = dsm.astype(np.float64)
        else:  # empty cells take their nearest neighbour's height (only to interpolate next to them)
            idx = ndimage.distance_transform_edt(~self.have, return_distances=False, return_indices=True)
            self.full = dsm[idx[0], idx[1]].astype(np.float64)
        self.enu = np.empty(dsm.shape + (3,))
        for r0 in range(0, dsm.shape[0], 256):
            E, N = grid.centres(slice(r0, r0 + 256))
            self.enu[r0:r0 + 256] = frame.grid_to_enu(E.ravel(), N.ravel(),
                                                      self.full[r0:r0 + 256].ravel()).reshape(E.shape + (3,))

    def _locate(self, e: np.ndarray, n: np.ndarray):
        g = self.grid
        c = (e - g.west) / g.resolution_m - 0.5
        r = (g.north - n) / g.resolution_m - 0.5
        r0 = np.clip(np.floor(r).astype(np.int64), 0, max(0, g.height - 2))
        c0 = np.clip(np.floor(c).astype(np.int64), 0, max(0, g.width - 2))
        r1 = np.minimum(r0 + 1, g.height - 1)
        c1 = np.minimum(c0 + 1, g.width - 1)
        fr = np.clip(r - r0, 0.0, 1.0)
        fc = np.clip(c - c0, 0.0, 1.0)
        return r, c, r0, c0, r1, c1, fr, fc

    def heights(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        g = self.grid
        r, c, r0, c0, r1, c1, fr, fc = self._locate(e, n)
        f = self.full
        h = (f[r0, c0] * (1 - fc) + f[r0, c1] * fc) * (1 - fr) + (f[r1, c0] * (1 - fc) + f[r1, c1] * fc) * fr
        ri = np.clip(np.rint(r).astype(np.int64), 0, g.height - 1)
        ci = np.clip(np.rint(c).astype(np.int64), 0, g.width - 1)
        h[~self.have[ri, ci]] = np.nan
        h[(r <= -0.5) | (r >= g.height - 0.5) | (c <= -0.5) | (c >= g.width - 0.5)] = np.nan
        return h

    def enu_at(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        _, _, r0, c0, r1, c1, fr, fc = self._locate(e, n)
        X = self.enu
        fr, fc = fr[:, None], fc[:, None]
        return (X[r0, c0] * (1 - fc) + X[r0, c1] * fc) * (1 - fr) + (X[r1, c0] * (1 - fc) + X[r1, c1] * fc) * fr


class _ViewData:
    """Per-view image and z-buffer, computed on first use."""

    def __init__(self, view: CameraView, dsm_enu: np.ndarray, have: np.ndarray, dsm_grid: RasterGrid,
                 bbox: tuple[float, float, float, float], depth_med: float, read_image: bool = True):
        self.view = view
        self.image = view.read_image() if read_image else None
        self.index = -1
        self.radiometry = None
        # z-buffer pixel: 1.5 DSM cells as seen from the view's median depth, so every pixel gets a cell
        cell_px = dsm_grid.resolution_m * view.focal_px / depth_med
        self.zb_px = max(1.0, 1.5 * cell_px)
        w, s, e, n = bbox
        r0 = max(0, int((dsm_grid.north - n) / dsm_grid.resolution_m))
        r1 = min(dsm_grid.height, int(np.ceil((dsm_grid.north - s) / dsm_grid.resolution_m)))
        c0 = max(0, int((w - dsm_grid.west) / dsm_grid.resolution_m))
        c1 = min(dsm_grid.width, int(np.ceil((e - dsm_grid.west) / dsm_grid.resolution_m)))
        zw = int(np.ceil(view.width / self.zb_px)) + 1
        zh = int(np.ceil(view.height / self.zb_px)) + 1
        zbuf = np.full(zh * zw, np.inf, np.float32)
        if r1 > r0 and c1 > c0:
            X = dsm_enu[r0:r1, c0:c1][have[r0:r1, c0:c1]]
            uv, z = view.project_distorted(X)
            good = (z > 0) & view.inside(uv)
            ui = np.floor((uv[good, 0] + 0.5) / self.zb_px).astype(np.int64)
            vi = np.floor((uv[good, 1] + 0.5) / self.zb_px).astype(np.int64)
            np.minimum.at(zbuf, vi * zw + ui, z[good].astype(np.float32))
        self.zbuf = zbuf.reshape(zh, zw)

    def visible(self, uv: np.ndarray, z: np.ndarray, tol: float) -> np.ndarray:
        ok = (z > 0) & self.view.inside(uv, margin=1.0)
        ui = np.clip(np.floor((uv[:, 0] + 0.5) / self.zb_px).astype(np.int64), 0, self.zbuf.shape[1] - 1)
        vi = np.clip(np.floor((uv[:, 1] + 0.5) / self.zb_px).astype(np.int64), 0, self.zbuf.shape[0] - 1)
        return ok & (z <= self.zbuf[vi, ui] + tol)

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """RGB float32 colours at the pixels uv, radiometrically corrected when a model is set."""
        rgb = self._sample(uv)
        if self.radiometry is not None and len(uv):
            rgb *= self.radiometry.correction(self.index, normalised_radius(self.view, uv))
        return rgb

    def _sample(self, uv: np.ndarray) -> np.ndarray:
        n = len(uv)
        if n == 0:     # remap refuses an empty map (a view that sees none of a tile's cells)
            return np.zeros((0, 3), np.float32)
        cols = 4096  # remap wants maps smaller than 32767 in each direction: fold the list into rows
        rows = -(-n // cols)
        m = np.zeros((rows * cols, 2), np.float32)
        m[:n] = uv
        m = m.reshape(rows, cols, 2)
        out = cv2.remap(self.image, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(-1, 3)[:n, ::-1].astype(np.float32)  # BGR -> RGB


def view_footprints(views: list[CameraView], frame: ProjectFrame, h_lo: float, h_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Per view: (west, south, east, north) of its ground footprint between ENU heights h_lo..h_hi, and the
    E, N of its centre ground point (optical axis at the mid height)."""
    boxes, centres = [], []
    for v in views:
        n = 8
        t = np.linspace(0, 1, n)
        u = np.concatenate([t * v.width, t * v.width, np.zeros(n), np.full(n, v.width)]) - 0.5
        w = np.concatenate([np.zeros(n), np.full(n, v.height), t * v.height, t * v.height]) - 0.5
        xy = v.undistort_points(np.stack([u, w], 1))
        rays = np.column_stack([xy, np.ones(len(xy))]) @ v.R_world_to_cam
        rays = np.vstack([rays, v.optical_axis_enu])
        pts = []
        for hh in (h_lo, h_hi, 0.5 * (h_lo + h_hi)):
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (hh - v.centre_enu_m[2]) / rays[:, 2]
            s = np.where(s > 0, s, np.nan)
            pts.append(v.centre_enu_m + s[:, None] * rays)
        P = np.vstack(pts[:2] + [pts[2][:-1]])
        P = P[np.all(np.isfinite(P), axis=1)]
        g = frame.enu_to_grid(P) if len(P) else np.zeros((0, 3))
        boxes.append([g[:, 0].min(), g[:, 1].min(), g[:, 0].max(), g[:, 1].max()] if len(g) else [np.nan] * 4)
        c = pts[2][-1]
        centres.append(frame.enu_to_grid(c[None])[0, :2] if np.all(np.isfinite(c)) else [np.nan, np.nan])
    return np.asarray(boxes, float), np.asarray(centres, float)


def build_orthophoto(views: list[CameraView], dsm: np.ndarray, dsm_grid: RasterGrid, ortho_grid: RasterGrid,
                     frame: ProjectFrame, ground_up_range: tuple[float, float],
                     depth_med: list[float], options: OrthoOptions | None = None, progress=None,
                     labels_out: np.ndarray | None = None, info: dict | None = None,
                     radiometry=None) -> np.ndarray:
    """RGBA (4, rows, cols) uint8 orthophoto on ``ortho_grid``.

    ``labels_out`` (int32, rows x cols), if given, receives the view index each cell was taken from (-1:
    none); ``info`` (a dict), if given, receives the radiometric model's summary and the stage times.
    ``radiometry`` (a RadiometryModel of ``views``, e.g. a tiled block's, block_radiometry.py): used as it is
    instead of an estimate from this DSM (when ``options.compensate``)."""
    o = options or OrthoOptions()
    report = progress or (lambda *a: None)
    boxes, centres = view_footprints(views, frame, *ground_up_range)
    usable = np.all(np.isfinite(boxes), axis=1) & np.all(np.isfinite(centres), axis=1)
    tol = o.occlusion_tolerance_cells * dsm_grid.resolution_m + 0.05
    out = np.zeros((4, ortho_grid.height, ortho_grid.width), np.uint8)
    cache: OrderedDict[int, _ViewData] = OrderedDict()
    sampler = DsmSampler(dsm, dsm_grid, frame)
    given, radiometry = radiometry, None
    info = info if info is not None else {}
    t0 = time.perf_counter()
    if o.compensate and given is not None:
        radiometry = given
        info["radiometry"] = dict(radiometry.summary(), source="given (the block's)")
    elif o.compensate and len(views) >= 2:
        report("ortho_radiometry", 0, 1)
        pts = sample_points(np.isfinite(dsm), sampler.enu, o.radiometry_samples)
        zb: dict[int, _ViewData] = {}

        def visible(k, uv, z):
            if not usable[k]:
                return np.zeros(len(uv), bool)
            if k not in zb:
                zb.clear()
                zb[k] = _ViewData(views[k], sampler.enu, sampler.have, dsm_grid, tuple(boxes[k]), depth_med[k],
                                  read_image=False)
            return zb[k].visible(uv, z, tol)

        obs = observe(views, pts, visible)
        radiometry = estimate_radiometry(obs, len(views), camera_index(views), vignetting=o.compensate_vignetting)
        info["radiometry"] = radiometry.summary()
        info["radiometry_model"] = radiometry
        report("ortho_radiometry", 1, 1)
    info["radiometry_s"] = time.perf_counter() - t0

    def view_data(k: int) -> _ViewData:
        if k in cache:
            cache.move_to_end(k)
            return cache[k]
        vd = _ViewData(views[k], sampler.enu, sampler.have, dsm_grid, tuple(boxes[k]), depth_med[k])
        vd.index = int(k)
        vd.radiometry = radiometry
        cache[k] = vd
        if len(cache) > o.image_cache:
            cache.popitem(last=False)
        return vd

    # blending: tiles twice as large (fewer margins to redo) and each processed with a margin of the
    # blending's reach, so that seams and pyramids run on across tile borders
    T = 2 * o.tile_cells if o.blend else o.tile_cells
    tiles = [(r0, c0) for r0 in range(0, ortho_grid.height, T)
             for c0 in (range(0, ortho_grid.width, T) if (r0 // T) % 2 == 0 else
                        reversed(range(0, ortho_grid.width, T)))]  # serpentine: neighbouring tiles share views
    reach = int(round(1.5 * 2 ** o.blend_levels))
    margin = reach if o.blend else 0
    t1 = time.perf_counter()
    for t_idx, (r0, c0) in enumerate(tiles):
        report("orthophoto", t_idx, len(tiles))
        rs, cs = slice(r0, min(r0 + T, ortho_grid.height)), slice(c0, min(c0 + T, ortho_grid.width))
        ers = slice(max(0, r0 - margin), min(r0 + T + margin, ortho_grid.height))
        ecs = slice(max(0, c0 - margin), min(c0 + T + margin, ortho_grid.width))
        E, N = ortho_grid.centres(ers, ecs)
        H = sampler.heights(E.ravel(), N.ravel()).reshape(E.shape)
        ok = np.isfinite(H)
        if not ok.any():
            continue
        e, n = E[ok], N[ok]
        w_, s_, e_, n_ = e.min(), n.min(), e.max(), n.max()
        cand = np.nonzero(usable & (boxes[:, 0] <= e_) & (boxes[:, 2] >= w_) & (boxes[:, 1] <= n_)
                          & (boxes[:, 3] >= s_))[0]
        if len(cand) == 0:
            continue
        X = sampler.enu_at(e, n)
        kmax = min(o.max_rank, len(cand))
        dist, order = cKDTree(centres[cand]).query(np.column_stack([e, n]), k=kmax)
        dist, order = dist.reshape(len(e), kmax), order.reshape(len(e), kmax)
        band = o.seam_band_m if o.blend else o.feather_m
        found, best_d, best_k, colour = _best_two(cand, dist, order, X, view_data, tol, band)
        if o.blend:
            rgb, lab = _blend_tile(E.shape, ok, found, best_d, best_k, colour, X, view_data, tol, o, reach)
        else:
            rgb = colour[:, 0]
            two = found == 2
            if o.feather_m > 0 and two.any():
                w1 = np.clip(0.5 + (best_d[two, 1] - best_d[two, 0]) / (2.0 * o.feather_m), 0.5, 1.0)[:, None]
                rgb[two] = w1 * colour[two, 0] + (1.0 - w1) * colour[two, 1]
            lab = np.full(E.shape, -1, np.int64)
            lab[ok] = np.where(found > 0, best_k[:, 0], -1)
            full = np.zeros(E.shape + (3,), np.float32)
            full[ok] = rgb
            rgb = full
        # the tile's core (without its margin)
        ir = slice(r0 - ers.start, r0 - ers.start + (rs.stop - rs.start))
        ic = slice(c0 - ecs.start, c0 - ecs.start + (cs.stop - cs.start))
        seen = lab[ir, ic] >= 0
        tile = np.zeros((4,) + seen.shape, np.uint8)
        core = rgb[ir, ic]
        for b in range(3):
            tile[b][seen] = np.clip(np.rint(core[..., b][seen]), 0, 255).astype(np.uint8)
        tile[3][seen] = 255
        out[:, rs, cs] = tile
        if labels_out is not None:
            labels_out[rs, cs] = lab[ir, ic]
    report("orthophoto", len(tiles), len(tiles))
    info["mosaic_s"] = time.perf_counter() - t1
    return out


def _best_two(cand, dist, order, X, view_data, tol, band):
    """Per cell, the first two visible views in rank order (the second only while it is less than ``band``
    farther than the first): found (0..2), their distances, view indices (-1 none) and colours."""
    npts, kmax = dist.shape
    found = np.zeros(npts, np.int8)
    best_d = np.full((npts, 2), np.inf)
    best_k = np.full((npts, 2), -1, np.int64)
    colour = np.zeros((npts, 2, 3), np.float32)
    for rank in range(kmax):
        need = np.nonzero((found == 0) | ((found == 1) & (dist[:, rank] - best_d[:, 0] < band)))[0]
        if len(need) == 0:
            break
        kk = cand[order[need, rank]]
        for k in np.unique(kk):
            sel = need[kk == k]
            vd = view_data(int(k))
            uv, z = vd.view.project_distorted(X[sel])
            vis = vd.visible(uv, z, tol)
            sel, uv = sel[vis], uv[vis]
            if len(sel) == 0:
                continue
            slot = found[sel].astype(np.int64)
            colour[sel, slot] = vd.sample(uv)
            best_d[sel, slot] = dist[sel, rank]
            best_k[sel, slot] = k
            found[sel] += 1
    return found, best_d, best_k, colour


def _blend_tile(shape, ok, found, best_d, best_k, colour, X, view_data, tol, o: OrthoOptions, reach: int):
    """Seamlines + multi-band blending of one (extended) tile: (rgb (h, w, 3) float32, labels (h, w))."""
    def grid(values, fill):
        g = np.full(shape + values.shape[1:], fill, dtype=values.dtype)
        g[ok] = values
        return g

    valid = grid(found > 0, False)
    l1, l2 = grid(best_k[:, 0], -1), grid(np.where(found == 2, best_k[:, 1], -1), -1)
    c1, c2 = grid(colour[:, 0], np.float32(0)), grid(colour[:, 1], np.float32(0))
    two = found == 2
    gap = np.full(len(found), np.inf)
    gap[two] = best_d[two, 1] - best_d[two, 0]
    margin_d = grid(gap, np.inf)
    in_band = (l2 >= 0) & (margin_d < o.seam_band_m)
    labels = refine_seams(l1, l2, margin_d, luminance(c1), luminance(c2), in_band, o.seam_band_m, valid)
    comp = np.where((labels == l2)[..., None] & (l2 >= 0)[..., None], c2, c1)
    present = [int(v) for v in np.unique(labels) if v >= 0]
    if len(present) < 2:
        return comp, labels
    # holes (no view) take their nearest seen colour so that the pyramids do not pull black in
    if not valid.all():
        idx = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
        comp = comp[idx[0], idx[1]]
    cell_of = np.full(shape, -1, np.int64)
    cell_of[ok] = np.arange(int(ok.sum()))
    diffs = {}
    for lab in present:
        rr_, cc_ = np.nonzero(labels == lab)
        # the label's region and its ring, cropped to their bounding box
        wr = slice(max(0, rr_.min() - reach - 1), min(shape[0], rr_.max() + reach + 2))
        wc = slice(max(0, cc_.min() - reach - 1), min(shape[1], cc_.max() + reach + 2))
        region = labels[wr, wc] == lab
        d = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, 3)
        ring = (d > 0) & (d <= reach) & valid[wr, wc]
        if not ring.any():
            continue
        I = np.full(region.shape + (3,), np.nan, np.float32)
        have1 = ring & (l1[wr, wc] == lab)
        have2 = ring & (l2[wr, wc] == lab)
        I[have1] = c1[wr, wc][have1]
        I[have2] = c2[wr, wc][have2]
        rest = ring & ~have1 & ~have2
        if rest.any():
            rr, cc = np.nonzero(rest)
            sel = cell_of[wr, wc][rr, cc]
            vd = view_data(lab)
            uv, z = vd.view.project_distorted(X[sel])
            vis = vd.visible(uv, z, tol)
            I[rr[vis], cc[vis]] = vd.sample(uv[vis])
        have = np.isfinite(I[..., 0])
        taper = np.clip((reach - d) / (reach / 3.0), 0.0, 1.0).astype(np.float32)
        D = np.zeros(shape + (3,), np.float32)
        D[wr, wc] = np.where(have[..., None], (I - comp[wr, wc]) * taper[..., None], 0.0)
        diffs[lab] = D
    rgb = multiband_blend(comp.astype(np.float32), labels, diffs, o.blend_levels)
    return rgb, labels
