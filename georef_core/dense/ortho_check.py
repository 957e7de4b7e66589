"""Where checkerboard targets appear in an orthophoto, compared with their surveyed positions.

A 2 x 2 checker's centre is a saddle point of the image intensity; OpenCV's ``cornerSubPix`` finds it to a
fraction of a cell from a start a few cells away. The start is deliberately offset from the surveyed
position (so that a found centre is not just the start echoed back), and the four quadrants around the
surveyed centre along the target's own axes must show the checker pattern (diagonal quadrants alike,
neighbouring ones opposite), so that a shifted or blurred orthophoto is not credited with a target.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rasterio


@dataclass
class TargetOffset:
    name: str
    de_m: float  # found - surveyed, easting
    dn_m: float
    pattern_ok: bool  # the checker pattern is at the surveyed position
    contrast: float  # |mean(dark diagonal) - mean(bright diagonal)| (grey levels)

    @property
    def offset_m(self) -> float:
        return float(np.hypot(self.de_m, self.dn_m))


def read_targets(path) -> list[dict]:
    """Rows of a targets CSV with ``name, easting_m, northing_m`` and optional ``rotation_deg``, ``size_m``
    (the simulator's truth/targets.csv)."""
    with Path(path).open() as f:
        return list(csv.DictReader(f))


def target_offsets(ortho_path, targets: list[dict], start_offset_m=(0.12, -0.10), window_px: int = 5) -> list[TargetOffset]:
    with rasterio.open(ortho_path) as ds:
        img = ds.read()
        T = ds.transform
    rgb = np.ascontiguousarray(np.transpose(img[:3], (1, 2, 0)))
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    alpha = img[3] if img.shape[0] >= 4 else np.full(gray.shape, 255, np.uint8)
    h, w = gray.shape
    out = []
    for t in targets:
        e, n = float(t["easting_m"]), float(t["northing_m"])
        rot = np.radians(float(t.get("rotation_deg") or 0.0))
        size = float(t.get("size_m") or 1.0)
        q, inside = [], True
        for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            a, b = sx * size / 4, sy * size / 4
            c, r = ~T @ (e + a * np.cos(rot) - b * np.sin(rot), n + a * np.sin(rot) + b * np.cos(rot))
            ri, ci = int(np.floor(r)), int(np.floor(c))
            if not (0 <= ri < h and 0 <= ci < w) or alpha[ri, ci] == 0:
                inside = False
                break
            q.append(float(gray[ri, ci]))
        if not inside:
            out.append(TargetOffset(t["name"], float("nan"), float("nan"), False, 0.0))
            continue
        contrast = abs((q[0] + q[2]) - (q[1] + q[3])) / 2
        pattern_ok = abs(q[0] - q[2]) < 0.3 * contrast and abs(q[1] - q[3]) < 0.3 * contrast and contrast > 60
        c, r = ~T @ (e + start_offset_m[0], n + start_offset_m[1])
        start = np.array([[[c - 0.5, r - 0.5]]], np.float32)
        p = cv2.cornerSubPix(gray, start, (window_px, window_px), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4))[0, 0].astype(float)
        ef, nf = T @ (p[0] + 0.5, p[1] + 0.5)  # float64: map coordinates overflow float32's precision
        out.append(TargetOffset(t["name"], float(ef - e), float(nf - n), bool(pattern_ok), float(contrast)))
    return out


# ---- seams ----------------------------------------------------------------------------------------------

