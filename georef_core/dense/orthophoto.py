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

from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .camera_views import CameraView
from ..project_frame import ProjectFrame
from .dsm_raster import RasterGrid


@dataclass
class OrthoOptions:
    feather_m: float = 1.0
    tile_cells: int = 512
    max_rank: int = 6  # views tried per cell (nearest centre points first)
    occlusion_tolerance_cells: float = 3.0  # depth tolerance of the z-buffer test, in DSM cells (+ 5 cm)
    image_cache: int = 16


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
                 bbox: tuple[float, float, float, float], depth_med: float):
        self.view = view
        self.image = view.read_image()
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
        n = len(uv)
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
                     depth_med: list[float], options: OrthoOptions | None = None, progress=None) -> np.ndarray:
    """RGBA (4, rows, cols) uint8 orthophoto on ``ortho_grid``."""
    o = options or OrthoOptions()
    report = progress or (lambda *a: None)
    boxes, centres = view_footprints(views, frame, *ground_up_range)
    usable = np.all(np.isfinite(boxes), axis=1) & np.all(np.isfinite(centres), axis=1)
    tol = o.occlusion_tolerance_cells * dsm_grid.resolution_m + 0.05
    out = np.zeros((4, ortho_grid.height, ortho_grid.width), np.uint8)
    cache: OrderedDict[int, _ViewData] = OrderedDict()
    sampler = DsmSampler(dsm, dsm_grid, frame)

    def view_data(k: int) -> _ViewData:
        if k in cache:
            cache.move_to_end(k)
            return cache[k]
        vd = _ViewData(views[k], sampler.enu, sampler.have, dsm_grid, tuple(boxes[k]), depth_med[k])
        cache[k] = vd
        if len(cache) > o.image_cache:
            cache.popitem(last=False)
        return vd

    T = o.tile_cells
    tiles = [(r0, c0) for r0 in range(0, ortho_grid.height, T)
             for c0 in (range(0, ortho_grid.width, T) if (r0 // T) % 2 == 0 else
                        reversed(range(0, ortho_grid.width, T)))]  # serpentine: neighbouring tiles share views
    for t_idx, (r0, c0) in enumerate(tiles):
        report("orthophoto", t_idx, len(tiles))
        rs, cs = slice(r0, min(r0 + T, ortho_grid.height)), slice(c0, min(c0 + T, ortho_grid.width))
        E, N = ortho_grid.centres(rs, cs)
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
        npts = len(e)
        found = np.zeros(npts, np.int8)  # views found so far (0..2)
        best_d = np.full((npts, 2), np.inf)
        colour = np.zeros((npts, 2, 3), np.float32)
        for rank in range(kmax):
            # a cell needs a first view, or a second one while it is within the feather band of the first
            need = np.nonzero((found == 0) | ((found == 1) & (dist[:, rank] - best_d[:, 0] < o.feather_m)))[0]
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
                found[sel] += 1
        rgb = colour[:, 0]
        two = found == 2
        if o.feather_m > 0 and two.any():
            w1 = np.clip(0.5 + (best_d[two, 1] - best_d[two, 0]) / (2.0 * o.feather_m), 0.5, 1.0)[:, None]
            rgb[two] = w1 * colour[two, 0] + (1.0 - w1) * colour[two, 1]
        tile = np.zeros((4,) + E.shape, np.uint8)
        seen = found > 0
        rr, cc = np.nonzero(ok)
        for b in range(3):
            tile[b, rr[seen], cc[seen]] = np.clip(np.rint(rgb[seen, b]), 0, 255).astype(np.uint8)
        tile[3, rr[seen], cc[seen]] = 255
        out[:, rs, cs] = tile
    report("orthophoto", len(tiles), len(tiles))
    return out
