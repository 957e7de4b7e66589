"""Heights along a polygon's outline, the raw material of every outline-derived base surface.

The whole outline is sampled, densified to about one DSM cell, not one pixel per vertex. Samples are
taken on the outline pushed ``offset`` outward (default 1.5 cells): a bilinear sample exactly on a
pile's toe mixes in the cells just inside it, which sit on the pile's flank (up to slope x cell/4 too
high, a 1-2 % volume error at 25 cm cells); 1.5 cells out, none of the four cells read is inside the
outline. Each exterior ring is sampled at equal arc-length steps plus its vertices (corners of the
outline matter to a triangulated base).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .raster_io import GridWindow


@dataclass
class OutlineSamples:
    """Samples along the (offset) outline: coordinates in the DSM CRS, heights (NaN where the DSM has
    no data), arc-length spacing and ring index of each sample (rings are closed profiles)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    ring: np.ndarray  # int, which exterior ring
    spacing_m: float
    offset_m: float

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.z)

    @property
    def n(self) -> int:
        return int(self.z.size)

    def valid_only(self) -> "OutlineSamples":
        m = self.valid
        return OutlineSamples(self.x[m], self.y[m], self.z[m], self.ring[m], self.spacing_m, self.offset_m)


def _ring_points(ring_xy: np.ndarray, spacing: float) -> np.ndarray:
    """Points at equal arc-length steps (about ``spacing``) along a closed ring, plus its vertices."""
    xy = ring_xy
    if np.allclose(xy[0], xy[-1]):
        xy = xy[:-1]
    closed = np.vstack([xy, xy[:1]])
    seg = np.hypot(np.diff(closed[:, 0]), np.diff(closed[:, 1]))
    s_vert = np.concatenate([[0.0], np.cumsum(seg)])
    length = s_vert[-1]
    n = max(int(np.ceil(length / spacing)), 8)
    s = np.unique(np.concatenate([np.linspace(0.0, length, n, endpoint=False), s_vert[:-1]]))
    px = np.interp(s, s_vert, closed[:, 0])
    py = np.interp(s, s_vert, closed[:, 1])
    return np.column_stack([px, py])


def offset_outline(geom, offset_m: float) -> list[np.ndarray]:
    """Exterior rings (as (n, 2) arrays) of ``geom`` grown outward by ``offset_m`` (mitred corners, so
    straight sides stay straight and corners stay corners)."""
    g = geom.buffer(offset_m, join_style="mitre", mitre_limit=3.0) if offset_m > 0 else geom
    parts = getattr(g, "geoms", [g])
    return [np.asarray(p.exterior.coords, dtype=float) for p in parts]


def bilinear(z: np.ndarray, window: GridWindow, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of cell-centre values at (x, y); NaN neighbours are left out (weights
    renormalised), NaN if all four are missing or the point is outside the window."""
    u, v = window.to_pixel(x, y)
    fu, fv = u - 0.5, v - 0.5
    j0, i0 = np.floor(fu).astype(np.int64), np.floor(fv).astype(np.int64)
    tu, tv = fu - j0, fv - i0
    acc = np.zeros(u.shape)
    wsum = np.zeros(u.shape)
    for di, dj, w in ((0, 0, (1 - tu) * (1 - tv)), (0, 1, tu * (1 - tv)), (1, 0, (1 - tu) * tv), (1, 1, tu * tv)):
        ii, jj = i0 + di, j0 + dj
        inside = (ii >= 0) & (ii < z.shape[0]) & (jj >= 0) & (jj < z.shape[1])
        val = np.full(u.shape, np.nan)
        val[inside] = z[ii[inside], jj[inside]]
        ok = np.isfinite(val) & (w > 0)
        acc[ok] += w[ok] * val[ok]
        wsum[ok] += w[ok]
    out = np.full(u.shape, np.nan)
    good = wsum > 1e-9
    out[good] = acc[good] / wsum[good]
    return out


def sample_outline(geom, window: GridWindow, read, spacing_m: float | None = None, offset_m: float | None = None,
                   tile: int = 256) -> OutlineSamples:
    """Heights along the outline of ``geom`` (DSM CRS); ``read(sub_window)`` returns the heights of a
    sub-window of ``window`` (from memory or from the file: only the tiles the outline crosses are read).
    Spacing and offset default to 1 and 1.5 cells."""
    cell = float(np.sqrt(window.cell_area_m2))
    spacing = cell if spacing_m is None else float(spacing_m)
    offset = 1.5 * cell if offset_m is None else float(offset_m)
    xs, ys, rs = [], [], []
    for k, ring in enumerate(offset_outline(geom, offset)):
        pts = _ring_points(ring, spacing)
        xs.append(pts[:, 0])
        ys.append(pts[:, 1])
        rs.append(np.full(len(pts), k))
    x, y = np.concatenate(xs), np.concatenate(ys)
    z = np.full(x.shape, np.nan)
    u, v = window.to_pixel(x, y)
    ti = np.floor(np.floor(v - 0.5) / tile).astype(np.int64)
    tj = np.floor(np.floor(u - 0.5) / tile).astype(np.int64)
    key = (ti + 1) * (window.ncols // tile + 3) + (tj + 1)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    for s0, s1 in zip(starts, np.r_[starts[1:], len(ks)]):
        m = order[s0:s1]
        a, b = ti[m[0]], tj[m[0]]
        r0, r1 = max(a * tile, 0), min(a * tile + tile + 1, window.nrows)
        c0, c1 = max(b * tile, 0), min(b * tile + tile + 1, window.ncols)
        if r1 <= r0 or c1 <= c0:
            continue
        sub = window.sub(r0, r1 - r0, c0, c1 - c0)
        z[m] = bilinear(read(sub), sub, x[m], y[m])
    return OutlineSamples(x, y, z, np.concatenate(rs), spacing, offset)


def block_means(samples: OutlineSamples, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A coarser outline: (x, y, z) means of runs of ``n`` consecutive valid samples along each ring, and
    for every sample the index of the run it went into (-1: no data)."""
    out = []
    group = np.full(samples.n, -1, np.int64)
    k0 = 0
    for k in np.unique(samples.ring):
        idx = np.flatnonzero((samples.ring == k) & samples.valid)
        step = n if len(idx) >= 3 * n else 1
        starts = np.arange(0, len(idx), step)
        pts = np.column_stack([samples.x[idx], samples.y[idx], samples.z[idx]])
        out.append(np.add.reduceat(pts, starts, axis=0) / np.diff(np.r_[starts, len(idx)])[:, None])
        group[idx] = k0 + np.arange(len(idx)) // step
        k0 += len(starts)
    return np.concatenate(out), group


def running_median_profile(samples: OutlineSamples, window_m: float) -> np.ndarray:
    """Heights smoothed by a running median along each closed ring (window about ``window_m``, at
    least 3 samples); NaN samples stay NaN and are left out of their neighbours' medians."""
    from scipy.ndimage import median_filter

    out = samples.z.copy()
    half = max(int(round(0.5 * window_m / samples.spacing_m)), 1)
    for k in np.unique(samples.ring):
        m = samples.ring == k
        zk = samples.z[m]
        ok = np.isfinite(zk)
        if ok.sum() < 2 * half + 1:
            continue
        zs = median_filter(zk[ok], size=2 * half + 1, mode="wrap")
        tmp = np.full(zk.shape, np.nan)
        tmp[ok] = zs
        out[m] = tmp
    return out