def seam_contrast(rgba: np.ndarray, labels: np.ndarray, reference: np.ndarray | None = None, reach_cells: int = 8,
                  interior_cells: int = 16, smooth_cells: float = 1.0) -> dict:
    """How visible the boundaries between views are in an orthophoto (the seam-contrast figure).

    The signal is the log luminance (in percent: 100 ln Y), smoothed by a Gaussian of ``smooth_cells``, or,
    with a ``reference`` orthophoto of the same grid (e.g. built from radiometrically perfect images of the
    same scene), the log of the ratio of the two luminances: then the texture cancels and only radiometric
    differences remain. Across every pair of 4-neighbour cells whose ``labels`` (the view each cell was
    taken from, -1: none) differ, the step is |mean signal of the ``reach_cells`` cells on one side - mean
    of the ``reach_cells`` cells on the other| along the row (or column) through the pair; the same
    statistic between cells inside one view's region (at least ``interior_cells`` from any boundary) is the
    level the image has anyway. Returns ``seam_step_percent`` and ``interior_step_percent`` (medians),
    ``seam_p90_percent``, ``ratio`` = seam / interior (1: boundaries as inconspicuous as the inside of an
    image) and the counts. Cells with alpha 0 (in either image) are left out. ``rgba``/``reference``: (4 or
    3, rows, cols) uint8."""
    from scipy import ndimage

    def log_lum(img):
        rgb = np.transpose(img[:3], (1, 2, 0)).astype(np.float32)
        y = rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114
        if smooth_cells > 0:
            y = cv2.GaussianBlur(y, (0, 0), smooth_cells)
        return 100.0 * np.log(np.maximum(y, 1.0))

    sig = log_lum(rgba)
    valid = (labels >= 0) & ((rgba[3] > 0) if rgba.shape[0] >= 4 else True)
    if reference is not None:
        sig = sig - log_lum(reference)
        if reference.shape[0] >= 4:
            valid &= reference[3] > 0
    boundary = np.zeros(labels.shape, bool)
    dh = (labels[:, 1:] != labels[:, :-1]) & valid[:, 1:] & valid[:, :-1]
    dv = (labels[1:, :] != labels[:-1, :]) & valid[1:, :] & valid[:-1, :]
    boundary[:, 1:] |= dh
    boundary[:, :-1] |= dh
    boundary[1:, :] |= dv
    boundary[:-1, :] |= dv
    far = ndimage.distance_transform_edt(~boundary) > interior_cells if boundary.any() else np.ones_like(boundary)
    k = int(reach_cells)
    steps, inner = [], []
    for axis in (1, 0):
        L = sig if axis == 1 else sig.T
        V = valid if axis == 1 else valid.T
        lab = labels if axis == 1 else labels.T
        F = far if axis == 1 else far.T
        n = L.shape[1]
        if n < 2 * k + 1:
            continue
        C = np.concatenate([np.zeros((L.shape[0], 1)), np.cumsum(L, axis=1, dtype=np.float64)], 1)
        Cv = np.concatenate([np.zeros((L.shape[0], 1)), np.cumsum(V, axis=1, dtype=np.float64)], 1)
        j = np.arange(k - 1, n - k)  # pair (j, j + 1): left cells j-k+1..j, right cells j+1..j+k
        step = np.abs((C[:, j + 1] - C[:, j + 1 - k]) - (C[:, j + 1 + k] - C[:, j + 1])) / k
        full = ((Cv[:, j + 1 + k] - Cv[:, j + 1 - k]) == 2 * k)
        a, b = lab[:, j], lab[:, j + 1]
        steps.append(step[(a != b) & full])
        inner.append(step[(a == b) & full & F[:, j] & F[:, j + 1]])
    s = np.concatenate(steps) if steps else np.zeros(0)
    i = np.concatenate(inner) if inner else np.zeros(0)
    ms = float(np.median(s)) if len(s) else float("nan")
    mi = float(np.median(i)) if len(i) else float("nan")
    return {"seam_step_percent": ms, "seam_p90_percent": float(np.percentile(s, 90)) if len(s) else float("nan"),
            "interior_step_percent": mi, "ratio": ms / mi if mi > 0 else float("nan"),
            "n_seam": int(len(s)), "n_interior": int(len(i))}


def ortho_inputs(run_dir, max_image_size: int = 1600) -> dict:
    """What ``build_orthophoto`` needs, rebuilt from a finished dense run (``RUN/oriented_images.json``,
    ``RUN/dense/dsm.tif``, ``RUN/dense/dense_summary.json``): to build the same run's orthophoto again with
    other options (benchmarks, tests). Keyword arguments of ``build_orthophoto`` except the options."""
    import json

    from .camera_views import views_from_oriented
    from .dsm_raster import NODATA, RasterGrid
    from ..photo.oriented_images import read_oriented_images

    run_dir = Path(run_dir)
    oriented = read_oriented_images(run_dir / "oriented_images.json")
    views = views_from_oriented(oriented, max_image_size)
    summary = json.loads((run_dir / "dense" / "dense_summary.json").read_text())
    with rasterio.open(run_dir / "dense" / "dsm.tif") as ds:
        dsm = ds.read(1).astype(np.float64)
        T = ds.transform
    dsm[dsm == NODATA] = np.nan
    grid = RasterGrid(float(T.c), float(T.f), float(T.a), dsm.shape[1], dsm.shape[0])
    ortho_res = (summary.get("ortho") or {}).get("resolution_m") or round(float(T.a) / 2, 4)
    ogrid = grid.with_resolution(float(ortho_res))
    frame = oriented.frame
    have = np.isfinite(dsm)
    E, N = grid.centres()
    step = max(1, int(np.sqrt(have.sum() / 20000)))
    sub = have[::step, ::step]
    enu = frame.grid_to_enu(E[::step, ::step][sub], N[::step, ::step][sub], dsm[::step, ::step][sub])
    lo, hi = np.percentile(enu[:, 2], [0.5, 99.5])
    depth = [float(v.centre_enu_m[2] - np.median(enu[:, 2])) for v in views]
    return {"views": views, "dsm": dsm, "dsm_grid": grid, "ortho_grid": ogrid, "frame": frame,
            "ground_up_range": (float(lo), float(hi)), "depth_med": depth}
