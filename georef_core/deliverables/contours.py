"""Contour lines of an elevation surface at a chosen interval, index contours flagged.

How they are made (docs/deliverables.md, "Contours"):

1. The surface (surface.read_surface: heights with NaN for no-data) is smoothed by a Gaussian of
   ``smoothing_m`` (default 1.5 cells) with normalised convolution: only valid cells are averaged, so no-data
   neither spreads nor pulls heights down, and no-data cells stay no-data; within about two sigmas of no-data
   (and of the raster's border) the smoothed height is blended back to the cell's own, since a one-sided
   kernel's mean is biased on a slope. The smoothing removes the
   cell-to-cell noise of a photogrammetric DSM (a few centimetres) that would otherwise make every contour
   a saw-tooth and scatter small rings over flat ground; it moves a contour horizontally by about
   (sigma^2 / 2) * curvature / slope, bounded in the tests.
2. Contours are traced on the cell centres (marching squares, contourpy) at every multiple of the interval
   between the lowest and highest height; a cell square with a no-data corner is not traced: contours stop
   at no-data.
3. Lines shorter than ``min_length_m`` (default 4 cells; noise specks) are dropped, the rest simplified by
   Douglas-Peucker within ``simplify_m`` (default a quarter cell) horizontally.
4. Every ``index_every``-th level (multiples of index_every x interval from height 0) is an index contour.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ProcessingError
from .surface import Surface

NICE_INTERVALS_M = (0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 2.5, 5.0, 10.0, 20.0, 25.0, 50.0, 100.0)
MAX_LEVELS = 2000


@dataclass
class ContourLine:
    level_m: float
    index: bool
    xy_m: np.ndarray          # (n, 2) CRS coordinates
    closed: bool

    @property
    def length_m(self) -> float:
        return float(np.hypot(*np.diff(self.xy_m, axis=0).T).sum())


@dataclass
class ContourSet:
    lines: list[ContourLine]
    interval_m: float
    index_every: int
    smoothing_m: float
    surface: Surface
    levels_m: list[float] = field(default_factory=list)

    @property
    def index_interval_m(self) -> float:
        return self.interval_m * self.index_every

    def summary(self) -> dict:
        s = self.surface
        return {"source": str(s.path), "crs": s.crs_label(), "vertical_datum": s.vertical_datum,
                "interval_m": self.interval_m, "index_every": self.index_every,
                "index_interval_m": round(self.index_interval_m, 6), "smoothing_sigma_m": round(self.smoothing_m, 4),
                "grid_cell_m": round(s.cell_m, 4), "lines": len(self.lines),
                "index_lines": sum(1 for c in self.lines if c.index),
                "levels": len(self.levels_m), "length_m": round(sum(c.length_m for c in self.lines), 1)}


def auto_interval(z_m: np.ndarray, target_levels: int = 40) -> float:
    """The smallest round interval giving at most ``target_levels`` levels over the surface's 1-99 %
    height range."""
    v = z_m[np.isfinite(z_m)]
    lo, hi = np.percentile(v, [1, 99]) if v.size else (0.0, 0.0)
    relief = max(float(hi - lo), 1e-6)
    for i in NICE_INTERVALS_M:
        if relief / i <= target_levels:
            return i
    return NICE_INTERVALS_M[-1]


def smooth_surface(z_m: np.ndarray, sigma_cells: float) -> np.ndarray:
    """Gaussian smoothing by normalised convolution: NaN cells neither contribute nor get filled."""
    from scipy.ndimage import gaussian_filter

    if sigma_cells <= 0:
        return z_m.copy()
    valid = np.isfinite(z_m)
    num = gaussian_filter(np.where(valid, z_m, 0.0), sigma_cells, mode="constant", truncate=3.0)
    den = gaussian_filter(valid.astype(np.float64), sigma_cells, mode="constant", truncate=3.0)
    out = np.full(z_m.shape, np.nan)
    ok = valid & (den > 1e-6)
    out[ok] = num[ok] / den[ok]
    # next to no-data the kernel is one-sided and its mean is biased on a slope (slope x centroid shift: 4 cm
    # on a 45 % flank with a 0.4 m kernel): blend back to the cell's own height where less than 95 % of the
    # kernel's weight is valid (none at 50 %)
    w = np.clip((den - 0.5) / 0.45, 0.0, 1.0)
    out[ok] = w[ok] * out[ok] + (1.0 - w[ok]) * z_m[ok]
    return out


def _levels(zmin: float, zmax: float, interval_m: float) -> list[tuple[int, float]]:
    k0, k1 = math.ceil(zmin / interval_m - 1e-9), math.floor(zmax / interval_m + 1e-9)
    if k1 - k0 + 1 > MAX_LEVELS:
        raise ProcessingError(f"a {interval_m:g} m interval gives {k1 - k0 + 1} contour levels over heights "
                              f"{zmin:.2f} to {zmax:.2f} m (at most {MAX_LEVELS}): choose a larger interval")
    return [(k, round(k * interval_m, 9)) for k in range(k0, k1 + 1)]


def trace_contours(surface: Surface, interval_m: float | None = None, index_every: int = 5,
                   smoothing_m: float | None = None, min_length_m: float | None = None,
                   simplify_m: float | None = None) -> ContourSet:
    """Contours of ``surface`` every ``interval_m`` (None: auto_interval), see the module's description."""
    import contourpy
    import shapely

    if interval_m is None:
        interval_m = auto_interval(surface.z_m)
    if not (interval_m > 0 and math.isfinite(interval_m)):
        raise ProcessingError(f"contour interval {interval_m!r} m: must be a positive number")
    if index_every < 1:
        raise ProcessingError(f"index contour every {index_every} intervals: must be 1 or more")
    cell = surface.cell_m
    smoothing_m = 1.5 * cell if smoothing_m is None else float(smoothing_m)
    min_length_m = 4.0 * cell if min_length_m is None else float(min_length_m)
    simplify_m = 0.25 * cell if simplify_m is None else float(simplify_m)
    zs = smooth_surface(surface.z_m, smoothing_m / cell)
    finite = np.isfinite(zs)
    if not finite.any():
        raise ProcessingError(f"{surface.path}: no valid height to contour")
    levels = _levels(float(np.nanmin(zs)), float(np.nanmax(zs)), interval_m)
    # contourpy wants increasing y: flip the north-up rows
    x, y = surface.x_m, surface.y_m[::-1]
    gen = contourpy.contour_generator(x=x, y=y, z=np.ma.masked_invalid(zs[::-1]), line_type="Separate",
                                      corner_mask=True)
    lines: list[ContourLine] = []
    for k, level in levels:
        for seg in gen.lines(level):
            if len(seg) < 2:
                continue
            closed = bool(len(seg) > 3 and np.abs(seg[0] - seg[-1]).max() < 1e-9)
            length = float(np.hypot(*np.diff(seg, axis=0).T).sum())
            if length < min_length_m:
                continue
            if simplify_m > 0 and len(seg) > 3:
                geom = shapely.simplify(shapely.LineString(seg), simplify_m, preserve_topology=False)
                seg = np.asarray(geom.coords)
                if len(seg) < 2:
                    continue
            lines.append(ContourLine(level, k % index_every == 0, seg, closed))
    return ContourSet(lines, float(interval_m), int(index_every), smoothing_m, surface, [lv for _, lv in levels])


