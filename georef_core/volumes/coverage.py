"""Exact fraction of each raster cell covered by a polygon.

Method (signed-area accumulation, exact for straight-edged polygons, holes and multipolygons):
in pixel coordinates (u to the right, v down, cell (i, j) = [j, j+1] x [i, i+1]) the covered length of
a horizontal line at height v inside row band i is the sum over the edges it crosses of signed
"is the cell point to the right of the edge" indicators. Integrating over the band, each piece of edge
inside a row band (height ``dv``, spanning u from ``u_lo`` to ``u_hi``) adds to cell j the signed
height times the mean fraction of that cell lying right of the piece,

    F(j) = (G(j + 1 - u_lo) - G(j + 1 - u_hi)) / (u_hi - u_lo),   G(x) = 0 | x^2/2 | x - 1/2
                                                                 (x <= 0 | 0 < x < 1 | x >= 1),

which is 0 left of the piece and 1 right of it. Storing the differences F(j) - F(j-1) ("deposits")
makes the coverage of a row the running sum of its deposits. Only O(perimeter in cells) deposits exist:
the interior (coverage exactly 1) and the exterior (0) cost nothing until cells are visited.

:class:`CellCoverage` holds the deposits row by row (CSR-like); ``dense()`` expands them, and the
volume kernel (:mod:`.integration`) walks them directly, one row at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .raster_io import GridWindow


@njit(cache=True, inline="always")
def _g_integral(x):
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return x - 0.5
    return 0.5 * x * x


@njit(cache=True, inline="always")
def _put(i, j, value, ncols, rows, cols, vals, n):
    if j >= ncols:
        return n
    if j < 0:
        j = 0  # a deposit left of the window adds to every cell of the row: same as at column 0
    rows[n] = i
    cols[n] = j
    vals[n] = value
    return n + 1


@njit(cache=True)
def _ring_deposits(u, v, nrows, ncols, rows, cols, vals, n):
    """Deposits of the closed ring (u[k], v[k]) (last point != first), appended from index n."""
    m = u.shape[0]
    for k in range(m):
        ua_, va_ = u[k], v[k]
        ub_, vb_ = u[(k + 1) % m], v[(k + 1) % m]
        if va_ == vb_:
            continue
        sign = 1.0 if vb_ > va_ else -1.0
        if va_ < vb_:
            ut, vt, vbot = ua_, va_, vb_
            dudv = (ub_ - ua_) / (vb_ - va_)
        else:
            ut, vt, vbot = ub_, vb_, va_
            dudv = (ua_ - ub_) / (va_ - vb_)
        i_start = max(int(math.floor(vt)), 0)
        i_end = min(int(math.ceil(vbot)), nrows)
        for i in range(i_start, i_end):
            v_lo = max(vt, float(i))
            v_hi = min(vbot, float(i + 1))
            if v_hi <= v_lo:
                continue
            u1 = ut + (v_lo - vt) * dudv
            u2 = ut + (v_hi - vt) * dudv
            d = sign * (v_hi - v_lo)
            lo = min(u1, u2)
            hi = max(u1, u2)
            if hi - lo < 1e-12:
                um = 0.5 * (lo + hi)
                j = int(math.floor(um))
                f = j + 1.0 - um  # fraction of cell j right of the (vertical) piece
                n = _put(i, j, d * f, ncols, rows, cols, vals, n)
                n = _put(i, j + 1, d * (1.0 - f), ncols, rows, cols, vals, n)
                continue
            j0 = int(math.floor(lo))
            j1 = int(math.floor(hi))
            inv = 1.0 / (hi - lo)
            js = max(j0, -1)
            f_prev = 0.0
            if js > j0:  # cells left of the window: their deposits telescope into one at column 0
                f_prev = (_g_integral(js - lo) - _g_integral(js - hi)) * inv
                n = _put(i, -1, d * f_prev, ncols, rows, cols, vals, n)
            je = min(j1, ncols - 1)
            for j in range(js, je + 1):
                f = (_g_integral(j + 1.0 - lo) - _g_integral(j + 1.0 - hi)) * inv
                n = _put(i, j, d * (f - f_prev), ncols, rows, cols, vals, n)
                f_prev = f
            if je == j1:
                n = _put(i, j1 + 1, d * (1.0 - f_prev), ncols, rows, cols, vals, n)
    return n


@njit(cache=True)
def _merge_sorted(rows, cols, vals):
    """Sum deposits with equal (row, col) (input sorted by row then col)."""
    n = rows.shape[0]
    k = -1
    for t in range(n):
        if k >= 0 and rows[t] == rows[k] and cols[t] == cols[k]:
            vals[k] += vals[t]
        else:
            k += 1
            rows[k] = rows[t]
            cols[k] = cols[t]
            vals[k] = vals[t]
    return k + 1


@njit(cache=True)
def _expand(row_ptr, cols, vals, nrows, ncols, out):
    for i in range(nrows):
        cov = 0.0
        j = 0
        for k in range(row_ptr[i], row_ptr[i + 1] + 1):
            jn = cols[k] if k < row_ptr[i + 1] else ncols
            w = min(max(cov, 0.0), 1.0)
            if w < 1e-12:
                w = 0.0
            for jj in range(j, jn):
                out[i, jj] = w
            if k < row_ptr[i + 1]:
                cov += vals[k]
            j = jn
    return out


@dataclass
class CellCoverage:
    """Coverage of a window's cells by a polygon, as per-row deposits (see the module docstring):
    the coverage of cell (i, j) is the sum of row i's deposits at columns <= j, clipped to [0, 1]."""

    nrows: int
    ncols: int
    row_ptr: np.ndarray  # int64, nrows + 1
    cols: np.ndarray  # int64
    vals: np.ndarray  # float64

    def dense(self, dtype=np.float32) -> np.ndarray:
        """Coverage fractions as a (nrows, ncols) array."""
        return _expand(self.row_ptr, self.cols, self.vals, self.nrows, self.ncols, np.zeros((self.nrows, self.ncols), dtype))

    def rows(self, row_start: int, nrows: int) -> "CellCoverage":
        """The coverage of rows [row_start, row_start + nrows) (a view on the same deposits)."""
        return CellCoverage(nrows, self.ncols, self.row_ptr[row_start:row_start + nrows + 1], self.cols, self.vals)

    def covered_area_cells(self) -> float:
        """Sum of the coverage fractions (polygon area inside the window, in cells)."""
        return float(self.dense(np.float64).sum())


def _pixel_rings(geom, window: GridWindow) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rings of ``geom`` in window pixel coordinates, oriented so the accumulated coverage is positive
    inside (exteriors with negative shoelace area in (u, v), holes positive)."""
    rings = []
    for part in getattr(geom, "geoms", [geom]):
        for idx, ring in enumerate([part.exterior, *part.interiors]):
            xy = np.asarray(ring.coords, dtype=float)[:-1, :2]
            if len(xy) < 3:
                continue
            u, v = window.to_pixel(xy[:, 0], xy[:, 1])
            area2 = float(np.sum(u * np.roll(v, -1) - np.roll(u, -1) * v))
            want_negative = idx == 0
            if (area2 < 0) != want_negative:
                u, v = u[::-1].copy(), v[::-1].copy()
            rings.append((np.ascontiguousarray(u), np.ascontiguousarray(v)))
    return rings


def polygon_coverage(geom, window: GridWindow) -> CellCoverage:
    """Exact coverage of ``window``'s cells by the shapely (Multi)Polygon ``geom`` (window's CRS)."""
    rings = _pixel_rings(geom, window)
    bound = 16
    for u, v in rings:
        du = np.abs(np.roll(u, -1) - u)
        vmax, vmin = np.maximum(v, np.roll(v, -1)), np.minimum(v, np.roll(v, -1))
        nv = np.maximum(np.minimum(np.ceil(vmax), window.nrows) - np.maximum(np.floor(vmin), 0), 0) + 1
        bound += int(np.sum(np.minimum(du + nv + 1, nv * (window.ncols + 3)) + 3 * nv + 4))
    rows = np.empty(bound, np.int64)
    cols = np.empty(bound, np.int64)
    vals = np.empty(bound, np.float64)
    n = 0
    for u, v in rings:
        n = _ring_deposits(u, v, window.nrows, window.ncols, rows, cols, vals, n)
    rows, cols, vals = rows[:n], cols[:n], vals[:n]
    order = np.lexsort((cols, rows))
    rows, cols, vals = rows[order], cols[order], vals[order]
    m = _merge_sorted(rows, cols, vals)
    rows, cols, vals = rows[:m], cols[:m], vals[:m]
    row_ptr = np.searchsorted(rows, np.arange(window.nrows + 1)).astype(np.int64)
    return CellCoverage(window.nrows, window.ncols, row_ptr, np.ascontiguousarray(cols), np.ascontiguousarray(vals))


def coverage_grid(geom, window: GridWindow, dtype=np.float32) -> np.ndarray:
    """Dense coverage fractions of ``window``'s cells by ``geom``."""
    return polygon_coverage(geom, window).dense(dtype)