def label_positions(line: ContourLine, spacing_m: float, min_length_m: float) -> list[tuple[float, float, float]]:
    """Where an index contour's labels go: (x, y, rotation_deg) every ``spacing_m`` along the line (one at
    its middle when shorter), none when the line is shorter than ``min_length_m``; the text reads
    left to right (rotation within -90..90 degrees)."""
    xy = line.xy_m
    d = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    total = d[-1]
    if total < min_length_m:
        return []
    n = max(1, int(total // spacing_m))
    out = []
    for s in (np.arange(n) + 0.5) * total / n:
        i = int(np.clip(np.searchsorted(d, s) - 1, 0, len(xy) - 2))
        f = (s - d[i]) / max(d[i + 1] - d[i], 1e-12)
        p = xy[i] + f * (xy[i + 1] - xy[i])
        ang = math.degrees(math.atan2(xy[i + 1, 1] - xy[i, 1], xy[i + 1, 0] - xy[i, 0]))
        if ang > 90:
            ang -= 180
        elif ang < -90:
            ang += 180
        out.append((float(p[0]), float(p[1]), ang))
    return out


def format_level(level_m: float, interval_m: float) -> str:
    """A level as text with as many decimals as the interval needs (0.25 m -> 2 decimals)."""
    dec = 0
    while dec < 4 and abs(round(interval_m, dec) - interval_m) > 1e-9:
        dec += 1
    return f"{level_m:.{dec}f}"
